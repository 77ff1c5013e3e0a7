"""The edges of a run, written once for every entry point: the JSON record a run's error
leaves on stdout, the one writer of a JSON object as a line, what to do when whoever
reads stdout has gone (``tmclsh ... | head``), and whether the terminal has gone. The exit status an exception ends a run with
is decided in ``errors.exit_status``.

A program reading ``--json`` output parses one shape of error whatever the command was (the
shell's lines, ``scan``, ``firmware``, ``monitor``, ``bridge``): ``{"line": ..., "error":
"..."}``, with ``"exit"`` when the error ends the run.
"""

from __future__ import annotations

import errno
import os
import sys
from typing import Any, TextIO

from .errors import EXIT_FAILED

try:  # (here, not where it is asked: nothing is imported in a unit's thread)
    import termios
except ImportError:  # (not on Windows)
    termios = None  # type: ignore[assignment]


def error_record(message: str, status: int | None = None, *, line: str | None = None,
                 **fields: Any) -> dict[str, Any]:
    """The one envelope of an error in JSON output: the line it belongs to (None: the run
    itself), what the command adds (``fields``), the message, and the exit status when the
    error ends the run."""
    record: dict[str, Any] = {"line": line, **fields, "error": message}
    if status is not None:
        record["exit"] = status
    return record


def write_json(obj: dict[str, Any], stream: TextIO | None = None) -> None:
    """One JSON object as one line, flushed at once: a program reading the pipe sees each
    result as it happens, not when a buffer fills."""
    import json  # (here: a run that writes no JSON does not import it)

    out = stream if stream is not None else sys.stdout
    out.write(json.dumps(obj) + "\n")
    out.flush()


def reader_gone() -> int:
    """Stdout's reader has gone (a broken pipe): stop quietly, as other command-line tools
    do, instead of ``tmclsh: [Errno 32] Broken pipe``. Stdout is pointed at the null device,
    so that the interpreter's last flush does not fail again. The exit status."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # (no file descriptor: a replaced stdout)
        try:
            sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (open as long as the run)
        except OSError:
            pass
    return EXIT_FAILED


def terminal_gone(fd: int) -> bool:
    """Whether ``fd`` is a terminal that has hung up (the window closed, the SSH session
    dropped): its settings can no longer be read (EIO). A file or pipe, which never was a
    terminal (ENOTTY), has not."""
    if termios is None:  # (no termios here: nothing to tell)
        return False
    try:
        termios.tcgetattr(fd)
    except (termios.error, OSError) as exc:
        return bool(exc.args) and exc.args[0] == errno.EIO
    return False


__all__ = ["error_record", "write_json", "reader_gone", "terminal_gone"]
