"""Clone a module: back its configuration up as a script, compare it, restore what differs.

The backup is a plain tmclsh script, so it is replayed, diffed and edited like any other: one
``SAP``/``SGP`` line per writable configuration parameter, everything else (read-only values,
motion state) as ``//`` comments that document the module without ever being written back.
``.diff`` and ``.restore`` read any script of SAP/SGP lines through the shell's own line
parser, so a hand-written file is checked exactly as typed commands are, before any byte is
sent. Parameters are keyed by number and motor/bank; names are only needed to carry a file
across module types (and for people), so a module without parameter data compares by number.

Which parameters are state and which make up the module's place on its line is data
(``state``/``link``/``breaks`` in the module files), never a list here. That place (address,
baud rate, CAN ids, ASCII start-up, ...) belongs to the module, not to the backup: a backup
of the module at address 1 restored onto the one at address 5 must not move it onto the
first one's address, so it is carried only when asked (--with-link).
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from itertools import zip_longest
from pathlib import Path
from typing import TYPE_CHECKING

from ..tmcl import asm
from ..tmcl import modules as moddb
from ..tmcl import instructions as isa
from ..base.errors import EXIT_USAGE, AsmError, RangeError, TmclError, ValidationError
from ..tmcl.modules import Module, Parameter
from ..client import reach
from ..client.text import AS_TYPED
from ..ops import program
from ..tmcl.frames import Control, Request, status_ok, status_text
from . import options
from .commands import command, find, options_of
from .lines import split_line

if TYPE_CHECKING:
    from ..client.core import Client
    from .session import Session

CATEGORY = "configuration"
# what is done to each kind of parameter: the instruction set's commands for it
# (GAP/SAP/STAP for axis parameters, GGP/SGP/STGP for global ones)
READ = {kind: isa.parameter_command(kind, "read").opcode for kind in ("axis", "global")}
WRITE = {kind: isa.parameter_command(kind, "write").opcode for kind in ("axis", "global")}
STORE = {kind: isa.parameter_command(kind, "store").opcode for kind in ("axis", "global")}
HEADER_LINES = 30  # the header keys are looked for in the file's first lines only
_HEADER = re.compile(r"^\s*//\s*(module|firmware|address|connection|date|program)\s*:\s*(.*?)\s*$",
                     re.IGNORECASE)


# the first line of every backup .save writes: how a replayed script is known as a backup
BACKUP_MARK = "// tmclsh configuration backup of a"
# the heading of the backup's last section: the module's link identity (``link`` in its data)
LINK_SECTION = "// -- link identity: where this module sits on its line"
LINK_SECTION_WHY = (
    "// These belong to the module saved, not to its configuration: .restore, .diff and",
    "// tmclsh -f leave them alone and say so; --with-link writes them too (the module moves).",
)


class CloneError(TmclError):
    """A backup that cannot be written or read, or a restore the module did not complete."""


# -- one parameter slot ------------------------------------------------------------------

@dataclass
class Slot:
    """One parameter of one motor (axis) or bank (global) with a value.

    ``param`` is the module's entry when the module has parameter data; without it the slot
    is known by number only (generic mode)."""

    kind: str  # "axis" | "global"
    number: int
    index: int  # motor (axis) or bank (global)
    value: int
    param: Parameter | None = None
    line: int | None = None  # where a file gave it
    outside: str | None = None  # the manual's range, when the value lies outside it

    @property
    def key(self) -> tuple[str, int, int]:
        return self.kind, self.number, self.index

    @property
    def name(self) -> str | None:
        p = self.param
        if p is None:
            return None
        return p.name if p.count == 1 else f"{p.name}#{self.number - p.number}"

    @property
    def label(self) -> str:
        return f"AP {self.number}" if self.kind == "axis" else f"GP {self.number}"

    @property
    def where(self) -> str:
        return f"motor {self.index}" if self.kind == "axis" else f"bank {self.index}"

    def title(self) -> str:
        return f"{self.name or self.label} ({self.label}, {self.where})"

    def to_json(self) -> dict[str, object]:
        return {"name": self.name, "number": self.number,
                ("motor" if self.kind == "axis" else "bank"): self.index}


def _shown(value: int, param: Parameter | None) -> int:
    """A reply's value as the parameter reads (``Parameter.reading``)."""
    return value if param is None else param.reading(value)


def _same(a: int, b: int) -> bool:
    return (a & 0xFFFFFFFF) == (b & 0xFFFFFFFF)


def _with_unit(value: int, param: Parameter | None) -> str:
    return f"{value} {param.unit}" if param is not None and param.unit else str(value)


def readable_slots(module: Module) -> Iterator[tuple[str, Parameter, int, int]]:
    """(kind, parameter, number, motor/bank) of everything a backup reads, in file order:
    each motor's axis parameters, then the global parameters bank by bank. A ``state`` run
    of RAM variables is not read (it is a program's scratch space, not configuration)."""
    for motor in range(module.motors):
        for p in module.axis_params:
            if p.readable:
                yield "axis", p, p.number, motor
    for p in sorted(module.global_params, key=lambda q: (q.bank, q.number)):
        if not p.readable or (p.state and p.count > 1):
            continue
        for n in range(p.number, p.number + p.count):
            yield "global", p, n, p.bank


