"""python-can as a transport (socketcan, pcan, slcan, virtual, ...).

python-can is imported here and only here, when a CAN link is opened, so serial users never pay
for its import.
"""

from __future__ import annotations

from ..errors import TransportError
from .base import CanTransport


class PythonCanTransport(CanTransport):
    def __init__(self, interface: str, channel: str, bitrate: int | None = None, **kwargs):
        super().__init__(f"{interface}:{channel}")
        self.interface = interface
        self.channel = channel
        self.bitrate = bitrate
        self.kwargs = kwargs
        self._bus = None

    def open(self) -> None:
        import can

        kw = dict(self.kwargs)
        if self.bitrate:
            kw["bitrate"] = self.bitrate
        try:
            self._bus = can.Bus(interface=self.interface, channel=self.channel, **kw)
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            raise TransportError(f"cannot open CAN {self.url}: {exc}") from exc

    def close(self) -> None:
        if self._bus is not None:
            try:
                self._bus.shutdown()
            finally:
                self._bus = None

    @property
    def is_open(self) -> bool:
        return self._bus is not None

    def send(self, arbitration_id: int, data: bytes) -> None:
        import can

        if self._bus is None:
            raise TransportError(f"CAN {self.url} is not open")
        msg = can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)
        try:
            self._bus.send(msg)
        except can.CanError as exc:
            raise TransportError(f"CAN send failed on {self.url}: {exc}") from exc

    def recv(self, timeout: float | None) -> tuple[int, bytes] | None:
        import can

        if self._bus is None:
            raise TransportError(f"CAN {self.url} is not open")
        try:
            msg = self._bus.recv(timeout)
        except can.CanError as exc:
            raise TransportError(f"CAN receive failed on {self.url}: {exc}") from exc
        if msg is None:
            return None
        return msg.arbitration_id, bytes(msg.data)

    def describe(self) -> str:
        return f"CAN {self.url}"
