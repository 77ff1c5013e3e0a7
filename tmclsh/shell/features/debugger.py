"""The program on the module, from the shell: run, step, breakpoints, where it stands, listings
(``upload.py`` puts a program on the module and reads it back).

Dot-commands over :mod:`tmclsh.ops.program` (which does the bus work and is usable without the
shell). The debugger's state lives in ``session.state.debugger`` (a :class:`DebuggerState`);
``session.state.program_state`` holds a short text for the toolbar ("run", "stop",
"step @12") and ``session.state.repeat_on_empty`` is set after ``.step`` so an empty line
steps again, as in gdb and pdb.

When the program's source is known (uploaded in this session, or named with ``.source-map``)
locations are shown as ``file:line`` with the line's text; otherwise as ``@address`` with the
instruction disassembled from the module's memory (read with 134, cached).

These firmwares have no breakpoint command: ``.continue`` steps the module (130) and reads the
program counter (GP 130) after each instruction until it reaches a breakpoint, so it runs
much slower than ``.run``, which ignores breakpoints.
"""

from __future__ import annotations

import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ...tmcl import asm
from ...base import files, limits
from ...ops import program
from ...base.errors import TmclError, ValidationError
from ...ops.program import AppStatus
from ...tmcl.frames import Control, Instruction
from ..lang.commands import command
from ..render import paged

if TYPE_CHECKING:
    from ..lang.session import Session

CATEGORY = "program"
LIST_CONTEXT = 5  # lines shown either side of the current one by .list
SHORT_LISTING = 20  # a program of up to this many lines is listed whole


class DebuggerError(TmclError):
    """A debugger command that cannot do what was asked (nothing was sent)."""


# -- state -------------------------------------------------------------------------------

@dataclass
class Breakpoint:
    number: int
    spec: str  # as typed, re-resolved when the program changes
    address: int
    hits: int = 0


@dataclass
class Display:
    number: int
    expr: str


@dataclass
class Where:
    """A program address in the terms the session knows: source line or disassembly."""

    pc: int
    file: str | None = None
    line: int | None = None
    text: str = ""
    label: str | None = None
    end: bool = False  # no instruction stored here (the end of the program, or none at all)

    @property
    def place(self) -> str:
        if self.file is not None and self.line is not None:
            return f"{_show_path(self.file)}:{self.line}"
        return f"@{self.pc}"

    def to_json(self) -> dict[str, object]:
        obj: dict[str, object] = {}
        if self.file is not None:
            obj["file"] = self.file
            obj["line"] = self.line
        if self.text:
            obj["text"] = self.text
        if self.end:
            obj["end"] = True
        return obj


@dataclass
class DebuggerState:
    program: asm.Program | None = None  # the source the stored program came from
    breakpoints: dict[int, Breakpoint] = field(default_factory=dict)
    displays: dict[int, Display] = field(default_factory=dict)
    next_breakpoint: int = 1
    next_display: int = 1
    memory: dict[int, Instruction] = field(default_factory=dict)  # 134 read cache
    files: dict[str, list[str] | None] = field(default_factory=dict)  # source text cache
    last: AppStatus | None = None

    @property
    def source_file(self) -> str | None:
        if self.program is None or not self.program.source:
            return None
        return self.program.source[0].file

    def forget_memory(self) -> None:
        self.memory.clear()

    def __rich__(self):
        from rich.table import Table

        table = Table(title="breakpoints", show_header=True, header_style="tmcl.name",
                      box=None, title_justify="left")
        table.add_column("#", justify="right")
        table.add_column("address", justify="right")
        table.add_column("where")
        table.add_column("hits", justify="right")
        for bp in sorted(self.breakpoints.values(), key=lambda b: b.number):
            table.add_row(str(bp.number), str(bp.address), bp.spec, str(bp.hits))
        return table


