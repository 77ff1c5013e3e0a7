"""Listening in: TMCL traffic another master sends, read into requests, replies and exchanges.

A PLC, the TMCL-IDE or a customer's program drives the module; tmclsh only listens (a CAN
bus, a serial tap on an RS485 line, a log file) or sits in the middle (a bridge). What it
hears is read here into ``Seen`` items, one per frame or run of bytes that is none, and into
``Exchange`` items, a request with the reply that answers it (or none) and the time between.
Nothing here sends or prints: the readers take bytes or CAN frames with their times, the
front end (shell/features/monitor.py) shows what they return.

* ``Monitor`` pairs replies with requests, learns which module answers at an address (its
  136 answers), and counts what it saw (``Summary``).
* ``SerialTap`` reads one serial line on which requests and replies interleave (an RS485
  tap): frames through the one frame decoder (tmcl/decoder.py), told apart by their
  contents and by what is waiting for an answer; bytes that are no frame come out as noise,
  never as frames.
* ``SerialPair`` reads the two directions of a bridge, each on its own (requests from the
  master, replies from the module), with the module's ASCII mode as text lines.
* ``CanReader`` reads CAN frames: requests on the modules' ids, replies on the reply ids
  (given, the modules' factory ids, or learnt from frames that answer each other).
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from ..base.canspec import LINK_DEFAULTS
from ..link.ascii import next_line, parse_reply
from ..tmcl.decoder import (CAN_DATA, CAN_VERSION, FRAME, FRAME_PIECE, NOISE, WHOLE, FrameDecoder,
                            can_reply, printable)
from ..tmcl.frames import Instruction, Reply, ReplyKind
from ..tmcl.modules import Module, identify
from ..tmcl.status import status_ok
from ..tmcl.traffic import (STATUSES, damaged_request, enters_ascii, expects, is_event,
                            known_command, leaves_ascii, plausible_reply, plausible_request,
                            version_answer)

REQUEST, REPLY, EVENT, NOISE_RUN, TEXT, OTHER = (
    "request", "reply", "event", "noise", "text", "other")
TX, RX = "tx", "rx"  # to a module, from one (where the wire tells: a bridge)

DEFAULT_HOST = LINK_DEFAULTS["host_address"]  # GP 76, the reply address as it leaves the factory
DEFAULT_CAN_ID, DEFAULT_REPLY_ID = 1, 2  # GP 71 and GP 70 as they leave the factory
NO_REPLY = "no reply expected"  # an exchange without a reply by design
TIMEOUT = 1.0  # s a request waits for its reply before it is called unanswered
_NORMAL, _VERSION, _MEMORY, _NONE = (ReplyKind.NORMAL, ReplyKind.VERSION_STRING,
                                     ReplyKind.MEMORY, ReplyKind.NONE)
_RECENT = 8  # unanswered requests a late reply may still answer
_CACHE = 4096  # decoded frames kept by their bytes (a log repeats the same frames)
_TEXT_BYTES = frozenset(range(32, 127)) | frozenset(b"\r\n\t")


@dataclass(eq=False, slots=True)
class Seen:
    """One thing on the wire: a frame, a text line, or bytes that are no frame.

    ``address``: the module's (a request's address or, on CAN, the id it was sent to; a
    reply's module byte). ``instruction``: a request's; ``reply``: a reply's or an event's.
    ``answers``: the request a reply answers; ``latency`` the seconds between them.
    ``direction``: ``tx``/``rx`` where the wire tells (a bridge). ``note``: what noise or an
    other frame is, in words. ``bad_sum``: a request whose checksum is wrong (the module
    answers it with status 1, whatever the command).
    """

    t: float
    kind: str
    raw: bytes
    address: int | None = None
    can_id: int | None = None
    instruction: Instruction | None = None
    reply: Reply | None = None
    answers: Seen | None = None
    latency: float | None = None
    direction: str | None = None
    note: str = ""
    late: bool = False  # a reply that came after its request was called unanswered
    bad_sum: bool = False


@dataclass(eq=False, slots=True)
class Exchange:
    """A request and what became of it: its reply, or ``note`` why there is none."""

    request: Seen
    reply: Seen | None
    note: str = ""
    by_design: bool = False  # no reply comes to this command (137, 205, 242): none missing

    @property
    def latency(self) -> float | None:
        return self.reply.latency if self.reply is not None else None

    @property
    def t(self) -> float:
        return self.request.t


Item = Seen | Exchange


@dataclass
class Summary:
    """What was seen, counted: for the end of a run."""

    frames: int = 0
    requests: int = 0
    replies: int = 0
    events: int = 0
    noise: int = 0  # runs of bytes that were no frame
    noise_bytes: int = 0
    text: int = 0
    other: int = 0
    unanswered: int = 0
    unpaired: int = 0  # replies no request was seen for
    late: int = 0
    statuses: Counter = field(default_factory=Counter)
    slowest: Exchange | None = None
    first: float | None = None
    last: float | None = None
    shown: int = 0  # lines or objects the front end showed (filters let through)
    filtered: bool = False  # a filter chose what was shown
    modules: dict[int, str] = field(default_factory=dict)  # address -> what 136 said
    # what a live run could not keep up with, counted (the wire never waits for it): lines
    # or objects not shown because their reader was not reading, frames not written to the
    # -o file because the disk was too slow, frames forwarded but not read (a bridge)
    dropped: int = 0
    capture_dropped: int = 0
    untold: int = 0

    @property
    def written(self) -> int:
        """Lines or objects handed to the output and not dropped: those the filters let
        through (``shown``) less those its reader did not take (``dropped``). (A reader
        that has gone takes nothing more, and reads no summary either.)"""
        return max(0, self.shown - self.dropped)

    @property
    def refused(self) -> int:
        """Replies whose status is an error (not 100, 101 or 128)."""
        return sum(n for s, n in self.statuses.items() if not status_ok(s))

    @property
    def errors(self) -> int:
        return self.refused + self.noise + self.unanswered + self.unpaired

    def to_json(self) -> dict[str, object]:
        slow = self.slowest
        return {"frames": self.frames, "requests": self.requests, "replies": self.replies,
                "events": self.events, "noise": self.noise, "noise_bytes": self.noise_bytes,
                "text": self.text, "other": self.other, "unanswered": self.unanswered,
                "unpaired": self.unpaired, "late": self.late, "errors": self.errors,
                "statuses": {str(k): v for k, v in sorted(self.statuses.items())},
                "slowest": None if slow is None else {
                    "t": round(slow.t, 6), "address": slow.request.address,
                    "op": slow.request.instruction.opcode,
                    "latency": round(slow.latency or 0.0, 6)},
                "seconds": round(self.last - self.first, 6) if self.first is not None
                and self.last is not None else 0.0,
                "modules": {str(k): v for k, v in sorted(self.modules.items())},
                "shown": self.written, "dropped_lines": self.dropped,
                "capture_dropped": self.capture_dropped, "untold": self.untold}


class Monitor:
    """Pairs replies with their requests and counts what was seen (no I/O).

    ``module``: the type given (``-m``), for every address; else each address's module is
    learnt from its 136 answers. ``timeout``: seconds a request waits for its reply.
    ``hosts``: host addresses replies go to (given; else the factory's 2, and any that
    answer a request).
    """

    def __init__(self, module: Module | None = None, timeout: float = TIMEOUT,
                 hosts: Iterable[int] | None = None):
        self.module = module
        self.timeout = timeout
        self.modules: dict[int, Module] = {}
        self.hosts: set[int] = set(hosts) if hosts else {DEFAULT_HOST}
        self.addresses: set[int] = set()  # module addresses that answered or were asked
        self.host_of: dict[int, int] = {}  # module address -> the host its replies went to
        self.waiting: list[Seen] = []  # requests still waiting for their reply, oldest first
        self.recent: deque[Seen] = deque(maxlen=_RECENT)
        self.summary = Summary()
        self.ascii = False  # a 139 was accepted: the line carries text lines
        self.leaving = False  # ... and a BIN was sent: the reply to it ends them

    def module_for(self, address: int | None) -> Module | None:
        if self.module is not None or address is None:
            return self.module
        return self.modules.get(address)

    def _count(self, t: float) -> None:
        s = self.summary
        s.frames += 1
        if s.first is None:
            s.first = t
        s.last = t

    # -- what is seen ----------------------------------------------------------------------
    def layout(self, request: Seen) -> ReplyKind:
        """How the answer to this request is laid out: a damaged request is answered with
        a status-1 frame, whatever its command says."""
        return _NORMAL if request.bad_sum else expects(request.instruction)

    def request(self, t: float, raw: bytes, ins: Instruction, address: int | None, *,
                can_id: int | None = None, direction: str | None = None,
                alone: bool = False, bad_sum: bool = False) -> list[Item]:
        """A request; ``alone``: the line carries one exchange at a time (a serial bus), so
        whatever still waited got no answer. ``bad_sum``: its checksum is wrong."""
        self._count(t)
        self.summary.requests += 1
        if address is not None:
            self.addresses.add(address)
        seen = Seen(t, REQUEST, raw, address, can_id, ins, direction=direction,
                    bad_sum=bad_sum)
        if bad_sum:
            seen.note = (f"bad checksum: {raw[FRAME - 1]:02x}, the bytes add up to "
                         f"{sum(raw[:FRAME - 1]) & 0xFF:02x}")
        out: list[Item] = [seen]
        if alone and self.waiting:
            out += self._give_up([r for r in self.waiting if r.address == address]
                                 or self.waiting, "no reply before the next request")
        if self.layout(seen) is _NONE:
            out.append(Exchange(seen, None, NO_REPLY, by_design=True))
        else:
            self.waiting.append(seen)
        return out

    def reply(self, t: float, raw: bytes, reply: Reply, request: Seen | None, *,
              can_id: int | None = None, direction: str | None = None) -> list[Item]:
        """A reply (``request``: the one it answers, found by the reader), or an event."""
        self._count(t)
        s = self.summary
        if is_event(reply.status, reply.opcode) and reply.version is None \
                and reply.stored is None:
            s.events += 1
            return [Seen(t, EVENT, raw, reply.module, can_id, reply=reply, direction=direction)]
        s.replies += 1
        s.statuses[reply.status] += 1
        address = request.address if request is not None else reply.module
        seen = Seen(t, REPLY, raw, address, can_id, reply=reply, answers=request,
                    direction=direction)
        if request is None:
            s.unpaired += 1
            return [seen]
        before: list[Item] = []
        waiting = self.waiting
        if waiting and waiting[0] is request:  # (the oldest answered: nothing passed over)
            del waiting[0]
        elif request in waiting:
            before = self._passed_over(request)
            waiting.remove(request)
        else:
            seen.late = True
            s.late += 1
            s.unanswered -= 1
            self.recent.remove(request)
        latency = seen.latency = t - request.t
        ex = Exchange(request, seen)
        if not seen.late and (s.slowest is None or latency > s.slowest.latency):
            s.slowest = ex
        if can_id is None:
            self.hosts.add(reply.host)
            if address is not None:
                self.host_of[address] = reply.host
        if address is not None:
            self.addresses.add(address)
        self._learn(request, reply)
        return before + [seen, ex] if before else [seen, ex]

    def _passed_over(self, request: Seen) -> list[Item]:
        """A module answers in the order it was asked: requests to it still waiting from
        before the one answered now got no answer (several may be sent before the first is
        answered, so a new request alone says nothing of those before it)."""
        older = []
        for r in self.waiting:
            if r is request:
                break
            if r.address == request.address and r.can_id == request.can_id:
                older.append(r)
        return self._give_up(older, "no reply: a later request to this module was "
                                    "answered") if older else []

    def _learn(self, request: Seen, reply: Reply) -> None:
        ins = request.instruction
        if reply.ok and enters_ascii(ins):
            self.ascii = True
        version, type1 = version_answer(ins, reply)
        if version is None and type1 is None or request.address is None:
            return
        if version is not None:
            self.summary.modules[request.address] = version
        if self.module is None:
            mod = identify(version, type1)
            if mod is not None:
                self.modules[request.address] = mod
                known = self.summary.modules.get(request.address)
                if known is None or not known.startswith(mod.name):
                    self.summary.modules[request.address] = (
                        f"{mod.name} ({version})" if version is not None else mod.name)

    def noise(self, t: float, raw: bytes, note: str = "",
              direction: str | None = None) -> list[Item]:
        s = self.summary
        s.noise += 1
        s.noise_bytes += len(raw)
        if s.first is None:
            s.first = t
        s.last = t
        return [Seen(t, NOISE_RUN, raw, direction=direction,
                     note=note or f"{len(raw)} bytes that are no frame")]

    def text(self, t: float, line: bytes, direction: str | None = None) -> list[Item]:
        """A line of the module's ASCII mode (a command or a reply, as the module reads it)."""
        self._count(t)
        self.summary.text += 1
        reply = parse_reply(line)
        note = ""
        if reply is not None:
            note = f"{reply.status} {reply.status_text}, value {reply.value}"
        return [Seen(t, TEXT, line, direction=direction, note=note)]

    def other(self, t: float, raw: bytes, note: str, can_id: int | None = None) -> list[Item]:
        self._count(t)
        self.summary.other += 1
        return [Seen(t, OTHER, raw, can_id=can_id, note=note)]

    # -- requests and their answers ----------------------------------------------------------
    def find(self, answers: Callable[[Seen], bool]) -> Seen | None:
        """The request a reply answers: the oldest waiting one ``answers`` accepts, else the
        latest one given up on (a late reply)."""
        for r in self.waiting:
            if answers(r):
                return r
        for r in reversed(self.recent):
            if self.layout(r) is _NORMAL and answers(r):
                return r
        return None

    def expecting(self, kind: ReplyKind) -> Seen | None:
        """The latest waiting request whose answer has this layout."""
        for r in reversed(self.waiting):
            if self.layout(r) is kind:
                return r
        return None

    def _give_up(self, requests: list[Seen], why: str) -> list[Item]:
        out: list[Item] = []
        for r in requests:
            self.waiting.remove(r)
            self.recent.append(r)
            self.summary.unanswered += 1
            out.append(Exchange(r, None, why))
        return out

    def expire(self, now: float) -> list[Item]:
        """Requests that waited longer than the timeout: unanswered."""
        if not self.waiting or now - self.waiting[0].t <= self.timeout:
            return []
        return self._give_up([r for r in self.waiting if now - r.t > self.timeout],
                             f"no reply within {self.timeout:g} s")

    def finish(self) -> list[Item]:
        """The end: every request still waiting is unanswered."""
        return self._give_up(list(self.waiting), "no reply before the end")


