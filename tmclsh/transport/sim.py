"""The built-in simulator, in process, behind the same byte interface as a serial port.

The client frames and parses exactly the bytes it would send to hardware, so the default
connection exercises the real protocol path.
"""

from __future__ import annotations

from ..errors import TransportError
from .base import StreamTransport


class SimTransport(StreamTransport):
    simulated = True

    def __init__(self, module: str = "TMCM-1311", address: int = 1, simulator=None, **sim_kw):
        super().__init__(f"sim://{module}")
        self.module_name = module
        self.address = address
        self._sim_kw = sim_kw
        self.simulator = simulator
        self._owns = simulator is None
        self._buf = bytearray()
        self._open = simulator is not None

    def open(self) -> None:
        if self.simulator is None:
            from ..sim import Simulator

            self.simulator = Simulator(self.module_name, address=self.address, **self._sim_kw)
        self._open = True

    def close(self) -> None:
        if self._owns and self.simulator is not None:
            self.simulator.close()
            self.simulator = None
        self._open = False

    @property
    def is_open(self) -> bool:
        return self._open

    def write(self, data: bytes) -> None:
        if not self._open or self.simulator is None:
            raise TransportError("simulator is not running")
        self.simulator.write(bytes(data))

    def read(self, size: int, timeout: float | None) -> bytes:
        if self.simulator is None:
            raise TransportError("simulator is not running")
        import time

        deadline = None if timeout is None else time.monotonic() + timeout
        while len(self._buf) < size:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            chunk = self.simulator.read(left)
            if chunk:
                self._buf += chunk
            elif left is not None and left <= 0:
                break
            elif deadline is not None and time.monotonic() >= deadline:
                break
        out = bytes(self._buf[:size])
        del self._buf[:size]
        return out

    def pending(self) -> int:
        if self.simulator is not None:
            self._buf += self.simulator.read(0)
        return len(self._buf)

    def describe(self) -> str:
        return f"SIMULATED {self.module_name}"
