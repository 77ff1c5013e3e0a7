"""``tmclsh firmware FILE.hex [CONNECTION] [--check] [--yes] [--json]``: the front end of a
firmware update (``tmclsh.ops.firmware`` does it).

What the user sees: each step as a line on standard error (with a progress bar, rate and time
left while the image is written, on a terminal), the question before anything is erased, and
a last line on standard output that names the old and the new version. With ``--json`` every
step is one object on standard output, and the result (or the failure) one more. Whatever
stops an update (an error, Ctrl-C, SIGTERM, a lost link), what is said names where the module
stands and, when it is not back in its firmware, the exact command that completes the update.
"""

from __future__ import annotations

import argparse
import shlex
import sys

from ..base.edges import error_record, write_json
from ..base.errors import (EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE, TmclError,
                           exit_status)
from ..base.interrupts import restore, stopped_words, unwind_on


def resume_command(args: argparse.Namespace, image: str | None = None) -> str:
    """This run's command again (with ``image`` in place of its file): what completes an
    update that broke off."""
    from ..base.canspec import FROM_PYTHON_CAN

    words = ["tmclsh", "firmware", image or args.file]
    for opt, key in (("--port", "port"), ("--sim", "sim"), ("--profile", "profile"),
                     ("--baud", "baud"), ("--bitrate", "bitrate"), ("--can-id", "can_id"),
                     ("--reply-id", "reply_id"), ("-a", "address"),
                     ("--host-address", "host_address"), ("--timeout", "timeout")):
        value = getattr(args, key, None)
        if isinstance(value, (list, tuple)):  # (--port, -a, --can-id, --reply-id take several)
            value = ",".join(map(str, value)) if value else None
        if value == "" and key == "sim":  # a bare --sim (the -m module, else a TMCM-1311)
            words.append(opt)
        elif value is not None:
            words += [opt, str(value)]
    can = getattr(args, "can", None)
    if can is not None:
        words += ["--can"] if can == FROM_PYTHON_CAN else ["--can", can]
    if getattr(args, "yes", False):
        words.append("--yes")
    return shlex.join(words)


class Report:
    """Steps as lines (stderr), or JSON objects (stdout); a rich progress bar while the
    image is written on a terminal."""

    def __init__(self, as_json: bool):
        self.json = as_json
        self.terminal = not as_json and sys.stderr.isatty()
        self._bar = None
        self._task = None

    def emit(self, obj: dict) -> None:
        write_json(obj)

    def line(self, text: str) -> None:
        if self._bar is not None:
            self._bar.console.print(text, markup=False, highlight=False)
        else:
            print(text, file=sys.stderr, flush=True)

    def step(self, step) -> None:
        if self.json:
            self.emit(step.to_json())
            return
        if step.step == "write" and step.done is not None:
            self._write(step)
            return
        self._end_bar()
        self.line(f"{step.text}")

    def _write(self, step) -> None:
        if not self.terminal:
            if step.done == 0:
                self.line(step.text)
            return
        if self._bar is None:
            from rich.console import Console
            from rich.progress import (BarColumn, DownloadColumn, Progress, TextColumn,
                                       TimeRemainingColumn, TransferSpeedColumn)

            self._bar = Progress(TextColumn("writing"), BarColumn(), DownloadColumn(),
                                 TransferSpeedColumn(), TimeRemainingColumn(),
                                 console=Console(stderr=True), transient=False)
            self._bar.start()
            self._task = self._bar.add_task("write", total=step.total)
            self._bar.console.print(step.text, markup=False, highlight=False)
        self._bar.update(self._task, completed=step.done)

    def _end_bar(self) -> None:
        if self._bar is not None:
            self._bar.stop()
            self._bar = None

    def ask(self, question: str) -> bool:
        from ..shell.repl.ask import ask_yes_no

        self._end_bar()
        return ask_yes_no(question)

    def close(self) -> None:
        self._end_bar()