# -- serial lines --------------------------------------------------------------------------

def _text_like(data: bytes) -> bool:
    """Bytes that read as text lines of the ASCII mode (a module that was in it before the
    monitor started): printable, ending in a line end, each line an address character and
    at least two more."""
    if data[-1:] not in (b"\r", b"\n") or not all(b in _TEXT_BYTES for b in data):
        return False
    lines = data.replace(b"\n", b"\r").split(b"\r")
    return all(not line or (len(line.strip()) >= 3 and 0x40 <= line[0] < 0x7F)
               for line in lines) and any(lines)


class _Lines:
    """Text lines of the ASCII mode, split as the module splits them (CR or LF), until the
    line leaves the mode: on the master's side after its BIN, on the module's after the
    reply to it (an echo of BIN comes first); a tap hears both."""

    def __init__(self) -> None:
        self.buf = bytearray()

    def take(self, monitor: Monitor, t: float, direction: str | None) -> tuple[list[Item], bool]:
        """(the lines, whether the text ended: what is left in ``buf`` are frames)."""
        out: list[Item] = []
        while True:
            used, line = next_line(self.buf)
            if line is None:
                return out, False
            del self.buf[:used]
            if not line.strip():
                continue
            out += monitor.text(t, line, direction)
            if direction != RX and leaves_ascii(line):
                monitor.leaving = True
                if direction == TX:
                    return out, True
            elif direction != TX and monitor.leaving and parse_reply(line) is not None:
                monitor.leaving = monitor.ascii = False
                return out, True

    def rest(self) -> bytes:
        rest, self.buf = bytes(self.buf), bytearray()
        return rest


