"""Frames on a wire: one framing object per wire shape, so the client never branches on the
link type.

A serial byte stream (RS232/RS485/USB, TCP, the in-process simulator) carries nine-byte
frames that only their checksum delimits (tmcl/decoder.py reads them); a CAN bus carries
addressed messages of seven data bytes. Each framing here writes a request, reads until the
reply that answers it, and takes in what comes meanwhile: 138 events are handed to the
client, late and unsolicited replies are written into its ledger, bytes that are no frame
are dropped and traced. The serial framing owns the request path's fast path: the common
case (nine bytes back that answer the request) is one ``transact`` call and a dictionary
lookup.

A framing is made by its transport (``Transport.framing``) for an owner, the client, whose
observers (tracers, counters, event queue) and ledger it writes to; it holds no other state
than the bytes read and not yet used.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Protocol

from ..base.errors import ChecksumError, TmclTimeoutError
from ..tmcl.decoder import (CAN_VERSION, FRAME, FRAME_PIECE, NOISE, FrameDecoder, can_reply,
                            is_frame, is_version_string)
from ..tmcl.frames import Control, Reply, ReplyKind, Request, Status
from .modes import BINARY

if TYPE_CHECKING:
    from collections.abc import Callable

    from .base import CanTransport, StreamTransport

_NORMAL, _VERSION, _MEMORY, _NONE = (ReplyKind.NORMAL, ReplyKind.VERSION_STRING,
                                     ReplyKind.MEMORY, ReplyKind.NONE)
_EVENT = int(Status.EVENT)
_OK = int(Status.OK)
_TARGET_REACHED = int(Control.TARGET_REACHED_EVENT)
_CAN_REPLY_LEN = 7
# After bytes that were no frame, how long a silent line is given to bring the rest of the
# reply before it is called corrupted (instead of waiting out the whole timeout).
QUIET_AFTER_GARBAGE = 0.05
# Download mode cannot use a marker: the line is waited on until it has been quiet this long.
DRAIN_QUIET = 0.03
_SEEN_REPLIES = 512  # distinct reply frames kept as Reply objects (the fast path)


class Owner(Protocol):
    """What a framing needs of the client it reads for."""

    host_address: int
    _downloading: bool
    can_id: int
    reply_id: int
    _also_from: int | None  # (client/reach.py: an answer from the new address is the answer)
    _also_host: int | None
    _also_reply_id: int | None
    _other_reply_ids: frozenset[int]  # more ids replies come on (a CAN bootloader's 0x7FF)
    stats: dict[str, int]
    _tracers: list  # (a framing asks whether any is there before it builds a trace's words)
    _sent_tracers: list  # tracers of requests only (add_tracer(sent_only=True))
    _sent_wanted: frozenset[int]  # the commands some sent-only tracer watches

    def _tell(self, direction: str, raw: bytes, decoded: object) -> None: ...

    def _trace_sent(self, raw: bytes, req: Request) -> None: ...

    def _discard(self, raw: bytes, why: str) -> None: ...

    def _event(self, raw: bytes, reply: Reply) -> None: ...

    def _late(self, address: int, opcode: int, reply: Reply | None) -> bool: ...

    def _noise_unsolicited(self) -> None: ...

    def _accept_version(self, window: bytes) -> bool: ...


def name_of(req: Request) -> str:
    """A request's command in words, for errors (``GAP``, ``136 (get version)``)."""
    from ..tmcl.instructions import by_opcode

    spec = by_opcode(req.opcode)
    if spec is not None:
        return spec.mnemonic
    try:
        return f"{req.opcode} ({Control(req.opcode).name.lower().replace('_', ' ')})"
    except ValueError:
        return f"command {req.opcode}"


def _echo_of(raw: bytes, seen: bytes) -> bool:
    """Are the first nine bytes of ``seen`` the request ``raw`` itself, one byte damaged at
    most (what an RS485 adapter that hears its own transmission gives back)?"""
    return len(seen) >= FRAME and sum(a != b for a, b in zip(raw, seen)) <= 1