def state(session: Session) -> DebuggerState:
    dbg = session.state.debugger
    if not isinstance(dbg, DebuggerState):
        dbg = DebuggerState()
        session.state.debugger = dbg
    return dbg


def _show_path(path: str) -> str:
    if path.startswith("<"):
        return path
    try:
        rel = os.path.relpath(path)
    except ValueError:
        return path
    return path if rel.startswith("..") else rel


# -- small parsing helpers ---------------------------------------------------------------

def _number(text: str, what: str) -> int:
    t = text.strip()
    try:
        if t.startswith("$"):
            return int(t[1:], 16)
        return int(t, 0)
    except ValueError:
        shown = t if len(t) <= 40 else t[:40] + "..."
        raise ValidationError(f"{what} must be a number, got {shown!r}") from None


def _resolve_file(session: Session, name: str) -> Path:
    p = Path(name).expanduser()
    if p.exists() or p.is_absolute():
        return p
    if session.location is not None:  # relative to the script being run
        beside = Path(session.location[0]).parent / name
        if beside.exists():
            return beside
    return p


# -- locations ---------------------------------------------------------------------------

def _cached_instruction(session: Session, address: int) -> Instruction | None:
    dbg = state(session)
    if address in dbg.memory:
        return dbg.memory[address]
    if not program.carried(session.client, Control.READ_MEMORY):
        return None
    module = session.module
    if not 0 <= address < module.program_memory:
        return None
    ins = program.read_instruction(session.client, address)
    dbg.memory[address] = ins
    return ins


def _enclosing_label(prog: asm.Program | None, pc: int) -> str | None:
    if prog is None:
        return None
    best = None
    for name, addr in prog.labels.items():
        if addr <= pc and (best is None or addr > best[1]):
            best = (name, addr)
    return best[0] if best else None


def where(session: Session, pc: int) -> Where:
    """``pc`` as a source line (when the source is known) or disassembled from memory."""
    dbg = state(session)
    prog = dbg.program
    loc = prog.loc(pc) if prog is not None else None
    if loc is not None and prog is not None and prog.image:
        # an image's "lines" are records of a binary file: cite the disassembly instead
        return Where(pc, text=loc.text, label=_enclosing_label(prog, pc))
    if loc is not None:
        return Where(pc, loc.file, loc.line, loc.text, _enclosing_label(prog, pc))
    try:
        ins = _cached_instruction(session, pc)
    except TmclError:
        ins = None
    if ins is None:
        return Where(pc)
    if program.is_end_marker(ins):  # (memory never written reads 0 0, 0, 0: no command)
        return Where(pc, end=True)
    text, _comment = asm.disassemble_instruction(ins, session.module)
    return Where(pc, text=text)


def _source_lines(session: Session, file: str) -> list[str] | None:
    dbg = state(session)
    if file not in dbg.files:
        try:
            dbg.files[file] = files.read_bytes(file, what="source").decode(
                "utf-8", errors="replace").splitlines()
        except files.FileError:
            dbg.files[file] = None
    return dbg.files[file]


