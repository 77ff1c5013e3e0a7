"""Entry of the shell proper: connect, then run -c lines, a -f script, or the REPL."""

from __future__ import annotations

import argparse
import sys

from ..errors import TmclError
from .render import Output
from .session import QuitShell, Session

EXIT_OK, EXIT_ERROR, EXIT_CONNECT = 0, 1, 3


def banner(session: Session) -> str:
    c = session.client
    mod = c.module.name if c.module else "unknown module"
    sim = " [SIMULATED]" if c.transport.simulated else ""
    mode = " ASCII mode" if c.mode == "ascii" else ""
    return f"tmclsh: {mod} at address {c.address} on {c.describe()}{sim}{mode}"


def report_error(session: Session, line: str | None, exc: BaseException) -> None:
    if getattr(exc, "shown", False):
        return
    where = ""
    if session.location is not None:
        where = f"{session.location[0]}:{session.location[1]}: "
    session.out.error(line, f"{where}{exc}")


def run_lines(session: Session, lines: list[str]) -> int:
    failed = False
    suspects = session.stats.suspects
    for line in lines:
        try:
            session.ensure_link()  # the link was lost on an earlier line (--keep-going)
            session.run_line(line)
        except QuitShell:
            break
        except TmclError as exc:
            failed = True
            report_error(session, line, exc)
            if not session.keep_going:
                break
    return EXIT_ERROR if failed or session.stats.suspects > suspects else EXIT_OK


def run_shell(args: argparse.Namespace) -> int:
    from ..connection import connection_settings, open_client

    _exit_cleanly_on_signals()
    settings = connection_settings(args)
    try:
        client = open_client(settings)
    except TmclError as exc:
        print(f"tmclsh: {exc}", file=sys.stderr)
        return EXIT_CONNECT
    try:
        return _run(args, client, settings)
    except KeyboardInterrupt:
        print(file=sys.stderr)
        _stop_on_interrupt(client)
        return 130
    except BrokenPipeError:
        # whoever read our output has gone (`tmclsh -c ... | head`): stop quietly, as other
        # command-line tools do, instead of `tmclsh: [Errno 32] Broken pipe`
        _silence_stdout()
        return EXIT_ERROR
    finally:
        client.close()  # leaves ASCII mode if tmclsh entered it, whatever happened


def _stop_on_interrupt(client) -> None:
    """Ctrl-C in -c/-f: stop everything (program.stop_everything) and say what reads back."""
    from ..program import stop_everything

    if not client.connected:
        print("interrupted; not connected, nothing could be stopped", file=sys.stderr)
        return
    try:
        report = stop_everything(client)
    except KeyboardInterrupt:
        print("interrupted again: the motors may still turn", file=sys.stderr)
        return
    except (TmclError, OSError) as exc:
        print(f"interrupted; stopping failed: {exc}", file=sys.stderr)
        return
    from .builtin import describe_stop

    ok, warnings = describe_stop(report)
    print("interrupted" + (f"; {ok}" if ok else ""), file=sys.stderr)
    for text in warnings:
        print(text, file=sys.stderr)


def _silence_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's last flush does not fail again."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _run(args: argparse.Namespace, client, settings: dict) -> int:
    from ..config import load_settings

    out = Output(json_mode=bool(args.json))
    interactive = args.command is None and args.script is None and sys.stdin.isatty()
    # `confirm = false` in the config file is a standing --yes
    yes = bool(args.yes) or load_settings().get("confirm") is False
    session = Session(client, out, interactive=interactive, yes=yes,
                      keep_going=bool(args.keep_going), settings=settings)
    if args.trace:
        from .trace import enable_trace

        enable_trace(session)
    try:
        if not interactive:
            status = _run_unattended(args, session)
        else:
            from .app import run_repl

            status = run_repl(session)
    except BaseException:
        session.close()
        raise
    if not session.close():  # a recording that could not be put in place
        status = status or EXIT_ERROR
    return status


def _run_unattended(args: argparse.Namespace, session: Session) -> int:
    """-c, -f, or stdin that is no terminal."""
    client, out = session.client, session.out
    # 138 messages are results too: in order with the others (the REPL shows them as they
    # come; see app.py)
    unlisten = lambda: None  # noqa: E731
    wrote = _watch_for_writes(client)
    if out.json:
        unlisten = client.add_listener(lambda reply: out.event(reply, client.event_time))
        client.start_event_poller()  # an event shows when it comes, not at the next line
    finished = False
    try:
        if args.command is not None:
            status = run_lines(session, session.split(args.command))
        else:
            from .script import run_file

            status = run_file(session, args.script or "-")
        finished = True
    finally:
        client.stop_event_poller()
        if finished:  # (after Ctrl-C: straight on to the stop, nothing else first)
            _last_events(session)
        unlisten()
        if wrote() and finished:  # only reads (or nothing) sent: nothing can have started
            _note_left_running(session)
    return status


def _last_events(session: Session) -> None:
    """Events that came after the last reply are results of the run as well."""
    client = session.client
    try:
        if client.connected and client.mode == "binary":
            client.poll()
        session.report_suspects()
    except (TmclError, OSError):
        pass


# commands that only read: a run of nothing else cannot have started a motor or the program
_READS = frozenset({6, 10, 15, 128, 134, 135, 136})  # GAP GGP GIO, stop, 134-136


def _watch_for_writes(client):
    """A tracer noting whether anything but a read was sent; returns the question."""
    from ..protocol import Request

    sent = []

    def tracer(direction: str, raw: bytes, decoded: object) -> None:
        if not sent and direction == "tx" and isinstance(decoded, Request) \
                and decoded.opcode not in _READS:
            sent.append(True)

    remove = client.add_tracer(tracer)

    def wrote() -> bool:
        remove()
        return bool(sent)

    return wrote


def _note_left_running(session: Session) -> None:
    """A script that ends while a motor turns or the program runs says so on stderr (it
    leaves them so: that may well be what it was for)."""
    from ..program import activity

    client = session.client
    if not client.connected:
        return
    try:
        act = activity(client)
    except (TmclError, OSError):
        return
    if not act.idle:
        print(f"tmclsh: note: {act}; left running (.stopall stops everything)",
              file=sys.stderr)


def _exit_cleanly_on_signals() -> None:
    """SIGTERM (kill, systemd) and SIGHUP (the terminal or SSH session went away) unwind like
    an exception, so ``client.close()`` still runs: a module is never left in ASCII or
    download mode because the shell was killed."""
    import signal

    def leave(signum: int, frame: object) -> None:
        raise SystemExit(128 + signum)

    for sig in (signal.SIGTERM, signal.SIGHUP):
        try:
            signal.signal(sig, leave)
        except (ValueError, OSError):  # not the main thread, or not on this platform
            pass
