"""The built-in simulator, in process, behind the same byte interface as a serial port.

The client frames and parses exactly the bytes it would send to hardware, so the default
connection exercises the real protocol path.
"""

from __future__ import annotations

import time

from ..base.errors import TransportError
from .base import StreamTransport


class SimTransport(StreamTransport):
    """A ``Simulator`` (or a ``SimBus`` of them) as a stream.

    Without ``simulator`` one is created on ``open()`` (``sim_kw`` are its arguments, e.g.
    ``host_address``) and closed on ``close()``; a given simulator belongs to the caller and
    is left running.
    """

    simulated = True

    def __init__(self, module: str = "TMCM-1311", address: int = 1, simulator=None, **sim_kw):
        name = getattr(getattr(simulator, "module", None), "name", None) or module
        super().__init__(f"sim://{name}")
        self.module_name = name
        self.address = address
        self._sim_kw = sim_kw
        self.simulator = simulator
        self._owns = simulator is None
        self._buf = bytearray()
        self._open = simulator is not None

    def open(self) -> None:
        if self.simulator is None:
            from ..sim import Simulator

            try:
                self.simulator = Simulator(self.module_name, self.address,
                                           **self._sim_kw).bench_layout()
            except ValueError as exc:
                raise TransportError(f"cannot start the simulator: {exc}") from exc
        self._buf.clear()
        self._open = True

    def close(self) -> None:
        self._open = False
        if self._owns and self.simulator is not None:
            sim, self.simulator = self.simulator, None
            sim.close()

    @property
    def is_open(self) -> bool:
        return self._open

    def _sim(self):
        if not self._open or self.simulator is None:
            raise TransportError("the simulator is not running")
        return self.simulator

    def write(self, data: bytes) -> None:
        self._sim().write(bytes(data))

    def read(self, size: int, timeout: float | None) -> bytes:
        sim = self._sim()
        buf = self._buf
        if len(buf) < size:
            deadline = None if timeout is None else time.monotonic() + timeout
            while len(buf) < size:
                if deadline is None:
                    buf += sim.read(None)
                    continue
                left = deadline - time.monotonic()
                if left <= 0:
                    buf += sim.read(0)
                    break
                buf += sim.read(left)
        out = bytes(buf[:size])
        del buf[:size]
        return out

    def pending(self) -> int:
        self._buf += self._sim().read(0)
        return len(self._buf)

    def describe(self) -> str:
        return f"SIMULATED {self.module_name}"
