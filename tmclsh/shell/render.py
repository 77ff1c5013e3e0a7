"""Replies rendered for people (rich) and for programs (JSON, one object per line).

Rendering does no I/O on the bus: everything it needs is in the Result and the module
database. For people a reply reads as a sentence with its status in words and colour::

    MaxPositioningSpeed = 1000 pps
    ok: MaxPositioningSpeed set to 1000 pps
    error 4: invalid value
    StatusWord = 9  (bits 0, 3 set)
      bit  0  target reached
      bit  3  position mode
    inputs = 5  IN_0=1 IN_1=0 IN_2=1 IN_3=0 IN_4=0 IN_5=0 IN_6=0 IN_7=0

For programs (``--json``) each result is the object DESIGN.md specifies, keys in its order.

rich is imported only when a terminal shows the text: in a pipe or a file (``-c``, ``-f``,
scripts) results and messages are written as plain lines, the same characters without
colour, and a start-up does not pay for rich.
"""

from __future__ import annotations

import os
import re
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import wraps
from typing import Any

from ..base.edges import error_record
from ..tmcl import instructions as isa
from ..client.text import Result
from ..tmcl.modules import Module, Parameter, type1_of
from ..tmcl.version import TYPE_FIRST, decode_type1, type1_bytes
from ..tmcl.frames import Control, Instruction, Reply, Request, Status, status_text
from .style import rich_theme


# spaces at the end of a line (before any closing colour codes): rich pads table cells and
# wrapped prose to the column width, which leaves trailing blanks in pipes and copied text
_TRAILING_BLANKS = re.compile(r"[ \t]+((?:\x1b\[[0-9;]*m)*)$", re.M)


def is_terminal(stream) -> bool:
    """Whether rich would treat ``stream`` as a terminal (the same environment rules)."""
    tty_compatible = os.environ.get("TTY_COMPATIBLE", "")
    if tty_compatible in ("0", "1"):
        return tty_compatible == "1"
    force_color = os.environ.get("FORCE_COLOR")
    if force_color is not None:
        return force_color != ""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


class Styled:
    """Text whose pieces carry style names: what the renderers build. It becomes rich Text
    only when rich prints it (``__rich__``); ``plain`` is the text without styles."""

    __slots__ = ("parts",)

    def __init__(self, text: str = "", style: str = ""):
        self.parts: list[tuple[str, str]] = [(text, style)] if text else []

    def append(self, text: str, style: str | None = None) -> Styled:
        if text:
            self.parts.append((text, style or ""))
        return self

    def append_text(self, other: Styled) -> Styled:
        self.parts.extend(other.parts)
        return self

    def rstrip(self) -> None:
        while self.parts:
            text, style = self.parts[-1]
            text = text.rstrip()
            if text:
                self.parts[-1] = (text, style)
                return
            self.parts.pop()

    @property
    def plain(self) -> str:
        return "".join([text for text, _ in self.parts])

    def __str__(self) -> str:
        return self.plain

    def __rich__(self):
        from rich.text import Text

        out = Text()
        for text, style in self.parts:
            out.append(text, style=style or None)
        return out


_CONTROL = dict.fromkeys((7, 8, 11, 12, 13))  # bell, backspace, vertical tab, form feed, CR


def _plain_line(text: str) -> str:
    """A line as the trimmed rich console writes it to a pipe: trailing blanks removed."""
    if not text.isprintable():
        text = text.translate(_CONTROL).expandtabs(8)  # as rich writes them
        text = "\n".join(line.rstrip(" ") for line in text.split("\n"))
    else:
        text = text.rstrip(" \t")
    return text + "\n"


def _write_plain(stream, text: str) -> None:
    """A line written as rich writes it to a pipe, and flushed at once (as rich does), so
    stdout and stderr keep their order in one file."""
    stream.write(_plain_line(text))
    stream.flush()


HOLD_SECONDS = 0.05  # Output.hold: results wait at most this long for the next flush
MEMO_LINES = 4096  # Output.result: formatted lines kept


