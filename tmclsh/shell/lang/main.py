"""Entry of the shell proper: connect, then run -c lines, a -f script, or the REPL."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING

from ...base.errors import (EXIT_CONNECT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE,
                            ModuleGoneError, TmclError)
from ...base.interrupts import Terminated, held, taken, unwind_on
from ..render import Output
from .session import QuitShell, Session, frames_sent

if TYPE_CHECKING:
    from ...base.config import Config

# why a run is cut short when whoever read its output went away (`tmclsh -f run.tmcl | head`):
# the words of its stop, on stderr
READER_GONE = "the output's reader went away"


def refused_line(session: Session, lines: list[str]) -> tuple[str, TmclError] | None:
    """The first of ``lines`` the module would refuse, checked before any is sent (as a
    script is): a typo in the last line of ``-c "MVP ...; SPA ..."`` must not leave the move
    of the first one running. Lines with ``${...}`` are checked when they run."""
    from ...base.errors import ValidationError
    from .lines import classify
    from .session import encode_typed, unknown_command

    for raw in lines:
        line = classify(raw)
        if line.unknown:
            return raw, ValidationError(unknown_command(line.word))
        if line.command is not None:
            check = line.command.checker()  # (its arguments, as a script's are checked)
            if check is not None:
                try:
                    check(session, line.args)
                except TmclError as exc:
                    return raw, exc
            if line.command.changes_link:
                return None
            continue
        if not line.text or "${" in line.text:
            continue
        try:
            encode_typed(session.client, line.text)
        except TmclError as exc:
            return raw, exc
    return None


def run_lines(session: Session, lines: list[str]) -> int:
    failed = False
    suspects, shared = session.stats.suspects, len(session.stats.shared)
    bad = refused_line(session, lines)
    if bad is not None:
        line, exc = bad
        why = "" if session.out.json else " (nothing was sent: every line is checked first)"
        session.out.error(line, f"{exc}{why}")
        return EXIT_USAGE
    refused = True  # every error so far was a file refused whole (exit_status 2)
    sent = frames_sent(session.client)
    progress = session.progress
    if progress is not None:
        progress(0, len(lines))
    for done, line in enumerate(lines, 1):
        if progress is not None:  # the line being run, as its errors number it
            progress(done, len(lines))
        try:
            session.ensure_link()  # the link was lost on an earlier line (--keep-going)
            session.run_line(line)
        except QuitShell:
            break
        except TmclError as exc:
            failed = True
            refused = refused and getattr(exc, "exit_status", None) == EXIT_USAGE
            session.report_error(line, exc)
            if not session.keep_going:
                break
            try:
                session.failed_unanswered(exc)
            except ModuleGoneError as gone:
                session.report_error(None, gone)
                return EXIT_CONNECT
    if failed and refused and frames_sent(session.client) == sent:
        return EXIT_USAGE  # a file refused before anything was sent, as -f says of a script
    doubtful = session.stats.suspects > suspects or len(session.stats.shared) > shared
    return EXIT_FAILED if failed or doubtful else EXIT_OK


def run_shell(args: argparse.Namespace) -> int:
    from ...client.connect import connection_settings, open_client

    exit_cleanly_on_signals()
    settings = connection_settings(args)
    # only a person at the prompt may be given the simulator for want of a module: a run
    # nobody watches (-c, -f, piped input) fails instead (exit 3)
    tracer = None
    if args.trace:  # the connect's own frames too (136, the download mode check, ...)
        from ..features.trace import connect_tracer as tracer
    try:
        client = open_client(settings, fallback=_interactive(args), notice=_notice,
                             tracer=tracer)
    except TmclError as exc:
        print(f"tmclsh: {exc}", file=sys.stderr)
        if args.json:  # stdout stays JSON: the failure is a record there too
            from ...base.edges import error_record, write_json

            write_json(error_record(str(exc), EXIT_CONNECT))
        return EXIT_CONNECT
    try:
        return run_connected(args, client, settings)
    except (KeyboardInterrupt, Terminated, RuntimeError) as exc:
        # a second Ctrl-C or SIGTERM until the stop has begun is part of this end: it
        # landed while the stop was imported, and the run ended without one
        with held(deliver=False):
            signalled = _signal_behind(exc)
            if signalled is None:
                raise
            _ready_to_stop()
            if not isinstance(signalled, Terminated):
                print(file=sys.stderr)
        if isinstance(signalled, Terminated):  # SIGTERM (a CI job's timeout), SIGHUP
            stop_on_interrupt(client, signalled.why)
            return signalled.code
        stop_on_interrupt(client)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # whoever read our output has gone (`tmclsh -c ... | head`)
        from ...base.edges import reader_gone

        return reader_gone()
    finally:
        client.close()  # leaves ASCII mode if tmclsh entered it, whatever happened


def _signal_behind(exc: BaseException) -> BaseException | None:
    """The Ctrl-C or SIGTERM/SIGHUP an exception stands for: itself, or the one it was
    raised from. A signal that lands while a module is first imported (a command's feature
    is imported when first used) comes out wrapped in another error (a dataclass being
    built raises RuntimeError from it); it is still the user's interrupt, not a failure."""
    seen = 0
    while exc is not None and seen < 8:
        if isinstance(exc, (KeyboardInterrupt, Terminated)):
            taken(exc)
            return exc
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return None