def resolve(session: Session, text: str, *, line_numbers: bool) -> tuple[int, str]:
    """A location typed by the user as ``(address, description)``.

    ``Label``; ``@ADDR`` (always an address); ``FILE:LINE``; a bare number is a source line
    when ``line_numbers`` and the source is known, else an address. ``L0012`` (the
    disassembler's generated labels) is address 12 when no source label has that name.
    """
    dbg = state(session)
    prog = dbg.program
    module = session.module
    t = text.strip()
    if not t:
        raise ValidationError("give a label, a line number or @address")

    def check(addr: int) -> int:
        if not 0 <= addr < module.program_memory:
            raise ValidationError(f"address {addr} is outside program memory "
                                  f"0..{module.program_memory - 1}")
        return addr

    if t.startswith("@"):
        addr = check(_number(t[1:], "address"))
        return addr, f"@{addr}"
    m = re.fullmatch(r"(.+):(\d{1,9})", t)
    if m and not t[0].isdigit():
        if prog is None:
            raise ValidationError(f"no source file is known for the stored program; "
                                  f"use .source-map FILE (or .upload FILE) before {t}")
        name, line = m.group(1), int(m.group(2))
        files = {loc.file for loc in prog.source}
        match = [f for f in files if f == name or Path(f).name == Path(name).name]
        if not match:
            raise ValidationError(f"{name} is not part of the program (files: "
                                  f"{', '.join(sorted(_show_path(f) for f in files))})")
        return _line_address(prog, line, match[0])
    if re.fullmatch(r"(\$|0[xX])?[0-9A-Fa-f]+", t) and (t[0].isdigit() or t[0] == "$"):
        n = _number(t, "line or address")
        if line_numbers and prog is not None:
            return _line_address(prog, n, dbg.source_file)
        addr = check(n)
        return addr, f"@{addr}"
    if prog is not None:
        for name, addr in prog.labels.items():
            if name.lower() == t.lower():
                return addr, name
    g = re.fullmatch(r"[Ll](\d{4})", t)
    if g:
        addr = check(int(g.group(1)))
        return addr, t.upper()
    if prog is None:
        raise ValidationError(f"unknown label {t!r}: no source file is known for the stored "
                              "program (use .source-map FILE), give @ADDRESS instead")
    labels = ", ".join(sorted(prog.labels)) or "none"
    raise ValidationError(f"unknown label {t!r} (labels: {labels})")


def _line_address(prog: asm.Program, line: int, file: str | None) -> tuple[int, str]:
    addr = prog.address_of_line(line, file)
    if addr is None:
        raise ValidationError(f"no instruction at or after line {line} of "
                              f"{_show_path(file or '?')}")
    loc = prog.loc(addr)
    assert loc is not None
    return addr, f"{_show_path(loc.file)}:{loc.line}"


# -- reporting ---------------------------------------------------------------------------

def _set_state(session: Session, st: AppStatus) -> None:
    state(session).last = st
    session.state.program_state = f"step @{st.pc}" if st.state == "step" else st.state


def _read_status(session: Session) -> AppStatus:
    st = program.status(session.client)
    _set_state(session, st)
    return st


def _display_values(session: Session) -> list[tuple[Display, str]]:
    out = []
    for d in sorted(state(session).displays.values(), key=lambda d: d.number):
        try:
            out.append((d, str(_evaluate(session, d.expr))))
        except TmclError as exc:
            out.append((d, f"<error: {exc}>"))
    return out


def _evaluate(session: Session, expr: str) -> int | float:
    evaluate = session.state.evaluate
    if callable(evaluate):
        return evaluate(session, expr)
    enc = session.client.encode(expr)
    if enc.spec is None or not enc.spec.reads:
        raise ValidationError(f"{expr!r} does not read a value; a display must not change "
                              "anything (use GAP, GGP, GIO, ...)")
    result = session.client.execute(expr)
    return result.value if result.value is not None else 0


def report(session: Session, st: AppStatus, *, prefix: str = "", extra: dict | None = None,
           displays: bool = True) -> None:
    """One stop line: state, address, source line (or disassembly), then the displays."""
    w = where(session, st.pc)
    values = _display_values(session) if displays else []
    out = session.out
    if out.json:
        obj: dict[str, object] = {**st.to_json(), **w.to_json()}
        if values:
            obj["display"] = {d.expr: v for d, v in values}
        if extra:
            obj.update(extra)
        out.emit(obj)
        return
    from rich.text import Text

    t = Text()
    if prefix:
        t.append(prefix + " ", style="tmcl.event")
    t.append(st.state, style="tmcl.value")
    t.append(f" @{st.pc}", style="tmcl.name")
    if w.file is not None:
        t.append(f"  {w.place}", style="tmcl.note")
    if w.text:
        t.append(f"  {w.text}")
    elif w.end:
        t.append("  (no instruction here: the end of the stored program)", style="tmcl.note")
    _line(session, t)
    for d, v in values:
        out.print(Text.assemble(f"  {d.number}: ", (d.expr, "tmcl.name"), " = ", (v, "tmcl.value")))


