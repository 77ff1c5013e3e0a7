"""A module's configuration, from Python: back it up, write and read the backup file, compare
it with the module, restore what differs. Plain functions on a client, never printing; the
shell's ``.save``/``.diff``/``.restore`` (``tmclsh.shell.features.clone``) are their front ends.

The backup is a plain tmclsh script, so it is replayed, diffed and edited like any other: one
``SAP``/``SGP`` line per writable configuration parameter, everything else (read-only values,
motion state) as ``//`` comments that document the module without ever being written back.
Reading a backup checks every SAP/SGP line through the assembler, against the live module,
so a hand-written file is checked exactly as typed commands are, before any byte is sent.
Parameters are keyed by number and motor/bank; names are only needed to carry a file across
module types (and for people), so a module without parameter data compares by number.

Which parameters are state and which make up the module's place on its line is data
(``state``/``link``/``breaks`` in the module files), never a list here. That place (address,
baud rate, CAN ids, ASCII start-up, ...) belongs to the module, not to the backup: a backup
of the module at address 1 restored onto the one at address 5 must not move it onto the
first one's address, so it is carried only when asked (``with_link``).

From Python::

    c = tmclsh.connect(sim="TMCM-1311")
    conf = backup.read_configuration(c)
    backup.write_backup("m.tmcl", conf.text())
    saved = backup.read_backup(c, Path("m.tmcl"))
    diffs = backup.compare(c, saved)
    done = backup.restore(c, diffs)
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from itertools import zip_longest
from pathlib import Path
from typing import TYPE_CHECKING

from ..base.errors import EXIT_USAGE, AsmError, RangeError, TmclError, ValidationError
from ..client import reach
from ..client.text import AS_TYPED
from ..tmcl import asm
from ..tmcl import instructions as isa
from ..tmcl import modules as moddb
from ..tmcl.frames import Control, Request, status_ok, status_text
from ..tmcl.modules import Module, Parameter
from ..tmcl.textlines import split_line

if TYPE_CHECKING:
    from ..client.core import Client

Progress = Callable[[], None]  # called once per parameter done (a front end's progress bar)

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


def _request(client: Client, opcode: int, slot: Slot | tuple[str, int, int], value: int = 0):
    number, index = (slot.number, slot.index) if isinstance(slot, Slot) else slot[1:]
    return client.request(Request.make(client.address, opcode, number, index, value))


# -- reading the configuration, writing the file ---------------------------------------------

def firmware(client: Client) -> str:
    """The module's firmware version (136), as the client knows it or asks; "unknown"."""
    if client.version:
        return client.version
    try:
        reply = client.request(Request(client.address, Control.GET_VERSION, 0, 0, 0))
    except TmclError:
        return "unknown"
    if reply is not None and reply.version:
        client.version = reply.version
        return reply.version
    return "unknown"


def _comment(p: Parameter, number: int) -> str:
    unit = f", {p.unit}" if p.unit else ""
    return f"{'AP' if p.kind == 'axis' else 'GP'} {number}{unit}: {p.description}"


@dataclass
class Configuration:
    """A module's configuration as read (``read_configuration``): every readable slot with
    the value the module holds, those it refused with their status; ``text`` is the backup.
    Link identity is the slots whose parameter is marked ``link`` (``link``)."""

    module: Module
    firmware: str
    address: int
    connection: str  # how it was reached: the client's description and mode
    slots: list[Slot]  # in the file's order (value 0 where refused)
    refused: dict[tuple[str, int, int], int] = field(default_factory=dict)  # key -> status

    def _kept(self) -> list[Slot]:
        return [s for s in self.slots if s.key not in self.refused and s.param is not None
                and not s.param.state and s.param.writable]

    @property
    def restorable(self) -> list[Slot]:
        """The slots a restore writes (SAP/SGP lines), link identity aside."""
        return [s for s in self._kept() if not s.param.link]  # type: ignore[union-attr]

    @property
    def link(self) -> list[Slot]:
        """The module's link identity: written back only when asked (``with_link``)."""
        return [s for s in self._kept() if s.param.link]  # type: ignore[union-attr]

    @property
    def outside(self) -> list[str]:
        """The values held outside the manual's ranges (saved as they are, marked ``!``)."""
        out = []
        for s in self._kept():
            p = s.param
            assert p is not None
            beyond = p.outside(s.value)
            if beyond is not None:
                out.append(f"{s.name or s.label} = {_with_unit(s.value, p)} "
                           f"({'motor' if s.kind == 'axis' else 'bank'} {s.index}; the manual "
                           f"says {beyond})")
        return out

    def text(self, program: str | None = None, when: datetime | None = None) -> str:
        """The backup file's text (``program``: the stored program's file, named in the
        header; ``when``: the date it names, now by default)."""
        return backup_text(self, program, when)