def _console(stderr: bool = False, color: str = "auto", file: Any = None):
    """A rich console that writes to whatever sys.stdout/sys.stderr is *now* (so output from
    other threads goes through prompt_toolkit's ``patch_stdout`` while the prompt runs).

    ``color`` is the setting: "always" colours even a pipe, NO_COLOR and a dumb terminal
    notwithstanding (someone asked for it: ``| less -R``); "never" never; "auto" when writing to
    a terminal that is not dumb and NO_COLOR is unset."""
    from rich.console import Console

    class TrimmedConsole(Console):
        def _render_buffer(self, buffer) -> str:
            return _TRAILING_BLANKS.sub(r"\1", super()._render_buffer(buffer))

    kw: dict[str, Any] = {}
    if color == "always":
        kw.update(force_terminal=True, no_color=False)
        if os.environ.get("TERM", "") in ("dumb", "unknown"):
            kw["color_system"] = "standard"  # rich would detect "no colours" for these
    else:
        no_color = (color == "never" or bool(os.environ.get("NO_COLOR"))
                    or os.environ.get("TERM") == "dumb")
        kw["no_color"] = no_color or None
    # markup=False: every string printed, in a table cell or title too, is shown as it is;
    # user text ('.param [/]', a file name '[bold]x') is never read as rich markup. Styles
    # are given as style= or Text spans, never as [tags] inside strings.
    if file is not None:  # (a unit's own stream, Output.stdout)
        kw["file"] = file
    return TrimmedConsole(stderr=stderr, theme=rich_theme(), highlight=False, soft_wrap=True,
                          markup=False, **kw)


def load_rich() -> None:
    """Import now, in this thread, what a console imports when it first writes (several units
    at once: a stop raised in a unit's thread must not land inside an import, shell/features/units.py)."""
    import io

    console = _console(file=io.StringIO())
    console.print(Styled("-", "tmcl.note"))
    console.print("note: :-)", style="tmcl.note")  # (text with colons: its emoji codes)