def _line(session: Session, text) -> None:
    """One line; on a terminal a long one (a source line's comment) ends in '…' instead of
    wrapping. Piped output keeps every character."""
    out = session.out
    if out.is_terminal:
        out.print(text, soft_wrap=False, no_wrap=True, overflow="ellipsis")
    else:
        out.print(text)


def _rebind_breakpoints(session: Session) -> None:
    """After the program changed: resolve each breakpoint's spec again; drop the lost ones."""
    dbg = state(session)
    for bp in list(dbg.breakpoints.values()):
        if bp.spec.startswith("@"):
            continue
        try:
            bp.address, _ = resolve(session, bp.spec, line_numbers=True)
        except TmclError:
            session.out.info(f"breakpoint {bp.number} ({bp.spec}) no longer resolves; deleted")
            del dbg.breakpoints[bp.number]


def _not_repeating(session: Session) -> None:
    repeat = session.state.repeat_on_empty
    if isinstance(repeat, str) and repeat.startswith(".step"):
        session.state.repeat_on_empty = None


# -- completion --------------------------------------------------------------------------


def complete_location(session: Session, text: str) -> list[str | tuple[str, str]]:
    dbg = state(session)
    out: list[str | tuple[str, str]] = []
    if dbg.program is not None:
        out += [(name, f"@{addr}") for name, addr in sorted(dbg.program.labels.items())]
    return out


def complete_breakpoints(session: Session, text: str) -> list[str | tuple[str, str]]:
    return [(str(n), bp.spec) for n, bp in sorted(state(session).breakpoints.items())]


# -- running -----------------------------------------------------------------------------

@command(".run")
def cmd_run(session: Session, argtext: str) -> None:
    _not_repeating(session)
    address = None
    if argtext.strip():
        program.require_binary(session.client, "running from an address (129 type 1)",
                               Control.RUN_APPLICATION, type_=1)
        address, _desc = resolve(session, argtext, line_numbers=False)
    program.run(session.client, address)
    st = _read_status(session)
    if state(session).breakpoints and not session.out.json:
        session.out.info("running at full speed: breakpoints only stop .continue")
    report(session, st, displays=False)


@command(".stop")
def cmd_stop(session: Session, argtext: str) -> None:
    _not_repeating(session)
    program.stop(session.client)
    report(session, _read_status(session))


@command(".reset")
def cmd_reset(session: Session, argtext: str) -> None:
    _not_repeating(session)
    program.reset(session.client)
    report(session, _read_status(session))


@command(".status")
def cmd_status(session: Session, argtext: str) -> None:
    report(session, _read_status(session), displays=False)


@command(".where")
def cmd_where(session: Session, argtext: str) -> None:
    st = _read_status(session)
    report(session, st, displays=False)
    w = where(session, st.pc)
    if w.label and not session.out.json:
        session.out.info(f"  in {w.label}")


# -- stepping ----------------------------------------------------------------------------

@command(".step")
def cmd_step(session: Session, argtext: str) -> None:
    n = int(limits.parse("count", argtext, ".step N")) if argtext.strip() else 1
    program.require_binary(session.client, "stepping (130)", Control.STEP_APPLICATION)
    pc: int | None = program.program_counter(session.client)
    _check_something_to_step(session, pc)
    session.state.repeat_on_empty = ".step" if n == 1 else f".step {n}"
    def waiting(pc: int) -> None:
        session.out.info(f"  WAIT at @{pc}: waiting for it to finish (Ctrl-C stops waiting)")

    done = 0
    try:
        for done in range(1, n + 1):
            session.time_left()  # the session's time limit, if it has one
            program.step_one(session.client, pc=pc, instruction_at=_stored(session),
                             on_wait=waiting)
            st = _read_status(session)
            pc = st.pc
            hit = _hit(session, st.pc)
            report(session, st, prefix=hit or "", extra={"step": done} if n > 1 else None)
            if st.state != "step":
                session.out.info("the program stopped (it ran a STOP or reached its end)")
                break
    except KeyboardInterrupt:
        session.end_interrupted_line()
        session.out.info(f"interrupted after {_plural(done - 1, 'step')}")
        report(session, _read_status(session), displays=False)
        raise  # the shell's Ctrl-C policy (stop the motors) applies as to any command