def read_configuration(client: Client, progress: Progress | None = None) -> Configuration:
    """Read every parameter a backup holds from the module (one request each); a status
    other than OK is kept with the slot (the file says it was not read)."""
    module = client.require_module()
    version = firmware(client)
    found = list(readable_slots(module))
    replies: list = [None] * len(found)
    for i in read_order([kind for kind, *_ in found]):
        kind, p, number, index = found[i]
        replies[i] = _request(client, READ[kind], Slot(kind, number, index, 0, p))
        if progress is not None:
            progress()
    slots: list[Slot] = []
    refused: dict[tuple[str, int, int], int] = {}
    for (kind, p, number, index), reply in zip(found, replies):
        if reply is None or not status_ok(reply.status):
            slot = Slot(kind, number, index, 0, p)
            refused[slot.key] = reply.status if reply is not None else 0
        else:
            slot = Slot(kind, number, index, _shown(reply.value, p), p)
        slots.append(slot)
    return Configuration(module, version, client.address,
                         f"{client.describe()} ({client.mode})", slots, refused)


def backup_text(conf: Configuration, program: str | None = None,
                when: datetime | None = None) -> str:
    """The backup's text: a header, then one SAP/SGP line per restorable value and a comment
    for each other one, link identity in a section of its own at the end."""
    module = conf.module
    body: list[str] = []
    saved = link_saved = 0
    link_body: list[str] = []
    outside = 0
    last_section = None
    for slot in conf.slots:
        kind, number, index, p = slot.kind, slot.number, slot.index, slot.param
        assert p is not None
        section = (kind, index)
        if section != last_section:
            where = f"motor {index}" if kind == "axis" else f"bank {index}"
            body.append("")
            body.append(f"// -- {'axis' if kind == 'axis' else 'global'} parameters, {where}")
            last_section = section
        name = slot.name or slot.label
        comment = _comment(p, number)
        if slot.key in conf.refused:
            status = conf.refused[slot.key]
            body.append(f"// {name}: not read, the module answered status {status} "
                        f"({status_text(status)})")
            continue
        value = slot.value
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
            outside += 1
        text = f"{mark}{mn} {target}, {index}, {value}  // {comment}"
        if p.link:  # the module's place on its line: a section of its own, at the end
            link_body.append(text)
            link_saved += 1
            continue
        body.append(text)
        saved += 1
    if link_body:
        body += ["", LINK_SECTION, *LINK_SECTION_WHY, *link_body]
    when = when or datetime.now(timezone.utc)
    head = [
        f"{BACKUP_MARK} {module.name} (.save); format: man tmclsh, CONFIGURATION BACKUPS",
        f"// module: {module.name}",
        f"// firmware: {conf.firmware}",
        f"// address: {conf.address}",
        f"// connection: {conf.connection}",
        f"// date: {when.strftime('%Y-%m-%d %H:%M:%S UTC')}",
    ]
    if program is not None:
        head.append(f"// program: {program}")
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
        held = conf.outside
        head.append(f"// {outside} value{'s' if outside != 1 else ''} outside the manual's ranges, "
                    f"as the module held {'them' if outside != 1 else 'it'} (on a fresh module often "
                    "unset defaults):")
        head.append(f"// the lines start with {AS_TYPED} (sent as written; the module decides): "
                    + "; ".join(held))
    return "\n".join(head + body) + "\n"


