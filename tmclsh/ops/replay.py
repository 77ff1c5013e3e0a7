"""Replaying a captured session: what another master sent, sent again, and what differs.

A technician reproduces what a PLC or a customer's program did: the capture (a ``monitor
-o`` or ``bridge -o`` serial capture, a CAN log python-can reads, candump's screen lines, a
``--log-dir`` transcript) is read into request/reply pairs by the monitor's one pairing
(ops/monitor.py, through the sources of ops/listen.py), each request is sent again through a
client to the module at the address (or CAN id) it went to, and every reply whose status or
value differs from the captured one is a difference, with both latencies.

Nothing here prints or asks: ``read_capture`` returns a ``Capture`` (what it holds, which
requests would write, store or move, which are never sent again), ``replay`` a ``Result``.
Whether a command only reads is the instruction set's fact (``instructions.only_reads``);
a replay that holds any other command is refused unless writes are allowed, naming them.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from ..base import clock
from ..base.errors import TmclError, TmclTimeoutError, TransportError, ValidationError
from ..base.files import FileError, stream_lines
from ..tmcl import instructions as isa
from ..tmcl.frames import Instruction, Reply, Request
from . import listen
from .monitor import (DEFAULT_CAN_ID, DEFAULT_REPLY_ID, REQUEST, CanReader, Exchange, Item,
                      Monitor)

SERIAL, CAN = "serial", "can"
_HEAD = 64  # lines looked at to tell a capture's format


@dataclass(slots=True)
class Captured:
    """One captured request and what answered it: ``address`` the module address (on CAN
    the id the request went to, ``reply_id`` the one its reply came on); ``reply`` None when
    none came (``note`` says why); ``latency`` seconds between them."""

    index: int
    t: float
    address: int
    instruction: Instruction
    reply: Reply | None
    latency: float | None
    reply_id: int | None = None
    note: str = ""

    @property
    def reads(self) -> bool:
        ins = self.instruction
        return isa.only_reads(ins.opcode, ins.type)

    @property
    def never(self) -> str | None:
        """Why this command is never sent again (the instruction set's ``not_a_line``)."""
        ctl = isa.control(self.instruction.opcode)
        return ctl.not_a_line if ctl is not None else None


@dataclass
class Capture:
    """A capture read into exchanges, in the order the requests were sent."""

    path: str
    link: str  # serial | can
    exchanges: list[Captured]
    skipped: int = 0  # requests not replayable (their checksum was wrong on the wire)

    @property
    def addresses(self) -> list[int]:
        return sorted({c.address for c in self.exchanges})

    def first_at(self, address: int) -> Captured:
        return next(c for c in self.exchanges if c.address == address)

    def settings(self) -> dict[str, int]:
        """Where the first module of the capture is, as connection settings: the module a
        replay connects to when the command line names no address."""
        first = self.exchanges[0]
        if self.link == CAN:
            out = {"can_id": first.address}
            if first.reply_id is not None:
                out["reply_id"] = first.reply_id
            return out
        return {"address": first.address}

    def writes(self) -> list[Captured]:
        """The requests that write, store or move (or may: unknown commands): sent only when
        allowed."""
        return [c for c in self.exchanges if not c.reads]

    def never(self) -> list[Captured]:
        return [c for c in self.exchanges if c.never is not None]

    def written(self) -> list[int]:
        """The addresses (CAN ids) the writes went to: where a replay's closing stop goes.
        A module the capture only read from was set moving by nothing the replay sent, and a
        stop sent there would halt what another cause runs (or, where nothing answers, wait
        out its retries and report a module that never was there)."""
        return sorted({c.address for c in self.writes()})


class WritesRefused(ValidationError):
    """The capture holds commands that write, store or move, and writes were not allowed."""

    def __init__(self, writes: list[Captured]):
        self.writes = writes
        what = ("1 command that writes, stores or moves" if len(writes) == 1
                else f"{len(writes)} commands that write, store or move")
        super().__init__(f"the capture holds {what}; nothing was sent")


@dataclass(slots=True)
class Outcome:
    """A captured exchange sent again: the reply now (None: none came, ``error`` why)."""

    captured: Captured
    reply: Reply | None
    latency: float | None
    error: str = ""

    @property
    def differences(self) -> list[str]:
        """What differs from the capture, in words (empty: the same)."""
        was, now = self.captured.reply, self.reply
        if was is None and now is None:
            return []
        if was is None:
            return ["a reply now, none in the capture"]
        if now is None:
            return [f"no reply now ({self.error})" if self.error else "no reply now"]
        out = []
        if was.status != now.status:
            out.append(f"status {was.status} -> {now.status}")
        if was.version is not None or now.version is not None:
            if was.version != now.version:
                out.append(f"version {was.version} -> {now.version}")
        elif was.stored is not None or now.stored is not None:
            if was.stored != now.stored:
                out.append(f"stored {was.stored} -> {now.stored}")
        elif was.value != now.value:
            out.append(f"value {was.value} -> {now.value}")
        return out

    @property
    def differs(self) -> bool:
        return bool(self.differences)

    def to_json(self) -> dict[str, object]:
        c, ins = self.captured, self.captured.instruction
        return {"index": c.index, "address": c.address, "op": ins.opcode, "type": ins.type,
                "motor": ins.motor, "value": ins.signed_value,
                "captured": _reply_json(c.reply), "now": _reply_json(self.reply),
                "latency_captured": _ms(c.latency), "latency": _ms(self.latency),
                "differs": self.differs, "differences": self.differences}


def _reply_json(reply: Reply | None) -> dict[str, object] | None:
    if reply is None:
        return None
    if reply.version is not None:
        return {"status": reply.status, "version": reply.version}
    return {"status": reply.status, "value": reply.value}


def _ms(seconds: float | None) -> float | None:
    return None if seconds is None else round(seconds * 1000, 3)


@dataclass
class Result:
    """What a replay did: one ``Outcome`` per exchange sent (all of them unless
    ``interrupted``), and the seconds it took."""

    capture: Capture
    outcomes: list[Outcome] = field(default_factory=list)
    seconds: float = 0.0
    interrupted: bool = False

    @property
    def differences(self) -> list[Outcome]:
        return [o for o in self.outcomes if o.differs]

    def to_json(self) -> dict[str, object]:
        return {"replayed": len(self.outcomes), "exchanges": len(self.capture.exchanges),
                "differences": len(self.differences), "addresses": self.capture.addresses,
                "link": self.capture.link, "seconds": round(self.seconds, 6),
                "interrupted": self.interrupted}


# -- reading a capture -----------------------------------------------------------------------

# a --log-dir transcript's frame line: time of day, tx> or <rx, the bytes in hex, the words
_TRANSCRIPT = re.compile(r"(\d\d):(\d\d):(\d\d(?:\.\d+)?) (tx>|<rx) ((?:[0-9a-f]{2} ?)+)")
_SERIAL = re.compile(r"\d+(?:\.\d*)?\s+(?:(?:tx|rx)\s+)?(?:[0-9A-Fa-f]{2}\s*)+")
_CANDUMP = re.compile(r"\s*(?:\(\d+(?:\.\d*)?\)\s*)?[\w.-]+\s+[0-9A-Fa-f]{1,8}\s+\[\d{1,2}\]")


def read_capture(path: str | Path) -> Capture:
    """The exchanges of a capture of any kind tmclsh reads (its kind told from its lines
    and, for a python-can log, its name), paired as the monitor pairs them."""
    from ..link import canlog

    head = _head(path)
    monitor = Monitor()
    if any(_TRANSCRIPT.match(line) for line in head):
        items, link = _transcript(path, monitor), SERIAL
    elif any(_CANDUMP.match(line) and "#" not in line for line in head):
        items, link = listen.can_log(_candump(path), CanReader(monitor)), CAN
    elif canlog.readable(path) and not any(_SERIAL.fullmatch(line) for line in head):
        items, link = listen.can_log(canlog.read_log(path), CanReader(monitor)), CAN
    else:
        items, link = listen.serial_capture(path, monitor), SERIAL
    return _paired(str(path), link, items)


def _head(path: str | Path) -> list[str]:
    """The first lines that are not comments, if the file is text (else none)."""
    try:
        fh = open(path, encoding="utf-8", errors="strict")
    except OSError as exc:
        raise FileError(f"cannot read {path}: {exc.strerror or exc}") from None
    out: list[str] = []
    with fh:
        try:
            for line in stream_lines(fh, str(path)):
                text = line.strip()
                if text and not text.startswith("#"):
                    out.append(text)
                    if len(out) >= _HEAD:
                        break
        except (UnicodeDecodeError, ValidationError):
            return []  # (a binary log: .blf, .db)
    return out


def _lines(path: str | Path) -> Iterator[tuple[int, str]]:
    with open(path, encoding="utf-8", errors="replace") as fh:
        yield from enumerate(stream_lines(fh, str(path)), 1)


def _candump(path: str | Path) -> Iterator:
    """candump's screen lines (which no python-can reader takes), a frame each."""
    from ..link.canlog import parse_line

    for no, line in _lines(path):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            frame = parse_line(line)
        except ValidationError as exc:
            raise ValidationError(f"{path}:{no}: {exc}") from None
        if frame is None:
            raise ValidationError(f"{path}:{no}: not a candump line")
        yield frame


def _transcript(path: str | Path, monitor: Monitor) -> Iterator[list[Item]]:
    """A ``--log-dir`` transcript's frames: nine-byte frames as a bridge's two directions;
    seven or eight bytes (a CAN link's) as CAN frames on the factory's ids."""
    chunks: list[tuple[float, str | None, bytes]] = []
    frames = []
    day = last = 0.0
    for _no, line in _lines(path):
        m = _TRANSCRIPT.match(line)
        if m is None:
            continue
        t = int(m.group(1)) * 3600 + int(m.group(2)) * 60 + float(m.group(3)) + day
        if t < last:  # past midnight
            day += 86400.0
            t += 86400.0
        last = t
        data = bytes.fromhex(m.group(5))
        tx = m.group(4) == "tx>"
        if len(data) in (7, 8):
            from ..link.base import CanFrame

            frames.append(CanFrame(t, DEFAULT_CAN_ID if tx else DEFAULT_REPLY_ID, data))
        else:
            chunks.append((t, "tx" if tx else "rx", data))
    if frames:
        return listen.can_log(iter(frames), CanReader(monitor))
    if not chunks:
        raise ValidationError(f"{path}: a transcript without frames (tx>/<rx lines)")
    return listen.serial_chunks(chunks, monitor)


def _paired(path: str, link: str, source: Iterable[list[Item]]) -> Capture:
    """The exchanges, in the order their requests were sent."""
    requests, answered = [], {}
    for items in source:
        for item in items:
            if isinstance(item, Exchange):
                answered[id(item.request)] = item
            elif item.kind == REQUEST:
                requests.append(item)
    out: list[Captured] = []
    skipped = 0
    for req in requests:
        ex = answered.get(id(req))
        if req.bad_sum or req.instruction is None or req.address is None:
            skipped += 1
            continue
        reply = ex.reply if ex is not None else None
        out.append(Captured(len(out) + 1, req.t, req.address, req.instruction,
                            reply.reply if reply is not None else None,
                            ex.latency if ex is not None else None,
                            reply.can_id if reply is not None else None,
                            ex.note if ex is not None else ""))
    if not out:
        raise ValidationError(f"{path}: no TMCL request in it to replay")
    return Capture(path, link, out, skipped)


# -- sending it again ------------------------------------------------------------------------

def replay(client, capture: Capture, *, as_captured: bool = False, writes: bool = False,
           sleep: Callable[[float], None] = clock.sleep,
           done: Callable[[Outcome], None] | None = None,
           into: Result | None = None) -> Result:
    """Send every captured request again, in order, each to the address (on CAN the ids) it
    went to; ``as_captured``: at the capture's pace, else each as soon as the last is
    answered. ``writes``: commands that write, store or move may be sent (else
    ``WritesRefused`` before anything is). ``done`` gets each outcome as it comes. A lost
    link raises (``TransportError``), Ctrl-C too: ``into``, a ``Result`` of the caller's,
    holds what was done up to there (``interrupted`` set)."""
    never = capture.never()
    if never:
        c = never[0]
        raise ValidationError(f"exchange {c.index}: command {c.instruction.opcode} is not "
                              f"replayed: {c.never}; nothing was sent")
    if not writes and capture.writes():
        raise WritesRefused(capture.writes())
    result = into if into is not None else Result(capture)
    start = time.monotonic()
    first = capture.exchanges[0].t
    kept = (client.address, client.can_id, client.reply_id, client._downloading)
    plan = _requests(client, capture)
    request, monotonic, is_can = client.request, time.monotonic, client.is_can
    outcomes, download = result.outcomes, _download_opcodes()
    try:
        for c, req in plan:
            if as_captured:
                wait = (c.t - first) - (monotonic() - start)
                if wait > 0:
                    sleep(wait)
            if is_can:
                client.can_id = c.address
                if c.reply_id is not None:
                    client.reply_id = c.reply_id
            else:  # (an answer in doubt is read again from the client's address)
                client.address = c.address
            error = ""
            sent = monotonic()
            try:
                reply = request(req)
            except TmclTimeoutError as exc:
                reply, error = None, str(exc)
            except TransportError:
                raise
            except TmclError as exc:  # a reply the client refuses (download mode, checksum)
                reply, error = getattr(exc, "reply", None), str(exc)
            outcome = Outcome(c, reply, monotonic() - sent, error)
            if req.opcode in download:
                _follow_download(client, c, reply)
            outcomes.append(outcome)
            if done is not None:
                done(outcome)
    except BaseException:
        result.interrupted = True
        result.seconds = time.monotonic() - start
        raise
    finally:
        client.address, client.can_id, client.reply_id, client._downloading = kept
    result.seconds = time.monotonic() - start
    return result


def aim(client, c: Captured) -> Request:
    """The request, to where it went: the client pointed at its serial address, or on CAN
    at the module's ids (the safety stop after a replay is aimed the same way)."""
    ins = c.instruction
    if client.is_can:
        client.can_id = c.address
        if c.reply_id is not None:
            client.reply_id = c.reply_id
        address = client.address
    else:
        address = client.address = c.address
    return Request.make(address, ins.opcode, ins.type, ins.motor, ins.signed_value)


def _requests(client, capture: Capture) -> list[tuple[Captured, Request]]:
    """Every exchange's request, made before the first is sent; the same request is one
    object (its bytes are made once, as a script's repeated line)."""
    made: dict[tuple[int, Instruction], Request] = {}
    out = []
    for c in capture.exchanges:
        ins = c.instruction
        address = client.address if client.is_can else c.address
        req = made.get((address, ins))
        if req is None:
            req = made[(address, ins)] = Request.make(address, ins.opcode, ins.type,
                                                      ins.motor, ins.signed_value)
        out.append((c, req))
    return out


def _download_opcodes() -> frozenset[int]:
    return frozenset(op for op, ctl in isa.controls().items() if ctl.download is not None)


def _follow_download(client, c: Captured, reply: Reply | None) -> None:
    """Between an accepted 132 and 133 the module stores what it gets (status 101): that is
    what the capture holds too, not a module left in download mode."""
    ctl = isa.control(c.instruction.opcode)
    if ctl is not None and ctl.download is not None and reply is not None and reply.ok:
        client._downloading = ctl.download == "enter"