def _check_something_to_step(session: Session, pc: int) -> None:
    """Refuse (nothing sent) where no instruction is stored: memory never written, or the
    end of the program."""
    ins = _cached_instruction(session, pc)
    if ins is None or not program.is_end_marker(ins):
        return
    first = ins if pc == 0 else _cached_instruction(session, 0)
    _not_repeating(session)
    if first is not None and program.is_end_marker(first):
        raise DebuggerError(f"program memory of the {session.module.name} is empty (no "
                            "instruction at address 0): nothing to step; .upload FILE "
                            "stores a program")
    raise DebuggerError(f"no instruction at @{pc} (the end of the stored program): nothing "
                        "to step; .reset or .run LABEL starts it again")


def refresh_program_state(session: Session) -> None:
    """After .connect: the prompt and toolbar show the new module's program state at once,
    and what was cached about the old module's memory is forgotten."""
    dbg = state(session)
    dbg.forget_memory()
    dbg.last = None
    session.state.program_state = None
    _not_repeating(session)
    client = session.client
    if (not client.connected or client.module is None
            or not program.carried(client, Control.STEP_APPLICATION)):
        return  # (nothing to debug where the program cannot be stepped: ASCII mode)
    try:
        _read_status(session)
    except TmclError:
        pass  # no program state to show: the toolbar shows none rather than an old one


def _stored(session: Session):
    """``instruction_at`` for tmclsh.ops.program: the cached stored instruction."""
    def at(address: int) -> Instruction:
        ins = _cached_instruction(session, address)
        if ins is None:  # pragma: no cover - binary mode is checked before stepping
            raise ValidationError(f"cannot read the instruction at {address}")
        return ins
    return at


def _plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def _hit(session: Session, pc: int) -> str | None:
    for bp in state(session).breakpoints.values():
        if bp.address == pc:
            return f"breakpoint {bp.number},"
    return None


@command(".continue")
def cmd_continue(session: Session, argtext: str) -> None:
    dbg = state(session)
    limit = _number(argtext, "MAXSTEPS") if argtext.strip() else None
    _not_repeating(session)
    if not dbg.breakpoints:
        program.run(session.client)
        session.out.info("no breakpoints: running at full speed (129)")
        report(session, _read_status(session), displays=False)
        return
    program.require_binary(session.client, "running to a breakpoint (130 steps)",
                           Control.STEP_APPLICATION)
    current = program.status(session.client)
    if current.state == "run":
        program.stop(session.client)
        session.out.info("stopped the running program to step it to a breakpoint")
    targets = {bp.address for bp in dbg.breakpoints.values()}
    steps = [0]

    def counted(n: int, pc: int) -> None:
        steps[0] = n
        session.time_left()  # the session's time limit, if it has one

    stored = _stored(session)

    began = time.monotonic()
    try:
        if not session.out.json and session.out.is_terminal:
            with session.out.console.status("stepping to a breakpoint (Ctrl-C stops)"):
                info = program.continue_to(session.client, targets, max_steps=limit,
                                           on_step=counted, instruction_at=stored)
        else:
            info = program.continue_to(session.client, targets, max_steps=limit,
                                       on_step=counted, instruction_at=stored)
    except KeyboardInterrupt:
        session.end_interrupted_line()
        session.out.info(f"interrupted after {_plural(steps[0], 'step')}")
        report(session, _read_status(session))
        raise  # the shell's Ctrl-C policy (stop the motors) applies as to any command
    st = _read_status(session)
    elapsed = time.monotonic() - began
    extra = {"reason": info.reason, "steps": info.steps}
    if info.reason == "breakpoint":
        bp = next(b for b in dbg.breakpoints.values() if b.address == info.pc)
        bp.hits += 1
        report(session, st, prefix=f"breakpoint {bp.number},", extra={**extra, "breakpoint":
                                                                    bp.number})
    elif info.reason == "ended":
        report(session, st, prefix="program stopped:", extra=extra)
    elif info.reason == "end":
        report(session, st, prefix="end of the stored program, no breakpoint reached:",
               extra=extra)
        if not session.out.json:
            session.out.info("  .reset or .run LABEL starts it again")
    else:
        report(session, st, prefix=f"{_plural(info.steps, 'step')}, no breakpoint:",
               extra=extra)
    if not session.out.json:
        session.out.info(f"  ({_plural(info.steps, 'step')} in {elapsed:.2f} s)")


