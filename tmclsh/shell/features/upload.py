"""The program onto and off the module, from the shell: ``.upload``, ``.dump`` (``.disasm``) and
``.source-map``.

Dot-commands over :mod:`tmclsh.ops.program` (the bus work) and :mod:`tmclsh.tmcl.sourcemap`
(the source kept beside an upload); the program they load or name is the one the debugger
(``debugger.py``) steps through and lists, so they set its state and rebind its breakpoints.
"""

from __future__ import annotations

import glob
import os
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

from ...base import files
from ...base.errors import AsmError, TmclError, ValidationError
from ...base.interrupts import Terminated
from ...client.shared import shared_text
from ...ops import program
from ...ops.program import UploadError
from ...tmcl import asm, sourcemap
from ...tmcl.frames import Control, Instruction
from ..lang import options
from ..lang.commands import command, options_of
from ..render import paging
from .debugger import (DebuggerError, _not_repeating, _number, _read_status, _rebind_breakpoints,
                       _resolve_file, _show_path, state, where)

if TYPE_CHECKING:
    from ..lang.session import Session

SOURCE_SUFFIXES = (".tmc", ".tmcl", ".inc", ".tmc.txt", ".txt")




# -- progress and completion --------------------------------------------------------------

@contextmanager
def _progress(session: Session) -> Iterator[program.Progress | None]:
    """A rich progress bar on a terminal; nothing under --json or when piped."""
    out = session.out
    if out.json or not out.is_terminal:
        yield None
        return
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                               TimeRemainingColumn)

    names = {"upload": "uploading", "verify": "verifying", "read": "reading"}
    with Progress(TextColumn("{task.description:>10}", markup=False), BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn(), console=out.console, transient=True) as bar:
        tasks: dict[str, object] = {}

        def update(phase: str, done: int, total: int) -> None:
            if phase not in tasks:
                tasks[phase] = bar.add_task(names.get(phase, phase), total=total)
            bar.update(tasks[phase], completed=done)  # type: ignore[arg-type]

        # what the client says meanwhile (the upload stored again after a lost reply) goes
        # above the bar, on its console: written beside it, it ran on from the bar's line
        client = session.client
        before = client.on_notice
        client.on_notice = lambda text: bar.console.print(text, style="tmcl.warn",
                                                          markup=False, highlight=False)
        try:
            yield update
        finally:
            client.on_notice = before


def complete_file(session: Session, text: str) -> list[str]:
    word = text.split()[-1] if text and not text.endswith(" ") else ""
    out = []
    for path in sorted(glob.glob(os.path.expanduser(word) + "*")):
        if os.path.isdir(path):
            out.append(path + os.sep)
        elif path.lower().endswith(SOURCE_SUFFIXES):
            out.append(path)
    return out


# -- upload and read-back ----------------------------------------------------------------

