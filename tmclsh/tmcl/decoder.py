"""Recognising frames in a serial byte stream: the one reader of the serial framing.

A serial TMCL frame is nine bytes whose last is the 8-bit sum of the other eight; nothing else
marks where a frame starts. So a reader that lost its place (a byte lost or added on an RS485
line, noise, a partial frame) finds it again by sliding one byte at a time until nine bytes
add up. The client (replies), ``scan`` (what a probe got back), the trace and ``.decode``
(pasted bytes), the simulator (requests) and the ASCII mode probe all read frames this way,
through ``FrameDecoder`` or its test ``is_frame``; nothing else decides where a frame is.

Two refinements keep noise from being taken for a frame, which matters for replies:

* a reply to our host address must carry a TMCL status byte (1-6, 100, 101, 128), except a
  134 read-back, whose status byte holds a stored instruction's type;
* once bytes were no frame, a window that adds up but is addressed to another host is taken
  for more noise, not for another host's frame: noise that happens to add up (1 in 256) is
  likelier, and taking it whole would swallow the start of the reply behind it.

A reader that hears every host (a tap on a bus, a bridge: ``host`` None) has no address to
tell noise from a frame after it lost its place; it may say which windows are plausible
there instead (``resync``: a known command to a module, a status to a host), which keeps
noise that happens to add up from being shown as a frame.

A window the sum rejects may still be taken whole when the reader says so (``whole``): a
version string (136 type 0 answers eight ASCII characters and no checksum), or a damaged
request a module answers with status 1. Garbage that happens to form a valid frame cannot be
told from one; no reader can do better without a sequence number, which TMCL has not.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

from .status import Status

FRAME = 9  # bytes of a serial frame, either direction
NOISE, FRAME_PIECE, WHOLE = 0, 1, 2  # what a piece is
_STATUSES = frozenset(int(s) for s in Status)

Piece = tuple[int, bytes]  # (NOISE | FRAME_PIECE | WHOLE, the bytes)


def is_frame(window: bytes | bytearray, host: int | None = None, memory: bool = False) -> bool:
    """Do these nine bytes make a frame? The sum must check out; with ``host`` given, a
    reply to it must also carry a TMCL status byte (not a 134 read-back: ``memory``)."""
    # (the sum of the first eight is the ninth: the sum of all nine less the ninth twice is
    # 0 modulo 256, asked without cutting the window; once per reply)
    return (not (sum(window) - 2 * window[8]) & 0xFF
            and (host is None or memory or window[0] != host or window[2] in _STATUSES))


def printable(data: bytes | bytearray) -> bool:
    """All printable ASCII: what a version string is made of."""
    return all(32 <= b < 127 for b in data)


CAN_DATA = 7  # data bytes of a CAN request or reply: the serial frame without address and sum
CAN_VERSION = 8  # data bytes of a CAN version string (136 type 0): eight characters


def can_reply(data: bytes | bytearray, version: bool = True) -> bytes | None:
    """The reply a CAN frame's data carries, as every reader of CAN replies reads it (the
    client, the monitor, the bridge, ``.decode``): eight printable characters are a version
    string where one may be awaited (``version``); otherwise seven bytes are a reply, and
    so are the first seven of eight: some modules send DLC 8 (a TMCM-1260's candump shows
    it), the eighth their sum or padding. None: no TMCL reply has this length."""
    n = len(data)
    if n == CAN_DATA:
        return bytes(data)  # (bytes given are the bytes returned, not a copy)
    if n == CAN_VERSION:
        return bytes(data) if version and printable(data) else bytes(data[:CAN_DATA])
    return None


def is_version_string(window: bytes | bytearray, host: int) -> bool:
    """Nine bytes that can be a 136 type 0 answer to ``host``: its address, then eight
    printable characters (no checksum to tell more)."""
    return len(window) >= FRAME and window[0] == host and printable(window[1:FRAME])


class FrameDecoder:
    """Bytes in, frames and noise out, one piece at a time (no I/O).

    ``host``: replies to this host address are read (see the module docstring); None reads
    every window that adds up as a frame (requests, a tap on a bus, pasted bytes).
    ``buf`` holds what is not read yet; callers that read the wire append to it (``feed``).
    ``resync``: after bytes that were no frame, a window that adds up is taken only if
    ``resync(window)`` says it is plausible (a reader of every host's frames; see the module
    docstring); None takes every such window, as before.
    """

    __slots__ = ("buf", "host", "resync", "_after_noise", "_taken")

    def __init__(self, host: int | None = None,
                 resync: Callable[[bytes | bytearray], bool] | None = None):
        self.buf = bytearray()
        self.host = host
        self.resync = resync
        self._after_noise = False
        # ``whole`` accepted the window now at the head while noise came first: it is
        # returned next without asking again (``whole`` may count what it accepts)
        self._taken = False

    def feed(self, data: bytes | bytearray) -> None:
        self.buf += data

    def clear(self) -> None:
        """Forget what is buffered (the line was reset, or used in another mode)."""
        self.buf.clear()
        self._after_noise = self._taken = False

    def forget_noise(self) -> None:
        """A new read starts: noise before it does not make the next window suspect."""
        self._after_noise = False

    def next(self, *, memory: bool = False,
             whole: Callable[[bytearray], bool] | None = None) -> Piece | None:
        """The piece at the head of the buffer, consumed; None: more bytes are needed.

        A frame is ``(FRAME_PIECE, nine bytes)``; ``whole(buf)`` is asked about a head
        window that is no frame (its first nine bytes; the rest of ``buf`` lies ahead) and
        may take it as ``(WHOLE, nine bytes)`` (``buf`` is the window and up to nine bytes
        after it, so a look ahead stays linear on a flood of bytes); bytes that start
        neither come back as one
        ``(NOISE, run)``, ended by the next frame or by the buffer running short.
        ``memory``: a 134 read-back is expected, whose status byte is no status.
        """
        buf, host = self.buf, self.host
        if self._taken:
            self._taken = self._after_noise = False
            window = bytes(buf[:FRAME])
            del buf[:FRAME]
            return WHOLE, window
        start = 0
        n = len(buf)
        while n - start >= FRAME:
            window = buf[start:start + FRAME]
            suspect = self._after_noise or start  # (bytes that were no frame came first)
            if is_frame(window, host, memory) and (
                    host is None or window[0] == host or not suspect) and (
                    self.resync is None or not suspect or self.resync(window)):
                kind = FRAME_PIECE
            elif whole is not None and whole(buf[start:start + 2 * FRAME]):
                kind = WHOLE
            else:
                start += 1
                self._after_noise = True
                continue
            if start:
                self._taken = kind == WHOLE
                break  # the noise before it first
            del buf[:FRAME]
            self._after_noise = False
            return kind, bytes(window)
        if not start:
            return None
        run = bytes(buf[:start])
        del buf[:start]
        return NOISE, run

    def settle(self) -> Piece | None:
        """Nothing more is coming for now: after noise, the bytes left that cannot start a
        reply to our host are noise too (the rest of a damaged reply)."""
        if not self._after_noise or self.host is None:
            return None
        buf = self.buf
        k = 0
        while k < len(buf) and buf[k] != self.host:
            k += 1
        if not k:
            return None
        run = bytes(buf[:k])
        del buf[:k]
        return NOISE, run

    def rest(self) -> bytes:
        """Take what is left (a partial frame that will not be completed)."""
        run = bytes(self.buf)
        self.clear()
        return run


def pieces(data: bytes, host: int | None = None) -> Iterator[Piece]:
    """Every piece of a finished byte string (pasted bytes, a capture): frames, and the
    noise between and after them, adjacent noise as one run."""
    dec = FrameDecoder(host)
    dec.feed(data)
    pending = b""
    while True:
        piece = dec.next()
        if piece is None:
            break
        if piece[0] == NOISE:
            pending += piece[1]
            continue
        if pending:
            yield NOISE, pending
            pending = b""
        yield piece
    pending += dec.rest()
    if pending:
        yield NOISE, pending