def read_order(kinds: list[str]) -> list[int]:
    """The order to read a backup's slots in (indexes into ``kinds``): axis and global
    parameters in turn. The client reads an answer again when it is byte for byte the one
    before it for another request of the same command (it may be a copy: Client._judge),
    and many parameters hold 0; a GAP's answer is never a GGP's."""
    axis = [i for i, k in enumerate(kinds) if k == "axis"]
    other = [i for i, k in enumerate(kinds) if k != "axis"]
    return [i for pair in zip_longest(axis, other) for i in pair if i is not None]


def _request(session: Session, opcode: int, slot: Slot | tuple[str, int, int],
             value: int = 0):
    c = session.client
    number, index = (slot.number, slot.index) if isinstance(slot, Slot) else slot[1:]
    return c.request(Request.make(c.address, opcode, number, index, value))


# -- argument parsing --------------------------------------------------------------------

def _args(argtext: str, command: str) -> tuple[str, set[str]]:
    """FILE and the options given (shell/options.py, as the table declares them)."""
    usage = find(command).syntax  # type: ignore[union-attr]
    try:
        pos, given = options.parse_words(argtext, options_of(command))
    except ValidationError as exc:
        raise ValidationError(f"{exc}; usage: {usage}") from None
    if len(pos) != 1:
        raise ValidationError(f"usage: {usage}")
    return pos[0], set(given)


def _file(session: Session, name: str) -> Path:
    p = Path(name).expanduser()
    if not p.exists() and not p.is_absolute() and session.location is not None:
        beside = Path(session.location[0]).parent / name
        if beside.exists():
            return beside
    return p


def complete_file(session: Session, text: str) -> list[str]:
    """Paths for FILE (the options after it are typed, not completed)."""
    import glob

    word = text.split()[-1] if text and not text.endswith(" ") else ""
    if word.startswith("-"):
        return []
    return [p + (os.sep if os.path.isdir(p) else "")
            for p in sorted(glob.glob(os.path.expanduser(word) + "*"))]


# -- progress ----------------------------------------------------------------------------

class _Progress:
    """A rich progress bar on a terminal; nothing under --json or in a pipe."""

    def __init__(self, session: Session, what: str, total: int):
        out = session.out
        self.bar = None
        if not out.json and out.is_terminal and total:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

            self.bar = Progress(TextColumn(what), BarColumn(), MofNCompleteColumn(),
                                console=out.console, transient=True)
            self.task = self.bar.add_task(what, total=total)

    def __enter__(self) -> Callable[[], None]:
        if self.bar is None:
            return lambda: None
        self.bar.start()
        return lambda: self.bar.advance(self.task)  # type: ignore[union-attr]

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.stop()


# -- .save ---------------------------------------------------------------------------------

def write_atomically(path: Path, text: str) -> None:
    """Write ``text`` to a temporary file beside ``path`` and rename it over ``path``, so a
    failed or interrupted save never leaves half a backup in place of a whole one. A device
    or pipe (``/dev/null``) is written as it is, never replaced by a file."""
    from ..base import files

    with files.atomic_writer(path, newline="\n") as fh:
        fh.write(text)


def _firmware(session: Session) -> str:
    c = session.client
    if c.version:
        return c.version
    try:
        reply = c.request(Request(c.address, Control.GET_VERSION, 0, 0, 0))
    except TmclError:
        return "unknown"
    if reply is not None and reply.version:
        c.version = reply.version
        return reply.version
    return "unknown"


def _comment(p: Parameter, number: int) -> str:
    unit = f", {p.unit}" if p.unit else ""
    return f"{'AP' if p.kind == 'axis' else 'GP'} {number}{unit}: {p.description}"


def save_lines(session: Session, path: Path, with_program: Path | None
               ) -> tuple[str, int, list[str]]:
    """The backup's text, how many parameters it restores (SAP/SGP lines), and which of the
    values the module holds lie outside the manual's ranges (saved all the same, marked so
    that .restore writes them back as they were: ``!SAP ...``, the module decides)."""
    c = session.client
    module = session.module
    firmware = _firmware(session)
    slots = list(readable_slots(module))
    body: list[str] = []
    saved = link_saved = 0
    link_body: list[str] = []
    outside: list[str] = []
    last_section = None
    replies: list = [None] * len(slots)
    with _Progress(session, "reading", len(slots)) as advance:
        for i in read_order([kind for kind, *_ in slots]):
            kind, p, number, index = slots[i]
            replies[i] = _request(session, READ[kind], Slot(kind, number, index, 0, p))
            advance()
    # (written in the file's own order)
    for (kind, p, number, index), reply in zip(slots, replies):
        section = (kind, index)
        if section != last_section:
            where = f"motor {index}" if kind == "axis" else f"bank {index}"
            body.append("")
            body.append(f"// -- {'axis' if kind == 'axis' else 'global'} parameters, {where}")
            last_section = section
        slot = Slot(kind, number, index, 0, p)
        name = slot.name or slot.label
        comment = _comment(p, number)
        if reply is None or not status_ok(reply.status):
            status = reply.status if reply is not None else 0
            body.append(f"// {name}: not read, the module answered status {status} "
                        f"({status_text(status)})")
            continue
        value = _shown(reply.value, p)
        if p.state or not p.writable:
            why = "state, not restored" if p.state else "read-only"
            body.append(f"// {name} = {_with_unit(value, p)} ({why}; {comment})")
            continue
        mn = isa.parameter_command(kind, "write").mnemonic
        target = p.name if p.count == 1 else str(number)  # a run is addressed by number
        if p.count > 1:
            comment = f"GP {number}: {p.name} #{number - p.number}"
        beyond = p.outside(value)
        mark = ""
        if beyond is not None:  # the module holds it: kept, and restorable as it is
            mark = AS_TYPED
            comment = f"{comment} (outside the manual's range {beyond}: as the module held it)"
            outside.append(f"{name} = {_with_unit(value, p)} ({'motor' if kind == 'axis' else 'bank'} "
                           f"{index}; the manual says {beyond})")
        text = f"{mark}{mn} {target}, {index}, {value}  // {comment}"
        if p.link:  # the module's place on its line: a section of its own, at the end
            link_body.append(text)
            link_saved += 1
            continue
        body.append(text)
        saved += 1
    if link_body:
        body += ["", LINK_SECTION, *LINK_SECTION_WHY, *link_body]
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
    head = [
        f"{BACKUP_MARK} {module.name} (.save); format: man tmclsh, CONFIGURATION BACKUPS",
        f"// module: {module.name}",
        f"// firmware: {firmware}",
        f"// address: {c.address}",
        f"// connection: {c.describe()} ({c.mode})",
        f"// date: {when}",
    ]
    if with_program is not None:
        head.append(f"// program: {with_program.name}")
    head += [
        f"// {saved} SAP/SGP lines restore the configuration; commented values are read-only",
        "// or motion state and are never written back.",
    ]
    if link_saved:
        head.append(f"// {link_saved} more, at the end, are this module's place on its line "
                    "(address, baud rate, CAN,")
        head.append("// ASCII start-up): left alone unless --with-link asks for them.")
    head += [
        "// Compare with the module: .diff FILE   write what differs: .restore FILE [--store]",
        "// Replay it: tmclsh -f FILE --yes (bank 0 global parameters go to EEPROM)",
    ]
    if outside:
        head.append(f"// {len(outside)} value{'s' if len(outside) != 1 else ''} outside the manual's ranges, "
                    f"as the module held {'them' if len(outside) != 1 else 'it'}: the lines start with "
                    f"{AS_TYPED} (sent as written; the module decides)")
    return "\n".join(head + body) + "\n", saved + link_saved, outside, link_saved


