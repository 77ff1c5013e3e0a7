"""pyserial as a transport: device paths and every pyserial URL (socket://, rfc2217://,
loop://, spy://, hwgrep://). The read timeout is only reconfigured when it changes, because
pyserial re-applies termios settings on every change and that would dominate a round trip.
"""

from __future__ import annotations

import serial as pyserial

from ..errors import TransportError
from .base import StreamTransport


class SerialTransport(StreamTransport):
    def __init__(self, port: str, baudrate: int = 9600):
        super().__init__(port)
        self.baudrate = baudrate
        self._ser: pyserial.SerialBase | None = None
        self._timeout: float | None = -1.0

    def open(self) -> None:
        try:
            self._ser = pyserial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0,
                                                do_not_open=False)
        except (pyserial.SerialException, OSError, ValueError) as exc:
            raise TransportError(_friendly(self.url, exc)) from exc
        self._timeout = 0

    def close(self) -> None:
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:  # closing a vanished port must not mask the real error
                pass
            self._ser = None

    @property
    def is_open(self) -> bool:
        return self._ser is not None and self._ser.is_open

    def _port(self) -> pyserial.SerialBase:
        if self._ser is None:
            raise TransportError(f"{self.url} is not open")
        return self._ser

    def write(self, data: bytes) -> None:
        try:
            self._port().write(data)
        except (pyserial.SerialException, OSError) as exc:
            self.close()
            raise TransportError(f"{self.url}: write failed ({exc}); is the module unplugged?") from exc

    def read(self, size: int, timeout: float | None) -> bytes:
        ser = self._port()
        try:
            if timeout != self._timeout:
                ser.timeout = timeout
                self._timeout = timeout
            return ser.read(size)
        except (pyserial.SerialException, OSError) as exc:
            self.close()
            raise TransportError(f"{self.url}: read failed ({exc}); is the module unplugged?") from exc

    def pending(self) -> int:
        try:
            return self._port().in_waiting
        except (pyserial.SerialException, OSError) as exc:
            self.close()
            raise TransportError(f"{self.url}: port lost ({exc})") from exc

    def set_baudrate(self, baud: int) -> None:
        self.baudrate = baud
        if self._ser is not None:
            self._ser.baudrate = baud

    def describe(self) -> str:
        return f"{self.url} @ {self.baudrate}"


def _friendly(url: str, exc: Exception) -> str:
    text = str(exc)
    if "Permission denied" in text:
        return (f"cannot open {url}: permission denied; add yourself to the 'dialout' group "
                "(sudo usermod -aG dialout $USER, then log in again)")
    if "No such file" in text or "could not open port" in text:
        return f"cannot open {url}: no such port (see 'tmclsh ports')"
    return f"cannot open {url}: {text}"