class SerialTap:
    """One serial line that carries both directions (a tap on an RS485 bus).

    Every frame is read through the frame decoder; a frame that answers the request waiting
    (its module address and command, with a status) is its reply, a frame to a host with a
    status that answers nothing is a reply without its request, anything else a request.
    After bytes that were no frame, a frame is taken only if it fits the traffic so far (a
    known command to an address seen before, or a reply to a known host): noise that
    happens to add up is shown as noise. Bytes that are still no frame when the line goes
    quiet (``quiet``) are a partial frame.
    """

    def __init__(self, monitor: Monitor):
        self.monitor = monitor
        self.decoder = FrameDecoder(None, resync=self._plausible)
        self.lines = _Lines()
        self._noise = bytearray()
        self._noise_t = 0.0

    def feed(self, data: bytes, t: float) -> list[Item]:
        m = self.monitor
        out: list[Item] = []
        if m.ascii:
            self.lines.buf += data
            items, done = self.lines.take(m, t, None)
            out += items
            if not done:
                return out
            data = self.lines.rest()
        self.decoder.feed(data)
        return out + self._read(t)

    def _read(self, t: float) -> list[Item]:
        m = self.monitor
        dec = self.decoder
        out: list[Item] = []
        while not m.ascii:
            piece = dec.next(whole=self._whole)
            if piece is None:
                break
            what, raw = piece
            if what == NOISE:
                if not self._noise:
                    self._noise_t = t
                self._noise += raw
                continue
            out += self._flush_noise()
            if what == FRAME_PIECE:
                out += self._frame(raw, t)
            else:  # a version string, taken whole (no checksum in its layout)
                req = m.expecting(_VERSION)
                reply = Reply.from_bytes(raw, _VERSION, module=req.address if req else 0)
                out += m.reply(t, raw, reply, req)
        if m.ascii and dec.buf:  # text from here on
            out += self.feed(dec.rest(), t)
        return out

    def _flush_noise(self) -> list[Item]:
        if not self._noise:
            return []
        raw, self._noise = bytes(self._noise), bytearray()
        return _noise_items(self.monitor, self._noise_t, raw)

    def quiet(self, t: float) -> list[Item]:
        """The line went quiet: what is left is a partial frame; requests may expire."""
        out = self._flush_noise()
        rest = self.decoder.rest()
        if rest:
            out += _noise_items(self.monitor, t, rest, partial=True)
        return out + self.monitor.expire(t)

    def end(self, t: float) -> list[Item]:
        return self.quiet(t) + self.monitor.finish()

    # -- what a frame is ---------------------------------------------------------------------
    def _answers(self, frame: bytes) -> Callable[[Seen], bool]:
        m = self.monitor

        def answers(r: Seen) -> bool:
            kind = m.layout(r)
            if kind is _MEMORY:
                return frame[0] in m.hosts
            return (frame[1] == r.address and frame[3] == r.instruction.opcode
                    and frame[2] in STATUSES)
        return answers

    def _frame(self, frame: bytes, t: float) -> list[Item]:
        m = self.monitor
        req = m.find(self._answers(frame))
        if req is not None:
            if m.layout(req) is _MEMORY:
                reply = Reply.from_memory_frame(frame, req.address, req.instruction.opcode)
            else:
                reply = Reply.from_frame(frame)
            return m.reply(t, frame, reply, req)
        if frame[2] in STATUSES and (is_event(frame[2], frame[3]) or (
                plausible_reply(frame, m.hosts) and frame[0] not in m.addresses)):
            return m.reply(t, frame, Reply.from_frame(frame), None)
        return m.request(t, frame, Instruction.from_bytes(frame[1:8]), frame[0], alone=True)

    def _plausible(self, window: bytes | bytearray) -> bool:
        m = self.monitor
        if plausible_reply(window, m.hosts):
            return True
        if m.expecting(_MEMORY) is not None and window[0] in m.hosts:
            return True
        return plausible_request(window) and (not m.addresses or window[0] in m.addresses)

    def _whole(self, window: bytearray) -> bool:
        """A version string (136 type 0) while one is awaited: host and eight characters."""
        req = self.monitor.expecting(_VERSION)
        return (req is not None and len(window) >= FRAME
                and window[0] in self.monitor.hosts and printable(window[1:FRAME]))