def _program_path(path: Path) -> Path:
    stem = path.name[: -len(path.suffix)] if path.suffix else path.name
    return path.with_name(f"{stem}.program.tmcl")


def _program_text(session: Session) -> tuple[str, int]:
    from ..ops import program

    c = session.client
    module = session.module
    with _Progress(session, "program", module.program_memory) as advance:
        image = program.read_program(c, progress=lambda phase, done, total: advance())
    head = (f"// stored program of the {module.name} at address {c.address} "
            f"({c.describe()}): {len(image)} instructions\n"
            "// upload it with .upload FILE\n")
    return head + (asm.disassemble(image, module) if image else ""), len(image)


def _what_it_holds(path: Path) -> str:
    """`` (a backup of a TMCM-1311, 2026-12-01 19:40:00 UTC)`` from a file's header, or ''."""
    try:
        with open(path, "rb") as fh:
            head = _header(fh.read(4096).decode("utf-8", "replace").splitlines())
    except OSError:
        return ""
    if "module" not in head:
        return ""
    when = f", {head['date']}" if head.get("date") else ""
    return f" (a backup of a {head['module']}{when})"


def _may_overwrite(session: Session, paths: list[Path | None], yes: bool) -> None:
    """Ask before a file that exists is replaced (the old module's only backup may be in
    it); where nobody can answer (-c, -f) it is refused unless --yes. Devices and pipes
    are written into, not replaced, so they are not asked about."""
    existing = [p for p in paths if p is not None and p.is_file()]
    if not existing or yes or session.yes:
        return
    one = len(existing) == 1
    names = " and ".join(f"{p}{_what_it_holds(p)}" for p in existing)
    if session.ask is not None and session.interactive:
        session.confirm(f"{names} {'exists' if one else 'exist'}; overwrite "
                        f"{'it' if one else 'them'}?")
        return
    from .session import Abort

    raise Abort(f"{names} {'exists' if one else 'exist'}; not overwritten: add --yes to "
                f"replace {'it' if one else 'them'}, or save under another name")


def _has_parameters_to_save(module: Module) -> None:
    """A backup reads the parameters the module's data lists; a module known by number only
    has none, and a file of 0 parameters restores nothing: refused, with what can be done."""
    if _has_data(module):
        return
    if getattr(module, "forced", False):
        type_name = getattr(module, "type_name", module.name)
        why = (f"generic mode (-m generic) uses no parameter data, so .save has nothing to "
               f"read: switch to the {type_name}'s data with '.module {type_name}' (or "
               "connect without -m generic) and .save again")
    else:
        why = (f"tmclsh has no parameter data for the {module.name}, so .save has nothing to "
               "read: describe its parameters in a module file (--module-file FILE; "
               "'tmclsh modules check FILE' checks it) and .save again, or read the values "
               "you need by number (GAP/GGP)")
    raise ValidationError(why + "; nothing saved (the stored program: .dump FILE)")


def _some(names: list[str], n: int = 6) -> str:
    return ", ".join(names[:n]) + (f" and {len(names) - n} more" if len(names) > n else "")