def cmd_firmware(args: argparse.Namespace) -> int:
    from ..client.connect import connection_settings
    from ..ops.firmware import FirmwareUpdate
    from ..tmcl.bootloader import read_image

    as_json = bool(getattr(args, "json", False))
    yes = bool(getattr(args, "yes", False))
    report = Report(as_json)

    def refuse(text: str, code: int) -> int:
        if as_json:
            report.emit(error_record(text, code))
        else:
            print(f"tmclsh: {text}", file=sys.stderr)
        return code

    try:
        image = read_image(args.file)
    except TmclError as exc:  # unreadable, no Intel HEX, a bad record checksum, empty
        return refuse(f"{exc}; nothing was sent", EXIT_USAGE)
    if not args.check and not yes and not sys.stdin.isatty():
        return refuse("tmclsh firmware asks before it erases the module's firmware, and "
                      "nobody can answer here (standard input is not a terminal): give --yes "
                      "to update without asking, or --check to see what would happen; "
                      "nothing was sent", EXIT_USAGE)
    settings = connection_settings(args)
    update = FirmwareUpdate(settings, image, progress=report.step,
                    confirm=None if yes or args.check else report.ask)
    # SIGTERM and SIGHUP unwind like Ctrl-C: the update still says where the module stands
    # (and one restarted into its bootloader before the erase is sent back)
    previous = unwind_on(("SIGTERM", "SIGHUP"))
    try:
        if args.check:
            plan = update.check()
            _show_plan(report, plan)
            return EXIT_OK if plan.problem is None else EXIT_FAILED
        result = update.run()
    except (KeyboardInterrupt, SystemExit) as exc:
        code = exc.code if isinstance(exc, SystemExit) and isinstance(exc.code, int) \
            else exit_status(exc)  # type: ignore[arg-type]
        report.close()
        # (which signal, in the words every run's summary says it with)
        _stopped(report, update, args, "interrupted" if code == EXIT_INTERRUPTED
                 else f"{stopped_words(exc)}; exit status {code}", None, code)
        return code
    except TmclError as exc:
        report.close()
        # no module is exit 3 only while the module was still running its firmware: from
        # its bootloader on, the update failed half way
        code = exit_status(exc) if update.state == "application" else EXIT_FAILED
        _stopped(report, update, args, str(exc), exc, code)
        return code
    finally:
        report.close()
        update.close()
        restore(previous)
    if as_json:
        report.emit(result.to_json())
    elif result.nothing_to_do:
        print(f"the {result.module} runs {result.new_version}, the image's version, already: "
              "nothing to do")
    else:
        old = result.old_version or "its bootloader (an update that broke off)"
        down = result.change == "downgrade"
        print(f"{'downgraded' if down else 'updated'} the {result.module} from {old} to "
              f"{result.new_version}{', an older version' if down else ''} "
              f"({result.written} bytes written in {result.seconds:.1f} s)")
    return EXIT_OK


def _stopped(report: Report, update, args: argparse.Namespace, what: str,
             exc: BaseException | None, code: int) -> None:
    """What stopped the update, where the module stands, and how to complete it."""
    from ..ops.firmware import ImageRefused

    situation = update.situation()
    resume = None
    if update.resumable:
        if isinstance(exc, ImageRefused):
            # (the same image again would be refused again: the module needs its own)
            resume = (resume_command(args, "IMAGE.hex")
                      + f"   (IMAGE.hex: an image for the {update.module})")
        else:
            resume = resume_command(args)
    if report.json:
        more = {"resume": resume} if resume else {}
        report.emit(error_record(what, code, state=update.state, situation=situation, **more))
        return
    print(f"tmclsh: {what}", file=sys.stderr)
    print(f"tmclsh: {situation}", file=sys.stderr)
    if resume:
        print(f"tmclsh: to complete the update, run: {resume}", file=sys.stderr)


def _show_plan(report: Report, plan) -> None:
    if report.json:
        report.emit(plan.to_json())
        return
    img = plan.image
    now = "in its bootloader" if plan.in_bootloader else "running its firmware"
    print(f"module  {plan.module}, {now}: {plan.version}")
    # (what the image carries, whoever it is for: the "would" line says what that means)
    name = plan.image_version.text if plan.image_version else \
        ", ".join(v.text for v in img.versions) or "no firmware version string"
    print(f"image   {img.name}: {name}, {img.length} bytes at 0x{img.start:08X}, checksum "
          f"0x{img.checksum:08X}")
    if plan.memory is not None:
        m = plan.memory
        fits = "yes" if plan.fits else "NO"
        pages = f", pages of {m.page_size} bytes" if m.page_size else ""
        print(f"fits    {fits}: application memory {m.describe()}{pages}")
    else:
        print("fits    asked of the bootloader before anything is erased (--check does not "
              "restart the module to ask; an image that does not fit is refused there and "
              "the firmware started again)")
    if plan.problem is not None:
        print(f"would   refuse: {plan.problem}")
    elif plan.nothing_to_do:
        print(f"would   do nothing: it runs {plan.version}, the image's version, already")
    elif plan.in_bootloader:
        print(f"would   complete the update: write {img.length} bytes (unless the memory "
              f"holds the image already), verify, start {plan.image_version.text}")
    else:
        down = f" (a DOWNGRADE: older than {plan.version})" if plan.change == "downgrade" else ""
        print(f"would   restart it into its bootloader, erase, write {img.length} bytes, "
              f"verify, start {plan.image_version.text}{down}")
