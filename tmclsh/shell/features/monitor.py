"""``tmclsh monitor`` and ``tmclsh bridge``: other masters' traffic, shown as ``--trace``
shows tmclsh's own.

For people, one line per exchange (time, address or CAN id, the request in the shell's
words with parameter names, the reply with its status in words, the time it took)::

    14:02:07.113 @1  GAP 4, 0  // MaxPositioningSpeed  =>  100 ok, GAP value 1000 (MaxPositioningSpeed = 1000 pps)  0.84 ms

and one line for everything that is no exchange (an event, a reply no request was seen
for, noise, a text line of the ASCII mode, other CAN traffic). For programs (``--json``),
one object per frame: ``{"t", "frame", "address", "op", "type", "motor", "value", ...}``,
``"status"`` and ``"latency"`` on replies, as tmclsh's own ``--json`` names them. A summary
ends every run (stderr for people, a last ``{"summary": ...}`` object for programs).

What is heard and how it is paired is ops/monitor.py's; where it comes from, ops/listen.py's
and ops/bridge.py's. This module only shows it.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Iterable
from typing import Any

from ...base.errors import (EXIT_FAILED, EXIT_OK, ConnectError, TmclError, TransportError,
                            UsageError, ValidationError)
from ...base.interrupts import Terminated, interrupted, restore, terminated_by, unwind_on
from ...base.spill import Spill, SpillWriter
from ...ops.filter import Filter
from ...ops.logread import Shape
from ...ops.monitor import (DEFAULT_REPLY_ID, EVENT, NOISE_RUN, OTHER, REPLY, REQUEST, RX,
                            TEXT, TX, CanReader, Exchange, Item, Monitor, Seen, Summary)
from ...tmcl import asm
from ...tmcl.frames import Request
from ...tmcl.modules import Module
from ...tmcl.status import status_ok, status_text
from ..render import (Styled, describe_instruction, describe_reply, event_motors, is_terminal,
                      reply_head, reply_words, took)
from .trace import timestamp

_MEMO = 4096  # words kept per frame's bytes (a log repeats the same frames)
_ARROW = {TX: "tx>", RX: "<rx", None: "   "}


def when(t: float) -> str:
    """A frame's time: the clock for live traffic and absolute log times, else the log's
    own seconds."""
    return timestamp(t) if t >= 1e8 else f"{t:12.6f}"


_BATCH = 512  # lines held before they are written together
# where a reply's value and bytes go in the fields every pair of a shape shares (no field
# of a frame holds a NUL)
_VALUE, _BYTES = "\0value", "\0bytes"


class View:
    """Items for people (lines) or programs (JSON objects), written to ``stream``."""

    def __init__(self, monitor: Monitor, *, json_mode: bool = False, hex_bytes: bool = False,
                 stream=None, color: str = "auto"):
        self.monitor = monitor
        self.json = json_mode
        self.hex = hex_bytes
        self.stream = stream if stream is not None else sys.stdout
        self._console = None
        self._color = color
        self._rich = not json_mode and (color == "always" or (
            color != "never" and is_terminal(self.stream)))
        self._words: dict[tuple, Any] = {}
        self._pending: list[str] = []  # plain lines not yet written (``flush`` writes them)
        # the live table on a terminal (shell/features/livetable.py): it counts what is
        # shown, and the lines go to it, to scroll above it
        self.table = None
        self._pairs: dict[Shape, tuple] = {}  # what the pairs of a shape say (``show_all``)
        self._latencies: dict[float, str] = {}  # a pair's latency as it is written
        # lines held before they are written together; 1 where each line is a write of its
        # own (a live run's writer counts the lines a reader did not take by its writes)
        self.batch = _BATCH

    # -- writing --------------------------------------------------------------------------
    def show(self, item: Item) -> bool:
        """Take ``item`` if it makes a line of its own; True if it did. Plain lines are
        written in batches (a log's hundred thousand lines cost a write each otherwise);
        ``flush`` writes what is held, which a live run does after each read."""
        if self.json:
            if item.__class__ is Exchange and item.reply is not None:
                return False  # (its frames were written as they came: most exchanges)
            text = self._json(item)
            if text is None:
                return False
        else:
            line = self.line(item)
            if line is None:
                return False
            if self.table is not None:
                self.table.line(line)
                return True
            if self._rich:
                self._write_pending()
                self.console.print(line, highlight=False, markup=False, soft_wrap=True)
                return True
            text = line.plain + "\n"
        pending = self._pending
        pending.append(text)
        if len(pending) >= self.batch:
            self._write_pending()
        return True

    def show_all(self, items: list) -> int:
        """Show every item (nothing chooses per line), a plain pair of a log
        (ops/logread.py) as its exchange's line or its two frames' objects, worded from
        what its shape's pairs share; how many lines or objects that made."""
        shown = 0
        pending = self._pending
        words = self._pair_words
        known = self._pairs
        fixed, learnt = self.monitor.module, self.monitor.modules.get  # (module_for, inline)
        show = self.show
        latencies = self._latencies
        if len(latencies) >= _MEMO:
            latencies.clear()
        if self.json:
            for item in items:
                if item.__class__ is not tuple:
                    shown += show(item)
                    continue
                t1, t2, data, value, shape = item
                mod = fixed if fixed is not None else learnt(shape.request.address)
                w = known.get(shape)
                if w is None or w[0] is not mod:
                    w = words(shape, mod)
                latency = t2 - t1
                said = latencies.get(latency)  # (a log's latencies repeat: worded once)
                if said is None:
                    said = latencies[latency] = f"{latency:.6f}"
                pending.append(f'{{"t": {t1:.6f}, {w[1]}}}\n{{"t": {t2:.6f}, {w[2]}{value}'
                               f'{w[3]}{data.hex(" ")}{w[4]}, "latency": {said}}}\n')
                shown += 2
        else:
            hexed = self.hex
            for item in items:
                if item.__class__ is not tuple:
                    shown += show(item)
                    continue
                t1, t2, data, value, shape = item
                mod = fixed if fixed is not None else learnt(shape.request.address)
                w = known.get(shape)
                if w is None or w[0] is not mod:
                    w = words(shape, mod)
                if w[2] is None:
                    pending.append(self._exchange_line(shape.exchange(t1, t2, data)).plain
                                   + "\n")
                    shown += 1
                    continue
                said = f"{w[2]}{value}" if w[3] is None else reply_words(w[2], value, w[3])
                if hexed:
                    said = f"[{data.hex(' ')}] {said}"
                latency = t2 - t1
                after = latencies.get(latency)
                if after is None:
                    after = latencies[latency] = took(latency)
                pending.append(f"{when(t1)}{w[1]}{said}{w[4]}{after}\n")
                shown += 1
        if len(pending) >= self.batch:
            self._write_pending()
        return shown

    def _pair_words(self, shape: Shape, mod: Module | None) -> tuple:
        """What every pair of ``shape`` says, from the general path's fields and words:
        (the module, then for JSON the request's fields, the reply's before its value,
        between it and its bytes, after them; for people the line between the time and the
        reply's words, the reply's words up to its value (None: the general path words
        each pair), its parameter, the line after them up to the latency)."""
        req = shape.request
        reply = shape.reply
        if self.json:
            rep = Seen(req.t, REPLY, b"", req.address, shape.reply_id, reply=reply, answers=req)
            fields = self._fields(rep, REPLY, mod)
            fields["value"], fields["bytes"] = _VALUE, _BYTES
            text = json.dumps(fields, ensure_ascii=False)[1:-1]
            head, rest = text.split(json.dumps(_VALUE))
            mid, tail = rest.split(json.dumps(_BYTES))
            w: tuple = (mod, self._body(req, REQUEST), head, mid + '"', '"' + tail)
        else:
            before = f" {self._where(req)}  " + (f"[{req.raw.hex(' ')}] " if self.hex else "")
            before += self._request_words(req) + "  =>  "
            after = (f"  (on id {shape.reply_id})" if shape.reply_id != DEFAULT_REPLY_ID
                     else "") + "  "
            head, param = None, None
            if not reply.is_event:  # (a status 128 to another command: described as one)
                ins = req.instruction
                head, param = reply_head(reply, mod, Request.make(
                    0, ins.opcode, ins.type, ins.motor, ins.value))
            w = (mod, before, head, param, after)
        if len(self._pairs) >= _MEMO:
            self._pairs.clear()
        self._pairs[shape] = w
        return w

    def _write_pending(self) -> None:
        if self._pending:
            text = "".join(self._pending)
            self._pending.clear()
            self.stream.write(text)

    def flush(self) -> None:
        self._write_pending()
        try:
            self.stream.flush()
        except (OSError, ValueError):
            pass

    @property
    def console(self):
        if self._console is None:
            from ..render import _console

            # (a live run's stream is a SpillWriter: the console writes through it too)
            file = self.stream if isinstance(self.stream, SpillWriter) else None
            self._console = _console(color=self._color, file=file)
        return self._console

    # -- words ----------------------------------------------------------------------------
    def _module(self, seen: Seen) -> Module | None:
        req = seen.answers if seen.answers is not None else seen
        return self.monitor.module_for(req.address)

    def _where(self, seen: Seen) -> str:
        if seen.can_id is not None and seen.kind != REPLY:
            return f"id {seen.can_id}"
        return f"@{seen.address}" if seen.address is not None else "@?"

    def _request_words(self, seen: Seen) -> str:
        mod = self._module(seen)
        key = ("req", seen.raw, id(mod))
        words = self._words.get(key)
        if words is None:
            words = self._remember(key, describe_instruction(seen.instruction, mod))
        return words

    def _reply_words(self, seen: Seen) -> str:
        mod = self._module(seen)
        req = seen.answers
        key = ("reply", seen.raw, req.raw if req is not None else None, id(mod))
        words = self._words.get(key)
        if words is None:
            request = None
            if req is not None:
                ins = req.instruction
                request = Request.make(0, ins.opcode, ins.type, ins.motor, ins.value)
            words = self._remember(key, describe_reply(seen.reply, mod, request))
        return words

    def _remember(self, key: tuple, value: Any) -> Any:
        if len(self._words) >= _MEMO:
            self._words.clear()
        self._words[key] = value
        return value

    def line(self, item: Item) -> Styled | None:
        """The line for people, or None for an item shown as part of another (a request
        and its reply are shown as their exchange)."""
        if isinstance(item, Exchange):
            return self._exchange_line(item)
        kind = item.kind
        if kind == REQUEST or (kind == REPLY and item.answers is not None):
            return None
        out = Styled(when(item.t), "tmcl.trace.time")
        arrow = _ARROW.get(item.direction, "   ") if item.direction else ""
        if arrow:
            out.append(f" {arrow}", f"tmcl.trace.{item.direction}")
        if kind == REPLY:
            out.append(f" {self._where(item)}  ", "tmcl.note")
            self._hex(out, item)
            out.append("(no request seen)  =>  ", "tmcl.note")
            out.append(self._reply_words(item), "" if item.reply.ok else "tmcl.status.error")
        elif kind == EVENT:
            out.append(f" {self._where(item)}  ", "tmcl.note")
            self._hex(out, item)
            out.append(describe_reply(item.reply, self._module(item)), "tmcl.event")
        elif kind == TEXT:
            out.append("  text  ", "tmcl.note")
            out.append(repr(item.raw.decode("latin-1"))[1:-1] if item.raw else "")
            if item.note:
                out.append(f"  ({item.note})", "tmcl.note")
        elif kind == NOISE_RUN:
            out.append("  ?? ", "tmcl.trace.drop")
            out.append(item.raw.hex(" "), "tmcl.trace.hex")
            out.append(f"  {item.note}", "tmcl.warn")
        else:  # OTHER
            out.append(f"  id {item.can_id} [{len(item.raw)}] ", "tmcl.note")
            out.append(item.raw.hex(" "), "tmcl.trace.hex")
            out.append(f"  {item.note}", "tmcl.trace.note")
        return out

    def _hex(self, out: Styled, seen: Seen) -> None:
        if self.hex:
            out.append(f"[{seen.raw.hex(' ')}] ", "tmcl.trace.hex")

    def _exchange_line(self, ex: Exchange) -> Styled:
        req, reply = ex.request, ex.reply
        out = Styled(when(req.t), "tmcl.trace.time")
        out.append(f" {self._where(req)}  ", "tmcl.note")
        self._hex(out, req)
        out.append(self._request_words(req))
        if req.bad_sum:
            out.append(f"  ({req.note})", "tmcl.warn")
        out.append("  =>  ", "tmcl.note")
        if reply is None:
            out.append(ex.note, "tmcl.note" if ex.by_design else "tmcl.warn")
            return out
        self._hex(out, reply)
        ok = reply.reply.ok
        out.append(self._reply_words(reply), "" if ok else "tmcl.status.error")
        if reply.can_id is not None and reply.can_id != DEFAULT_REPLY_ID:
            out.append(f"  (on id {reply.can_id})", "tmcl.note")
        out.append(f"  {took(reply.latency)}", "tmcl.note")
        if reply.late:
            out.append("  (late: after the request was given up)", "tmcl.warn")
        return out

    # -- JSON -----------------------------------------------------------------------------
    def _json(self, item: Item) -> str | None:
        if isinstance(item, Exchange):
            if item.reply is not None:
                return None  # (its frames were written as they came)
            seen, t = item.request, item.request.t
            body = self._body(seen, "no-reply" if item.by_design else "unanswered")
            return f'{{"t": {t:.6f}, {body}, "note": {json.dumps(item.note)}}}\n'
        body = self._body(item, item.kind)
        latency = item.latency
        if latency is None:
            return f'{{"t": {item.t:.6f}, {body}}}\n'
        late = ', "late": true' if item.late else ""
        return f'{{"t": {item.t:.6f}, {body}, "latency": {latency:.6f}{late}}}\n'

    def _body(self, seen: Seen, frame: str) -> str:
        """The object's fields but its times, made once per kind of frame and its bytes."""
        req = seen.answers
        mod = self.monitor.module_for(req.address if req is not None else seen.address)
        key = ("json", frame, seen.raw, req.raw if req is not None else None, id(mod),
               seen.address, seen.can_id, seen.direction)
        body = self._words.get(key)
        if body is None:
            body = self._remember(key, json.dumps(self._fields(seen, frame, mod),
                                                  ensure_ascii=False)[1:-1])
        return body

    def _fields(self, seen: Seen, frame: str, mod: Module | None) -> dict[str, Any]:
        obj: dict[str, Any] = {"frame": frame}
        if seen.address is not None:
            obj["address"] = seen.address
        if seen.can_id is not None:
            obj["can_id"] = seen.can_id
        if seen.direction is not None:
            obj["direction"] = seen.direction
        kind = seen.kind
        if kind == REQUEST:
            ins = seen.instruction
            obj.update(op=ins.opcode, type=ins.type, motor=ins.motor, value=ins.signed_value)
            _line(obj, seen, mod)
        elif kind in (REPLY, EVENT):
            reply = seen.reply
            req = seen.answers
            obj["op"] = reply.opcode
            if req is not None:
                obj.update(type=req.instruction.type, motor=req.instruction.motor)
            if kind == EVENT:
                obj.update(event=reply.opcode, motors=event_motors(reply))
            elif seen.can_id is None:
                obj["host"] = reply.host
            obj["status"] = reply.status
            if reply.version is not None:
                obj["version"] = reply.version
            elif reply.stored is not None:
                s = reply.stored
                obj["stored"] = {"op": s.opcode, "type": s.type, "motor": s.motor,
                                 "value": s.signed_value}
            else:
                obj["value"] = reply.value
            if not status_ok(reply.status):
                obj["error"] = status_text(reply.status)
            if req is not None:
                _line(obj, req, mod)
        elif kind == TEXT:
            obj["text"] = seen.raw.decode("latin-1")
        if kind in (NOISE_RUN, OTHER, TEXT) and seen.note or seen.bad_sum:
            obj["note"] = seen.note
        obj["bytes"] = seen.raw.hex(" ")
        return obj

    # -- the end --------------------------------------------------------------------------
    def summary(self, summary: Summary, err=None) -> None:
        self._write_pending()
        if self.json:
            self.stream.write(json.dumps({"summary": summary.to_json()}) + "\n")
            self.flush()
            return
        err = err if err is not None else sys.stderr
        for text in summary_lines(summary, self):
            err.write(text + "\n")
        err.flush()


def _line(obj: dict[str, Any], req: Seen, mod: Module | None) -> None:
    """``"line"``: the request as the shell takes it; ``"param"``: the parameter it names."""
    text, comment = asm.disassemble_instruction(req.instruction, mod)
    obj["line"] = text
    from ..render import param_for

    param = param_for(req.instruction, mod)
    if param is not None:
        obj["param"] = param.name


def _n(count: int, one: str, many: str | None = None) -> str:
    return f"{count} {one if count == 1 else (many or one + 's')}"


def summary_lines(s: Summary, view: View) -> list[str]:
    """The end of a run in words (frames, errors, status counts, the slowest exchange)."""
    span = (s.last - s.first) if s.first is not None and s.last is not None else 0.0
    parts = [_n(s.requests, "request"), _n(s.replies, "reply", "replies")]
    for n, one, many in ((s.unanswered, "unanswered", "unanswered"),
                         (s.unpaired, "reply without its request", "replies without their "
                                                                    "request"),
                         (s.late, "late reply", "late replies"), (s.events, "event", None),
                         (s.text, "text line", None), (s.other, "other frame", None)):
        if n:
            parts.append(_n(n, one, many))
    if s.noise:
        parts.append(f"{_n(s.noise, 'run')} of noise ({_n(s.noise_bytes, 'byte')})")
    lines = [f"{_n(s.frames, 'frame')} in {span:.3f} s: " + ", ".join(parts)
             + f"; {_n(s.errors, 'error')}"]
    if s.statuses:
        lines.append("statuses: " + ", ".join(f"{k} {status_text(k)} x{n}"
                                              for k, n in sorted(s.statuses.items())))
    if s.slowest is not None:
        req = s.slowest.request
        lines.append(f"slowest exchange: {took(s.slowest.latency)}, {when(req.t).strip()} "
                     f"{view._where(req)} {view._request_words(req)}")
    if s.modules:
        lines.append("modules: " + ", ".join(f"@{a} {v}" for a, v in sorted(s.modules.items())))
    if s.filtered:
        lines.append(f"shown: {_n(s.written, 'line')} (the filters let these through)")
    if s.dropped:
        lines.append(f"not shown: {_n(s.dropped, 'line')} (the output was not being read; "
                     "the traffic went on, counted above)")
    if s.capture_dropped:
        lines.append(f"not written to the -o file: {_n(s.capture_dropped, 'frame')} (the disk "
                     "did not keep up)")
    if s.untold:
        lines.append(f"forwarded but not read: {_n(s.untold, 'chunk')} (reading fell too far "
                     "behind; the frames went through)")
    return lines


# -- running ---------------------------------------------------------------------------------

class Limits:
    """When a run ends besides Ctrl-C: ``--count`` lines shown, ``--duration`` seconds (of
    the clock live, of the log's own times when reading a log)."""

    def __init__(self, count: int | None, duration: float | None, log_time: bool):
        self.count = count
        self.duration = duration
        self.log_time = log_time
        self.started = time.monotonic()

    def reached(self, shown: int, summary: Summary) -> bool:
        if self.count is not None and shown >= self.count:
            return True
        if self.duration is None:
            return False
        if self.log_time:
            return (summary.first is not None and summary.last is not None
                    and summary.last - summary.first >= self.duration)
        return time.monotonic() - self.started >= self.duration


def interruptible() -> dict:
    """SIGINT (Ctrl-C), SIGTERM and SIGHUP (the terminal closed, the SSH session dropped) end
    a run, the summary still written and what a bridge's traffic left still ended: also
    where SIGINT came in ignored (a program started in the background by a shell). The
    handlers before, for ``restore``."""
    return unwind_on(("SIGINT", "SIGTERM", "SIGHUP"), interrupted)


def show_items(items: Iterable[Item], view: View, filt: Filter, summary: Summary,
               limits: Limits | None) -> bool:
    """Show what passes the filter; True once the count is reached."""
    every = not filt.active  # (the common case, without a call a frame)
    table = view.table
    if every and table is None and (limits is None or limits.count is None):
        summary.shown += view.show_all(items)
        return False
    show = view.show
    for item in items:
        if every or filt(item):
            if table is not None:
                table.take(item)
            if show(item):
                summary.shown += 1
                if limits is not None and limits.count is not None \
                        and summary.shown >= limits.count:
                    return True
    return False


def load_module(name: str | None) -> Module | None:
    if not name:
        return None
    from ...tmcl.modules import load

    return load(name)


def run_monitor(args) -> int:
    """``tmclsh monitor``: listen, show, summarise (sends nothing, ever)."""
    from ...ops import listen

    module = load_module(getattr(args, "module", None))
    timeout = getattr(args, "timeout", None) or 1.0
    monitor = Monitor(module, timeout=timeout, hosts=getattr(args, "host_address", None))
    filt = Filter(args.address or (), args.op or (), args.param or (), monitor)
    can_spec = getattr(args, "can", None)
    log_path = getattr(args, "log", None)
    port = getattr(args, "port", None)
    if sum(x is not None for x in (can_spec, log_path, port)) != 1:
        raise UsageError("monitor listens to one of --can [IFACE:CHANNEL], --log FILE "
                              "or --port TAP")
    if log_path is not None:
        _readable(log_path)
    json_mode = bool(getattr(args, "json", False))
    from .livetable import wanted

    with_table = wanted(args, json_mode)
    is_can = can_spec is not None or (log_path is not None and _can_log(log_path))
    view = View(monitor, json_mode=json_mode, hex_bytes=args.hex)
    capture, close_capture, _ = _capture(args.output, is_can)
    transport = None
    live = log_path is None
    capture_dropped = lambda: 0  # noqa: E731
    out = None
    if live:  # (a log is read at the reader's pace: nothing is dropped)
        capture, close_capture, capture_dropped = off_the_wire(capture, close_capture)
        out = live_output(view)
    table = live_table(with_table, view, monitor, out, live)
    try:
        if can_spec is not None:
            from ...link.spec import LinkSpec

            link = LinkSpec.parse(can=can_spec, bitrate=getattr(args, "bitrate", None))
            transport = _open(link.open)
            reader: Any = CanReader(monitor, args.can_id, args.reply_id)
            source = listen.can_bus(transport, reader, capture=capture)
        elif port is not None:
            from ...link.spec import LinkSpec
            from ...ops.monitor import SerialTap

            link = LinkSpec.parse(port=port, baud=getattr(args, "baud", None))
            baud = link.baud
            transport = _open(lambda: link.open(listen_only=True))
            reader = SerialTap(monitor)
            source = listen.serial_tap(transport, reader, quiet=listen.quiet_time(baud),
                                       capture=capture)
        elif is_can:
            from ...link.canlog import read_log

            reader = CanReader(monitor, args.can_id, args.reply_id)
            if filt.active or args.count is not None or args.duration is not None \
                    or view._rich or view.table is not None:  # (each frame's items as
                # they come, to choose by or to count in the table)
                source = listen.can_log(read_log(log_path), reader, capture=capture)
            else:  # (the plain pairs in tuples, read and written in batches)
                from ...ops.logread import pairs

                source = pairs(reader, read_log(log_path), capture=capture)
        else:
            reader = None
            source = listen.serial_capture(log_path, monitor)
        def started() -> None:
            if live:
                print(f"listening on {transport.describe()} (nothing is sent); Ctrl-C ends",
                      file=sys.stderr, flush=True)
            if table is not None:
                table.start()

        failed, ended = _run(source, reader if live else None, view, filt, monitor,
                             Limits(args.count, args.duration, not live), live, started)
    finally:
        if transport is not None:
            transport.close()
        close_capture()
        monitor.summary.capture_dropped = capture_dropped()
        end_table(view)
        if out is not None:
            end_live_output(view, out, monitor.summary)
    if ended is not None:  # SIGTERM, SIGHUP: said as every command says it
        said_ended(ended, "stopped listening")
    if out is not None and out.gone:  # (the reader of stdout has gone: end quietly, as
        from ...base.edges import reader_gone  # other tools do; a monitor only listens)

        if not json_mode:
            view.summary(monitor.summary)  # (on stderr, still the user's)
        gone = reader_gone()
        return gone if ended is None else ended.code  # type: ignore[return-value]
    if failed is not None:  # (what was heard until then is still summed up)
        print(f"tmclsh: {failed}", file=sys.stderr, flush=True)
    if failed is None or monitor.summary.frames or monitor.summary.noise:
        view.summary(monitor.summary)  # (of a log that gave nothing, only why)
    if ended is not None:
        return ended.code  # type: ignore[return-value]
    return EXIT_OK if failed is None else EXIT_FAILED


def said_ended(ended: Terminated, what: str) -> None:
    """The SIGTERM or SIGHUP that ended a run taking it as Ctrl-C, on stderr in the words a
    run of ``-c``/``-f`` uses (``terminated (SIGTERM): ...``); its exit status is the
    signal's (143, 129), as there. Said where stderr still takes it."""
    try:
        print(f"{ended.why}: {what}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def _readable(path: str) -> None:
    """A log that cannot be opened is one line before anything is shown."""
    from ...base.files import FileError

    try:
        with open(path, "rb"):
            pass
    except OSError as exc:
        raise FileError(f"cannot read {path}: {exc.strerror or exc}") from None


def _can_log(path: str) -> bool:
    from ...link.canlog import readable

    return readable(path)


def _open(opener):
    """The wire opened, or a ConnectError (exit 3) saying why not."""
    try:
        return opener()
    except (TransportError, ValidationError) as exc:
        raise ConnectError(str(exc)) from exc


def _capture(path: str | None, is_can: bool):
    """``-o FILE``: (what takes each frame or chunk, what closes the file, what pushes what
    was written to the disk: before a fork, so no process writes it twice)."""
    if not path:
        return None, lambda: None, lambda: None
    if is_can:
        from ...link.canlog import LogWriter

        writer: Any = LogWriter(path)
    else:
        from ...ops.capture import CaptureWriter

        writer = CaptureWriter(path)
    return writer.write, writer.close, writer.flush


CAPTURE_BOUND = 100_000  # frames a live -o file may fall behind before the newest are dropped


def off_the_wire(capture, close_capture):
    """A live ``-o`` file written on a thread of its own, so a slow disk never holds up the
    wire: (what takes each frame, what closes the file, how many frames were dropped)."""
    if capture is None:
        return None, close_capture, lambda: 0
    spill = Spill(lambda args: capture(*args), CAPTURE_BOUND, name="capture")

    def put(*args) -> None:
        spill.put(args)

    def close() -> None:
        try:
            spill.close()
        finally:
            close_capture()
    return put, close, lambda: spill.dropped


def live_output(view: View, poll: float | None = None) -> SpillWriter:
    """What a live run shows goes through a writer that never blocks: a reader that stops
    reading (a paused pager, a full pipe) loses lines, counted, and never the wire's pace.
    ``poll``: written in batches that often (SpillWriter)."""
    view.flush()
    out = SpillWriter(view.stream, poll=poll)
    view.stream = out
    view.batch = 1
    return out


def end_live_output(view: View, out: SpillWriter, summary: Summary) -> None:
    """Let what was shown reach its reader (as long as that takes, Ctrl-C gives up on it),
    count what was dropped, and write the rest (the summary) straight."""
    try:
        out.close()
    except KeyboardInterrupt:
        pass
    summary.dropped = out.dropped + (view.table.dropped if view.table is not None else 0)
    view.stream = out.stream


def live_table(wanted: bool, view: View, monitor: Monitor, out: SpillWriter | None,
               live: bool):
    """The live table per module (shell/features/livetable.py), when it is wanted: what
    ``view`` shows goes to it, drawn through ``out`` for live traffic (never holding it
    up), straight to the terminal for a log. None: the lines alone, as ever."""
    if not wanted:
        return None
    from .livetable import LiveTable

    view.table = LiveTable(monitor, out if out is not None else view.stream,
                           clock=time.time if live else None, color=view._color)
    return view.table


def end_table(view: View) -> None:
    """The last lines and the table as the run ended, left on the screen."""
    if view.table is not None:
        try:
            view.table.stop()
        except KeyboardInterrupt:
            pass


def _run(source, reader, view: View, filt: Filter, monitor: Monitor, limits: Limits,
         live: bool, started: Callable[[], None] = lambda: None
         ) -> tuple[str | None, Terminated | None]:
    """Show what the source yields until it ends, the limits are reached or Ctrl-C; a live
    source is ended by the reader (requests still waiting are unanswered). Returns why the
    source failed (a lost adapter, a log python-can cannot read on), else None; and the
    SIGTERM or SIGHUP that ended it, if one did. ``started`` says it listens (and starts
    the table) once a signal ends the run as it should: one sent as soon as "listening on"
    shows was an exit 130 from Python's own Ctrl-C."""
    previous = interruptible()
    summary = monitor.summary
    failed = ended = None
    try:
        try:
            started()
            table = view.table
            for items in source:
                if show_items(items, view, filt, summary, limits) \
                        or limits.reached(summary.shown, summary):
                    break
                if live:
                    view.flush()
                    if getattr(view.stream, "gone", False):
                        break  # (`monitor | head`: what it heard no one reads any more)
                elif table is not None:
                    table.tick()
        except KeyboardInterrupt as exc:
            ended = terminated_by(exc)
        except TmclError as exc:
            failed = str(exc)
        finally:
            close = getattr(source, "close", None)
            if close is not None:
                close()
        if reader is not None and not limits.reached(summary.shown, summary):
            show_items(reader.end(time.time()), view, filt, summary, limits)
    finally:
        restore(previous)
        view.flush()
    return failed, ended