class Output:
    """Where results go: rich text for people, JSON lines for programs, errors to stderr."""

    def __init__(self, json_mode: bool = False, color: str = "auto"):
        self.json = json_mode
        self._color = color
        self._paging = False  # inside paged(): a nested one adds nothing
        # whether results come from the built-in simulator (the session sets it): every
        # JSON object then says so, so no program takes them for a module's
        self.simulated: Callable[[], bool] = lambda: False
        self.started = time.monotonic()  # "t" of event objects counts from here
        self._console = None
        self._err = None
        self._terminal: dict[int, tuple[object, bool]] = {}  # is_terminal, by stream
        self._stdout_terminal: tuple[object, bool] = (None, False)  # see result
        # hold: results to a pipe or a file are not written line by line but every
        # HOLD_SECONDS, and before anything else is written or a command runs (a script
        # file's run sets it; see flush). A line written is a system call per line.
        self.hold = False
        self._held = None  # the stream the held lines go to
        self._held_lines: list[str] = []
        self._held_at = 0.0
        self._memo: dict[tuple, tuple] = {}  # see result
        # a unit of several (shell/features/units.py): the fields every JSON object starts with
        # ({"unit": 2, "port": ..., "address": ...}), and who is told of each error said
        self.tag: dict[str, Any] | None = None
        self.on_error: Callable[[str], None] | None = None
        # where this output goes when not to whatever sys.stdout/sys.stderr is at the time: a
        # unit's own streams, so what other threads write for it (the event poller) is its too
        self.stdout: Any = None
        self.stderr: Any = None
        # events come from the event poller's thread (--json runs): every write and flush of
        # this output's lines takes this lock, so lines stay whole and held results go out
        # before a later event (its own: several units' outputs never wait on one another)
        self._emit_lock = threading.RLock()

    # the rich consoles, made when first needed (a test may put its own in place)
    @property
    def console(self):
        self.flush()  # results held back go out before what rich writes
        if self._console is None:
            self._console = _console(color=self._color, file=self.stdout)
        return self._console

    @console.setter
    def console(self, value) -> None:
        self._console = value

    def set_color(self, color: str) -> None:
        """The ``color`` setting from now on ("never": the consoles made already lose their
        colour too; those made later are made so)."""
        self._color = color
        if color == "never":
            for console in (self._console, self._err):
                if console is not None:
                    console.no_color = True

    def flush(self) -> None:
        """Write out the results held back (see ``hold``)."""
        if self._held is None:
            return
        with self._emit_lock:
            stream, self._held = self._held, None
            if stream is not None:
                lines = self._held_lines
                text = "".join(lines)
                lines.clear()
                stream.write(text)
                stream.flush()

    def _write(self, stream, line: str, hold: bool = True) -> None:
        """One finished line to stdout: written now, or held (see ``hold``)."""
        with self._emit_lock:
            held = self._held
            if held is not stream and held is not None:
                self.flush()
                held = None
            if not (hold and self.hold):
                stream.write(line)
                stream.flush()
                return
            self._held_lines.append(line)
            if held is None:
                self._held, self._held_at = stream, time.monotonic()
            elif time.monotonic() - self._held_at >= HOLD_SECONDS:
                self.flush()

    def _write_json(self, line: str) -> None:
        stream = self.stdout or sys.stdout
        self._write(stream, line, not self._is_terminal(stream))

    @property
    def err(self):
        self.flush()  # stdout held back goes out before what goes to stderr
        if self._err is None:
            self._err = _console(stderr=True, color=self._color, file=self.stderr)
        return self._err

    @err.setter
    def err(self, value) -> None:
        self._err = value

    @property
    def is_terminal(self) -> bool:
        """Whether results go to a terminal (colour, live views, progress bars)."""
        if self._console is not None or self._color == "always":
            return self.console.is_terminal
        return self._is_terminal(self.stdout or sys.stdout)

    def _is_terminal(self, stream) -> bool:
        """is_terminal(stream), asked once per stream (isatty is a system call per line)."""
        known = self._terminal.get(id(stream))
        if known is None or known[0] is not stream:
            known = self._terminal[id(stream)] = (stream, is_terminal(stream))
        return known[1]

    def _plain(self, stderr: bool = False):
        """The stream to write plain text to, or None when rich must write (a terminal, colour
        asked for in a pipe, or a console put in place)."""
        if self._color == "always":
            return None
        if stderr:
            stream = self.stderr or sys.stderr
            return stream if self._err is None and not self._is_terminal(stream) else None
        stream = self.stdout or sys.stdout
        return stream if self._console is None and not self._is_terminal(stream) else None

    # -- JSON ---------------------------------------------------------------------------
    def emit(self, obj: dict[str, Any]) -> None:
        if self.tag is not None:
            obj = {**self.tag, **obj}
        if self.simulated():
            obj = {**obj, "simulated": True}
        import json  # (imported by the first JSON line: text output never needs it)

        self._write_json(json.dumps(obj, ensure_ascii=False) + "\n")

    # -- people -------------------------------------------------------------------------
    def print(self, *items: Any, **kw: Any) -> None:
        if self.json:
            return
        # plain strings (no markup: the console reads none), not wrapped (soft_wrap=False
        # wraps at the width even in a pipe)
        stream = self._plain() if kw.get("markup", False) is False and kw.get("soft_wrap", True) \
            else None
        if stream is not None and all(isinstance(i, str) for i in items) \
                and set(kw) <= {"markup", "style", "soft_wrap"}:
            self.flush()
            _write_plain(stream, " ".join(items))  # the text as rich would write it
            return
        self.console.print(*items, **kw)

    def info(self, text: str) -> None:
        """A status line for people (stderr under --json, so stdout stays parseable)."""
        self._message(text, "tmcl.note", stderr=self.json)

    def ok(self, text: str) -> None:
        """A confirmation that something was done (``motors 0, 1 stopped``)."""
        self._message(text, "" if self.json else "tmcl.ok", stderr=self.json)

    def warn(self, text: str) -> None:
        self._message(text, "tmcl.warn", stderr=True)

    def saw_error(self, text: str) -> None:
        """An error is being said (whichever way): tell ``on_error``."""
        if self.on_error is not None:
            self.on_error(text)

    def error(self, line: str | None, message: str,
              record: dict[str, object] | None = None) -> None:
        """``record``: the fields a failed check (.expect, .wait) has in JSON, passed or not."""
        self.saw_error(message)
        if self.json:
            self.emit(error_record(message, line=line, **(record or {})))
        else:
            self._message(f"error: {message}", "tmcl.error", stderr=True)

    def result(self, result: Result, module: Module | None) -> None:
        # A result's line (text or JSON) depends on the line, its instruction, the module and
        # these reply fields only (a raw command number's, a version's or a read-back's
        # reply says more): each line made is kept, so a script repeating its lines formats
        # each once. Whatever else result_json or render_result come to read goes into the key.
        json_mode = self.json
        stream = self.stdout or sys.stdout
        reply = result.reply
        key = None
        if reply is not None and not result.in_doubt:
            key = (result.line, reply.value, reply.status, reply.opcode)
            hit = self._memo.get(key)
            if (hit is not None and hit[5] is stream and hit[0] is result.encoded
                    and hit[1] is module and hit[2] is json_mode and hit[3] is self.simulated()
                    and (json_mode or self._console is None) and reply.version is None
                    and reply.stored is None):
                self._write(stream, hit[4], hit[6])  # (a line made for this same stream)
                return
        known = self._stdout_terminal  # (_is_terminal, for the stream asked last)
        if known[0] is stream:
            terminal = known[1]
        else:
            terminal = self._is_terminal(stream)
            self._stdout_terminal = (stream, terminal)
        if not json_mode and (terminal or self._console is not None or self._color == "always"):
            stream = None  # rich writes (as _plain says, inline: once per line)
        enc = result.encoded
        if stream is None or reply is None or reply.version is not None \
                or reply.stored is not None or enc.spec is None:
            key = None  # not kept: rich writes it, or the reply says more than the key
        if json_mode:
            obj = result_json(result)
            if self.tag is not None:
                obj = {**self.tag, **obj}
            if self.simulated():
                obj["simulated"] = True
            import json  # (as in emit)

            line = json.dumps(obj, ensure_ascii=False) + "\n"
            self._write_json(line)
        else:
            text = render_result(result, module)
            if result.in_doubt:
                text.append(f"  ({IN_DOUBT})", style="tmcl.status.error")
            if stream is None:
                self.console.print(text)
                return
            line = _plain_line(text.plain)
            self._write(stream, line)
        if key is not None:
            if len(self._memo) >= MEMO_LINES:
                self._memo.clear()
            # (the stream and whether to hold its lines, as _write was told above)
            self._memo[key] = (enc, module, json_mode, self.simulated(), line, stream,
                               not (json_mode and terminal))

    @contextmanager
    def paged(self, enabled: bool = True) -> Iterator[None]:
        """Output printed inside goes through the pager when it would not fit the terminal
        (``$PAGER``, else less; ``q`` leaves it), else straight out. Errors (stderr) are not
        held back. Only for a person at a terminal: JSON and pipes get the text as it is."""
        console = self.console
        if not enabled or self.json or self._paging or not console.is_terminal:
            yield
            return
        capture = console.capture()
        self._paging = True
        done = False
        try:
            with capture:
                yield
            done = True
        finally:
            self._paging = False
            text = capture.get()
            # an interrupted or failed command shows what it printed, without a pager
            if not done or _rows(text, console.size.width) < console.size.height:
                console.file.write(text)
                console.file.flush()
            else:
                _page(text)

    def event(self, reply: Reply, at: float | None = None) -> None:
        """A 138 event (or any unsolicited reply), shown when it arrives. ``at``: when it
        arrived (time.monotonic()); JSON gives it as seconds since the run started."""
        if self.json:
            t = (time.monotonic() if at is None else at) - self.started
            self.emit({"event": int(Control.TARGET_REACHED_EVENT), "motors": event_motors(reply),
                       "t": round(t, 4)})
            return
        stream = self._plain()
        if stream is None:
            self.console.print(render_event(reply), style="tmcl.event", markup=False)
        else:
            self.flush()
            _write_plain(stream, render_event(reply))

    def _message(self, text: str, style: str, stderr: bool) -> None:
        """One message line: on a terminal wrapped between words (not cut mid-word by the
        terminal), in a pipe or a file one line as it is."""
        self.flush()
        stream = self._plain(stderr)
        if stream is None:
            _message(self.err if stderr else self.console, text, style)
        else:
            _write_plain(stream, text)