class SerialFraming:
    """Nine-byte frames on a byte stream, read through the one frame decoder."""

    mode = BINARY  # (Client.mode: the facts of the mode this framing talks)

    def __init__(self, transport: StreamTransport, owner: Owner):
        self.transport = transport
        self.owner = owner
        self.decoder = FrameDecoder(owner.host_address)
        self._seen: dict[bytes, Reply] = {}  # frame -> Reply (the fast path)
        self._ready: Callable[[], bool] = transport.ready

    # -- what waits --------------------------------------------------------------------
    def waiting(self) -> bool:
        """Is anything waiting to be read (one cheap check before a request)? The port is
        not asked when the last reply's read took all it held less than a frame's wire
        time ago: whatever has come since is no whole frame yet (what came behind the
        reply was read with it and waits in the decoder; a run of requests at the line's
        pace is spared a system call per request)."""
        if self.decoder.buf:
            return True
        t = self.transport
        emptied = t.emptied
        if emptied and time.monotonic() - emptied < FRAME * t.byte_time:
            return False
        return self._ready()

    def clear(self) -> None:
        """Forget what is buffered (the line was in another mode, or reset)."""
        self.decoder.clear()

    def refusal(self, req: Request) -> str | None:
        """Why ``req`` cannot be sent on this framing (None: it can; every request fits in a
        frame; the ASCII framing's refuses what the module's ASCII mode does not know)."""
        return None

    def quiet_time(self) -> float:
        """How long a line must be silent before nothing more is on its way: two frames'
        wire time at its baud rate (0 where bytes do not travel at one)."""
        t = self.transport
        if t.simulated:
            return 0.0
        baud = getattr(t, "baudrate", None)
        frame = 10 * FRAME / baud if isinstance(baud, (int, float)) and baud else 0.01
        return 2 * frame + 0.005

    # -- a request and its reply --------------------------------------------------------
    def exchange(self, req: Request, kind: ReplyKind, timeout: float,
                 absorb: bool = True) -> Reply | None:
        """Send ``req``, return its reply (None for a command without one)."""
        t = self.transport
        o = self.owner
        if kind != _NORMAL and absorb:
            # these layouts take any well-formed frame: clear out what is already here
            self.absorb()
        raw = req.to_bytes()
        if o._sent_tracers and req.opcode in o._sent_wanted:
            o._trace_sent(raw, req)
        dec = self.decoder
        host = dec.host = o.host_address  # (the client's may change between requests)
        buf = dec.buf
        tracing = o._tracers
        if buf or kind == _NONE or tracing:
            deadline = time.monotonic() + timeout
            t.write(raw)
            o.stats["sent"] += 1
            if tracing:
                o._tell("tx", raw, req)  # (when it goes: the trace shows the time)
            if kind == _NONE:
                return None
            # the first read uses the client's timeout, so a pyserial URL port is not
            # reconfigured
            head = b"" if buf else t.read(FRAME, timeout)
        else:
            o.stats["sent"] += 1
            # (more than nine bytes: what had come behind the reply was read with it; the
            # decoder below reads them frame by frame, and what is left behind the answer
            # is taken in before the next request, as what waits then is)
            head = t.transact(raw, FRAME, timeout)
            # (the deadline from when the request went, t.sent_at, made below only when the
            # reply is not the common case: what can wait is not done before the request)
            deadline = 0.0
        if not buf:
            # the common case first: nine bytes that are the reply. The same nine bytes are
            # the same (immutable) reply, and a script repeating its lines mostly gets
            # answers it has had before: one met before passed the decoder's test (which
            # does not depend on the request) and is taken with the others.
            seen = self._seen
            reply = seen.get(head) if kind == _NORMAL and head.__class__ is bytes else None
            if (reply is not None and reply.module == req.address
                    and reply.opcode == req.opcode and reply.host == host):
                if tracing:
                    o._tell("rx", head, reply)
                return reply
            if (len(head) == FRAME and kind == _NORMAL and head[1] == req.address
                    and head[3] == req.opcode and head[0] == host and head[2] != _EVENT
                    and is_frame(head, host)):
                reply = Reply.from_frame(head)
                if head.__class__ is bytes:
                    if len(seen) >= _SEEN_REPLIES:
                        seen.clear()
                    seen[head] = reply
                if tracing:
                    o._tell("rx", head, reply)
                return reply
            if (len(head) == FRAME and kind == _MEMORY and head[0] == host
                    and is_frame(head) and not (head[2] == _EVENT
                                                and head[3] == _TARGET_REACHED)):
                # a 134 read-back (upload's verify), taken as _take takes it from a line
                # that was just absorbed
                reply = Reply.from_memory_frame(head, req.address, req.opcode)
                if tracing:
                    o._tell("rx", head, reply)
                return reply
            buf += head
            if not deadline:
                deadline = t.sent_at + timeout
            wait = deadline - time.monotonic()
        else:
            wait = timeout
        # the decoder reads from here on (the common case above never needs it): noise
        # before this request does not make its first window suspect
        dec.forget_noise()
        junk = bytearray()
        garbled = False  # bytes that were no frame came since the last whole frame
        memory = kind == _MEMORY
        accept = self._accept_version(kind)
        while True:
            while True:
                piece = dec.next(memory=memory, whole=accept)
                if piece is None:
                    break
                what, data = piece
                if what == NOISE:
                    junk += data
                    garbled = True
                    continue
                garbled = False
                if junk:
                    self._drop(junk, "bytes that are no frame")
                got = self._take(req, kind, what, data)
                if got is not None:
                    return got
            if wait <= 0:
                break
            # bytes that are no frame and then silence: a damaged reply, no need to wait
            # any longer (the answer may come behind it as well: an event, say). But an
            # RS485 adapter's echo of the request, one byte damaged, says nothing about
            # when the reply comes: a module may wait up to 255 ms (GP 75) to answer.
            damaged_reply = garbled and not _echo_of(raw, bytes(junk[:FRAME] + buf))
            if damaged_reply:
                wait = min(wait, QUIET_AFTER_GARBAGE)
            chunk = t.read(FRAME - len(buf), wait)
            if chunk:
                buf += chunk
            elif damaged_reply:
                break
            wait = deadline - time.monotonic()
        # what is left can never complete a frame: the rest of a damaged or truncated reply
        junk += dec.rest()
        self._drop(junk, "incomplete frame")
        if garbled:
            raise ChecksumError(f"corrupted reply to {name_of(req)} from address "
                                f"{req.address} (bad checksum)")
        raise TmclTimeoutError(f"no reply to {name_of(req)} from address {req.address} "
                               f"within {timeout:g} s")

    def _accept_version(self, kind: ReplyKind) -> Callable[[bytearray], bool]:
        """Which nine bytes that are no frame are taken whole: the version string asked
        for; else a late or repeated one the ledger expects (see Client._accept_version)."""
        host = self.decoder.host
        if kind == _VERSION:
            return lambda w: is_version_string(w, host)
        return self.owner._accept_version

    def _take(self, req: Request, kind: ReplyKind, what: int, head: bytes) -> Reply | None:
        """A frame (or a version string taken whole) read while ``req`` waits: its reply,
        or None when it was something else (queued, written down, dropped)."""
        o = self.owner
        host = self.decoder.host
        if what != FRAME_PIECE:
            if kind != _VERSION:
                return None  # a late or repeated version string (accept_version said so)
            reply = Reply.from_bytes(head, kind, module=req.address)
        elif (o._also_from is not None or o._also_host is not None) and head[0] in (
                host, o._also_host) and head[1] in (req.address, o._also_from) and \
                head[3] == req.opcode and is_frame(head, head[0]) and head[2] != _EVENT:
            reply = Reply.from_frame(head)  # a write that moved the module: its answer
        elif head[0] != host:
            # a frame for another host, or our own request echoed by an RS485 adapter
            o._discard(head, f"frame for address {head[0]}, not host {host}")
            return None
        elif head[2] == _EVENT and head[3] == _TARGET_REACHED:
            # (a 134 read-back of a stored instruction could have this shape too, but only
            # one whose opcode equals the address, with type 128 and motor 138)
            o._event(head, Reply.from_frame(head))
            return None
        elif kind == _MEMORY:
            reply = Reply.from_memory_frame(head, req.address, req.opcode)
        elif head[1] != req.address or head[3] != req.opcode or (
                kind == _VERSION and head[2] == _OK):
            # (a normal frame answering 136 type 0 can only carry an error status)
            o._late(head[1], head[3], Reply.from_frame(head))
            o._discard(head, f"stale reply (op {head[3]} from address {head[1]})")
            return None
        else:
            reply = Reply.from_frame(head)
        if o._tracers:
            o._tell("rx", head, reply)
        return reply

    def _drop(self, junk: bytearray, why: str) -> None:
        if junk:
            self.owner._discard(bytes(junk), why)
            junk.clear()

    # -- what comes between requests ------------------------------------------------------
    def absorb(self, timeout: float = 0.0, *, flushing: bool = False) -> bool:
        """Take in whatever is pending now (or, if nothing is, what comes within
        ``timeout``): events are queued, anything else is stale. False if nothing came.
        ``flushing``: before a request (the trace says so)."""
        t = self.transport
        o = self.owner
        dec = self.decoder
        data = t.read_available()
        if not data and timeout:
            data = t.read(1, timeout) + t.read_available()
        dec.feed(data)
        dec.forget_noise()
        host = dec.host = o.host_address
        junk = bytearray()
        noise = False
        while True:
            piece = dec.next(whole=o._accept_version)
            if piece is None:
                break
            what, head = piece
            if what == NOISE:
                junk += head
                continue
            noise = noise or bool(junk)
            self._drop(junk, "bytes that are no frame")
            if what != FRAME_PIECE:
                continue  # a late or repeated version string, written down already
            if head[0] == host and head[2] == _EVENT and head[3] == _TARGET_REACHED:
                o._event(head, Reply.from_frame(head))
                continue
            expected = head[0] != host or o._late(head[1], head[3], Reply.from_frame(head))
            why = "late reply" if expected else "reply no request was waiting for"
            o._discard(head, f"discarded before the request: {why}" if flushing else why)
        rest = dec.settle()
        if rest is not None:
            junk += rest[1]
        noise = noise or bool(junk)
        self._drop(junk, "bytes that are no frame")
        if noise:
            # bytes that are no frame while nothing was outstanding: a damaged reply,
            # possibly the real answer to the last request (which then took another)
            o._noise_unsolicited()
        return bool(data)

    def drain(self, hard_stop: float) -> None:
        """Read until the line has been quiet for a moment (at most ``hard_stop`` s); then
        drop everything that is not an event, including a partial frame."""
        t = self.transport
        end = time.monotonic() + hard_stop
        while time.monotonic() < end:
            chunk = t.read(64, DRAIN_QUIET)
            if not chunk:
                break
            self.decoder.feed(chunk)
        self.absorb()
        if self.decoder.buf:
            self.owner._discard(self.decoder.rest(), "partial frame")


