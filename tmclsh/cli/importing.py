"""``tmclsh modules import pytrinamic NAME|--all [-o FILE]``: module files from PyTrinamic.

The conversion is ``tmcl/modules/from_pytrinamic.py``; here are the command's words, where the
files go (the config directory's ``modules/``, where tmclsh finds them by itself, unless
``-o``), and what is said about each: written, or left out and why.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..base.edges import write_json
from ..base.errors import EXIT_OK, EXIT_USAGE, UsageError

LIBRARIES = ("pytrinamic",)


def _say(args: argparse.Namespace, obj: dict, text: str, *, err: bool = False) -> None:
    if getattr(args, "json", False):
        write_json(obj)
    else:
        print(text, file=sys.stderr if err else sys.stdout)


def import_modules(args: argparse.Namespace) -> int:
    from ..base.files import write_file
    from ..tmcl.modules import from_pytrinamic as fp
    from ..tmcl.modules import user_dir

    words = list(args.file)
    if not words or words[0].lower() not in LIBRARIES:
        raise UsageError("modules import takes where to import from, then what: modules "
                         "import pytrinamic NAME (or --all); PyTrinamic is the library "
                         "tmclsh imports module tables from")
    if args.import_all == (len(words) == 2) or len(words) > 2:
        raise UsageError("modules import pytrinamic takes one NAME (TMCM1260) or --all")
    if args.import_all and args.output == "-":
        raise UsageError("--all writes one file per module: -o takes a folder, not '-'")
    pairs = fp.targets() if args.import_all else [fp.find(words[1])]
    folder = Path(args.output) if (args.import_all and args.output) else user_dir()
    ver = fp.version()
    written = 0
    for cls, name in pairs:
        try:
            imp = fp.convert(cls, name)
        except fp.ImportFailed as exc:
            if not args.import_all:
                raise
            _say(args, {"class": cls, "skipped": str(exc)}, f"left out: {exc}", err=True)
            continue
        refusal = fp.refuse_built_in(imp.name)
        if refusal and (args.import_all or not args.output):
            if not args.import_all:
                raise UsageError(refusal)
            _say(args, {"class": cls, "module": imp.name, "skipped": refusal},
                 f"left out: {refusal}", err=True)
            continue
        if args.output == "-":
            sys.stdout.write(imp.text)
            written += 1
            continue
        path = Path(args.output) if (args.output and not args.import_all) \
            else folder / fp.file_name(imp.name)
        try:
            _check_overwrite(path)
        except UsageError as exc:
            if not args.import_all:
                raise
            _say(args, {"class": cls, "module": imp.name, "skipped": str(exc)},
                 f"left out: {exc}", err=True)
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        write_file(path, imp.text)
        written += 1
        motors = f"{imp.motors} motor" + ("s" if imp.motors > 1 else "")
        _say(args, {"module": imp.name, "class": cls, "file": str(path), "motors": imp.motors,
                    "axis": imp.axis, "global": imp.globals_, "pytrinamic": ver},
             f"{path}: {imp.name}, {motors}, {imp.axis} axis and {imp.globals_} global "
             f"parameters (names and numbers from PyTrinamic {ver}'s {cls})")
    if not written:
        print("tmclsh: no module file written", file=sys.stderr)
        return EXIT_USAGE if not args.import_all else EXIT_OK
    return EXIT_OK


def _check_overwrite(path: Path) -> None:
    """An earlier import is replaced; any other file (one a user wrote or edited) is not."""
    from ..tmcl.modules.from_pytrinamic import SOURCE_TAG

    if not path.exists():
        return
    try:
        with path.open(encoding="utf-8", errors="replace") as fh:
            first = fh.readline()
    except OSError as exc:
        raise UsageError(f"{path}: cannot read it to see whether it may be replaced: "
                         f"{exc.strerror or exc}") from None
    if not first.startswith(SOURCE_TAG):
        raise UsageError(f"{path} exists and was not written by an import (or its first line "
                         "was edited): not replaced; remove it or give -o another FILE")