@command(".break")
def cmd_break(session: Session, argtext: str) -> None:
    dbg = state(session)
    if not argtext.strip():
        if not dbg.breakpoints:
            session.out.info("no breakpoints")
        elif session.out.json:
            session.out.emit({"breakpoints": [
                {"number": b.number, "address": b.address, "where": b.spec, "hits": b.hits}
                for b in dbg.breakpoints.values()]})
        else:
            session.out.print(dbg)
        return
    address, desc = resolve(session, argtext, line_numbers=True)
    for bp in dbg.breakpoints.values():
        if bp.address == address:
            session.out.info(f"breakpoint {bp.number} is already at {address} ({bp.spec})")
            return
    number = dbg.next_breakpoint
    dbg.next_breakpoint += 1
    spec = desc if not argtext.strip().startswith("@") else f"@{address}"
    dbg.breakpoints[number] = Breakpoint(number, spec, address)
    w = where(session, address)
    if session.out.json:
        session.out.emit({"breakpoint": number, "address": address, **w.to_json()})
    else:
        session.out.print(f"breakpoint {number} at @{address}  {w.place}  {w.text}".rstrip())


@command(".delete")
def cmd_delete(session: Session, argtext: str) -> None:
    dbg = state(session)
    if not argtext.strip():
        n = len(dbg.breakpoints)
        dbg.breakpoints.clear()
        session.out.info(f"deleted {n} breakpoint{'s' if n != 1 else ''}")
        return
    for word in argtext.replace(",", " ").split():
        number = _number(word, "breakpoint number")
        if dbg.breakpoints.pop(number, None) is None:
            known = ", ".join(map(str, sorted(dbg.breakpoints))) or "none"
            raise ValidationError(f"no breakpoint {number} (breakpoints: {known})")
        session.out.info(f"deleted breakpoint {number}")


# -- looking at the program --------------------------------------------------------------

@command(".list")
@paged
def cmd_list(session: Session, argtext: str) -> None:
    dbg = state(session)
    pc: int | None = None
    try:
        pc = _read_status(session).pc
    except TmclError:
        pc = dbg.last.pc if dbg.last is not None else None
    span = _span(session, argtext)
    if span is not None:
        center = span.first if not span.lines else 0
    elif argtext.strip():
        center, _ = resolve(session, argtext, line_numbers=True)
    elif pc is not None:
        center = pc
    else:
        center = 0
    breaks = {bp.address for bp in dbg.breakpoints.values()}
    rows, before, after = _listing(session, center, pc, breaks, span)
    if session.out.json:
        obj: dict[str, object] = {"pc": pc, "lines": rows}
        if before or after:
            obj["more"] = {"before": before, "after": after}
        session.out.emit(obj)
        return
    from rich.text import Text

    if before:
        session.out.print("      ...", style="tmcl.note")
    for row in rows:
        mark = "->" if row["current"] else "  "
        bmark = "B" if row["break"] else " "
        addr = f"@{row['address']}" if row.get("address") is not None else ""
        num = f"{row['line']:>4}" if row.get("line") is not None else ""
        t = Text()
        t.append(f"{mark}{bmark} ", style="tmcl.event" if row["current"] else "tmcl.error"
                 if row["break"] else "")
        if num:
            t.append(f"{num} ", style="tmcl.note")
        t.append(f"{addr:>6}  ", style="tmcl.name")
        t.append(str(row["text"]), style="bold" if row["current"] else "")
        _line(session, t)
    if after:
        session.out.print("      ...", style="tmcl.note")