def _ready_to_stop() -> None:
    """The stop's modules imported (the first time they are compiled, which takes a while)."""
    from ...ops import stop  # noqa: F401
    from ..features import stop as front  # noqa: F401


def stop_on_interrupt(client, why: str = "interrupted") -> None:
    """Ctrl-C, SIGTERM or SIGHUP in -c/-f (and SIGTERM/SIGHUP at the prompt): the one stop
    (stop.py), said on stderr; then the same at each address ``.address`` left a motor
    told to move at (this run's modules only: no other address is sent anything)."""
    from ..features.stop import ToStderr, stop_everywhere

    stop_everywhere(client, ToStderr(), why, back=False)  # (the run ends: no way back)


def _interactive(args: argparse.Namespace) -> bool:
    return args.command is None and args.script is None and sys.stdin.isatty()


def _notice(text: str) -> None:
    print(f"tmclsh: {text}", file=sys.stderr)


def run_connected(args: argparse.Namespace, client, settings: dict, *,
                  prepare: Callable[[Session], None] | None = None,
                  config: Config | None = None) -> int:
    """The session on a connected client: ``-c``, ``-f``, or the prompt; ``prepare(session)``
    before the first line (a unit of several gives its session its own variables and view,
    shell/features/units.py, with ``config``, the config file it read once). Exit status."""
    from ...base.config import load_settings
    from ...client.advice import SHELL

    shell_settings = load_settings(config)
    out = Output(json_mode=bool(args.json), color=str(shell_settings.get("color", "auto")))
    interactive = _interactive(args)
    # `confirm = false` in the config file is a standing --yes
    yes = bool(args.yes) or shell_settings.get("confirm") is False
    session = Session(client, out, interactive=interactive, yes=yes,
                      keep_going=bool(args.keep_going), settings=settings)
    session.with_link = bool(getattr(args, "with_link", False))
    if client.module is not None and client.module.generic:
        out.warn(f"{client.module.type_name}: {client.module.NOTICE}")  # once, at the start
    client.on_notice = out.warn  # what the client does on its own (ends download mode)
    # from here on its messages' advice is in the shell's words (".address 5", "-a 5" being
    # no line the prompt or a script takes), the command line's option where the shell has
    # no command (client/advice.py); what the connect said before stays the command line's
    client.advice = SHELL
    if not interactive:  # who and where, for scripts run on several (shell/features/units.py sets them)
        address = client.can_id if client.is_can else client.address
        session.variables.update(unit=1, address=address, port=_link_text(settings))
    if prepare is not None:
        prepare(session)
    if args.trace:
        from ..features.trace import enable_trace

        enable_trace(session)
    try:
        if not interactive:
            from ...base import startup

            startup.release()  # (the work begins: base/startup.py)
            status = _run_unattended(args, session)
        else:
            from ..repl.app import run_repl

            status = run_repl(session)
    except BaseException:
        session.close()
        raise
    if not session.close():  # a recording that could not be put in place
        status = status or EXIT_FAILED
    return status


def _link_text(settings: dict) -> str:
    """What ``${port}`` says: the port, CAN bus or simulated module the run talks to."""
    for key in ("port", "can", "sim"):
        if settings.get(key):
            return str(settings[key])
    return ""


