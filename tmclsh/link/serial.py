"""pyserial as a transport: device paths and every pyserial URL (socket://, rfc2217://,
loop://, spy://, hwgrep://).

pyserial opens and configures every port. For a plain POSIX device (a tty or pty, the common
case and the hot path of every round trip) reads and writes then go straight to its file
descriptor with ``os.read``/``os.write`` and ``select``, which is what pyserial's own
``read``/``write`` do underneath, minus about 8 us of per-call bookkeeping; on Linux the
request path's looks at the descriptor (anything waiting before the request, the reply's
arrival) go through an epoll registered once. The reply's read takes whatever came behind it
too, so the look before the next request is needed only once a frame could have come since
(``StreamTransport.emptied``, ``SerialFraming.waiting``). Everything else
(URL handlers, Windows) goes through pyserial's ``read``/``write``.

pyserial re-applies the termios settings (and the exclusive lock) whenever ``timeout``
changes, which would cost more than a whole round trip; so on that path the read timeout is
only set when it differs from the last one, and the client asks with the same timeout for the
first read of every transaction.
"""

from __future__ import annotations

import os
import select
import sys
import time
from urllib.parse import urlsplit

import serial as pyserial

from ..base.canspec import LINK_DEFAULTS
from ..base.errors import TransportError
from .base import StreamTransport

try:  # bytes waiting on a POSIX descriptor (what pyserial's in_waiting asks, minus its layers)
    import fcntl
    import termios

    _FIONREAD: int | None = termios.FIONREAD
except ImportError:  # pragma: no cover - Windows: pyserial's in_waiting
    _FIONREAD = None
# Linux: the descriptor registered once and asked with epoll, a third of what select's sets
# or a FIONREAD ioctl cost per call (asked for the reply, and whether anything waits before a
# request that does not follow a reply closely)
_EPOLL = getattr(select, "epoll", None)
_FOUR_ZEROS = bytes(4)
# what transact's one read asks for: the answer and whatever came behind it, so the framing
# sees a copy that came right behind a reply without looking at the port again
_READ_ALL = 256  # (a small read: what Python allocates for it is dearer beyond 512 bytes)
_BYTEORDER = sys.byteorder  # (asked before every request)

WRITE_TIMEOUT = 2.0  # a write that cannot finish in this time means the port is stuck


def is_url(port: str) -> bool:
    return "://" in port