# `.list 1 8`, `.list 1,8`, `.list 1-8`, `.list 1..8`, `.list Loop @20`
_RANGE = re.compile(r"(\S+?)\s*(?:\.\.|,|\s|(?<=\d)-(?=[\d$@]))\s*(\S+)")


@dataclass
class Span:
    """A range typed to .list: source lines, or program addresses."""

    first: int
    last: int
    lines: bool


def _span(session: Session, argtext: str) -> Span | None:
    """Source lines when the source is known and both ends are line numbers, else program
    addresses; None when one location was typed."""
    m = _RANGE.fullmatch(argtext.strip())
    if m is None:
        return None
    a, b = m.group(1), m.group(2)
    prog = state(session).program
    lines = prog is not None and not prog.image and a.isdigit() and b.isdigit()
    if lines:
        first, last = int(a), int(b)
    else:
        first = resolve(session, a, line_numbers=False)[0]
        last = resolve(session, b, line_numbers=False)[0]
        ends = [prog.loc(x) for x in (first, last)] if prog is not None and not \
            prog.image else [None]
        if all(e is not None for e in ends) and ends[0].file == ends[-1].file:  # type: ignore
            first, last, lines = ends[0].line, ends[-1].line, True  # type: ignore[union-attr]
    if last < first:
        raise ValidationError(f"empty range {a}..{b}: the first end comes after the last")
    return Span(first, last, lines)


def _listing(session: Session, center: int, pc: int | None, breaks: set[int],
             span: Span | None = None) -> tuple[list[dict], bool, bool]:
    """The rows to list, and whether lines were left out before and after them. A short
    program is listed whole, a longer one in a window around ``center``, a span as typed."""
    dbg = state(session)
    prog = dbg.program
    if span is not None and not span.lines:
        center = span.first
    loc = prog.loc(center) if prog is not None and not prog.image else None
    if span is not None and span.lines and prog is not None and prog.source:
        loc = prog.source[0]
    if prog is not None and loc is not None:  # (an image's file holds bytes, not lines)
        lines = _source_lines(session, loc.file)
        addr_of: dict[int, int] = {}
        for idx, sl in enumerate(prog.source):
            if sl.file == loc.file:
                addr_of.setdefault(sl.line, prog.origin + idx)
        if lines is not None:
            if span is not None and span.lines:
                lo, hi = max(1, span.first), min(len(lines), span.last)
                if lo > hi:
                    raise ValidationError(f"{_show_path(loc.file)} has {len(lines)} lines")
            elif len(lines) <= SHORT_LISTING:
                lo, hi = 1, len(lines)
            else:
                lo = max(1, loc.line - LIST_CONTEXT)
                hi = min(len(lines), loc.line + LIST_CONTEXT)
            rows = []
            for n in range(lo, hi + 1):
                addr = addr_of.get(n)
                rows.append({"line": n, "address": addr, "text": lines[n - 1].rstrip(),
                             "current": addr is not None and addr == pc,
                             "break": addr is not None and addr in breaks})
            return rows, lo > 1, hi < len(lines)
    module = session.module
    # what there is to list: the known program, else all of memory
    first, last = 0, module.program_memory - 1
    if prog is not None and prog.origin <= center < prog.origin + len(prog):
        first, last = prog.origin, prog.origin + len(prog) - 1
    if span is not None and not span.lines:
        lo, hi = span.first, span.last
    elif last - first < SHORT_LISTING:
        lo, hi = first, min(last + 1, module.program_memory - 1)  # (and where it ends)
    else:
        lo = max(0, center - LIST_CONTEXT)
        hi = min(module.program_memory - 1, center + LIST_CONTEXT)
    rows = []
    for addr in range(lo, hi + 1):
        w = where(session, addr)
        text = w.text or ("(no instruction stored)" if w.end else "?")
        rows.append({"line": w.line, "address": addr, "text": text,
                     "current": addr == pc, "break": addr in breaks})
    return rows, lo > first, hi < last


