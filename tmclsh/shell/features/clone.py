"""Clone a module, the shell's front ends: ``.save``, ``.diff`` and ``.restore`` (their
options, questions, progress bars, tables and messages), and a backup replayed with ``-f``.

What they do to the module (reading its configuration, the backup file's format, comparing,
restoring) is ``tmclsh.ops.backup``, usable from Python without a shell; see its docstring for
the format and why a module's link identity is left alone unless --with-link asks.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from ...base.errors import TmclError, ValidationError
from ...client.text import AS_TYPED
from ...ops import backup as ops
from ...ops import program
# (the names others import from here: tests, scripts/bench.py, which also reads old trees)
from ...ops.backup import (BACKUP_MARK, READ, STORE, WRITE, Backup,  # noqa: F401
                           BackupFileError, CloneError, Difference, Slot, Written,
                           left_alone_text, readable_slots)
from ...tmcl import asm
from ...tmcl.frames import Control
from ...tmcl.modules import Module
from ..lang import options
from ..lang.commands import command, find, options_of
from ..lang.lines import split_line

if TYPE_CHECKING:
    from ..lang.session import Session

CATEGORY = "configuration"


# -- argument parsing --------------------------------------------------------------------

def _args(argtext: str, command: str) -> tuple[str, set[str]]:
    """FILE and the options given (shell/lang/options.py, as the table declares them)."""
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

write_atomically = ops.write_backup  # (the name it had here)


def save_lines(session: Session, path: Path, with_program: Path | None
               ) -> tuple[str, int, list[str], int]:
    """The backup's text, how many parameters it restores (SAP/SGP lines), which of the
    values the module holds lie outside the manual's ranges (saved all the same, marked so
    that .restore writes them back as they were: ``!SAP ...``, the module decides), and how
    many of them are its link identity."""
    total = sum(1 for _ in readable_slots(session.module))
    with _Progress(session, "reading", total) as advance:
        conf = ops.read_configuration(session.client, progress=advance)
    text = conf.text(with_program.name if with_program is not None else None)
    link_saved = len(conf.link)
    return text, len(conf.restorable) + link_saved, conf.outside, link_saved


def _program_path(path: Path) -> Path:
    stem = path.name[: -len(path.suffix)] if path.suffix else path.name
    return path.with_name(f"{stem}.program.tmcl")


def _program_text(session: Session) -> tuple[str, int]:
    from ...ops import program

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
            head = ops.header(fh.read(4096).decode("utf-8", "replace").splitlines())
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
    from ..lang.session import Abort

    raise Abort(f"{names} {'exists' if one else 'exist'}; not overwritten: add --yes to "
                f"replace {'it' if one else 'them'}, or save under another name")


def _has_parameters_to_save(module: Module) -> None:
    """A backup reads the parameters the module's data lists; a module known by number only
    has none, and a file of 0 parameters restores nothing: refused, with what can be done."""
    if ops.has_data(module):
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
    beyond = f"; {len(outside)} outside the manual's ranges, marked {AS_TYPED}" if outside else ""
    out.ok(f"saved {_count(saved)} of the {session.module.name} to {path}{link}{beyond}")
    if names_only:
        out.warn(f"{_count(len(names_only))} known by name only, saved as comments, not "
                 "restorable: " + _some(names_only))
    if outside and _first_time("outside"):
        out.info(f"({AS_TYPED} marks a value outside the manual's range, often a fresh "
                 "module's unset default: saved as the module holds it, and .restore writes "
                 "it back; each line's comment says the range)")
    if prog_path is not None:
        out.ok(f"saved the stored program ({instructions} instructions) to {prog_path}")


_SAID: set[str] = set()  # notes said once per run (every unit's .save would say the same)
_SAID_LOCK = threading.Lock()


def _first_time(note: str) -> bool:
    """True the first time ``note`` comes up in this process (units run in threads)."""
    with _SAID_LOCK:
        if note in _SAID:
            return False
        _SAID.add(note)
        return True


# -- reading a backup --------------------------------------------------------------------

def read_backup(session: Session, path: Path, *, force: bool, command: str,
                with_link: bool = False) -> Backup:
    """``ops.backup.read_backup`` with the shell's own line cutting (its commands)."""
    return ops.read_backup(session.client, path, force=force, command=command,
                           with_link=with_link, split=split_line)


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
        rest = [t for t in texts if not ops.writes_link(session.client, t, module, number, left)]
        if len(rest) != len(texts):
            kept[number - 1] = "; ".join(rest)
    if left:
        session.out.info(f"{path}: left alone, the module's own place on its line (write "
                         "it with --with-link): " + left_alone_text(left))
    return kept


