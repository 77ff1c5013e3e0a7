"""``tmclsh replace --from (CONNECTION | BACKUP) --to CONNECTION ...``: the front end of a
module replacement (``tmclsh.ops.replace`` does it).

What the technician sees: each step as a line on standard error as it ends (and what the
firmware update does meanwhile), then one report on standard output: a table on a terminal,
plain lines elsewhere, one JSON object with ``--json``. A run that stops (a step failed,
Ctrl-C, SIGTERM, a lost link) says where both modules stand and the one command that
completes the job: this command again, with ``--yes``.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from ..base.errors import (EXIT_CONNECT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE,
                           ConnectError, TmclError, UsageError)
from ..base.interrupts import restore, unwind_on

CAN_PREFIX = "can:"


def resume_command(args: argparse.Namespace, image: str | None = None) -> str:
    """This run's command again, with --yes (and ``image`` for its --firmware): what
    completes a replacement that stopped."""
    words = ["tmclsh", "replace", "--from", args.source, "--to", args.target]
    if args.from_address != 1:
        words += ["--from-address", str(args.from_address)]
    if args.to_address != 1:
        words += ["--to-address", str(args.to_address)]
    if image or args.firmware:
        words += ["--firmware", image or args.firmware]
    for flag in ("with_link", "force"):
        if getattr(args, flag, False):
            words.append("--" + flag.replace("_", "-"))
    for key in ("baud", "timeout"):
        value = getattr(args, key, None)
        if value is not None:
            words += ["--" + key, str(value)]
    words.append("--yes")
    if getattr(args, "json", False):
        words.append("--json")
    return shlex.join(words)


def settings_of(spec: str, address: int, args: argparse.Namespace) -> dict:
    """A connection as ``client.connect.open_client`` takes it, from ``--from``/``--to``."""
    from ..base.canspec import parse_can

    out: dict = {"address": address}
    for key in ("baud", "timeout", "retries"):
        value = getattr(args, key, None)
        if value is not None:
            out[key] = value
    if spec.startswith(CAN_PREFIX):
        out["can"] = spec[len(CAN_PREFIX):]
        parse_can(out["can"])  # a malformed one is a usage error before anything is opened
    else:
        out["port"] = spec
    return out


class View:
    """Steps as lines on stderr while they end; the report on stdout at the end."""

    def __init__(self, as_json: bool):
        self.json = as_json

    def step(self, outcome) -> None:
        if not self.json:
            print(f"{outcome.step}: {outcome.state}: {outcome.text}", file=sys.stderr,
                  flush=True)

    def notice(self, text: str) -> None:
        if not self.json:
            print(f"  {text}", file=sys.stderr, flush=True)

    def report(self, report, resume: str | None, status: int) -> None:
        if self.json:
            obj = report.to_json()
            if resume:
                obj["resume"] = resume
            obj["exit"] = status
            print(json.dumps(obj), flush=True)
            return
        if sys.stdout.isatty():
            self._table(report)
        else:
            for o in report.steps:
                print(f"{o.step:<14} {o.state:<8} {o.text}")
        if report.ok:
            print(f"replaced: {report.source} -> {report.target}")
            return
        if report.situation:
            print(f"tmclsh: {report.situation}", file=sys.stderr)
        if resume:
            print(f"tmclsh: to complete the replacement, run: {resume}", file=sys.stderr)

    def _table(self, report) -> None:
        from rich.console import Console
        from rich.table import Table

        table = Table(title=f"replace {report.source} -> {report.target}")
        for column in ("step", "outcome", "what"):
            table.add_column(column, overflow="fold")
        for o in report.steps:
            table.add_row(o.step, o.state, o.text)
        Console().print(table)


def cmd_replace(args: argparse.Namespace) -> int:
    from ..ops.replace import Replacement, ReplaceError, is_backup, validate
    from ..tmcl.bootloader import read_image

    as_json = bool(getattr(args, "json", False))
    yes = bool(getattr(args, "yes", False))
    view = View(as_json)

    def refuse(text: str, code: int) -> int:
        if as_json:
            print(json.dumps({"error": text, "exit": code}), flush=True)
        else:
            print(f"tmclsh: {text}", file=sys.stderr)
        return code

    image = None
    try:
        if args.firmware:
            image = read_image(args.firmware)
        if is_backup(args.source):
            source = Path(args.source)
        elif Path(args.source).is_file():  # (a port is a device, never a regular file)
            raise UsageError(f"--from {args.source}: a file, but not a backup .save wrote (a "
                             "backup's first line is '// tmclsh configuration backup'); give "
                             "that backup, or the old module's port")
        else:
            source = settings_of(args.source, args.from_address, args)
        target = settings_of(args.target, args.to_address, args)
        validate(source, target)
    except TmclError as exc:
        return refuse(f"{exc}; nothing was sent", EXIT_USAGE)
    if not yes and not sys.stdin.isatty():
        return refuse("tmclsh replace asks before it writes to the new module, and nobody can "
                      "answer here (standard input is not a terminal): give --yes; nothing "
                      "was sent", EXIT_USAGE)
    confirm = None
    if not yes:
        from ..shell.repl.ask import ask_yes_no

        confirm = ask_yes_no
    replacement = Replacement(source, target, image=image, with_link=args.with_link,
                              force=args.force, on_step=view.step, notice=view.notice,
                              confirm=confirm,
                              source_name=_named(args.source, args.from_address, source),
                              target_name=_named(args.target, args.to_address, target))
    previous = unwind_on(("SIGTERM", "SIGHUP"))
    try:
        report = replacement.run()
    except (KeyboardInterrupt, SystemExit) as exc:
        code = exc.code if isinstance(exc, SystemExit) and isinstance(exc.code, int) \
            else EXIT_INTERRUPTED
        view.report(replacement.report, resume_command(args), code)
        return code
    except ConnectError as exc:
        return refuse(f"{exc}; nothing was written", EXIT_CONNECT)
    except ReplaceError as exc:
        return refuse(f"{exc}; nothing was sent", EXIT_USAGE)
    finally:
        restore(previous)
    status = EXIT_OK if report.ok else EXIT_FAILED
    view.report(report, None if report.ok else _resume(args, report), status)
    return status


def _resume(args: argparse.Namespace, report) -> str:
    """The command that completes the job; where an image is needed, which one."""
    at = report.stopped_at
    needed = at.data.get("needed") if at is not None and at.step == "firmware" else None
    if at is not None and at.step == "firmware" and "needed" in at.data:
        return (resume_command(args, "IMAGE.hex") + "   (IMAGE.hex: the image of "
                + (needed or "the old module's firmware") + ")")
    return resume_command(args)


def _named(given: str, address: int, where) -> str:
    """A module as the report names it: as given, with its address unless it is the
    default, 1 (on a line several modules share the port alone does not say which)."""
    if isinstance(where, Path) or address == 1:
        return given
    return f"{given} address {address}"
