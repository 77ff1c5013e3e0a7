"""A CAN log read at the reader's pace: the common request/reply pair as one small tuple.

A log of a master polling its modules is mostly one exchange a hundred thousand times: a
request on a module's id and, before anything else, its plain answer on the reply id.
``CanReader.feed`` makes two ``Seen`` and an ``Exchange`` of every such pair, which costs more
than python-can's own reading of the frames. ``pairs`` reads the same frames and hands such a
pair over as a ``Pair`` tuple instead: the two times, the reply's data and value, and its
``Shape``, what every pair of that request, reply id and status has in common, worked out
once. Everything else goes through ``feed`` itself, frame by frame: a request followed by
anything but its plain answer (it is given to the monitor first, at its own time), the 136
and 139 exchanges that teach the monitor something, other ids, errors and remote frames. The
monitor's state and counts end as ``feed`` leaves them (tests/ops/test_monitor_can.py reads
logs both ways and compares every line).

Where a front end chooses per line (a filter, a count, a duration), ``listen.can_log`` is the
way: a pair's request is handed over only with its reply here.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator

from ..link.base import CanFrame
from ..tmcl.decoder import CAN_DATA, can_reply
from ..tmcl.frames import CAN_REPLY, Instruction, Reply, ReplyKind
from ..tmcl.traffic import STATUSES, expects, is_event, teaches
from .monitor import REPLY, REQUEST, CanReader, Exchange, Item, Seen

BATCH = 512  # frames read before what they gave is handed over
_unpack = CAN_REPLY.unpack_from


class Shape:
    """What the plain pairs of one request (its id and bytes), one reply id and one status
    share: the request as the monitor sees it (``request``, at the time of the first such
    pair) and the first reply of the shape (``reply``; another pair's differs in its value)."""

    __slots__ = ("request", "reply_id", "reply", "status")

    def __init__(self, request: Seen, reply_id: int, reply: Reply):
        self.request = request
        self.reply_id = reply_id
        self.reply = reply
        self.status = reply.status

    def exchange(self, t_req: float, t_rep: float, data: bytes) -> Exchange:
        """The pair as ``feed`` makes it: two ``Seen`` and their ``Exchange``."""
        proto = self.request
        req = Seen(t_req, REQUEST, proto.raw, proto.address, proto.can_id, proto.instruction)
        reply = Reply.from_frame(b"\0" + can_reply(data))  # (host 0: the reply id says it)
        rep = Seen(t_rep, REPLY, data, proto.address, self.reply_id, reply=reply, answers=req,
                   latency=t_rep - t_req)
        return Exchange(req, rep)


# (request time, reply time, the reply's data, its value, its Shape)
Pair = tuple[float, float, bytes, int, Shape]


class _Request:
    """A request's bytes on one id, read once: whether its answer can make a plain pair, and
    the shapes of the pairs it made, by reply id and status (False: no plain answer)."""

    __slots__ = ("instruction", "plain", "shapes", "seen")

    def __init__(self, t: float, arb: int, data: bytes):
        ins = self.instruction = Instruction.from_bytes(data[:CAN_DATA])
        self.plain = expects(ins) is ReplyKind.NORMAL and not teaches(ins)
        self.shapes: dict[int, Shape | bool] = {}
        self.seen = Seen(t, REQUEST, data, arb, arb, ins)

    def shape(self, arb: int, seven: bytes) -> Shape | bool:
        status, opcode = seven[1], seven[2]
        if status not in STATUSES or is_event(status, opcode):
            return False
        return Shape(self.seen, arb, Reply.from_frame(b"\0" + seven))


def _latency(ex: Exchange | None) -> float:
    """The slowest exchange's latency, or less than any (the first exchange is the slowest)."""
    return float("-inf") if ex is None else ex.latency  # type: ignore[return-value]


def _may_learn(reader: CanReader) -> bool:
    """Whether the next frame may tell the monitor which module answers at an address (a
    136 waiting, given up on or held): what it shows before then is worded without it, so
    it is handed over first."""
    m = reader.monitor
    return bool(reader.held) or any(teaches(r.instruction) for r in m.waiting) \
        or any(teaches(r.instruction) for r in m.recent)


def pairs(reader: CanReader, frames: Iterable[CanFrame], *,
          capture: Callable[[CanFrame], None] | None = None,
          batch: int = BATCH) -> Iterator[list[Item | Pair]]:
    """Every frame of a log (``link.canlog.read_log``), read as ``listen.can_log`` reads it,
    in lists of about ``batch`` frames' items, the plain pairs as ``Pair`` tuples; at the end
    the requests still waiting are unanswered. ``capture`` takes every frame first."""
    m = reader.monitor
    s = m.summary
    feed = reader.feed
    request_ids, reply_ids, answered_on = reader.request_ids, reader.reply_ids, reader.answered_on
    timeout = m.timeout
    statuses, addresses = s.statuses, m.addresses
    waiting, held = m.waiting, reader.held  # (changed in place, never replaced)
    known: dict[tuple[int, bytes], _Request] = {}
    out: list[Item | Pair] = []
    pending: tuple[float, int, bytes, _Request] | None = None  # a request not handed over yet
    counted = 0  # pairs not yet in the summary's counts
    first = last = 0.0
    slowest = _latency(s.slowest)

    def settle() -> None:
        """The pairs read so far into the summary (before the general path reads it)."""
        nonlocal counted
        if counted:
            s.frames += 2 * counted
            s.requests += counted
            s.replies += counted
            if s.first is None:
                s.first = first
            s.last = last
            counted = 0

    def hand_over() -> list[Item]:
        """The request waiting for its answer, given to the monitor as ``feed`` would have."""
        nonlocal pending
        t, arb, data, req = pending  # type: ignore[misc]
        pending = None
        settle()
        return m.request(t, data, req.instruction, arb, can_id=arb)

    t = 0.0
    try:
        for f in frames:
            if capture is not None:
                capture(f)
            t, arb, data, extended, error, remote = f
            if pending is not None:
                pt, parb, pdata, req = pending
                if arb in reply_ids and arb not in request_ids and t - pt <= timeout \
                        and not (extended or error or remote):
                    seven = can_reply(data)
                    if seven is not None and len(seven) == CAN_DATA \
                            and seven[2] == req.instruction.opcode:
                        key = arb << 8 | seven[1]
                        shape = req.shapes.get(key)
                        if shape is None:
                            shape = req.shapes[key] = req.shape(arb, seven)
                        on = answered_on.get(parb)
                        if shape and (on == arb or on is None):
                            if on is None:
                                answered_on[parb] = arb
                            pending = None
                            latency = t - pt
                            if latency > slowest:
                                settle()
                                s.slowest = shape.exchange(pt, t, data)  # type: ignore[union-attr]
                                slowest = latency
                            if not counted:
                                first = pt
                            counted += 1
                            last = t
                            statuses[seven[1]] += 1
                            out.append((pt, t, data, _unpack(seven)[3], shape))
                            if len(out) >= batch:
                                settle()
                                yield out
                                out = []
                            continue
                out += hand_over()
            if arb in request_ids and not (waiting or held or extended or error or remote) \
                    and len(data) >= CAN_DATA:
                req = known.get((arb, data))  # type: ignore[assignment]
                if req is None:
                    if len(known) >= 4096:
                        known.clear()
                    req = known[(arb, data)] = _Request(t, arb, data)
                    addresses.add(arb)  # (as the monitor's request does, when it comes)
                if req.plain:
                    pending = (t, arb, data, req)
                    continue
            settle()
            if out and _may_learn(reader):  # (what came before is shown as the module was)
                yield out
                out = []
            out += feed(t, arb, data, extended=extended, error=error, remote=remote)
            slowest = _latency(s.slowest)
            if len(out) >= batch:
                yield out
                out = []
        if pending is not None:
            out += hand_over()
        settle()
        yield out + reader.end(t)
    except Exception:
        # (a log python-can cannot read on: what came before is still shown and counted)
        if pending is not None:
            out += hand_over()
        settle()
        if out:
            yield out
        raise
    finally:
        # (Ctrl-C while what this gave was shown: what was read is counted)
        if pending is not None:
            hand_over()
        settle()