def _rows(text: str, width: int) -> int:
    """Terminal rows ``text`` takes, long lines wrapped."""
    from rich.cells import cell_len
    from rich.text import Text

    width = max(width, 1)
    return sum(max(1, -(-cell_len(line) // width))
               for line in Text.from_ansi(text).plain.splitlines())


def _page(text: str) -> None:
    """Through rich's system pager (pydoc's: $MANPAGER, $PAGER, else less or more). Colours
    stay only where the pager shows them (less -R); any other pager gets plain text."""
    from rich.pager import SystemPager
    from rich.text import Text

    pager = os.environ.get("MANPAGER") or os.environ.get("PAGER")
    if pager is None:
        # colours (rich's documentation asks less users for -R), and the last page stays on
        # the screen after q (-X), so the table is still there to read at the prompt
        os.environ.setdefault("LESS", "-RX")
    less_raw = "R" in os.environ.get("LESS", "").upper() or "-R" in (pager or "").upper()
    if not ((pager is None or "less" in pager) and less_raw):
        text = Text.from_ansi(text).plain
    SystemPager().show(text)


def paging(session: Any) -> bool:
    """Long output is paged in the interactive shell when the ``pager`` setting is on
    (app.py keeps it in ``session.state``), never in -c, -f or a script run from the shell."""
    return bool(session.interactive and session.state.pager
                and not session.state.script_depth)


def paged(handler: Callable[[Any, str], None]) -> Callable[[Any, str], None]:
    """A dot-command whose output may be long (``.help``, ``.params``): paged (see
    ``Output.paged``)."""

    @wraps(handler)
    def run(session: Any, arg: str, *args: Any, **kw: Any) -> None:
        with session.out.paged(paging(session)):
            handler(session, arg, *args, **kw)

    return run


def _message(console, text: str, style: str) -> None:
    console.print(text, style=style, markup=False, soft_wrap=not console.is_terminal)


IN_DOUBT = ("in doubt: this answer may have been another request's, and reading again "
            "did not settle it; run it again to be sure")


def result_json(result: Result) -> dict[str, Any]:
    """``{"line", "op", "type", "motor", "value", "status", "reply"}`` (DESIGN.md), plus
    ``"error"`` when the module refused."""
    ins = result.encoded.instruction
    reply = result.reply
    obj: dict[str, Any] = {"line": result.line, "op": ins.opcode, "type": ins.type,
                           "motor": ins.motor, "value": ins.signed_value,
                           "status": reply.status if reply else None,
                           "reply": reply.value if reply else None}
    if reply is not None and reply.version is not None:
        obj["reply"] = reply.version
    if reply is not None and reply.stored is not None:
        obj["reply"] = reply.value
        obj["stored"] = {"op": reply.stored.opcode, "type": reply.stored.type,
                         "motor": reply.stored.motor, "value": reply.stored.signed_value}
    if reply is not None and reply.status not in (Status.OK, Status.LOADED, Status.EVENT):
        obj["error"] = status_text(reply.status)
    if result.in_doubt:
        obj["in_doubt"] = True
        obj["warning"] = IN_DOUBT
    param = result.encoded.parameter
    if param is not None and reply is not None and reply.ok and result.encoded.spec is not None \
            and result.encoded.spec.reads:
        obj["reply"] = param.reading(reply.value)
        outside = param.outside(obj["reply"])
        if outside is not None:
            obj["outside_range"] = outside  # the manual's range the value lies outside
    return obj


def _unsigned(value: int, param: Parameter | None) -> int:
    return value if param is None else param.reading(value)


def value_text(value: int, param: Parameter | None) -> str:
    """``1000 pps``, ``8 (256 microsteps)``, ``17 (start up in ASCII mode; ...)``."""
    if param is None:
        return str(value)
    value = _unsigned(value, param)
    text = f"{value}"
    if param.unit:
        text += f" {param.unit}"
    meaning = param.describe_value(value)
    if meaning:
        text += f" ({meaning})"
    outside = param.outside(value)
    if outside is not None:
        text += f" (outside the manual's range {outside})"
    return text


# what a successful command without a read value did, in words
def render_result(result: Result, module: Module | None) -> Styled:
    reply = result.reply
    enc = result.encoded
    ins = enc.instruction
    out = Styled()
    if reply is None:
        out.append("sent (this command has no reply)", style="tmcl.note")
        return out
    if reply.version is not None:
        out.append("firmware ", style="tmcl.note")
        out.append(reply.version, style="tmcl.value")
        return out
    if not reply.ok:
        out.append(f"error {reply.status}: {status_text(reply.status)}", style="tmcl.status.error")
        hint = _status_hint(reply.status)
        if hint:
            out.append(f"  ({hint})", style="tmcl.note")
        return out
    spec = enc.spec
    if reply.stored is not None:
        out.append(f"stored at {ins.signed_value}: ", style="tmcl.note")
        out.append(describe_instruction(reply.stored, module), style="tmcl.value")
        return out
    if spec is None:  # a raw command number
        if ins.opcode == Control.GET_VERSION and ins.type == 1:
            out.append(version_text(reply.value, module), style="tmcl.value")
            return out
        if reply.opcode == ins.opcode and (isa.is_control(ins.opcode)
                                           or isa.by_opcode(ins.opcode)):
            out.append("ok", style="tmcl.status.ok")
            ctl = isa.control(ins.opcode)
            name = ctl.name.split(" (")[0] if ctl else isa.by_opcode(ins.opcode).mnemonic
            out.append(f" ({ins.opcode}: {name}), value {reply.value}")
            return out
        out.append(describe_reply(reply, module))
        return out
    if spec.reads_with(ins.type, module) and spec.done_text(ins.type, module) is None:
        return _render_read(out, result, module)
    out.append("ok", style="tmcl.status.ok")
    if spec.turns is not None:  # ROR/ROL: which way, said from the sign
        velocity = module.units.get("velocity", "") if module else ""
        out.append(": " + _rotate_text(spec, ins.motor, ins.signed_value, velocity))
        return out
    done = spec.done_text(ins.type, module)
    if done is not None:
        out.append(": " + done.format(**_done_fields(result, module)).rstrip())
    elif reply.value:
        out.append(f", value {reply.value}")
    return out


def _done_fields(result: Result, module: Module | None) -> dict[str, object]:
    """What a ``done`` sentence of the instruction set may name (instructions.toml)."""
    ins, param, reply = result.encoded.instruction, result.encoded.parameter, result.reply
    port = module.port(ins.motor, ins.type) if module is not None else None
    port_name = port.name if port is not None else f"port {ins.type}"
    if module is not None and ins.type == module.io_all_port:
        port_name = "all outputs"
    value = ins.signed_value
    return {"motor": ins.motor, "value": value,
            "value_text": value_text(value, param) if param is not None else str(value),
            "param": param.name if param is not None else f"parameter {ins.type}",
            "port": port_name, "reply": reply.value if reply is not None else "",
            "running": "running" if reply is not None and reply.value else "not running",
            "position_unit": module.units.get("position", "") if module else "",
            "velocity_unit": module.units.get("velocity", "") if module else ""}


def _rotate_text(spec, motor: int, value: int, unit: str) -> str:
    """Which way the motor turns: ROL with a negative speed turns right (the module sets
    the target speed to -value), and speed 0 stops it."""
    if value == 0:
        return f"motor {motor} stopping (speed 0; it ramps down)"
    way = spec.turns if value > 0 else ("left" if spec.turns == "right" else "right")
    text = f"motor {motor} rotating {way} at {abs(value)} {unit}".rstrip()
    return f"{text} ({spec.mnemonic} with a negative speed)" if value < 0 else text


def _render_read(out, result: Result, module: Module | None):
    reply = result.reply
    assert reply is not None
    enc = result.encoded
    ins = enc.instruction
    spec = enc.spec
    param = enc.parameter
    if param is None:  # a raw `6 4, 0, 0`: name the parameter all the same
        param = param_for(ins, module)
    if spec is not None and spec.type_kind == "port" and module is not None:
        if ins.type == module.io_all_port and ins.motor in module.io_all_banks:
            ports = sorted((p for p in module.io if p.bank == ins.motor), key=lambda p: p.port)
            what = "outputs" if ports and ports[0].kind == "digital_out" else "inputs"
            out.append(f"{what} = ")
            out.append(str(reply.value), style="tmcl.value")
            out.append(f"  ({reply.value & 0xFF:#010b})  ", style="tmcl.note")
            for i, p in enumerate(ports):
                on = bool(reply.value >> p.port & 1)
                out.append(f"{p.name}={int(on)}", style="tmcl.bit.on" if on else "tmcl.bit.off")
                if i + 1 < len(ports):
                    out.append(" ")
            return out
        port = module.port(ins.motor, ins.type)
        if port is not None:
            out.append(port.name, style="tmcl.name")
            out.append(" = ")
            out.append(_scaled(reply.value, port.unit), style="tmcl.value")
            if port.unit.startswith("1/"):
                out.append(f"  ({reply.value} × {port.unit})", style="tmcl.note")
            return out
    if param is not None:
        out.append(param.name, style="tmcl.name")
        if param.count > 1:
            out.append(f"[{ins.type}]", style="tmcl.name")
        out.append(" = ")
        value = _unsigned(reply.value, param)
        if param.bits:
            out.append(str(value), style="tmcl.value")
            if param.unit:
                out.append(f" {param.unit}")
            on = [b for b in sorted(param.bits) if value >> b & 1]
            if value in param.values:
                out.append(f" ({param.values[value]})")
            out.append(f"  ({_bits_summary(on)})", style="tmcl.note")
            if on:
                out.append("\n")
                out.append_text(render_bits(value, param, only_set=True))
            return out
        out.append(value_text(reply.value, param), style="tmcl.value")
        return out
    out.append(str(reply.value), style="tmcl.value")
    return out


def _bits_summary(on: list[int]) -> str:
    if not on:
        return "no bits set"
    return f"bit{'s' if len(on) > 1 else ''} {', '.join(map(str, on))} set"


def render_bits(value: int, param: Parameter, only_set: bool = False) -> Styled:
    """One line per documented bit: ``  bit  0  target reached``."""
    text = Styled()
    for bit, meaning in sorted(param.bits.items()):
        on = bool(value >> bit & 1)
        if only_set and not on:
            continue
        mark = "" if only_set else (" 1" if on else " 0")
        text.append(f"  bit {bit:2d}{mark}  {meaning}\n",
                    style="tmcl.bit.on" if on else "tmcl.bit.off")
    text.rstrip()
    return text


def _status_hint(status: int) -> str:
    return {
        Status.WRONG_CHECKSUM: "the module saw a corrupted frame; check the cabling and baud rate",
        Status.INVALID_COMMAND: "this firmware does not know the command",
        Status.WRONG_TYPE: "the module does not have this parameter/type",
        Status.INVALID_VALUE: "the module refused the value",
        Status.EEPROM_LOCKED: "unlock it with GP 73 (EEPROMLockFlag)",
        Status.COMMAND_NOT_AVAILABLE: "not available in the module's current state",
    }.get(status, "")


def prose_list(items, empty: str = "none") -> str:
    """``0, 1, 2`` for people, never ``[0, 1, 2]``; ``empty`` when there is nothing."""
    words = [str(i) for i in items]
    return ", ".join(words) if words else empty


def version_text(value: int, module: Module | None, layout: str | None = None) -> str:
    """The value field read the way the module's manual lays out its four bytes (or as
    ``layout`` says): ``05 1F 6F 00: module type 1311 (05 1F), version 111 (6F 00, low byte
    first)``."""
    b = [f"{x:02X}" for x in (value & 0xFFFFFFFF).to_bytes(4, "big")]
    raw = " ".join(b)
    if layout is None:
        decoded = type1_of(value, module)
        layout = module.version_layout if module is not None else TYPE_FIRST
    else:
        decoded = decode_type1(value, layout)
    if decoded is None:
        return f"{raw} (not a module type and version this module's manual describes)"
    kind, ver = decoded
    kind_at, ver_at = type1_bytes(layout)
    low_first = "" if layout == TYPE_FIRST else ", low byte first"
    return (f"{raw}: module type {kind} ({' '.join(b[kind_at])}{low_first}), "
            f"version {ver} ({' '.join(b[ver_at])}, low byte first)")


def _scaled(value: int, unit: str) -> str:
    """``240 1/10 V`` reads as ``24.0 V``."""
    m = re.fullmatch(r"1/(10|100|1000) (\S.*)", unit)
    if not m:
        return f"{value} {unit}".rstrip()
    den = int(m.group(1))
    digits = len(m.group(1)) - 1
    return f"{value / den:.{digits}f} {m.group(2)}"


def event_motors(reply: Reply) -> list[int]:
    return [m for m in range(8) if reply.value >> m & 1]


def render_event(reply: Reply) -> str:
    motors = [str(m) for m in event_motors(reply)]
    return f"event: target position reached (motor {', '.join(motors) or reply.value})"


# -- describing instructions and replies -------------------------------------------------

def describe_instruction(ins: Instruction, module: Module | None) -> str:
    """``GAP 4, 0  // MaxPositioningSpeed``, ``136 type 0: firmware version``."""
    if isa.is_control(ins.opcode):
        ctl = isa.control(ins.opcode)
        if ctl is not None:
            fields = [f"{name} {v}" for name, v in (("type", ins.type), ("motor", ins.motor),
                                                    ("value", ins.signed_value)) if v]
            return f"{ins.opcode} {_control_name(ins.opcode)}" + (
                f" ({', '.join(fields)})" if fields else "")
    from ..tmcl import asm  # (the disassembler: a trace, .decode)

    text, comment = asm.disassemble_instruction(ins, module)
    return f"{text}  // {comment}" if comment else text


def param_for(ins: Instruction, module: Module | None):
    if module is None:
        return None
    spec = isa.by_opcode(ins.opcode)
    if spec is None:
        return None
    if spec.type_kind == "axis_param":
        return module.axis(ins.type)
    if spec.type_kind == "global_param":
        return module.glob(ins.type, ins.motor)
    return None


def took(seconds: float | None) -> str:
    """How long an exchange took, in the unit that reads best."""
    if seconds is None:
        return ""
    return f"{seconds * 1000:.2f} ms" if seconds < 1 else f"{seconds:.3f} s"


def describe_reply(reply: Reply, module: Module | None = None,
                   request: Request | None = None) -> str:
    """``100 ok, value 1000 (MaxPositioningSpeed = 1000 pps)``, ``event: ...``."""
    if reply.version is not None:
        return f"version {reply.version!r}"
    if reply.stored is not None:
        return f"stored instruction: {describe_instruction(reply.stored, module)}"
    if reply.is_event:
        motors = [str(m) for m in range(8) if reply.value >> m & 1]
        return f"event: target position reached, motor {', '.join(motors) or '-'}"
    head, param = reply_head(reply, module, request)
    return reply_words(head, reply.value, param)


def reply_head(reply: Reply, module: Module | None = None,
               request: Request | None = None) -> tuple[str, Parameter | None]:
    """A reply with a value in words up to the value (``100 ok, GAP value ``), and the
    parameter whose meaning follows the value, if any: the same for every reply of one
    status to one request, so a log's thousands of them are worded once (``reply_words``
    puts a value in)."""
    spec = isa.by_opcode(reply.opcode)
    what = spec.mnemonic if spec else (f"{reply.opcode}" if not isa.is_control(reply.opcode) else
                                        f"{reply.opcode} ({_control_name(reply.opcode)})")
    head = f"{reply.status} {status_text(reply.status)}, {what} value "
    if request is not None and request.opcode == reply.opcode and reply.ok:
        param = param_for(request.instruction, module)
        if param is not None and spec is not None and spec.reads:
            return head, param
    return head, None


def reply_words(head: str, value: int, param: Parameter | None) -> str:
    """``describe_reply`` of a reply with a value, from its ``reply_head``."""
    if param is None:
        return f"{head}{value}"
    return f"{head}{value} ({param.name} = {value_text(value, param)})"


def _control_name(opcode: int) -> str:
    ctl = isa.control(opcode)
    return ctl.name.split(" (")[0] if ctl else "unknown command"