@command(".display")
def cmd_display(session: Session, argtext: str) -> None:
    dbg = state(session)
    expr = argtext.strip()
    if not expr:
        values = _display_values(session)
        if session.out.json:
            session.out.emit({"display": {d.expr: v for d, v in values}})
        elif not values:
            session.out.info("no displays (add one with .display EXPR)")
        for d, v in values:
            session.out.print(f"{d.number}: {d.expr} = {v}")
        return
    value = _evaluate(session, expr)  # refuses bad expressions before keeping them
    number = dbg.next_display
    dbg.next_display += 1
    dbg.displays[number] = Display(number, expr)
    if session.out.json:
        session.out.emit({"display": number, "expr": expr, "value": value})
    else:
        session.out.print(f"{number}: {expr} = {value}")


@command(".undisplay")
def cmd_undisplay(session: Session, argtext: str) -> None:
    dbg = state(session)
    if not argtext.strip():
        dbg.displays.clear()
        session.out.info("all displays removed")
        return
    number = _number(argtext, "display number")
    if dbg.displays.pop(number, None) is None:
        raise ValidationError(f"no display {number}")


@command(".vars")
def cmd_vars(session: Session, argtext: str) -> None:
    module = session.module
    valid = program.user_variable_range(module)
    arg = argtext.strip().lower()
    show_all = False
    if not arg or arg == "all":
        numbers = valid
    else:
        m = re.fullmatch(r"(\w+)\s*(?:\.\.|-)\s*(\w+)", arg)
        if m:
            lo, hi = _number(m.group(1), "FROM"), _number(m.group(2), "TO")
            if hi < lo:
                raise ValidationError(f"empty range {lo}..{hi}")
            numbers = range(lo, hi + 1)
        else:
            n = _number(arg, "variable number")
            numbers = range(n, n + 1)
        show_all = True
    values = program.read_user_variables(session.client, numbers)
    shown = {n: v for n, v in values.items() if show_all or v != 0}
    if session.out.json:
        session.out.emit({"vars": {str(n): v for n, v in shown.items()}})
        return
    if not shown:
        session.out.info(f"all user variables {numbers.start}..{numbers.stop - 1} are 0")
        return
    from rich.table import Table

    table = Table(box=None, show_header=False)
    for _ in range(min(4, len(shown))):
        table.add_column(justify="right", style="tmcl.name")
        table.add_column(justify="right", style="tmcl.value")
    cells = [(f"#{n}", str(v)) for n, v in shown.items()]
    cols = min(4, len(cells))
    for i in range(0, len(cells), cols):
        chunk = cells[i:i + cols]
        row: list[str] = []
        for name, val in chunk:
            row += [name, val]
        row += [""] * (2 * cols - len(row))
        table.add_row(*row)
    session.out.print(table)
    hidden = len(values) - len(shown)
    if hidden:
        session.out.info(f"({hidden} more are 0)")


__all__ = ["DebuggerState", "Breakpoint", "Display", "Where", "state", "where", "resolve",
           "report"]