def write_backup(path: Path | str, text: str) -> None:
    """Write ``text`` to a temporary file beside ``path`` and rename it over ``path``, so a
    failed or interrupted save never leaves half a backup in place of a whole one. A device
    or pipe (``/dev/null``) is written as it is, never replaced by a file."""
    from ..base import files

    with files.atomic_writer(Path(path), newline="\n") as fh:
        fh.write(text)


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


def header(lines: list[str]) -> dict[str, str]:
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


def has_data(module: Module) -> bool:
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


def read_backup(client: Client, path: Path | str, *, force: bool = False,
                command: str | None = None, with_link: bool = False,
                split: Callable[[str], list[str]] = split_line) -> Backup:
    """Parse and check every line of ``path`` against the live module (nothing is sent).
    Only comments, blank lines and SAP/SGP lines the module accepts may be in it: anything
    else is an error at FILE:LINE, so a typo never reads as "matches". ``command`` (.diff,
    .restore: the shell's) is named in the hint for another module's backup, and ``.diff``
    compares whatever the file holds; None (Python) is read for a restore, the hint naming
    ``force=True``. ``split`` cuts a line of the file into shell lines (the shell's own,
    which knows its commands, from the shell)."""
    live = client.require_module()
    path = Path(path)
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
    head = header(lines)
    backup = Backup(path, head.get("module"), head.get("program"), with_link=with_link)
    source = _source_module(backup.module_name, live)
    other = backup.module_name is not None and _norm(backup.module_name) != _norm(live.name)
    if other and not force and has_data(live):
        verb = "compare" if command == ".diff" else "restore"
        how = (f"{command} {path} --force" if command is not None
               else "read_backup(..., force=True)")
        raise BackupFileError(
            f"{path} is a backup of a {backup.module_name}, this is a {live.name}; {verb} by "
            f"parameter name with {how} (parameters the {live.name} does not have are "
            "skipped)", "check")
    # .diff compares whatever the file holds; .restore writes a value outside the manual's
    # range only where the file says so (``!``, as .save writes the module's own) or --force
    anything = command == ".diff" or force
    refused: list[BackupFileError] = []
    for number, raw in enumerate(lines, 1):
        for shell_line in split(raw):  # comments off, `;` between lines
            as_typed = anything or shell_line.startswith(AS_TYPED)
            try:
                _read_line(client, backup, path, number, shell_line, source, live,
                           as_typed)
            except BackupFileError as exc:
                refused.append(exc)
    if refused:  # every refused line at once: one run to see them all, not one per line
        if len(refused) == 1:
            raise refused[0]
        kinds = {e.kind for e in refused}
        hint = (f"\n(a value outside the manual's range is written only from a line that "
                f"starts with {AS_TYPED}, as .save marks the module's own, or with "
                f"{command + ' --force' if command is not None else 'force=True'})"
                if "range" in kinds and command != ".diff" else "")
        raise BackupFileError(f"{path}: {len(refused)} lines refused, nothing sent:\n"
                              + "\n".join(f"  {e}" for e in refused) + hint,
                              "range" if kinds == {"range"} else refused[0].kind)
    if not (backup.slots or backup.state or backup.skipped or backup.left_alone):
        # an empty or truncated file must not read as "matches" either
        raise BackupFileError(f"{path} has no SAP/SGP lines: nothing to compare or restore "
                              "(a backup is written by .save)")
    return backup


def _read_line(client: Client, backup: Backup, path: Path, number: int, text: str,
               source: Module | None, live: Module, as_typed: bool = False) -> None:
    line = _parse(path, number, text, source or live)
    try:
        enc = client.check(line, source or live, as_typed=as_typed)
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
        if p is None and line.is_raw and has_data(live):
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
    if not has_data(live):  # numbers only (generic mode): the file's names give the numbers
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


def writes_link(client: Client, text: str, module: Module, number: int,
                left: list[Slot]) -> bool:
    """Whether one shell line writes a parameter of the module's link identity (noted)."""
    if text.startswith(".") or "${" in text:
        return False
    try:
        line = asm.parse_line(text.removeprefix(AS_TYPED), number)
        if line.mnemonic is None:
            return False
        enc = client.check(line, module, as_typed=True)
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