class SerialTransport(StreamTransport):
    # a listener (a tap on a bus): RTS and DTR are left inactive when the port opens, so an
    # RS485 adapter that switches its driver on RTS never drives the line
    listen_only = False

    def __init__(self, port: str, baudrate: int = LINK_DEFAULTS["baud"]):  # type: ignore[assignment]
        super().__init__(port)
        if not isinstance(baudrate, int) or baudrate <= 0:
            raise ValueError(f"baud rate must be a positive number, got {baudrate!r}")
        self.baudrate = baudrate
        self.byte_time = 10 / baudrate  # start bit, 8 data bits, stop bit
        self._ser: pyserial.SerialBase | None = None
        self._fd: int | None = None  # set when reads and writes may use the descriptor
        self._poll: select.epoll | None = None  # the descriptor's epoll (Linux), with _fd
        self._timeout: float | None = 0.0

    def open(self) -> None:
        if self._ser is not None:
            return
        kw: dict = {"baudrate": self.baudrate, "timeout": 0, "write_timeout": WRITE_TIMEOUT}
        if not is_url(self.url):
            # two programs on one port steal each other's replies: refuse the second
            kw["exclusive"] = True
        try:
            try:
                self._ser = ser = self._open(kw)
            except NotImplementedError:
                # rfc2217:// has no write timeout; its writes are bounded by the TCP socket
                del kw["write_timeout"]
                self._ser = ser = self._open(kw)
        except (pyserial.SerialException, OSError, ValueError) as exc:
            raise TransportError(_friendly(self.url, exc)) from exc
        self._timeout = 0
        # pyserial's POSIX port opens the descriptor non-blocking and reads it with select
        fd = getattr(ser, "fd", None)
        self._fd = fd if os.name == "posix" and type(ser) is pyserial.Serial \
            and isinstance(fd, int) else None
        if self._fd is not None and _EPOLL is not None:
            try:
                poll = _EPOLL(1)
                poll.register(self._fd, select.EPOLLIN)
            except OSError:  # (out of descriptors: select and the ioctl still do the job)
                pass
            else:
                self._poll = poll

    def _open(self, kw: dict) -> pyserial.SerialBase:
        if not self.listen_only or is_url(self.url):
            return pyserial.serial_for_url(self.url, **kw)
        ser = pyserial.serial_for_url(self.url, do_not_open=True, **kw)
        ser.rts = ser.dtr = False  # (applied as the port opens)
        ser.open()
        return ser

    def close(self) -> None:
        ser, self._ser = self._ser, None
        self._fd = None
        self.emptied = 0.0
        poll, self._poll = self._poll, None
        if poll is not None:
            poll.close()
        if ser is not None:
            try:
                ser.close()
            except Exception:  # closing a vanished port must not mask the real error
                pass

    @property
    def is_open(self) -> bool:
        # (a descriptor is kept only while the port is open: close() drops it; asked twice
        # per script line, so pyserial's own property is left for the other ports)
        return self._fd is not None or (self._ser is not None and self._ser.is_open)

    def _port(self) -> pyserial.SerialBase:
        if self._ser is None:
            raise TransportError(f"{self.url} is not open")
        return self._ser

    def _lost(self, what: str, exc: Exception) -> TransportError:
        self.close()
        reason = str(exc)
        if not reason.lower().startswith(what):  # pyserial often says "read failed: ..." itself
            reason = f"{what} failed: {reason}"
        gone = f"lost {self.url} ({reason}); the port is gone (module unplugged or powered off?)"
        err = TransportError(f"{gone}. Reconnect once it is back.")
        err.lost = gone  # type: ignore[attr-defined]  # (no advice: the bridge ends with it)
        return err

    def write(self, data: bytes) -> None:
        self.emptied = 0.0  # (what this asks for may come at once: the port is looked at)
        fd = self._fd
        if fd is not None:
            try:
                n = os.write(fd, data)
            except BlockingIOError:
                n = 0  # output buffer full: pyserial waits for room (up to WRITE_TIMEOUT)
            except OSError as exc:
                raise self._lost("write", exc) from exc
            if n == len(data):
                return
            data = data[n:]
        try:
            self._port().write(data)
        except pyserial.SerialTimeoutException as exc:
            raise TransportError(f"{self.url}: write timed out after {WRITE_TIMEOUT:g} s "
                                 "(flow control stuck?)") from exc
        except (pyserial.SerialException, OSError) as exc:
            raise self._lost("write", exc) from exc

    def read(self, size: int, timeout: float | None) -> bytes:
        fd = self._fd
        if fd is not None:
            return self._read_fd(fd, size, timeout)
        ser = self._port()
        try:
            if timeout != self._timeout:
                ser.timeout = timeout
                self._timeout = timeout
            return ser.read(size)
        except (pyserial.SerialException, OSError) as exc:
            raise self._lost("read", exc) from exc

    def transact(self, data: bytes, size: int, timeout: float | None) -> bytes:
        fd = self._fd
        if fd is None:
            return super().transact(data, size, timeout)
        try:  # (write's common case, written out: once per request)
            n = os.write(fd, data)
        except BlockingIOError:
            n = 0  # output buffer full: write() waits for room as pyserial does
        except OSError as exc:
            raise self._lost("write", exc) from exc
        if n != len(data):
            self.write(data[n:])
        # the reply mostly comes whole: one wait, one read; anything else as read() does it
        self.sent_at = start = time.monotonic()
        poll = self._poll
        try:
            if poll is not None:
                ready = poll.poll(-1 if timeout is None else timeout)
            else:
                ready = select.select((fd,), (), (), timeout)[0]
        except (OSError, ValueError) as exc:
            raise self._lost("read", exc) from exc
        if not ready:
            self.emptied = 0.0
            return b""  # timed out
        try:
            got = os.read(fd, _READ_ALL)
        except BlockingIOError:
            got = bytes()  # (select saw it readable and something else took it: wait on)
        except OSError as exc:
            raise self._lost("read", exc) from exc
        else:
            if not got:
                raise self._lost("read", OSError("device reports readiness to read but "
                                                 "returned no data"))
        if len(got) >= size:
            # a read that got less than it asked for took all there was; the port was empty
            # then, which is no earlier than the wait began (the time taken: no clock read
            # between a reply and the next request)
            self.emptied = start if len(got) < _READ_ALL else 0.0
            return got
        self.emptied = 0.0
        left = None if timeout is None else max(0.0, timeout - (time.monotonic() - start))
        return got + self._read_fd(fd, size - len(got), left)

    def _read_fd(self, fd: int, size: int, timeout: float | None) -> bytes:
        """pyserial's POSIX ``read`` with the same meaning of ``timeout``."""
        deadline = None if timeout is None else time.monotonic() + timeout
        wait = timeout
        data = b""
        while True:
            chunk = None
            try:
                ready = select.select((fd,), (), (), wait)[0]
            except (OSError, ValueError) as exc:
                raise self._lost("read", exc) from exc
            if ready:
                try:
                    chunk = os.read(fd, size - len(data))
                except BlockingIOError:
                    pass
                except OSError as exc:
                    raise self._lost("read", exc) from exc
                if chunk == b"":
                    # a vanished USB device stays readable and reads nothing (as pyserial says)
                    raise self._lost("read", OSError("device reports readiness to read but "
                                                     "returned no data"))
                if chunk:
                    data += chunk
                    if len(data) >= size:
                        return data
            if deadline is not None:
                wait = deadline - time.monotonic()
                if wait <= 0:
                    if not chunk:
                        return data  # timed out
                    wait = 0  # one more look at what is there already

    def read_some(self, timeout: float | None) -> bytes:
        fd = self._fd
        if fd is None:
            return super().read_some(timeout)
        if timeout != 0:  # (0: the caller's own wait found it readable, the bridge's)
            try:
                ready = select.select((fd,), (), (), timeout)[0]
            except (OSError, ValueError) as exc:
                raise self._lost("read", exc) from exc
            if not ready:
                return b""
        try:
            data = os.read(fd, 4096)
        except BlockingIOError:
            return b""
        except OSError as exc:
            raise self._lost("read", exc) from exc
        if not data:  # (as _read_fd: a vanished USB device stays readable, reads nothing)
            raise self._lost("read", OSError("device reports readiness to read but "
                                             "returned no data"))
        return data

    def fileno(self) -> int | None:
        return self._fd

    def ready(self) -> bool:
        poll = self._poll
        if poll is None:
            return self.pending() > 0
        # (readable, or hung up: what a read then says, as select would have it)
        try:
            return bool(poll.poll(0))
        except (OSError, ValueError) as exc:  # (ValueError: closed meanwhile)
            raise self._lost("status query", exc) from exc

    def pending(self) -> int:
        fd = self._fd
        if fd is not None and _FIONREAD is not None:
            # one ioctl, without pyserial's layers (before every request where no epoll is)
            try:
                return int.from_bytes(fcntl.ioctl(fd, _FIONREAD, _FOUR_ZEROS), _BYTEORDER)
            except OSError as exc:
                raise self._lost("status query", exc) from exc
        try:
            return self._port().in_waiting
        except (pyserial.SerialException, OSError) as exc:
            raise self._lost("status query", exc) from exc

    def set_baudrate(self, baud: int) -> None:
        self.baudrate = baud
        self.byte_time = 10 / baud if baud > 0 else 0.0
        if self._ser is not None:
            try:
                self._ser.baudrate = baud
            except (pyserial.SerialException, OSError, ValueError) as exc:
                raise TransportError(f"{self.url}: cannot set {baud} baud: {exc}") from exc

    def describe(self) -> str:
        if is_url(self.url) and not self.url.startswith(("rfc2217://", "spy://", "hwgrep://")):
            return self.url  # socket://, loop://: a baud rate means nothing there
        return f"{self.url} @ {self.baudrate}"