def _known_by_name_only(module: Module, names_only: bool) -> list[str]:
    """The parameters whose data gives a name but neither a range nor whether they are
    settings (a file imported from PyTrinamic marks them all ``state``): a backup can only
    keep their values as comments. A backup that silently restores none of them would read
    as a backup; it is refused, saying what could not be saved, unless --names-only asks
    for the comments. -> the names (with --names-only)"""
    names = sorted({p.name for kind, p, _, _ in readable_slots(module)
                    if p.state and p.writable and p.min is None and p.max is None
                    and not p.choices})
    if not names or names_only:
        return names
    whence = f" ({module.origin})" if module.origin else ""
    raise ValidationError(
        f"the {module.name}'s data{whence} knows {_count(len(names))} by name only, without "
        f"ranges or which are settings, so a backup could not restore them: "
        f"{_some(names)}; nothing saved. Add --names-only to save their values as comments "
        "(a record, not a restorable backup), or describe them in a module file "
        "(--module-file FILE)")


@command(".save")
def cmd_save(session: Session, argtext: str) -> None:
    name, given = _args(argtext, ".save")
    _has_parameters_to_save(session.module)
    names_only = _known_by_name_only(session.module, "--names-only" in given)
    path = Path(name).expanduser()
    if path.is_dir():
        raise CloneError(f"cannot write {path}: it is a directory")
    prog_path = _program_path(path) if "--program" in given else None
    if prog_path is not None and not program.carried(session.client, Control.READ_MEMORY):
        raise ValidationError("--program reads program memory (134), which needs binary mode "
                              "(.mode binary)")
    _may_overwrite(session, [path, prog_path], "--yes" in given)  # before anything is read
    text, saved, outside, link_saved = save_lines(session, path, prog_path)
    instructions = None
    if prog_path is not None:
        prog_text, instructions = _program_text(session)
        write_atomically(prog_path, prog_text)
    write_atomically(path, text)
    out = session.out
    if out.json:
        obj: dict[str, object] = {"saved": saved, "link": link_saved, "file": str(path)}
        if names_only:
            obj["names_only"] = names_only
        if outside:
            obj["outside_range"] = outside
        if prog_path is not None:
            obj.update({"program": str(prog_path), "instructions": instructions})
        out.emit(obj)
        return
    link = (f" ({link_saved} of them its link identity, which .restore and -f leave alone "
            "unless --with-link)" if link_saved else "")
    out.ok(f"saved {_count(saved)} of the {session.module.name} to {path}{link}")
    if names_only:
        out.warn(f"{_count(len(names_only))} known by name only, saved as comments, not "
                 "restorable: " + _some(names_only))
    if outside:
        out.warn(f"{len(outside)} of them {'lie' if len(outside) != 1 else 'lies'} outside the "
                 "manual's ranges, as the module holds them (saved as they are, marked with "
                 f"{AS_TYPED}: .restore writes them back): " + "; ".join(outside))
    if prog_path is not None:
        out.ok(f"saved the stored program ({instructions} instructions) to {prog_path}")


# -- reading a backup --------------------------------------------------------------------

@dataclass
class Backup:
    """What a script says the parameters should be."""

    path: Path
    module_name: str | None = None  # from the header, when it names one
    program: str | None = None
    slots: dict[tuple[str, int, int], Slot] = field(default_factory=dict)
    state: list[Slot] = field(default_factory=list)  # state lines a hand-written file sets
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (what, why), across modules
    with_link: bool = False  # the module's link identity is compared and written too
    left_alone: list[Slot] = field(default_factory=list)  # link identity, without --with-link


def _header(lines: list[str]) -> dict[str, str]:
    found: dict[str, str] = {}
    for text in lines[:HEADER_LINES]:
        m = _HEADER.match(text)
        if m:
            found.setdefault(m.group(1).lower(), m.group(2))
    return found


def _source_module(name: str | None, live: Module) -> Module | None:
    """The module the file's names belong to: its header's, when tmclsh knows that module."""
    if name is None or _norm(name) == _norm(live.name):
        return None
    try:
        return moddb.load(name)
    except ValidationError:
        return None