def _run_unattended(args: argparse.Namespace, session: Session) -> int:
    """-c, -f, or stdin that is no terminal."""
    client, out = session.client, session.out
    # 138 messages are results too: in order with the others (the REPL shows them as they
    # come; see app.py)
    unlisten = lambda: None  # noqa: E731
    started = _watch_for_starts(client)
    session.moved = lambda: started(keep=True)
    if out.json:
        unlisten = client.add_listener(lambda reply: out.event(reply, client._taps.event_time))
        client.start_event_poller()  # an event shows when it comes, not at the next line
    finished = reader_gone = False
    suspects, shared = session.stats.suspects, len(session.stats.shared)
    try:
        if args.command is not None:
            status = run_lines(session, session.split(args.command))
        else:
            from .script import run_file

            status = run_file(session, args.script or "-")
        finished = True
    except BrokenPipeError:
        reader_gone = True
        raise
    finally:
        client.stop_event_poller()
        if finished:  # (after Ctrl-C: straight on to the stop, nothing else first)
            _last_events(session)
        unlisten()
        moved = started()  # else nothing this run sent can have started anything
        if moved and finished:
            _note_left_running(session)
        elif moved and reader_gone:
            # `tmclsh -f turn.tmcl | head`: the run is cut short where its reader stopped
            # reading, and what it set moving (which a later line may have stopped) is
            # stopped as on Ctrl-C; a run that moved nothing sends nothing more
            stop_on_interrupt(client, READER_GONE)
    if status == EXIT_OK and (session.stats.suspects > suspects
                              or len(session.stats.shared) > shared):
        # (an answer found suspect as the run ended is no pass either, nor a run on an
        # address two modules answer at)
        status = EXIT_FAILED
    return status


def _last_events(session: Session) -> None:
    """Events that came after the last reply are results of the run as well."""
    try:
        session.confirm_answers()  # (the last answer may show only now to be another's)
    except (TmclError, OSError):
        pass


def _watch_for_starts(client):
    """A tracer noting whether anything that starts motion was sent (the instruction set's
    ``starts_motion``, and a write to a parameter whose data says it does: SAP 2, the target
    speed a velocity mode follows); returns the question."""
    from ...tmcl.frames import Request
    from ...tmcl.instructions import starting_opcodes

    starts = starting_opcodes()
    writes = _motion_parameters(client)
    sent = []

    def tracer(direction: str, raw: bytes, decoded: object) -> None:
        if not sent and direction == "tx" and isinstance(decoded, Request) and (
                decoded.opcode in starts or (decoded.opcode, decoded.type) in writes):
            sent.append(True)

    remove = client.add_tracer(tracer, sent_only=True,
                               opcodes=starts | {op for op, _ in writes})

    def started(keep: bool = False) -> bool:
        if not keep:
            remove()
        return bool(sent)

    return started


def _motion_parameters(client) -> frozenset[tuple[int, int]]:
    """(write command, parameter number) of the parameters whose data says writing them can
    start the motor."""
    from ...tmcl import instructions as isa

    mod = client.module
    if mod is None or mod.generic:
        return frozenset()
    writes = [s for s in isa.all_instructions() if s.access == "write" and s.on(mod)]
    return frozenset((s.opcode, p.number) for s in writes
                     for p in (mod.axis_params if s.type_kind == "axis_param"
                               else mod.global_params)
                     if p.starts_motion)


def _note_left_running(session: Session) -> None:
    """A script that ends while a motor turns, or one it told to turn reads still (stalled,
    not started yet), or the program runs, says so on stderr, and on stdout with --json (it
    leaves them so: that may well be what it was for). Each address the script left a motor
    told to move at is asked too, and named (``.address 1`` then ``ROR``, ``.address 2``)."""
    from ...ops.stop import activity_everywhere

    client = session.client
    if not client.connected:
        return
    try:
        found = activity_everywhere(client)
    except (TmclError, OSError):
        return
    for address, act, why in found:
        at = f"address {address}: " if len(found) > 1 else ""
        stop = (f".stopall at address {address} stops everything" if len(found) > 1
                else ".stopall stops everything")
        if act.only_slowing:
            print(f"tmclsh: note: {at}{act} as the run ends", file=sys.stderr)
            continue
        if act.idle:
            continue
        unread = f" ({why})" if why else ""
        print(f"tmclsh: note: {at}{act}{unread}; left running ({stop})", file=sys.stderr)
        if session.out.json:  # (a program reading stdout learns it there)
            session.out.emit({"left_running": act.to_json(), "address": address})


def exit_cleanly_on_signals() -> None:
    """SIGTERM (kill, systemd, a CI job's timeout) and SIGHUP (the terminal or SSH session
    went away) unwind like an exception: the motors and the stored program are stopped as
    for Ctrl-C and ``client.close()`` runs, so a module is never left moving, or in ASCII or
    download mode, because the shell was killed."""
    unwind_on(("SIGTERM", "SIGHUP"))