def _friendly(url: str, exc: Exception) -> str:
    text = str(exc)
    if "Permission denied" in text:
        return (f"cannot open {url}: permission denied; add yourself to the 'dialout' group "
                "(sudo usermod -aG dialout $USER, then log in again)")
    if "Could not exclusively lock" in text or "Resource temporarily unavailable" in text:
        return f"cannot open {url}: the port is in use by another program"
    if "No such file" in text:
        return f"cannot open {url}: no such port (see 'tmclsh ports')"
    if "Inappropriate ioctl" in text:  # (ENOTTY: a regular file, /dev/null)
        return f"cannot open {url}: not a serial port (see 'tmclsh ports')"
    if "Connection refused" in text:
        return f"cannot open {url}: connection refused (is the server running?)"
    where = _network_address(url)
    if where is not None:
        return f"cannot open {url}: {where}"
    if any(s in text for s in _NO_SUCH_HOST):
        host = urlsplit(url).hostname
        return f"cannot open {url}: no host named {host!r} is known (a typo, or no network?)"
    # pyserial repeats the URL in its own words: said once
    text = text.removeprefix(f"Could not open port {url}: ")
    return f"cannot open {url}: {text}"


# how a failed name lookup reads on Linux, macOS and Windows
_NO_SUCH_HOST = ("Name or service not known", "nodename nor servname", "getaddrinfo failed",
                 "No address associated", "Temporary failure in name resolution")


def _network_address(url: str) -> str | None:
    """What is wrong with a socket:// or rfc2217:// URL's host and port, in words: pyserial
    reports a missing or impossible port number with text from its own internals."""
    scheme = url.partition("://")[0].lower()
    if scheme not in ("socket", "rfc2217"):
        return None
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:
        if "Port" in str(exc):
            return f"the port must be a number 1..65535 ({scheme}://HOST:PORT)"
        return f"not a valid address ({exc}); give {scheme}://HOST:PORT"
    if not parts.hostname:
        return f"no host: give {scheme}://HOST:PORT"
    if port is None:
        return f"no port number: give {scheme}://HOST:PORT"
    if not 0 < port < 65536:
        return f"the port must be a number 1..65535 ({scheme}://HOST:PORT)"
    return None