def _norm(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", name.lower())


def _has_data(module: Module) -> bool:
    return bool(module.axis_params or module.global_params)


def _counterpart(live: Module, p: Parameter, number: int, index: int) -> Parameter | None:
    """The live module's parameter with the same name (and bank), or None."""
    if p.kind == "axis":
        return next((q for q in live.axis_params if _norm(q.name) == _norm(p.name)), None)
    return next((q for q in live.global_params
                 if _norm(q.name) == _norm(p.name) and q.bank == p.bank
                 and q.count == p.count), None)


class BackupFileError(CloneError):
    """A backup that cannot be used as a whole: unreadable, or a line that is not a SAP/SGP
    line the module accepts. Raised before anything is sent; in -c, exit status 2 (as -f
    gives for a script it refuses) when nothing else of the run was sent either."""

    exit_status = EXIT_USAGE  # nothing was sent

    def __init__(self, message: str, kind: str = "syntax"):
        self.kind = kind
        super().__init__(message)


ONLY = "a backup holds only SAP/SGP lines and comments"


def _refuse(path: Path, number: int, message: str, kind: str = "syntax") -> BackupFileError:
    """FILE:LINE: message, as -f says it of a script line."""
    return BackupFileError(f"{path}:{number}: {message}", kind)


def _parse(path: Path, number: int, text: str, module: Module) -> asm.Line:
    """One shell line of a backup as a SAP/SGP line, or the error that says what it is
    instead (an unknown command is named with the suggestions a typed line gets). A leading
    ``!`` (the override) is not part of the command."""
    text = text.removeprefix(AS_TYPED)
    if text.startswith("."):
        raise _refuse(path, number, f"shell command {text.split()[0]!r}: {ONLY}")
    if "${" in text:
        raise _refuse(path, number, f"{text!r} uses a ${{...}} variable, which .diff and "
                                    f".restore do not expand: {ONLY}")
    try:
        line = asm.parse_line(text, number, str(path))
    except AsmError as exc:
        raise _refuse(path, number, exc.message, exc.kind) from None
    what = None
    if line.include is not None:
        what = "#include"
    elif line.constant is not None:
        what = f"a constant ({line.constant} = ...)"
    elif line.label is not None:
        what = f"a label ({line.label}:)"
    if what is not None:
        raise _refuse(path, number, f"{what}: {ONLY}")
    mn = line.mnemonic
    spec = isa.by_opcode(int(mn)) if line.is_raw else isa.by_mnemonic(mn or "")
    if spec is not None and spec.sets_parameter:  # SAP, SGP: what a backup is made of
        return line
    if line.is_raw:
        name = f" ({spec.mnemonic})" if spec is not None else ""
        writes = " or ".join(f"{s.mnemonic} ({s.opcode})" for s in _setters())
        raise _refuse(path, number, f"command {mn}{name} is not {writes}: {ONLY}")
    try:
        asm.encode(line, module, direct=True)
    except AsmError as exc:  # an unknown command: `unknown command 'SPA'; did you mean ...`
        if isa.by_mnemonic(mn) is None:
            raise _refuse(path, number, exc.message, exc.kind) from None
    raise _refuse(path, number, f"{mn} is not {' or '.join(s.mnemonic for s in _setters())}: "
                  f"{ONLY}")


def _setters() -> list[isa.InstructionSpec]:
    return [isa.parameter_command(kind, "write") for kind in ("axis", "global")]


def read_backup(session: Session, path: Path, *, force: bool, command: str,
                with_link: bool = False) -> Backup:
    """Parse and check every line of ``path`` against the live module (nothing is sent).
    Only comments, blank lines and SAP/SGP lines the module accepts may be in it: anything
    else is an error at FILE:LINE, so a typo never reads as "matches". ``command`` (.diff,
    .restore) is named in the hint for another module's backup."""
    live = session.module
    from ..base import files

    try:
        text = files.read_bytes(path, what="backup").decode("utf-8")  # bounded: /dev/zero
    except files.FileError as exc:
        raise BackupFileError(str(exc), "unreadable") from None
    except UnicodeDecodeError:
        raise BackupFileError(f"cannot read {path}: not a text file (UTF-8)",
                              "unreadable") from None
    lines = text.splitlines()
    if len(lines) > files.MAX_LINES:  # as for a script: a limit, not minutes of parsing
        raise BackupFileError(f"{path}: backup longer than {files.MAX_LINES:,} lines; not read",
                              "unreadable")
    head = _header(lines)
    backup = Backup(path, head.get("module"), head.get("program"), with_link=with_link)
    source = _source_module(backup.module_name, live)
    other = backup.module_name is not None and _norm(backup.module_name) != _norm(live.name)
    if other and not force and _has_data(live):
        verb = "compare" if command == ".diff" else "restore"
        raise BackupFileError(
            f"{path} is a backup of a {backup.module_name}, this is a {live.name}; {verb} by "
            f"parameter name with {command} {path} --force (parameters the {live.name} does "
            "not have are skipped)", "check")
    # .diff compares whatever the file holds; .restore writes a value outside the manual's
    # range only where the file says so (``!``, as .save writes the module's own) or --force
    anything = command == ".diff" or force
    refused: list[BackupFileError] = []
    for number, raw in enumerate(lines, 1):
        for shell_line in split_line(raw):  # comments off, `;` between lines
            as_typed = anything or shell_line.startswith(AS_TYPED)
            try:
                _read_line(session, backup, path, number, shell_line, source, live,
                           as_typed)
            except BackupFileError as exc:
                refused.append(exc)
    if refused:  # every refused line at once: one run to see them all, not one per line
        if len(refused) == 1:
            raise refused[0]
        kinds = {e.kind for e in refused}
        hint = (f"\n(a value outside the manual's range is written only from a line that "
                f"starts with {AS_TYPED}, as .save marks the module's own, or with "
                f"{command} --force)" if "range" in kinds and command != ".diff" else "")
        raise BackupFileError(f"{path}: {len(refused)} lines refused, nothing sent:\n"
                              + "\n".join(f"  {e}" for e in refused) + hint,
                              "range" if kinds == {"range"} else refused[0].kind)
    if not (backup.slots or backup.state or backup.skipped or backup.left_alone):
        # an empty or truncated file must not read as "matches" either
        raise BackupFileError(f"{path} has no SAP/SGP lines: nothing to compare or restore "
                              "(a backup is written by .save)")
    return backup


def _read_line(session: Session, backup: Backup, path: Path, number: int, text: str,
               source: Module | None, live: Module, as_typed: bool = False) -> None:
    line = _parse(path, number, text, source or live)
    try:
        enc = session.client.check(line, source or live, as_typed=as_typed)
    except AsmError as exc:
        raise _refuse(path, number, exc.message, exc.kind) from None
    ins = enc.instruction
    kind = "axis" if isa.by_opcode(ins.opcode).type_kind == "axis_param" else "global"
    p = enc.parameter
    if p is not None and p.state:  # the file's own module says it is state
        backup.state.append(Slot(kind, ins.type, ins.motor, ins.value, p, number))
        return
    if source is not None and p is not None:
        slot = _carry(backup, live, p, ins.type, ins.motor, ins.value, number)
        if slot is None:
            return
    else:
        if p is None and line.is_raw and _has_data(live):
            # `5 4, 0, 100`: sent as typed when replayed; checked here like a named line
            p = live.axis(ins.type) if kind == "axis" else live.glob(ins.type, ins.motor)
            if p is None:
                raise _refuse(path, number, f"{live.name} has no {kind} parameter {ins.type}"
                              + (f" in bank {ins.motor}" if kind == "global" else ""), "check")
            try:
                if kind == "axis":
                    live.check_motor(ins.motor)
                if not p.writable:
                    raise ValidationError(f"{p.label} {p.name} is read-only")
                if not as_typed:
                    p.check(_shown(ins.value, p))
            except RangeError as exc:
                raise _refuse(path, number, str(exc), "range") from None
            except ValidationError as exc:
                raise _refuse(path, number, str(exc), "check") from None
        slot = Slot(kind, ins.type, ins.motor, _shown(ins.value, p), p, number)
    if slot.param is not None:
        slot.outside = slot.param.outside(slot.value)
    if slot.param is not None and slot.param.state:
        backup.state.append(slot)
        return
    if slot.param is not None and slot.param.link and not backup.with_link:
        backup.left_alone.append(slot)  # the module's own place on its line: not the file's
        return
    backup.slots[slot.key] = slot  # a later line for the same parameter wins, as replayed


def _carry(backup: Backup, live: Module, p: Parameter, number: int, index: int, value: int,
           line: int) -> Slot | None:
    """A line of another module's backup, mapped onto the live module by name (or skipped)."""
    if not _has_data(live):  # numbers only (generic mode): the file's names give the numbers
        return Slot(p.kind, number, index, value, None, line)
    what = f"{p.name if p.count == 1 else f'{p.name}#{number - p.number}'} " \
           f"({'motor' if p.kind == 'axis' else 'bank'} {index}, line {line})"
    q = _counterpart(live, p, number, index)
    if q is None:
        backup.skipped.append((what, f"the {live.name} has no such parameter"))
        return None
    if p.kind == "axis" and index >= live.motors:
        backup.skipped.append((what, f"the {live.name} has no motor {index}"))
        return None
    if not q.writable:
        backup.skipped.append((what, f"read-only on the {live.name}"))
        return None
    if p.unit != q.unit:  # 1234 pps is no 1234 rpm; a 0..255 scale is no mA either
        backup.skipped.append((what, f"units differ: {_unit_of(p)} there, {_unit_of(q)} on the "
                                     f"{live.name} (not converted)"))
        return None
    new_number = q.number + (number - p.number)
    shown = _shown(value, q)
    if not q.in_range(shown):
        backup.skipped.append((what, f"{shown} is out of range on the {live.name} "
                                     f"({q.range_text}{' ' + q.unit if q.unit else ''})"))
        return None
    return Slot(p.kind, new_number, q.bank if p.kind == "global" else index, shown, q, line)


def left_alone_text(slots: list[Slot]) -> str:
    """``SerialAddress = 1, ...`` (the file's values): what a clone did not carry."""
    return ", ".join(f"{s.name or s.label} = {s.value}" for s in slots)


def replay_lines(session: Session, path: Path | str, lines: list[str]) -> list[str]:
    """A script replayed with -f (or .source): when it is a configuration backup (.save's
    first line), the lines that write the live module's link identity are left out, unless
    --with-link was given, and what was left alone is said. The module being replayed onto
    keeps its own address, baud rate, CAN and ASCII settings; another module's would move
    it off its place on the line (or onto another module's). Line numbers stay as they were
    (a line left out is blank). Lines that do not parse are kept: the script's own checks
    report them at their line."""
    if not lines or not lines[0].startswith(BACKUP_MARK) or session.with_link:
        return lines
    try:
        module = session.module
    except TmclError:
        return lines
    left: list[Slot] = []
    kept = list(lines)
    for number, raw in enumerate(lines, 1):
        texts = split_line(raw)
        rest = [t for t in texts if not _writes_link(session, t, module, number, left)]
        if len(rest) != len(texts):
            kept[number - 1] = "; ".join(rest)
    if left:
        session.out.info(f"{path}: left alone, the module's own place on its line (write "
                         "it with --with-link): " + left_alone_text(left))
    return kept


def _writes_link(session: Session, text: str, module: Module, number: int,
                 left: list[Slot]) -> bool:
    """Whether one shell line writes a parameter of the module's link identity (noted)."""
    if text.startswith(".") or "${" in text:
        return False
    try:
        line = asm.parse_line(text.removeprefix(AS_TYPED), number)
        if line.mnemonic is None:
            return False
        enc = session.client.check(line, module, as_typed=True)
    except TmclError:
        return False
    p = enc.parameter
    if p is None or not p.link or enc.spec is None or not enc.spec.sets_parameter:
        return False
    ins = enc.instruction
    left.append(Slot(p.kind, ins.type, ins.motor, p.reading(ins.value), p, number))
    return True


def _unit_of(p: Parameter) -> str:
    return p.unit if p.unit else f"no unit given ({p.range_text})"


@dataclass
class Difference:
    slot: Slot  # the saved value
    live: int

    def to_json(self) -> dict[str, object]:
        return {**self.slot.to_json(), "saved": self.slot.value, "live": self.live}


def compare(session: Session, backup: Backup) -> list[Difference]:
    """Read each saved parameter from the module (one request each); the ones that differ."""
    diffs: list[tuple[int, Difference]] = []
    slots = list(backup.slots.values())
    with _Progress(session, "comparing", len(slots)) as advance:
        for i in read_order([slot.kind for slot in slots]):
            slot = slots[i]
            reply = _request(session, READ[slot.kind], slot)
            advance()
            if reply is None or not status_ok(reply.status):
                status = reply.status if reply is not None else 0
                raise CloneError(f"{backup.path}:{slot.line}: reading {slot.title()} failed: "
                                 f"status {status} ({status_text(status)})")
            live = _shown(reply.value, slot.param)
            if not _same(live, slot.value):
                diffs.append((i, Difference(slot, live)))
    return [d for _, d in sorted(diffs, key=lambda x: x[0])]


def _notes(session: Session, backup: Backup, live: Module, command: str) -> None:
    out = session.out
    if backup.left_alone:  # (under --json on stderr: stdout holds the differences)
        verb = "compare" if command == ".diff" else "write"
        out.info(f"left alone, the module's own place on its line ({verb} it with "
                 f"--with-link): " + left_alone_text(backup.left_alone))
    if backup.skipped:
        out.info(f"{_count(len(backup.skipped))} of the {backup.module_name} backup skipped "
                 f"on the {live.name}:")
        for what, why in backup.skipped:
            out.info(f"  {what}: {why}")
    if backup.state:
        names = ", ".join(s.name or s.label for s in backup.state[:6])
        more = "..." if len(backup.state) > 6 else ""
        n = len(backup.state)
        out.info(f"{n} state line{'' if n == 1 else 's'} in {backup.path.name} not compared or "
                 f"restored ({names}{more})")


def _table(session: Session, title: str, columns: list[str], rows: list[list[str]]) -> None:
    from rich.table import Table

    table = Table(title=title, title_justify="left", show_edge=False, pad_edge=False)
    for col in columns:
        table.add_column(col, justify="right" if col in ("number", "saved", "live", "old",
                                                         "new", "motor/bank") else "left")
    for row in rows:
        table.add_row(*row)
    session.out.print(table)


def _count(n: int) -> str:
    return f"{n} parameter" + ("" if n == 1 else "s")


class DiffFound(TmclError):
    """``.diff --exit-code``: the module differs from the file."""


def _against_backup(session: Session, argtext: str, command: str):
    """What .diff and .restore both start with: the backup read and checked, the live values
    compared with it, and the notes on what was not compared. -> (backup, diffs, flags given)"""
    name, given = _args(argtext, command)
    backup = read_backup(session, _file(session, name), force="--force" in given,
                         command=command, with_link="--with-link" in given)
    diffs = compare(session, backup)
    _notes(session, backup, session.module, command)
    return backup, diffs, given


@command(".diff")
def cmd_diff(session: Session, argtext: str) -> None:
    backup, diffs, given = _against_backup(session, argtext, ".diff")
    live = session.module
    out = session.out
    if out.json:
        for what, why in backup.skipped:  # not compared, and why (another module's backup)
            out.emit({"skipped": what, "why": why})
        for d in diffs:
            out.emit(d.to_json())
    elif not diffs:
        out.ok(f"no differences: the {live.name} matches {backup.path.name} "
               f"({_count(len(backup.slots))} compared)")
    else:
        rows = [[d.slot.name or "", d.slot.label, d.slot.where, str(d.slot.value), str(d.live),
                 d.slot.param.unit if d.slot.param else ""] for d in diffs]
        _table(session, f"{len(diffs)} of {_count(len(backup.slots))} "
                        f"{'differs' if len(backup.slots) == 1 else 'differ'} from "
                        f"{backup.path.name}", ["name", "number", "motor/bank", "saved", "live",
                                                "unit"], rows)
    if diffs and "--exit-code" in given:
        err = DiffFound(f"{_count(len(diffs))} {'differs' if len(diffs) == 1 else 'differ'} "
                        f"from {backup.path}")
        err.shown = True  # type: ignore[attr-defined]  # the table (or the JSON) said it
        raise err


# -- .restore ------------------------------------------------------------------------------

@dataclass
class Written:
    diff: Difference
    error: str | None = None
    read_back: int | None = None
    stored: bool = False

    def to_json(self) -> dict[str, object]:
        obj = {**self.diff.slot.to_json(), "old": self.diff.live, "new": self.diff.slot.value}
        if self.diff.slot.outside is not None:
            obj["outside_range"] = self.diff.slot.outside
        if self.error:
            obj["error"] = self.error
        return obj


def _is_link(slot: Slot) -> bool:
    return slot.param is not None and slot.param.link


def _cuts(client: Client, param: Parameter | None) -> bool:
    """Whether writing ``param`` may cut the link in use with nothing to follow (``breaks``
    in the module data): a CAN bit rate on CAN, the ASCII echo while talking ASCII. A CAN id
    written over a serial line cuts nothing here."""
    return client.cut_by(param.breaks if param is not None and param.link else None)


def _left_alone_json(backup: Backup) -> list[dict[str, object]]:
    return [{**s.to_json(), "saved": s.value} for s in backup.left_alone]


@command(".restore")
def cmd_restore(session: Session, argtext: str) -> None:
    backup, diffs, given = _against_backup(session, argtext, ".restore")
    live = session.module
    c = session.client
    out = session.out
    if backup.program:
        out.info(f"{backup.path.name} names a stored program ({backup.program}); .restore "
                 f"does not upload it (use .upload {backup.program})")
    if not diffs:
        if out.json:
            out.emit({"file": str(backup.path), "restored": [], "failed": [],
                      "skipped": [w for w, _ in backup.skipped], "stored": 0,
                      "left_alone": _left_alone_json(backup)})
        else:
            out.ok(f"nothing to restore: the {live.name} matches {backup.path.name}"
                   + (" (its link identity aside)" if backup.left_alone else ""))
        return
    yes = "--yes" in given
    address = c.address
    eeprom = sum(1 for d in diffs if d.slot.kind == "global" and d.slot.param is not None
                 and d.slot.param.storable and d.slot.index == 0)
    question = (f"write {_count(len(diffs))} from {backup.path.name} to the {live.name} at "
                f"address {c.address}?")
    if eeprom:
        question += (f" ({eeprom} global parameter{'' if eeprom == 1 else 's'} of bank 0 "
                     f"{'is' if eeprom == 1 else 'are'} written straight to EEPROM)")
    moves = [d for d in diffs if _is_link(d.slot)]
    if moves:  # --with-link: each change of the module's place on its line, old and new
        question += (" Its place on the line changes: "
                     + ", ".join(f"{d.slot.name or d.slot.label} ({d.slot.label}) {d.live} -> "
                                 f"{d.slot.value}" for d in moves))
    if not yes:
        session.confirm(question)
    # link settings last, and last of all those that may cut this connection: after one of
    # them the module may no longer hear it
    order = sorted(diffs, key=lambda d: (_is_link(d.slot), _cuts(c, d.slot.param)))
    done: list[Written] = []
    link_changed: list[Written] = []
    with _Progress(session, "restoring", len(order)) as advance:
        for d in order:
            slot = d.slot
            w = Written(d)
            done.append(w)
            try:
                if _is_link(slot) and slot.param.reaches is not None:  # type: ignore[union-attr]
                    # followed as a typed SGP 66 is: the module is talked to where it is now
                    req = Request.make(c.address, WRITE[slot.kind], slot.number, slot.index,
                                       slot.value)
                    reply = reach.write(c, req, slot.param)  # type: ignore[arg-type]
                else:
                    reply = _request(session, WRITE[slot.kind], slot, slot.value)
                if reply is not None and not status_ok(reply.status):
                    w.error = (f"the module refused {slot.value}: status {reply.status} "
                               f"({status_text(reply.status)})")
                    continue
                if _cuts(c, slot.param):
                    link_changed.append(w)
                    continue
                back = _request(session, READ[slot.kind], slot)
                if back is None or not status_ok(back.status):
                    w.error = "written, but reading it back failed"
                    continue
                w.read_back = _shown(back.value, slot.param)
                if not _same(w.read_back, slot.value):
                    w.error = f"written {slot.value}, but the module reads back {w.read_back}"
            except TmclError as exc:
                w.error = str(exc)
                if link_changed:
                    break  # the link changed under us; the rest cannot be reached
            finally:
                advance()
    ok = [w for w in done if w.error is None]
    stored = 0
    if "--store" in given and ok:
        storable = [w for w in ok if w.diff.slot.param is not None and w.diff.slot.param.storable
                    and w not in link_changed]
        if storable:
            if not yes:
                session.confirm(f"store {_count(len(storable))} restored permanently in "
                                "the module's EEPROM (STAP/STGP)?")
            for w in storable:
                slot = w.diff.slot
                reply = _request(session, STORE[slot.kind], slot)
                if reply is not None and not status_ok(reply.status):
                    w.error = (f"restored, but storing it failed: status {reply.status} "
                               f"({status_text(reply.status)})")
                else:
                    w.stored = True
                    stored += 1
    failed = [w for w in done if w.error is not None]
    restored = [w for w in done if w.error is None]
    _report_restore(session, backup, restored, failed, link_changed, stored)
    if c.address != address:
        out.info(f"the {live.name} answers at address {c.address} now (it was at {address})")
    if failed:
        err = CloneError(f"{len(failed)} of {_count(len(done))} "
                         f"{'was' if len(failed) == 1 else 'were'} not restored")
        err.shown = session.out.json  # type: ignore[attr-defined]  # the JSON object said it
        raise err


def _report_restore(session: Session, backup: Backup, restored: list[Written],
                    failed: list[Written], link_changed: list[Written], stored: int) -> None:
    out = session.out
    if out.json:
        out.emit({"file": str(backup.path), "restored": [w.to_json() for w in restored],
                  "failed": [w.to_json() for w in failed],
                  "skipped": [w for w, _ in backup.skipped], "stored": stored,
                  "left_alone": _left_alone_json(backup),
                  "address": session.client.address})
        return
    if restored:
        rows = [[w.diff.slot.name or "", w.diff.slot.label, w.diff.slot.where,
                 str(w.diff.live), str(w.diff.slot.value),
                 ("not read back (link)" if w in link_changed else "read back")
                 + (", stored" if w.stored else "")] for w in restored]
        _table(session, f"restored {_count(len(restored))} from {backup.path.name}",
               ["name", "number", "motor/bank", "old", "new", "verified"], rows)
        beyond = [w.diff.slot for w in restored if w.diff.slot.outside is not None]
        if beyond:
            out.warn(f"{len(beyond)} of them outside the manual's ranges, as the module took "
                     "them: " + "; ".join(f"{s.title()} = {s.value} (the manual says "
                                          f"{s.outside})" for s in beyond))
    for w in failed:
        out.warn(f"not restored: {w.diff.slot.title()}: {w.error}")
    for w in link_changed:
        if w.error is None:
            p = w.diff.slot.param
            out.warn(f"{p.name if p else w.diff.slot.label} is now {w.diff.slot.value}: the "
                     "module may only answer with the new setting (reconnect)")