@command(".upload")
def cmd_upload(session: Session, argtext: str) -> None:
    pos, opts = options.parse_words(argtext, options_of(".upload"))
    if len(pos) != 1:
        raise ValidationError("usage: .upload FILE [--at ADDR] [--yes] [--no-verify]")
    program.require_binary(session.client, "uploading a program (132/133)",
                           Control.START_DOWNLOAD, Control.QUIT_DOWNLOAD)
    module = session.module
    origin = _number(str(opts["--at"]), "--at") if "--at" in opts else 0
    path = _resolve_file(session, pos[0])
    prog = asm.load_program(path, module, origin)
    if not len(prog):
        raise ValidationError(f"{path} holds no instructions; nothing to upload")
    program.check_fits(module, origin, len(prog))
    first, last = origin, origin + len(prog) - 1
    if not opts.get("--yes"):
        session.confirm(f"{_running_note(session)}overwrite the {module.name}'s program "
                        f"memory at {first}..{last} with {len(prog)} instructions from "
                        f"{path.name}?")
    dbg = state(session)
    dbg.forget_memory()
    _not_repeating(session)
    try:
        with _progress(session) as progress:
            result = program.upload(session.client, prog, origin,
                                    verify=not opts.get("--no-verify"), progress=progress)
    except UploadError:
        dbg.program = None  # memory now holds parts of two programs
        session.state.program_state = "stop"
        raise
    except (KeyboardInterrupt, Terminated) as exc:  # (Ctrl-C, SIGTERM, SIGHUP)
        if isinstance(exc.__cause__, UploadError):  # (cut short in the upload, not its verify)
            dbg.program = None
            session.state.program_state = "stop"
            # say what is in memory, then let the shell's Ctrl-C policy run (motors stop)
            session.out.error(None, str(exc.__cause__))
        raise
    dbg.program = prog
    dbg.files.clear()
    if result.verified:
        dbg.memory.update({origin + i: ins for i, ins in enumerate(prog.instructions)})
    if result.mismatch is None:
        _keep_source(prog, module.name, origin, path)
    _rebind_breakpoints(session)
    seconds = result.upload_seconds + result.verify_seconds
    rate = f", {len(prog) / result.upload_seconds:.0f}/s" if result.upload_seconds > 0 else ""
    if result.mismatch is not None:
        mm = result.mismatch
        w = where(session, mm.address)
        expected, _ = asm.disassemble_instruction(mm.expected, module)
        actual, _ = asm.disassemble_instruction(mm.actual, module)
        if mm.shared:
            message = (f"verify failed at address {mm.address} ({w.place}): "
                       f"{shared_text(session.client.address)}; the program went to both")
        elif mm.doubtful:
            message = (f"verify failed at address {mm.address} ({w.place}): its read-back "
                       "stayed in doubt (the line brought answers nothing waited for, so a "
                       "reply may have been another request's); upload again on a quieter "
                       "line")
        else:
            message = (f"verify failed at address {mm.address} ({w.place}): uploaded "
                       f"'{expected}', the module holds '{actual}'")
        if session.out.json:
            session.out.emit({**result.to_json(), "error": message})
        else:
            session.out.print(f"uploaded {result.count} instructions to {first}..{last}",
                              style="tmcl.warn")
            session.out.error(None, message)
        err = DebuggerError(message)
        err.shown = True  # type: ignore[attr-defined]
        raise err
    if session.out.json:
        session.out.emit(result.to_json())
    else:
        verified = "verified: read back identical" if result.verified else "not verified"
        session.out.print(f"uploaded {result.count} instructions from {path.name} to "
                          f"{first}..{last}; {verified} ({seconds:.2f} s{rate})",
                          style="tmcl.ok")
    try:
        _read_status(session)
    except TmclError:
        pass


def _running_note(session: Session) -> str:
    """The start of the upload question when the stored program runs: the download (132)
    stops it, which the person answering should know. Read only when someone is asked."""
    if session.yes or session.ask is None or not session.interactive:
        return ""
    try:
        st = _read_status(session)
    except TmclError:
        return ""
    if st.state != "run":
        return ""
    return f"the stored program is running (at @{st.pc}); the upload stops it. "


def _keep_source(prog: asm.Program, module: str, origin: int, path: Path) -> None:
    """The source of an upload, for .dump later (sourcemap.py); never fails the upload.
    An image file is kept by name only, so that .dump names this upload and not an older
    source of the same bytes."""
    if prog.image:
        sourcemap.save(prog.instructions, module, origin, path, "", image=True)
        return
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return
    sourcemap.save(prog.instructions, module, origin, path, text)


def _original_source(session: Session, image: list[Instruction], start: int,
                     header: str) -> tuple[str, sourcemap.SourceMap] | None:
    """The source this image was uploaded from, if tmclsh kept it and it still assembles
    to exactly these bytes (an include file may have changed since); for an upload from an
    image file, its disassembly under a line naming that file."""
    module = session.module
    kept = sourcemap.lookup(image, module.name, start)
    if kept is None:
        return None
    if kept.image:
        return (header + f"// uploaded from the image {kept.file}, {kept.uploaded} (no labels "
                "or comments: generated)\n" + asm.disassemble(image, module, start), kept)
    text = (header + f"// source: {kept.file}, uploaded {kept.uploaded} (labels and comments "
            "as written)\n" + kept.text)
    try:
        again = asm.assemble(text, module, kept.file, start, Path(kept.file).parent)
    except AsmError:
        return None
    return (text, kept) if program.same_image(again.instructions, image) else None