def compare(client: Client, backup: Backup, progress: Progress | None = None
            ) -> list[Difference]:
    """Read each saved parameter from the module (one request each); the ones that differ."""
    diffs: list[tuple[int, Difference]] = []
    slots = list(backup.slots.values())
    for i in read_order([slot.kind for slot in slots]):
        slot = slots[i]
        reply = _request(client, READ[slot.kind], slot)
        if progress is not None:
            progress()
        if reply is None or not status_ok(reply.status):
            status = reply.status if reply is not None else 0
            raise CloneError(f"{backup.path}:{slot.line}: reading {slot.title()} failed: "
                             f"status {status} ({status_text(status)})")
        live = _shown(reply.value, slot.param)
        if not _same(live, slot.value):
            diffs.append((i, Difference(slot, live)))
    return [d for _, d in sorted(diffs, key=lambda x: x[0])]


# -- restoring -------------------------------------------------------------------------------

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


def is_link(slot: Slot) -> bool:
    return slot.param is not None and slot.param.link


def cuts(client: Client, param: Parameter | None) -> bool:
    """Whether writing ``param`` may cut the link in use with nothing to follow (``breaks``
    in the module data): a CAN bit rate on CAN, the ASCII echo while talking ASCII. A CAN id
    written over a serial line cuts nothing here."""
    return client.cut_by(param.breaks if param is not None and param.link else None)


def restore_order(client: Client, diffs: list[Difference]) -> list[Difference]:
    """Link settings last, and last of all those that may cut this connection: after one of
    them the module may no longer hear it."""
    return sorted(diffs, key=lambda d: (is_link(d.slot), cuts(client, d.slot.param)))


def restore(client: Client, diffs: list[Difference], progress: Progress | None = None
            ) -> tuple[list[Written], list[Written]]:
    """Write what differs (``restore_order``), each read back unless it may have cut the
    link. -> (every write, with its error if any; those that changed the link, not read
    back). Stops after an error that follows a link change: the rest cannot be reached."""
    done: list[Written] = []
    link_changed: list[Written] = []
    for d in restore_order(client, diffs):
        slot = d.slot
        w = Written(d)
        done.append(w)
        try:
            if is_link(slot) and slot.param.reaches is not None:  # type: ignore[union-attr]
                # followed as a typed SGP 66 is: the module is talked to where it is now
                req = Request.make(client.address, WRITE[slot.kind], slot.number, slot.index,
                                   slot.value)
                reply = reach.write(client, req, slot.param)  # type: ignore[arg-type]
            else:
                reply = _request(client, WRITE[slot.kind], slot, slot.value)
            if reply is not None and not status_ok(reply.status):
                w.error = (f"the module refused {slot.value}: status {reply.status} "
                           f"({status_text(reply.status)})")
                continue
            if cuts(client, slot.param):
                link_changed.append(w)
                continue
            back = _request(client, READ[slot.kind], slot)
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
            if progress is not None:
                progress()
    return done, link_changed


def storable(done: list[Written], link_changed: list[Written]) -> list[Written]:
    """Of what was restored, what can be stored in the module's EEPROM (STAP/STGP)."""
    return [w for w in done if w.error is None and w.diff.slot.param is not None
            and w.diff.slot.param.storable and w not in link_changed]


def store(client: Client, written: list[Written],
          link_changed: list[Written] | None = None) -> int:
    """Store each restored value permanently (STAP/STGP); how many were stored (a refusal is
    the write's error). What ``restore`` returns may be given as it is: only what was
    written and read back, of a parameter the module stores, is (``storable``)."""
    stored = 0
    for w in storable(written, link_changed or []):
        slot = w.diff.slot
        reply = _request(client, STORE[slot.kind], slot)
        if reply is not None and not status_ok(reply.status):
            w.error = (f"restored, but storing it failed: status {reply.status} "
                       f"({status_text(reply.status)})")
        else:
            w.stored = True
            stored += 1
    return stored