def _noise_items(monitor: Monitor, t: float, raw: bytes, partial: bool = False,
                 direction: str | None = None) -> list[Item]:
    """Bytes that are no frame: text lines when they read as such (a module that starts up
    in ASCII mode), else noise, or a partial frame when the line went quiet after them."""
    if _text_like(raw):
        out: list[Item] = []
        for line in raw.replace(b"\r\n", b"\r").replace(b"\n", b"\r").split(b"\r"):
            if line.strip():
                out += monitor.text(t, line, direction)
        return out
    if partial and len(raw) < FRAME:
        return monitor.noise(t, raw, f"partial frame: {len(raw)} of {FRAME} bytes, then "
                                     "nothing", direction)
    return monitor.noise(t, raw, direction=direction)


class SerialPair:
    """The two directions of a serial link, each on its own (a bridge in the middle):
    requests from the master (``TX``), replies from the module (``RX``). Text lines of the
    ASCII mode are shown as lines."""

    def __init__(self, monitor: Monitor):
        self.monitor = monitor
        self.decoders = {TX: FrameDecoder(None, resync=self._plausible_request),
                         RX: FrameDecoder(None, resync=self._plausible_reply)}
        self.lines = {TX: _Lines(), RX: _Lines()}
        self.text = {TX: False, RX: False}  # the direction carries text lines

    def feed(self, direction: str, data: bytes, t: float) -> list[Item]:
        m = self.monitor
        out: list[Item] = []
        if self.text[direction]:
            lines = self.lines[direction]
            lines.buf += data
            items, done = lines.take(m, t, direction)
            out += items
            if not done:
                return out
            self.text[direction] = False
            data = lines.rest()
        dec = self.decoders[direction]
        dec.feed(data)
        noise = bytearray()
        while not self.text[direction]:
            piece = dec.next(whole=self._whole if direction == RX else self._damaged)
            if piece is None:
                break
            what, raw = piece
            if what == NOISE:
                noise += raw
                continue
            if noise:
                out += _noise_items(m, t, bytes(noise), direction=direction)
                noise.clear()
            if direction == TX:
                if self.text[RX]:  # binary again, though no reply to BIN was read
                    self.text[RX] = m.ascii = m.leaving = False
                    self.decoders[RX].feed(self.lines[RX].rest())
                # (not ``alone``: a master may send requests ahead of their replies)
                out += m.request(t, raw, Instruction.from_bytes(raw[1:8]), raw[0],
                                 direction=TX, bad_sum=what == WHOLE)
            else:
                out += self._reply(raw, what, t)
                if m.ascii and not self.text[TX]:  # 139 accepted: text from here on
                    self.text = {TX: True, RX: True}
                    for d in (TX, RX):
                        rest = self.decoders[d].rest()
                        if rest:
                            out += self.feed(d, rest, t)
        if noise:
            out += _noise_items(m, t, bytes(noise), direction=direction)
        return out

    def _reply(self, raw: bytes, what: int, t: float) -> list[Item]:
        m = self.monitor
        if what != FRAME_PIECE:
            req = m.expecting(_VERSION)
            reply = Reply.from_bytes(raw, _VERSION, module=req.address if req else 0)
            return m.reply(t, raw, reply, req, direction=RX)
        req = m.find(lambda r: m.layout(r) is _MEMORY
                     or (raw[1] == r.address and raw[3] == r.instruction.opcode))
        if req is not None and m.layout(req) is _MEMORY:
            reply = Reply.from_memory_frame(raw, req.address, req.instruction.opcode)
        else:
            reply = Reply.from_frame(raw)
        return m.reply(t, raw, reply, req, direction=RX)

    def quiet(self, t: float) -> list[Item]:
        out: list[Item] = []
        for d, dec in self.decoders.items():
            rest = dec.rest()
            if rest:
                out += _noise_items(self.monitor, t, rest, partial=True, direction=d)
        return out + self.monitor.expire(t)

    def end(self, t: float) -> list[Item]:
        return self.quiet(t) + self.monitor.finish()

    def _plausible_request(self, window: bytes | bytearray) -> bool:
        return plausible_request(window)

    def _plausible_reply(self, window: bytes | bytearray) -> bool:
        return (plausible_reply(window) or self.monitor.expecting(_MEMORY) is not None)

    def _whole(self, window: bytearray) -> bool:
        return (self.monitor.expecting(_VERSION) is not None and len(window) >= FRAME
                and printable(window[1:FRAME]))

    def _damaged(self, window: bytearray) -> bool:
        """A request whose checksum is wrong: shown as one, paired with the module's
        status-1 answer (not as noise and a partial frame)."""
        return damaged_request(window, self.monitor.addresses)


