"""Byte transports: how bytes reach a module, with no knowledge of TMCL framing.

Two shapes exist because the wire differs: a serial-like *stream* (RS232/RS485/USB, TCP,
RFC 2217, the in-process simulator) and a *CAN* bus of addressed 8-byte messages. The client
does the framing for each; a transport only moves bytes and maps its library's exceptions onto
``TransportError`` so the shell can say "port gone" the same way for every link.

Timeouts are float seconds with pyserial's meanings: None waits forever, 0 never waits.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, NamedTuple

if TYPE_CHECKING:
    from .framing import CanFraming, Owner, SerialFraming


class CanFrame(NamedTuple):
    """A CAN frame as a listener hears it (a bus, a log file): when (the bus's or the log's
    timestamp, in seconds), on which id, its data, and what kind of frame it is."""

    t: float
    arbitration_id: int
    data: bytes
    extended: bool = False
    error: bool = False
    remote: bool = False


class Transport(ABC):
    kind = "stream"  # or "can"
    simulated = False

    def framing(self, owner: Owner) -> SerialFraming | CanFraming:
        """The framing object that reads and writes frames on this wire for ``owner``."""
        raise NotImplementedError

    def __init__(self, url: str):
        self.url = url

    @abstractmethod
    def open(self) -> None: ...

    @abstractmethod
    def close(self) -> None: ...

    @property
    @abstractmethod
    def is_open(self) -> bool: ...

    def describe(self) -> str:
        """What the banner and toolbar call this link."""
        return self.url

    def __enter__(self) -> Transport:
        if not self.is_open:
            self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.url!r})"


class StreamTransport(Transport):
    kind = "stream"
    # when the last ``transact`` read took every byte the port held (``time.monotonic()``;
    # 0.0: not known), and how long one byte takes on the wire (0.0: bytes do not travel
    # at a known pace). A whole frame cannot have come since less than its wire time ago,
    # which spares the framing a look at the port before the next request.
    emptied = 0.0
    byte_time = 0.0
    sent_at = 0.0  # when the last ``transact`` had written its request (time.monotonic())

    @abstractmethod
    def write(self, data: bytes) -> None: ...

    @abstractmethod
    def read(self, size: int, timeout: float | None) -> bytes:
        """Up to ``size`` bytes: returns when ``size`` arrived or the timeout passed."""

    @abstractmethod
    def pending(self) -> int:
        """Bytes that can be read now without waiting."""

    def ready(self) -> bool:
        """Is anything to be read now (the client asks before every request, so a transport
        may answer it more cheaply than by counting the bytes)? True may also mean the line
        has something to say that a read will tell (a port hung up)."""
        return self.pending() > 0

    def transact(self, data: bytes, size: int, timeout: float | None) -> bytes:
        """``write(data)``, then ``read(size, timeout)``: the request path's common case in
        one call, so a transport can do it in fewer steps (the serial port's own descriptor).
        It may return more than ``size``: what had come behind the answer, read with it
        (then ``emptied`` says when the port was found empty)."""
        self.write(data)
        self.sent_at = time.monotonic()
        return self.read(size, timeout)

    def read_available(self) -> bytes:
        n = self.pending()
        return self.read(n, 0) if n else b""

    def read_some(self, timeout: float | None) -> bytes:
        """Whatever comes first, as soon as it comes: at least a byte, or b"" after
        ``timeout`` (a reader that forwards bytes as they arrive: the bridge)."""
        data = self.read(1, timeout)
        return data + self.read_available() if data else data

    def fileno(self) -> int | None:
        """The descriptor a caller may wait on with ``select`` until there is something to
        read (then ``read_some(0)``, which on such a port reads without a wait of its own),
        or None where the port has none (a pyserial URL, the in-process simulator): such a
        port is waited on by its own ``read_some``."""
        return None

    def set_baudrate(self, baud: int) -> None:  # pragma: no cover - only real ports
        raise NotImplementedError

    def framing(self, owner: Owner) -> SerialFraming:
        """How frames travel on this wire: nine-byte frames delimited by their checksum."""
        from .framing import SerialFraming

        return SerialFraming(self, owner)


class CanTransport(Transport):
    kind = "can"

    @abstractmethod
    def send(self, arbitration_id: int, data: bytes) -> None: ...

    @abstractmethod
    def recv(self, timeout: float | None) -> tuple[int, bytes] | None: ...

    def framing(self, owner: Owner) -> CanFraming:
        """How frames travel on this wire: seven data bytes to an id, replies on another."""
        from .framing import CanFraming

        return CanFraming(self, owner)
