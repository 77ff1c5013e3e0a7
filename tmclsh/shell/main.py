"""Entry of the shell proper: connect, then run -c lines, a -f script, or the REPL."""

from __future__ import annotations

import argparse
import sys

from ..errors import TmclError
from .render import Output, prose_list
from .session import QuitShell, Session

EXIT_OK, EXIT_ERROR, EXIT_CONNECT = 0, 1, 3


def banner(session: Session) -> str:
    c = session.client
    mod = c.module.label if c.module else "unknown module"
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
    for line in lines:
        try:
            session.run_line(line)
        except QuitShell:
            break
        except TmclError as exc:
            failed = True
            report_error(session, line, exc)
            if not session.keep_going:
                break
    return EXIT_ERROR if failed else EXIT_OK


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
        stopped = client.stop_all() if client.connected else []
        print(f"\ninterrupted; motors stopped: {prose_list(stopped)}", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # whoever read our output has gone (`tmclsh -c ... | head`): stop quietly, as other
        # command-line tools do, instead of `tmclsh: [Errno 32] Broken pipe`
        _silence_stdout()
        return EXIT_ERROR
    finally:
        client.close()  # leaves ASCII mode if tmclsh entered it, whatever happened


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

    shell_settings = load_settings()
    out = Output(json_mode=bool(args.json), color=str(shell_settings.get("color", "auto")))
    interactive = args.command is None and args.script is None and sys.stdin.isatty()
    # `confirm = false` in the config file is a standing --yes
    yes = bool(args.yes) or shell_settings.get("confirm") is False
    session = Session(client, out, interactive=interactive, yes=yes,
                      keep_going=bool(args.keep_going), settings=settings)
    if client.module is not None and client.module.generic:
        out.warn(f"{client.module.type_name}: {client.module.NOTICE}")  # once, at the start
    if args.trace:
        from .trace import enable_trace

        enable_trace(session)
    try:
        if args.command is not None:
            status = run_lines(session, session.split(args.command))
        elif args.script is not None or not interactive:
            from .script import run_file

            status = run_file(session, args.script or "-")
        else:
            from .app import run_repl

            status = run_repl(session)
    except BaseException:
        session.close()
        raise
    if not session.close():  # a recording that could not be put in place
        status = status or EXIT_ERROR
    return status


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