def needs_yes(session: Session, lines: list[str]) -> tuple[int, str] | None:
    """A configuration backup replayed where nobody can answer and without --yes: its first
    line that would ask (a bank 0 global parameter writes the EEPROM) and the question. Asked
    only at that line, the replay would stop halfway, the module's configuration half the
    backup's and half its own; refused before anything is sent, it is as it was."""
    if not lines or not lines[0].startswith(BACKUP_MARK) or session.can_answer():
        return None
    from ..lang.session import confirmation

    try:
        module = session.module
    except TmclError:
        return None
    for number, raw in enumerate(lines, 1):
        for text in split_line(raw):
            if text.startswith(".") or "${" in text:
                continue
            try:
                line = asm.parse_line(text.removeprefix(AS_TYPED), number)
                if line.mnemonic is None:
                    continue
                enc = session.client.check(line, module, as_typed=True)
            except TmclError:
                continue  # (the script's own checks report it at its line)
            question = confirmation(enc)
            if question is not None:
                return number, question
    return None


def replay_hint(session: Session, path: Path | str, lines: list[str], *,
                stopped: bool) -> str | None:
    """What to do instead, when replaying a configuration backup with -f went wrong: it was
    another module's (its lines name parameters this one lacks, so the check refuses it whole),
    or the module refused a line and the run stopped there (--keep-going goes on; .restore
    writes what differs and lists every refusal)."""
    if not lines or not lines[0].startswith(BACKUP_MARK):
        return None
    saved_from = next((line.split(":", 1)[1].strip() for line in lines[1:8]
                       if line.startswith("// module:")), None)
    try:
        here = session.module.name
    except TmclError:
        return None
    if saved_from is not None and saved_from != here:
        return (f"{path} is a backup of a {saved_from}, not of this {here}: .restore {path} "
                f"--force writes the values the {here} has too and lists the rest")
    if stopped and not session.keep_going:
        return (f"{path} is a configuration backup: -f stops at the first line the module "
                "refuses; --keep-going replays the rest, and .restore "
                f"{path} writes what differs and lists every value the module refuses")
    return None


def compare(session: Session, backup: Backup) -> list[Difference]:
    """Read each saved parameter from the module (one request each); the ones that differ."""
    with _Progress(session, "comparing", len(backup.slots)) as advance:
        return ops.compare(session.client, backup, progress=advance)


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
    moves = [d for d in diffs if ops.is_link(d.slot)]
    if moves:  # --with-link: each change of the module's place on its line, old and new
        question += (" Its place on the line changes: "
                     + ", ".join(f"{d.slot.name or d.slot.label} ({d.slot.label}) {d.live} -> "
                                 f"{d.slot.value}" for d in moves))
    if not yes:
        session.confirm(question)
    with _Progress(session, "restoring", len(diffs)) as advance:
        done, link_changed = ops.restore(c, diffs, progress=advance)
    stored = 0
    if "--store" in given:
        storable = ops.storable(done, link_changed)
        if storable:
            if not yes:
                session.confirm(f"store {_count(len(storable))} restored permanently in "
                                "the module's EEPROM (STAP/STGP)?")
            stored = ops.store(c, storable)
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