@command(".dump")
def cmd_dump(session: Session, argtext: str) -> None:
    pos, opts = options.parse_words(argtext, options_of(".dump"))
    if opts.get("-o") and not pos:  # `.dump -o FILE`, as asm -o
        raise ValidationError("-o needs a FILE")
    if len(pos) > 1:
        raise ValidationError("usage: .dump [[-o] FILE] [--at ADDR] [--count N]")
    program.require_binary(session.client, "reading program memory (134)",
                           Control.READ_MEMORY)
    module = session.module
    start = _number(str(opts["--at"]), "--at") if "--at" in opts else 0
    count = _number(str(opts["--count"]), "--count") if "--count" in opts else None
    with _progress(session) as progress:
        image = program.read_program(session.client, start, count, progress=progress)
    dbg = state(session)
    dbg.forget_memory()
    dbg.memory.update({start + i: ins for i, ins in enumerate(image)})
    c = session.client
    header = (f"// program memory of the {module.name} at address {c.address} "
              f"({c.describe()}): {len(image)} instructions from {start}\n")
    if start:
        header += f"// assemble with --at {start}\n"
    original = _original_source(session, image, start, header) if image else None
    if original is not None:
        text, kept = original
        same = True
    else:
        kept = None
        text = header + (asm.disassemble(image, module, start) if image else "")
        try:
            again = asm.assemble(text, module, "<dump>", start).instructions if image else []
            same = program.same_image(again, image)
        except AsmError as exc:  # pragma: no cover - a disassembler bug
            same, again = False, []
            session.out.warn(f"the disassembly does not assemble: {exc}")
        if not same:
            session.out.warn("warning: the disassembly does not reassemble to the same image")
    if pos:
        path = Path(pos[0]).expanduser()
        kind = path.suffix.lower()
        if kind in (".bin", ".hex"):
            same = True  # the bytes as read (a TMCL-IDE image, or hex text), no disassembly
        if kind == ".bin":
            data: str | bytes = asm.image_bytes(image)
        elif kind == ".hex":
            data = asm.hex_text(image)
        else:
            data = text
        files.write_file(path, data)  # all or nothing
        if session.out.json:
            obj = {"dumped": len(image), "file": str(path), "identical": same}
            if kept is not None:
                obj["uploaded_from"] = kept.file
            session.out.emit(obj)
        else:
            session.out.print(f"wrote {len(image)} instructions ({start}.."
                              f"{start + len(image) - 1}) to {path}"
                              + (f", the source uploaded from {_show_path(kept.file)}"
                                 if kept is not None else "")
                              + ("; it assembles back to the same image" if same else ""),
                              style="tmcl.ok")
        return
    if session.out.json:
        obj = {"dumped": len(image), "source": text}
        if kept is not None:
            obj["uploaded_from"] = kept.file
        session.out.emit(obj)
        return
    if not image:
        session.out.info(f"program memory is empty at {start} (end marker)")
        return
    with session.out.paged(paging(session)):  # (not the progress bar of the reading)
        session.out.print(text.rstrip("\n"), markup=False, highlight=False)


@command(".source-map")
def cmd_source_map(session: Session, argtext: str) -> None:
    pos, opts = options.parse_words(argtext, options_of(".source-map"))
    dbg = state(session)
    if opts.get("--off"):
        dbg.program = None
        session.out.info("source map off: locations are disassembled from memory")
        return
    if not pos:
        if dbg.source_file is None:
            session.out.info("no source file is known for the stored program")
        else:
            assert dbg.program is not None
            session.out.print(f"{_show_path(dbg.source_file)}: {len(dbg.program)} instructions "
                              f"at {dbg.program.origin}..{dbg.program.origin + len(dbg.program) - 1}")
        return
    if len(pos) != 1:
        raise ValidationError("usage: .source-map FILE [--at ADDR]")
    module = session.module
    origin = _number(str(opts["--at"]), "--at") if "--at" in opts else 0
    path = _resolve_file(session, pos[0])
    prog = asm.load_program(path, module, origin)
    message = f"{_show_path(str(path))} mapped to {origin}..{origin + len(prog) - 1}"
    if len(prog) and program.carried(session.client, Control.READ_MEMORY):
        mm = program.verify_image(session.client, prog.instructions, origin)
        if mm is not None:
            loc = prog.loc(mm.address)
            session.out.warn(f"warning: the stored program differs from {path.name} at "
                             f"address {mm.address} ({loc.file if loc else '?'}:"
                             f"{loc.line if loc else '?'}); lines shown may not match")
        else:
            message += " (matches the stored program)"
    dbg.program = prog
    dbg.files.clear()
    dbg.forget_memory()
    _rebind_breakpoints(session)
    session.out.info(message)
