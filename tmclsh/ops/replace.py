"""Swapping a module in the field: from an old module (live, only ever read) or its backup,
to a new module of the same type, in five steps, each returning its outcome:

1. ``identify``: what the old module is (type, firmware, configuration, stored program) and
   what the new one is; another type is refused unless ``force`` (settings are then carried
   by name under ``read_backup``'s unit-aware rules, and the firmware is left alone);
2. ``firmware``: the new module brought to the old one's firmware version from the image
   the technician names (``ops.firmware.Update``); without one, which image is needed;
3. ``configuration``: the old configuration restored and stored (``ops.backup``); the new
   module's link identity stays its own unless ``with_link``;
4. ``program``: the old module's stored program uploaded and verified (``ops.program``),
   unless the new module holds it already;
5. ``verify``: every setting and the program read back from the new module.

Why steps as data: whatever stops a run (a refusal, Ctrl-C, SIGTERM, a lost link), the
report says which steps were done and where both modules stand, and every step looks before
it writes, so running the same replacement again completes it: a firmware already at the
old version is skipped (one left in its bootloader is completed), only settings that still
differ are written, a program already there is not uploaded again.

Nothing here prints: each finished step goes to ``on_step``, what happens inside one to
``notice``, the question before the first write to ``confirm``.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ..base.errors import (ConnectError, InBootloaderError, NoAnswerError, TmclError,
                           TmclTimeoutError, TransportError, ValidationError)
from ..base.interrupts import Terminated, stopped_words
from ..tmcl import instructions as isa
from ..tmcl import modules as moddb
from ..tmcl.frames import Control, Instruction
from ..tmcl.version import parse_string
from . import backup as bk
from . import program as prog

if TYPE_CHECKING:
    from ..tmcl.bootloader import Image

STEPS = ("identify", "firmware", "configuration", "program", "verify")
# a step's outcome
DONE, SKIPPED, FAILED, STOPPED, NOT_RUN = "done", "skipped", "failed", "stopped", "not run"
OLD_UNCHANGED = "the old module was only read: it is as it was"
# the same when the old module is known from its backup: no module was read at all
BACKUP_UNCHANGED = "the old module's backup {} was only read"


class ReplaceError(TmclError):
    """A replacement that cannot start (a backup that cannot be read, a bad setting)."""


@dataclass
class Outcome:
    """One step's result: ``state`` is one of done, skipped, failed, stopped, not run;
    ``text`` says what was done or found, for people; ``data`` the same for programs."""

    step: str
    state: str
    text: str
    data: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"step": self.step, "outcome": self.state, "text": self.text, **self.data}


@dataclass
class Report:
    """The whole replacement: each step's outcome in order, and where the modules stand."""

    source: str  # the old module or backup, as named
    target: str  # the new module, as named
    steps: list[Outcome] = field(default_factory=list)
    situation: str | None = None  # where both modules stand after a failed or stopped step

    @property
    def ok(self) -> bool:
        return len(self.steps) == len(STEPS) and all(
            o.state in (DONE, SKIPPED) for o in self.steps)

    @property
    def stopped_at(self) -> Outcome | None:
        return next((o for o in self.steps if o.state in (FAILED, STOPPED)), None)

    def to_json(self) -> dict:
        out: dict = {"replace": "done" if self.ok else "incomplete", "from": self.source,
                     "to": self.target, "steps": [o.to_json() for o in self.steps]}
        if self.situation:
            out["situation"] = self.situation
        return out


class Stop(Exception):
    """A step ends the run with this outcome (failed, or declined)."""

    def __init__(self, outcome: Outcome):
        super().__init__(outcome.text)
        self.outcome = outcome


@dataclass
class Old:
    """What the old module was: from the module itself or from its backup."""

    module: moddb.Module
    firmware: str  # its 136 string, "unknown" from a backup that does not say
    backup: Path  # its configuration as a backup file (read back by read_backup)
    program: list[Instruction] | None  # None: not known (a backup without one, ASCII mode)
    described: str
    address: int | None = None  # where it answered (a backup's header: where it was saved)