class CanFraming:
    """Seven data bytes to the module's CAN id, replies on the reply id."""

    mode = BINARY

    def __init__(self, transport: CanTransport, owner: Owner):
        self.transport = transport
        self.owner = owner

    def waiting(self) -> bool:
        return True  # (a non-blocking receive is the only way to know)

    def clear(self) -> None:
        pass  # every message is whole

    def quiet_time(self) -> float:
        return 0.0

    def refusal(self, req: Request) -> str | None:
        return None

    def exchange(self, req: Request, kind: ReplyKind, timeout: float,
                 absorb: bool = True) -> Reply | None:
        t = self.transport
        o = self.owner
        if kind != _NORMAL:
            self.absorb()
        data = req.to_can()
        if o._sent_tracers and req.opcode in o._sent_wanted:
            o._trace_sent(data, req)
        t.send(o.can_id, data)
        o.stats["sent"] += 1
        if o._tracers:
            o._tell("tx", data, req)
        if kind == _NONE:
            return None
        deadline = time.monotonic() + timeout
        wait = timeout
        while True:
            msg = t.recv(wait)
            if msg is not None:
                reply = self._take(req, kind, msg[0], msg[1])
                if reply is not None:
                    return reply
            wait = deadline - time.monotonic()
            if wait <= 0:
                break
        raise TmclTimeoutError(f"no CAN reply to {name_of(req)} on id {o.reply_id} "
                               f"(sent to id {o.can_id}) within {timeout:g} s")

    def _take(self, req: Request, kind: ReplyKind, arb: int, data: bytes) -> Reply | None:
        o = self.owner
        if arb != o.reply_id and arb not in o._other_reply_ids and (
                o._also_reply_id is None or arb != o._also_reply_id):
            return None  # other traffic on the bus
        host = o.host_address
        got = can_reply(data, version=kind == _VERSION)  # (the one reading of CAN replies)
        if got is None:
            o._discard(data, f"not a TMCL reply ({len(data)} bytes)")
            return None
        data = got
        if len(data) == CAN_VERSION:
            reply = Reply.from_can(host, data, kind, module=req.address)
            if o._tracers:
                o._tell("rx", data, reply)
            return reply
        elif data[1] == _EVENT and data[2] == _TARGET_REACHED:
            o._event(data, Reply.from_can(host, data))
            return None
        elif kind == _MEMORY:
            reply = Reply.from_can(host, data, kind, module=req.address)
        else:
            reply = Reply.from_can(host, data)
            if reply.opcode != req.opcode or (kind == _VERSION and reply.status == _OK):
                o._late(reply.module, reply.opcode, reply)
                o._discard(data, f"stale reply (op {reply.opcode})")
                return None
        if o._tracers:
            o._tell("rx", data, reply)
        return reply

    def _take_any(self, timeout: float) -> bool:
        """Receive one message: events are queued, anything else dropped. False if none."""
        o = self.owner
        msg = self.transport.recv(timeout)
        if msg is None:
            return False
        arb, data = msg
        data = can_reply(data, version=False) or data
        ours = arb == o.reply_id or arb in o._other_reply_ids
        if ours and len(data) == _CAN_REPLY_LEN and data[1] == _EVENT \
                and data[2] == _TARGET_REACHED:
            o._event(data, Reply.from_can(o.host_address, data))
        elif ours:
            if len(data) == _CAN_REPLY_LEN:
                o._late(data[0], data[2], Reply.from_can(o.host_address, data))
            o._discard(data, "stale reply")
        return True

    def absorb(self, timeout: float = 0.0, *, flushing: bool = False) -> bool:
        got = False
        while self._take_any(0 if got else timeout):
            got = True
        return got

    def drain(self, hard_stop: float) -> None:
        end = time.monotonic() + hard_stop
        while time.monotonic() < end and self._take_any(DRAIN_QUIET):
            pass