# -- CAN -------------------------------------------------------------------------------------

_CAN_LEN = CAN_DATA  # data bytes of a TMCL request or reply on CAN


def _byte(req: Seen | None) -> int:
    """A request's address as a reply's module byte (a CAN id above 255 has none)."""
    return req.address if req is not None and req.address is not None \
        and req.address <= 0xFF else 0


class CanReader:
    """CAN frames: requests on the modules' ids, replies on the reply ids.

    ``request_ids``/``reply_ids``: given, or None for the factory's (GP 71 = 1, GP 70 = 2)
    and, with ``learn``, any pair of ids whose frames answer each other (a 7-byte frame on
    one id, then on another a reply with a status to the same command). A reply is paired
    with the oldest waiting request of its command, preferring the id that answered that
    module before. Frames on other ids, remote and error frames are ``other``.
    """

    def __init__(self, monitor: Monitor, request_ids: Iterable[int] | None = None,
                 reply_ids: Iterable[int] | None = None, learn: bool | None = None):
        self.monitor = monitor
        self.request_ids = set(request_ids) if request_ids else {DEFAULT_CAN_ID}
        self.reply_ids = set(reply_ids) if reply_ids else {DEFAULT_REPLY_ID}
        self.learn = (request_ids is None and reply_ids is None) if learn is None else learn
        self.answered_on: dict[int, int] = {}  # request id -> the reply id that answered it
        self.held: deque[Seen] = deque()  # frames on unknown ids that may be requests
        self._ins: dict[bytes, Instruction] = {}
        self._replies: dict[bytes, Reply] = {}

    def feed(self, t: float, arb: int, data: bytes, *, extended: bool = False,
             error: bool = False, remote: bool = False) -> list[Item]:
        m = self.monitor
        if not (extended or error or remote or self.held):
            # the common pair, request then its reply, without the general path's searches
            # (a log is read at the reader's pace: this is most of what it costs)
            waiting = m.waiting
            if not waiting or t - waiting[0].t <= m.timeout:
                if arb in self.request_ids:
                    if len(data) >= _CAN_LEN:
                        return self._request(t, arb, data)
                elif arb in self.reply_ids and len(waiting) == 1:
                    got = self._plain_reply(t, arb, data, waiting[0])
                    if got is not None:
                        return got
        out: list[Item] = []
        if self.held and t - self.held[0].t > m.timeout:
            out += self._release(t)
        if m.waiting and t - m.waiting[0].t > m.timeout:
            out += m.expire(t)
        if error or remote:
            return out + m.other(t, data, "error frame" if error else "remote frame",
                                 can_id=arb)
        if extended:
            return out + m.other(t, data, f"extended id {arb:#x}: not TMCL", can_id=arb)
        if arb in self.request_ids:
            if len(data) < _CAN_LEN:
                return out + m.other(t, data, f"{len(data)} bytes on a request id: not "
                                              "a TMCL request", can_id=arb)
            return out + self._request(t, arb, data)
        if arb in self.reply_ids:
            return out + self._reply(t, arb, data, known=True)
        if self.learn:
            got = self._reply(t, arb, data, known=False)
            if got:
                self.reply_ids.add(arb)
                return out + got
            if len(data) >= _CAN_LEN:
                self.held.append(Seen(t, OTHER, data, can_id=arb))
                return out
        return out + m.other(t, data, f"id {arb}: no TMCL id", can_id=arb)

    def _request(self, t: float, arb: int, data: bytes) -> list[Item]:
        raw = data[:_CAN_LEN]
        ins = self._ins.get(raw)
        if ins is None:
            ins = Instruction.from_bytes(raw)
            if len(self._ins) >= _CACHE:
                self._ins.clear()
            self._ins[raw] = ins
        # (a request to a module that still waits says nothing of the one before: requests
        # may be sent ahead of their replies; the reply to a later one does: Monitor.reply)
        return self.monitor.request(t, data, ins, arb, can_id=arb)

    def _plain_reply(self, t: float, arb: int, data: bytes, request: Seen) -> list[Item] | None:
        """A reply on a known reply id to the one request waiting, when it is a plain
        answer to it (no version string, no event, no read-back, the same command, an id
        that may answer it): what ``_reply`` makes of it, found without its searches.
        None: not that case, ``_reply`` decides."""
        n = len(data)
        if not (n == _CAN_LEN or n == CAN_VERSION and not printable(data)) \
                or request.bad_sum or data[1] not in STATUSES:
            return None
        ins = request.instruction
        if expects(ins) is not _NORMAL:
            return None
        seven = bytes(data[:_CAN_LEN])
        reply = self._replies.get(seven)
        if reply is None:
            reply = Reply.from_frame(b"\0" + seven)  # (host 0: the reply id says it)
            if len(self._replies) >= _CACHE:
                self._replies.clear()
            self._replies[seven] = reply
        if reply.opcode != ins.opcode or is_event(reply.status, reply.opcode):
            return None
        on = self.answered_on.get(request.can_id)
        if on is not None and on != arb:
            return None
        self.answered_on[request.can_id] = arb
        return self.monitor.reply(t, data, reply, request, can_id=arb)

    def _answers(self, arb: int, opcode: int | None) -> Callable[[Seen], bool]:
        """Whether a waiting request is the one a reply on ``arb`` answers: its command (any,
        for None), sent to an id this reply id answered before or not yet answered."""
        answered_on = self.answered_on

        def answers(r: Seen) -> bool:
            on = answered_on.get(r.can_id)
            return ((on is None or on == arb)
                    and (opcode is None or r.instruction.opcode == opcode))
        return answers

    def _reply(self, t: float, arb: int, data: bytes, known: bool) -> list[Item]:
        """A frame on a reply id (``known``), or one on an unknown id that answers a request
        (learning); [] when it answers nothing and is not known to be a reply."""
        m = self.monitor
        awaited = m.expecting(_VERSION)
        got = can_reply(data, version=known or awaited is not None)  # (the one reading)
        if got is not None and len(got) == CAN_VERSION:
            req, before = awaited, []
            if req is None and not known:
                req, before = self._learn_held(lambda ins: expects(ins) is _VERSION)
            if req is not None or known:
                if req is not None:
                    self.answered_on[req.can_id] = arb
                reply = Reply.from_can(0, data, _VERSION, module=_byte(req))
                return before + m.reply(t, data, reply, req, can_id=arb)
        if got is None:
            return m.other(t, data, f"{len(data)} bytes on a reply id: not a TMCL reply",
                           can_id=arb) if known else []
        seven = got
        reply, req = None, None
        if seven[1] in STATUSES:
            reply = self._replies.get(seven)
            if reply is None:
                reply = Reply.from_frame(b"\0" + seven)  # (host 0: the reply id says it)
                if len(self._replies) >= _CACHE:
                    self._replies.clear()
                self._replies[seven] = reply
            if is_event(reply.status, reply.opcode):
                return m.reply(t, data, reply, None, can_id=arb) if known else []
            req = m.find(self._answers(arb, reply.opcode))
        if req is None:  # a 134 read-back: the stored instruction where the status would be
            mem = m.expecting(_MEMORY)
            if mem is not None and self._answers(arb, None)(mem):
                self.answered_on[mem.can_id] = arb
                stored = Reply.from_memory_frame(b"\0" + seven, _byte(mem),
                                                 mem.instruction.opcode)
                return m.reply(t, data, stored, mem, can_id=arb)
        if reply is None:
            return m.other(t, data, f"no TMCL status ({data[1]}): not a TMCL reply",
                           can_id=arb) if known else []
        before = []
        if req is None and not known:
            opcode = reply.opcode
            req, before = self._learn_held(lambda ins: ins.opcode == opcode
                                           and known_command(opcode))
            if req is None:
                return []
        if req is not None:
            self.answered_on[req.can_id] = arb
        return before + m.reply(t, data, reply, req, can_id=arb)

    def _learn_held(self, answered: Callable[[Instruction], bool]
                    ) -> tuple[Seen | None, list[Item]]:
        """A frame held on an unknown id that a reply answers: it was a request. Its id is
        learnt and it is counted now, at its own time: (the request, what that gives)."""
        for h in self.held:
            ins = Instruction.from_bytes(h.raw[:_CAN_LEN])
            if answered(ins):
                self.held.remove(h)
                self.request_ids.add(h.can_id)
                items = self.monitor.request(h.t, h.raw, ins, h.can_id, can_id=h.can_id)
                return items[0], items  # type: ignore[return-value]
        return None, []

    def _release(self, t: float) -> list[Item]:
        """Held frames nothing answered: other traffic."""
        out: list[Item] = []
        while self.held and t - self.held[0].t > self.monitor.timeout:
            h = self.held.popleft()
            out += self.monitor.other(h.t, h.raw, f"id {h.can_id}: no TMCL id",
                                      can_id=h.can_id)
        return out

    def quiet(self, t: float) -> list[Item]:
        return self._release(t) + self.monitor.expire(t)

    def end(self, t: float) -> list[Item]:
        out = self._release(float("inf")) if self.held else []
        return out + self.monitor.finish()