def is_backup(source: str) -> bool:
    """Whether ``--from`` names a backup file (``.save``'s first line) rather than a port."""
    path = Path(source)
    try:
        if not path.is_file():
            return False
        with open(path, "rb") as fh:
            return fh.read(len(bk.BACKUP_MARK)).decode("utf-8", "replace") == bk.BACKUP_MARK
    except OSError:
        return False


class Replacement:
    """One replacement. ``source``: the old module's connection settings (as
    ``client.connect.open_client`` takes them) or the path of its backup; ``target``: the
    new module's settings; ``image``: the firmware image (``tmcl.bootloader.Image``) that
    brings the new module to the old version, if needed."""

    def __init__(self, source: dict | Path, target: dict, *, image: Image | None = None,
                 with_link: bool = False, force: bool = False,
                 on_step: Callable[[Outcome], None] | None = None,
                 notice: Callable[[str], None] | None = None,
                 confirm: Callable[[str], bool] | None = None,
                 source_name: str = "", target_name: str = ""):
        self.source = source
        self.target = dict(target)
        self.image = image
        self.with_link = with_link
        self.force = force
        self.on_step = on_step or (lambda o: None)
        self.notice = notice or (lambda text: None)
        self.confirm = confirm
        self.report = Report(source_name or _name(source), target_name or _name(target))
        self.old: Old | None = None
        self.new = None  # the new module's client, while connected
        self.new_module: moddb.Module | None = None
        self.new_version: str | None = None  # its 136 string (B: in its bootloader)
        self.new_found = False
        self.backup: bk.Backup | None = None
        self.update = None  # the firmware update, while one runs
        self.upload_error: prog.UploadError | None = None
        self.upload_began = False  # the program step's upload was started
        self.written = 0  # settings written by this run
        # settings the configuration step has sent so far (the last may have been cut
        # short), and whether it got to the end of its writes (then ``written`` is exact)
        self.tried, self.restored = 0, False
        self._dir = tempfile.TemporaryDirectory(prefix="tmclsh-replace-")

    # -- running the steps ----------------------------------------------------------------
    def run(self) -> Report:
        """Every step in order until one fails. A step interrupted (Ctrl-C, SIGTERM as
        SystemExit) or losing its link is recorded as stopped, a step that fails as failed;
        ``report.situation`` says where both modules stand. Ctrl-C and SIGTERM are raised
        again once recorded; no module to talk to at the start is a ``ConnectError``."""
        handlers = {"identify": self._identify, "firmware": self._firmware,
                    "configuration": self._configuration, "program": self._program,
                    "verify": self._verify}
        try:
            for name in STEPS:
                try:
                    outcome = handlers[name]()
                except Stop as stop:
                    outcome = stop.outcome
                except (KeyboardInterrupt, SystemExit) as exc:
                    # which stopped it, in the words every command uses (interrupted
                    # (Ctrl-C), terminated (SIGTERM), hung up (SIGHUP)); the situation
                    # says what the step had done
                    why = stopped_words(exc) if isinstance(exc, (KeyboardInterrupt,
                                                                  Terminated)) \
                        else "stopped"
                    self._end(Outcome(name, STOPPED, f"{why} during this step"))
                    raise
                except ConnectError as exc:
                    if name == "identify" or (name == "firmware" and not self.new_found):
                        raise  # no module to replace, or none to replace it with
                    outcome = Outcome(name, FAILED, str(exc))
                except TmclError as exc:
                    outcome = Outcome(name, STOPPED if _link_lost(exc) else FAILED, str(exc))
                self.report.steps.append(outcome)
                self.on_step(outcome)
                if outcome.state in (FAILED, STOPPED):
                    self.report.situation = self.situation(name)
                    break
            done = {o.step for o in self.report.steps}
            for name in STEPS:
                if name not in done:
                    self.report.steps.append(Outcome(name, NOT_RUN, "not run"))
            return self.report
        finally:
            self.close()

    def _end(self, outcome: Outcome) -> None:
        self.report.steps.append(outcome)
        self.report.situation = self.situation(outcome.step)
        self.on_step(outcome)
        done = {o.step for o in self.report.steps}
        self.report.steps += [Outcome(n, NOT_RUN, "not run") for n in STEPS if n not in done]

    def situation(self, step: str) -> str:
        """Where both modules stand after ``step`` failed or was stopped."""
        new = {
            "identify": "nothing was written to the new module",
            "firmware": (self.update.situation() if self.update is not None
                         else "its firmware was not changed"),
            "configuration": self._configuration_situation(),
            "program": self._program_situation(),
            "verify": "written as the steps above say (what reads back differently is "
                      "named in the verify step)",
        }[step]
        old = (BACKUP_UNCHANGED.format(self.report.source) if isinstance(self.source, Path)
               else OLD_UNCHANGED)
        return f"{old}; new module: {new}"

    def _tried_one(self) -> None:
        self.tried += 1

    def _configuration_situation(self) -> str:
        """The new module's settings after the configuration step stopped: how many were
        written, or, cut short among its writes, how many were sent (the last one as the
        stop came, which may or may not have been taken)."""
        n = self.written if self.restored else self.tried
        plural = "s" if n != 1 else ""
        if not n:
            return "no setting was written to the new module"
        if self.restored:
            return f"{n} setting{plural} written to the new module (the rest as they were)"
        return (f"{n} setting{plural} written to the new module, the last as it was stopped "
                "(it may not have been taken); the rest as they were")

    def _program_situation(self) -> str:
        """The new module's program memory after the program step stopped: what the
        upload wrote, or that it had not begun, or that only its verify was cut short."""
        if self.upload_error is not None:
            return f"program memory: {self.upload_error.memory_text()}"
        if not self.upload_began:
            return "its program memory was not changed (the upload had not begun)"
        return ("the program was uploaded whole; its read-back was cut short: not known to "
                "read back equal")

    def close(self) -> None:
        self._close_new()
        self._dir.cleanup()

    def _close_new(self) -> None:
        if self.new is not None:
            try:
                self.new.close()
            finally:
                self.new = None

    # -- the links ------------------------------------------------------------------------
    def _open(self, settings: dict, which: str):
        from ..client.connect import open_client

        try:
            return open_client(dict(settings), notice=self.notice)
        except InBootloaderError:
            raise
        except ConnectError as exc:
            try:
                again = type(exc)(f"the {which} module: {exc}")
            except TypeError:  # (a subclass that takes more than its message)
                again = ConnectError(f"the {which} module: {exc}")
            raise again from None
        except TransportError as exc:  # no such port: no module to talk to
            raise ConnectError(f"the {which} module: {exc}") from None

    def _connect_new(self) -> None:
        """The new module's client; one found in its bootloader (an update that broke off)
        or not answering where asked (perhaps in its bootloader at its own address and
        rate) is left to the firmware step."""
        self._close_new()
        try:
            c = self._open(self.target, "new")
        except InBootloaderError as exc:
            self.new_version = exc.version
            parsed = parse_string(exc.version)
            self.new_module = moddb.by_firmware_id(parsed.type_number) if parsed else None
            self.new_found = True
            return
        except NoAnswerError:
            moved = self._moved()
            if moved is not None:
                c = moved
            elif self.image is None:
                raise
            else:
                self.new_version, self.new_module, self.new_found = None, None, False
                return
        self.new = c
        self.new_module = c.require_module()
        self.new_version = c.version or bk.firmware(c)
        self.new_found = True

    def _moved(self):
        """With ``with_link``, a run that carried the link identity already has moved the
        new module to the old one's address: looked for there (a client, or None)."""
        where = self.old.address if self.old is not None else None
        if not self.with_link or where is None or where == (self.target.get("address") or 1):
            return None
        try:
            c = self._open({**self.target, "address": where}, "new")
        except ConnectError:
            return None
        self.notice(f"the new module answers at address {where}, the old one's: moved there "
                    "by --with-link before")
        self.target["address"] = where
        return c

    def _client(self):
        if self.new is None:
            self._connect_new()
        if self.new is None:
            raise TmclError("the new module does not answer in its firmware")
        return self.new

    # -- 1. identify ----------------------------------------------------------------------
    def _identify(self) -> Outcome:
        self.old = self._read_old()
        self._connect_new()
        old = self.old
        data: dict = {"old": {"module": old.module.name, "firmware": old.firmware,
                              "program": None if old.program is None else len(old.program)}}
        if not self.new_found:
            new_text = (f"the new module does not answer at address "
                        f"{self.target.get('address') or 1}: looked for in its bootloader "
                        "by the firmware step")
            data["new"] = None
        else:
            where = " (in its bootloader)" if self._new_in_bootloader() else ""
            name = self.new_module.name if self.new_module else "an unknown module"
            new_text = f"new: {name}, firmware {self.new_version}{where}"
            data["new"] = {"module": name, "firmware": self.new_version,
                           "bootloader": bool(where)}
        program = ("no stored program known" if old.program is None else
                   f"a stored program of {len(old.program)} instructions"
                   if old.program else "no stored program")
        text = f"old: {old.described}, firmware {old.firmware}, {program}; {new_text}"
        if (self.new_module is not None and self.new_module.name != old.module.name):
            if not self.force:
                raise Stop(Outcome("identify", FAILED,
                                   f"{text}: the old module is a {old.module.name}, the new one "
                                   f"a {self.new_module.name}; nothing was written (--force "
                                   "carries the settings by name where the units agree, and "
                                   "leaves the firmware alone)", data))
            text += "; another type, forced: settings carried by name"
        if self.confirm is not None and not self.confirm(
                f"Write the old module's firmware version, settings and program to the new "
                f"module ({self.report.target})? The old module is only read"):
            raise Stop(Outcome("identify", FAILED, f"{text}; declined: nothing was written",
                               data))
        return Outcome("identify", DONE, text, data)

    def _other_type(self) -> bool:
        return self.new_module is not None and self.new_module.name != self.old.module.name

    def _new_in_bootloader(self) -> bool:
        parsed = parse_string(self.new_version or "")
        return parsed is not None and parsed.bootloader

    def _read_old(self) -> Old:
        if isinstance(self.source, Path):
            return self._read_backup_source(self.source)
        c = self._open(self.source, "old")
        try:
            module = c.require_module()
            version = bk.firmware(c)
            conf = bk.read_configuration(c)
            program = None
            # (the module's ASCII mode has no 134: no program is known, not an empty one)
            if module.program_memory and prog.carried(c, Control.READ_MEMORY):
                program = prog.read_program(c)
            path = Path(self._dir.name) / "old.tmcl"
            bk.write_backup(path, conf.text())
            return Old(module, version, path, program,
                       f"{module.name} at address {c.address} on {c.describe()}", c.address)
        finally:
            c.close()

    def _read_backup_source(self, path: Path) -> Old:
        from ..base import files
        from ..tmcl import asm

        try:
            text = files.read_bytes(path, what="backup").decode("utf-8")
        except (files.FileError, UnicodeDecodeError) as exc:
            raise ReplaceError(f"cannot read {path}: {exc}") from None
        head = bk.header(text.splitlines())
        name = head.get("module")
        try:
            module = moddb.load(name) if name else None
        except ValidationError:
            module = None
        if module is None:
            raise ReplaceError(f"{path} names no module tmclsh knows ({name or 'none'}): "
                               "not a backup .save wrote?")
        program = None
        if head.get("program"):
            where = path.parent / head["program"]
            program = list(asm.assemble_file(where, module).instructions)
        address = head.get("address", "")
        return Old(module, head.get("firmware") or "unknown", path, program,
                   f"the backup {path.name} of a {module.name}",
                   int(address) if address.isdigit() else None)

    # -- 2. firmware ----------------------------------------------------------------------
    def _firmware(self) -> Outcome:
        old = self.old
        assert old is not None
        want = parse_string(old.firmware)
        if self._other_type():
            return Outcome("firmware", SKIPPED, "another module type (forced): its firmware "
                                                f"{self.new_version} left as it is")
        if want is None or want.bootloader:
            if self._new_in_bootloader() or not self.new_found:
                return self._update(None)
            return Outcome("firmware", SKIPPED, f"the old firmware version is not known "
                                                f"({old.firmware}): the new module's "
                                                f"{self.new_version} left as it is")
        have = parse_string(self.new_version or "")
        if have is not None and not have.bootloader and have.number == want.number:
            return Outcome("firmware", SKIPPED, f"the new module runs {self.new_version}, the "
                                                "old one's version, already",
                           {"version": self.new_version})
        return self._update(want)

    def _update(self, want) -> Outcome:
        from .firmware import Update

        now = (f"runs {self.new_version}" if self.new_found and not self._new_in_bootloader()
               else "is in its bootloader" if self.new_found else "does not answer")
        if self.image is None:
            need = (f"an image of {want.text} for the {self.old.module.name}"
                    if want is not None else f"an image for the {self.old.module.name}")
            raise Stop(Outcome("firmware", FAILED,
                               f"the new module {now}, the old one ran {self.old.firmware}: "
                               f"give --firmware FILE.hex, {need}; nothing was written",
                               {"needed": want.text if want is not None else None}))
        if want is not None:
            has = self.image.version_for(want.type_number)
            if has is None or has.number != want.number:
                carries = has.text if has is not None else \
                    ", ".join(v.text for v in self.image.versions) or "no version string"
                raise Stop(Outcome("firmware", FAILED,
                                   f"{self.image.name} carries {carries}, the old module ran "
                                   f"{want.text}: give its image; nothing was written",
                                   {"needed": want.text}))
        self._close_new()
        self.update = Update(self.target, self.image,
                             progress=lambda step: self.notice(step.text))
        try:
            result = self.update.run()
        finally:
            self.update.close()
        self._connect_new()
        self.update = None
        if result.nothing_to_do:
            return Outcome("firmware", SKIPPED, f"the new module runs {result.new_version} "
                                                "already", {"version": result.new_version})
        was = result.old_version or "its bootloader (an update that broke off)"
        return Outcome("firmware", DONE, f"from {was} to {result.new_version}, the old "
                                         f"module's version ({self.image.name})",
                       {"old_version": result.old_version, "version": result.new_version,
                        "written": result.written})

    # -- 3. configuration -----------------------------------------------------------------
    def _read_backup(self) -> bk.Backup:
        if self.backup is None:
            c = self._client()
            self.backup = bk.read_backup(c, self.old.backup,
                                         force=self._other_type() and self.force,
                                         command="replace", with_link=self.with_link)
        return self.backup

    def _configuration(self) -> Outcome:
        c = self._client()
        backup = self._read_backup()
        diffs = bk.compare(c, backup)
        done, link_changed = bk.restore(c, diffs, progress=self._tried_one)
        self.written = sum(1 for w in done if w.error is None)
        self.restored = True
        if link_changed or (self.with_link and c.address != self.target.get("address")):
            self.target["address"] = c.address  # (followed: the module moved)
        errors = [w for w in done if w.error]
        stored = bk.store(c, bk.storable(done, link_changed))
        outside = sum(1 for w in done if w.error is None and w.diff.slot.outside is not None)
        data = {"written": self.written, "stored": stored, "outside_range": outside,
                "differences": [w.to_json() for w in done]}
        notes = []
        if self.with_link:
            notes.append(f"its link identity carried too: it answers at address "
                         f"{c.address}")
        if backup.left_alone:
            n = len(backup.left_alone)
            notes.append(f"its link identity ({n} setting{'s' if n != 1 else ''}: address, "
                         "baud rate, CAN ids, ...) kept as the new module's (--with-link "
                         "carries the old one's)")
            data["left_alone"] = [s.to_json() for s in backup.left_alone]
        if backup.skipped:
            notes.append(f"{len(backup.skipped)} skipped: "
                         + "; ".join(f"{what}: {why}" for what, why in backup.skipped))
            data["skipped"] = [{"what": w, "why": y} for w, y in backup.skipped]
        tail = f"; {'; '.join(notes)}" if notes else ""
        if errors:
            return Outcome("configuration", FAILED,
                           f"{len(errors)} of {len(done)} settings not written: "
                           + "; ".join(f"{w.diff.slot.title()}: {w.error}" for w in errors)
                           + tail, data)
        if not done:
            return Outcome("configuration", SKIPPED,
                           f"all {len(backup.slots)} settings equal the old module's already"
                           + tail, data)
        held = f" ({outside} outside the manual's ranges, as the old module held them)" \
            if outside else ""
        return Outcome("configuration", DONE,
                       f"{self.written} of {len(backup.slots)} settings written{held}, "
                       f"{stored} stored{tail}", data)

    # -- 4. program -----------------------------------------------------------------------
    def _program(self) -> Outcome:
        old = self.old.program
        if old is None:
            return Outcome("program", SKIPPED, "the old module's program was not read (a "
                                               "backup that names none, or ASCII mode): the "
                                               "new module's left alone")
        if not old:
            return Outcome("program", SKIPPED, "the old module holds no stored program")
        if self._other_type():
            return Outcome("program", SKIPPED,
                           f"another module type (forced): the old program ({len(old)} "
                           f"instructions) is not carried, its parameter and port numbers are "
                           f"the {self.old.module.name}'s; the new module's left alone")
        c = self._client()
        held = prog.read_program(c)
        if prog.same_image(held, old):
            return Outcome("program", SKIPPED, f"the new module holds the same program "
                                               f"({len(old)} instructions) already",
                           {"instructions": len(old)})
        image = list(old)
        if len(held) > len(old) and len(old) < c.require_module().program_memory:
            image.append(Instruction(isa.END_MARKER, 0, 0, 0))  # its own program ends here
        self.upload_began = True  # (from here the new module's memory may change)
        try:
            result = prog.upload(c, image, 0, verify=True)
        except prog.UploadError as exc:
            self.upload_error = exc
            raise
        except (KeyboardInterrupt, Terminated) as exc:  # (what it had written: the cause)
            if isinstance(exc.__cause__, prog.UploadError):
                self.upload_error = exc.__cause__
            raise
        if not result.verified:
            at = result.mismatch.address if result.mismatch else "?"
            return Outcome("program", FAILED, f"uploaded, but address {at} reads back "
                                              "differently", {"mismatch": at})
        return Outcome("program", DONE, f"{len(old)} instructions uploaded and verified",
                       {"instructions": len(old)})

    # -- 5. verify ------------------------------------------------------------------------
    def _verify(self) -> Outcome:
        c = self._client()
        backup = self._read_backup()
        diffs = bk.compare(c, backup)
        data: dict = {"settings": len(backup.slots), "differences": [d.to_json() for d in diffs]}
        problems = [f"{d.slot.title()} reads {d.live}, the old module held {d.slot.value}"
                    for d in diffs]
        old = None if self._other_type() else self.old.program
        if old:
            held = prog.read_program(c)
            data["instructions"] = len(held)
            if not prog.same_image(held, old):
                problems.append(f"the program reads back {len(held)} instructions, not the "
                                f"old module's {len(old)}" if len(held) != len(old) else
                                "the program reads back differently")
        version = bk.firmware(c)
        data["firmware"] = version
        want = parse_string(self.old.firmware)
        have = parse_string(version)
        if (not self._other_type() and want is not None and have is not None and not want.bootloader
                and have.number != want.number):
            problems.append(f"it runs {version}, not the old module's {self.old.firmware}")
        if problems:
            return Outcome("verify", FAILED, "; ".join(problems), data)
        program = f" and the program ({len(old)} instructions)" if old else ""
        return Outcome("verify", DONE, f"{len(backup.slots)} settings{program} read back "
                                       f"equal to the old module's; firmware {version}", data)


def _link_lost(exc: BaseException) -> bool:
    """A lost link or a module gone silent (also behind an upload's error): the step was
    stopped by it, not failed by what the module said."""
    lost = (TransportError, TmclTimeoutError)
    return isinstance(exc, lost) or isinstance(exc.__cause__, lost)


def _name(where: dict | Path) -> str:
    """A connection or backup as the report names it."""
    if isinstance(where, Path):
        return str(where)
    link = where.get("port") or (f"can:{where['can']}" if where.get("can") else None) or \
        f"sim:{where.get('sim')}"
    return f"{link} address {where.get('address') or 1}"


def validate(source: dict | Path, target: dict) -> None:
    """The old and the new module must not be one (it would be written while read)."""
    if isinstance(source, dict):
        same = all(source.get(k) == target.get(k) for k in ("port", "can", "sim"))
        if same and (source.get("address") or 1) == (target.get("address") or 1):
            raise ValidationError("--from and --to name the same module: nothing to replace")
