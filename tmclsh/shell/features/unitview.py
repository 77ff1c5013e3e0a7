"""What the user sees of several units at once (shell/features/units.py runs them).

Every unit's thread writes as a run of one module does (``Output``, ``print`` to stderr);
while units run, ``sys.stdout`` and ``sys.stderr`` are routers that hand what a unit's
thread writes to that unit's ``Record``, line by line, and what other threads write to the
real streams. A record keeps its lines in a buffer of its own (its own lock, for its lines
cut in pieces); the main thread alone takes them out and writes them (``View.drain``, every
tick and before the run's own words), so units never wait on one another to write, and what
every unit said since the last tick goes out as one write and one flush for each run of
lines to the same stream (not one for each unit: 32 units would be 32 system calls a tick,
each taking the interpreter from the units' threads). A view then shows the lines:

* ``TableView`` (stdout is a terminal): a live table, one row per unit (unit, module and
  firmware, line reached of how many, checks passed and failed, errors, the last error,
  time); a unit's results are not printed (its transcript keeps them), what it says on
  stderr (errors, warnings, notes) is printed above the table with the unit in front;
* ``PrefixView`` (a pipe or a file): every line with its unit in front, ``[2 /dev/ttyACM1 @1]``;
* ``JsonView`` (``--json``): the unit's objects as they are (``Output.tag`` has put
  ``"unit"`` and its port and address, or CAN id, first in each), its stderr prefixed, and a
  summary object when the unit ends (``"summary": true``).

At the end every view shows one summary table (on stderr under ``--json``). With
``--log-dir DIR`` each unit also writes a transcript: every frame sent and answered (as
``--trace`` shows them) and every line it showed, each with the time.
"""

from __future__ import annotations

import io
import json
import re
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from ... import __version__
from ...base.errors import EXIT_CONNECT, EXIT_OK, EXIT_USAGE
from .trace import Tracer, timestamp

if TYPE_CHECKING:
    import argparse

    from ..lang.session import Session
    from ...ops.units import Unit

_ROUTE = threading.local()  # .record: the Record the current thread writes to


class _Router(io.TextIOBase):
    """``sys.stdout``/``sys.stderr`` while units run (see the module docstring)."""

    def __init__(self, real: TextIO, stream: str):
        super().__init__()
        self.real, self.stream = real, stream

    def write(self, text: str) -> int:
        record = getattr(_ROUTE, "record", None)
        if record is None:
            return self.real.write(text)
        record.write(self.stream, text)
        return len(text)

    def flush(self) -> None:
        if getattr(_ROUTE, "record", None) is None:
            self.real.flush()

    def isatty(self) -> bool:
        return getattr(_ROUTE, "record", None) is None and self.real.isatty()

    def fileno(self) -> int:
        if getattr(_ROUTE, "record", None) is not None:
            raise io.UnsupportedOperation("a unit's output has no file descriptor")
        return self.real.fileno()

    def writable(self) -> bool:
        return True

    @property
    def encoding(self) -> str:  # type: ignore[override]
        return getattr(self.real, "encoding", "utf-8") or "utf-8"

    @property
    def errors(self) -> str | None:  # type: ignore[override]
        return getattr(self.real, "errors", None)


class _Stream:
    """One of a unit's own streams (``Output.stdout``/``stderr``): whichever thread writes."""

    def __init__(self, record: Record, stream: str):
        self.record, self.stream = record, stream

    def write(self, text: str) -> int:
        self.record.write(self.stream, text)
        return len(text)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False


class Record:
    """One unit as the views show it; its own thread updates it, the main thread reads it."""

    def __init__(self, unit: Unit, view: View, log_dir: Path | None):
        self.unit, self.view = unit, view
        self.state = "waiting"  # connecting, running, done, not run
        self.status: int | None = None
        self.module: str | None = None
        self.firmware: str | None = None
        self.done = 0
        self.total: int | None = None
        self.last_error = ""
        self.started: float | None = None
        self.ended: float | None = None
        self.session: Session | None = None
        self.why_not = ""
        self._partial = {"out": "", "err": ""}
        self._lines_lock = threading.Lock()  # (the unit's thread and its event poller)
        # what the view is still to show, in order: (stream, lines), or ("done", None)
        self.pending: deque[tuple[str, list[str] | None]] = deque()
        self.streams = (_Stream(self, "out"), _Stream(self, "err"))
        self._log: TextIO | None = None
        self._log_lock = threading.Lock()
        self._log_path = None if log_dir is None else log_dir / _log_name(unit)
        # a client tracer factory for the transcript (None: no --log-dir)
        self.tracer = self._tracer if self._log_path is not None else None

    # -- what the unit's thread tells ----------------------------------------------------
    @contextmanager
    def attached(self) -> Iterator[None]:
        _ROUTE.record = self
        try:
            yield
        finally:
            self.flush_lines()
            _ROUTE.record = None

    def begin(self) -> None:
        self.state, self.started = "connecting", time.monotonic()
        if self._log_path is not None:
            self._log_path.parent.mkdir(parents=True, exist_ok=True)
            self._log = open(self._log_path, "w", encoding="utf-8")
            self._log_line("#", f"tmclsh {__version__}, unit {self.unit.label}, started "
                                f"{time.strftime('%Y-%m-%d %H:%M:%S')}")

    def connected(self, client: Any) -> None:
        mod = client.module
        self.module = mod.name if mod is not None else None
        self.firmware = client.version
        self.state = "running"

    def progress(self, done: int, total: int) -> None:
        self.done, self.total = done, total

    def error(self, text: str) -> None:
        first = text.splitlines()[0] if text else text
        self.last_error = re.sub(r"^\S*[/\\](?=[^/\\\s]+:\d+: )", "", first)  # (FILE:LINE: the name)

    def notice(self, text: str) -> None:
        print(f"tmclsh: {text}", file=sys.stderr)

    def end(self, status: int, interrupted: str | None = None) -> None:
        self.status, self.ended, self.state = status, time.monotonic(), "done"
        if interrupted is not None and status not in (EXIT_OK, EXIT_CONNECT):
            self.why_not = interrupted
        self.flush_lines()
        self.pending.append(("done", None))
        if self._log is not None:
            self._log_line("#", f"ended {time.strftime('%Y-%m-%d %H:%M:%S')}: "
                                f"{self.result} (exit status {status})")
            with self._log_lock:
                self._log.close()
                self._log = None

    def not_run(self, why: str) -> None:
        """Never started (the run was stopped first); nothing if it ran."""
        if self.state == "waiting":
            self.state, self.why_not = "not run", why
            self.pending.append(("done", None))

    # -- lines ---------------------------------------------------------------------------
    def write(self, stream: str, text: str) -> None:
        with self._lines_lock:
            data = self._partial[stream] + text
            if "\n" not in data:
                self._partial[stream] = data
                return
            *lines, self._partial[stream] = data.split("\n")
            self._shown(stream, lines)

    def flush_lines(self) -> None:
        with self._lines_lock:
            for stream in ("out", "err"):
                rest, self._partial[stream] = self._partial[stream], ""
                if rest:
                    self._shown(stream, [rest])

    def _shown(self, stream: str, lines: list[str]) -> None:
        if self._log is not None:
            for line in lines:
                self._log_line(stream, line)
        self.pending.append((stream, lines))

    def _log_line(self, kind: str, text: str) -> None:
        with self._log_lock:
            if self._log is not None:
                self._log.write(f"{timestamp()} {kind:<3} {text}\n")

    def _tracer(self, client: Any):
        def write(line: Any) -> None:
            with self._log_lock:
                if self._log is not None:
                    self._log.write(line.plain + "\n")

        return Tracer(None, write=write, module=lambda: client.module)

    # -- what the views read -------------------------------------------------------------
    @property
    def counts(self) -> tuple[int, int, int]:
        """Checks passed, checks failed, errors."""
        s = self.session.stats if self.session is not None else None
        return (s.checks_passed, s.checks_failed, s.errors) if s is not None else (0, 0, 0)

    @property
    def commands(self) -> int:
        return self.session.stats.commands if self.session is not None else 0

    @property
    def seconds(self) -> float:
        if self.started is None:
            return 0.0
        return (self.ended or time.monotonic()) - self.started

    @property
    def result(self) -> str:
        if self.state == "not run":
            return "not run"
        if self.state != "done":
            return self.state
        if self.why_not:
            return "stopped"
        return {EXIT_OK: "passed", EXIT_CONNECT: "no module",
                EXIT_USAGE: "refused"}.get(self.status, "failed")  # type: ignore[arg-type]

    @property
    def line(self) -> int:
        """The line reached, numbered as the file's lines: the one running, or the one it
        stopped at (all when passed)."""
        if self.total is None:
            return 0
        return self.total if self.status == EXIT_OK else self.done

    @property
    def reached(self) -> str:
        if self.total is None:
            return "-"
        return f"{self.line}/{self.total}"

    @property
    def shared(self) -> list[int]:
        """The addresses two modules answered at during the run (the unit failed for it)."""
        return list(self.session.stats.shared) if self.session is not None else []

    def summary(self) -> dict:
        passed, failed, errors = self.counts
        row = {**self.unit.tag(self._address()), "summary": True, "result": self.result,
               "exit": self.status, "module": self.module, "firmware": self.firmware,
               "line": self.line, "of": self.total, "commands": self.commands,
               "checks_passed": passed, "checks_failed": failed, "errors": errors,
               "error": self.last_error or None, "seconds": round(self.seconds, 3)}
        if self.shared:
            row["duplicate"] = True  # (two modules answer at the unit's address)
        return row

    def _address(self) -> int:
        u = self.unit
        if u.kind == "can":
            return u.can_id if u.can_id is not None else 1
        return u.address if u.address is not None else 1


def _log_name(unit: Unit) -> str:
    where = re.sub(r"[^A-Za-z0-9.-]+", "-", unit.where).strip("-")
    return f"unit-{unit.number:02d}-{where}.log"


# -- the views ---------------------------------------------------------------------------

class View:
    """What every view does; subclasses show the lines and the rows their way."""

    def __init__(self, units: list[Unit], log_dir: Path | None):
        self.log_dir = log_dir
        self.records = {u.number: Record(u, self, log_dir) for u in units}
        self.out, self.err = sys.stdout, sys.stderr  # the real streams
        # the streams whose reader went away (a broken pipe): nothing more is written to
        # them; stdout's going cuts the run short (``out_gone``, shell/features/units.py)
        self._gone: set[int] = set()
        # while draining: what is to be written, and to which stream (one write for a run
        # of text to one stream; a change of stream writes what was held, so stdout and
        # stderr keep their order in one file)
        self._held: list[str] | None = None
        self._held_stream: TextIO | None = None

    def record(self, unit: Unit) -> Record:
        return self.records[unit.number]

    @contextmanager
    def showing(self) -> Iterator[None]:
        sys.stdout, sys.stderr = _Router(self.out, "out"), _Router(self.err, "err")
        try:
            self.start()
            yield
        finally:
            try:
                self.stop()
            finally:
                sys.stdout, sys.stderr = self.out, self.err

    def start(self) -> None:
        pass

    def stop(self) -> None:
        pass

    def tick(self) -> None:
        self.drain()

    def drain(self) -> None:
        """Show what the units have written since (main thread: the one writer)."""
        self._held = []
        try:
            for record in self.records.values():
                pending = record.pending
                while pending:
                    stream, lines = pending.popleft()
                    if lines is None:
                        self.unit_done(record)
                    else:
                        self.lines(record, stream, lines)
        finally:
            self._send_held()
            self._held = None

    def _send_held(self) -> None:
        held, stream = self._held, self._held_stream
        if held and stream is not None:
            text = "".join(held)
            held.clear()
            self._put(stream, text)

    @property
    def out_gone(self) -> bool:
        """Whoever read stdout went away (``tmclsh ... | head``)."""
        return id(self.out) in self._gone

    def _write(self, stream: TextIO, text: str) -> None:
        if id(stream) in self._gone:
            return
        held = self._held
        if held is not None:
            if stream is not self._held_stream:
                self._send_held()
                self._held_stream = stream
            held.append(text)
            return
        self._put(stream, text)

    def _put(self, stream: TextIO, text: str) -> None:
        if id(stream) in self._gone:
            return
        try:
            stream.write(text)
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: that stream is heard no more
            self._gone.add(id(stream))

    def note(self, text: str) -> None:
        """The run's own words (not a unit's), on stderr."""
        self.drain()
        self._write(self.err, f"tmclsh: {text}\n")

    def lines(self, record: Record, stream: str, lines: list[str]) -> None:
        prefix = f"[{record.unit.label}] "
        self._write(self.out if stream == "out" else self.err,
                    "".join(prefix + line + "\n" for line in lines))

    def unit_done(self, record: Record) -> None:
        pass

    def finish(self, records: list[Record]) -> None:
        self.drain()
        self._write(self.out, plain_table(records))


class PrefixView(View):
    """A pipe or a file: every line with its unit in front."""


class JsonView(View):
    """``--json``: objects as the unit's Output made them (tagged), a summary per unit."""

    def lines(self, record: Record, stream: str, lines: list[str]) -> None:
        if stream == "out":
            self._write(self.out, "".join(line + "\n" for line in lines))
        else:
            super().lines(record, stream, lines)

    def unit_done(self, record: Record) -> None:
        self._write(self.out, json.dumps(record.summary(), ensure_ascii=False) + "\n")

    def finish(self, records: list[Record]) -> None:
        self.drain()
        self._write(self.err, plain_table(records))


class TableView(View):
    """A terminal: a live table of the units, their stderr above it, a summary table."""

    hidden = False  # a unit's results were kept out of the table (said at the end)

    def start(self) -> None:
        from rich.console import Console
        from rich.live import Live

        from ..style import rich_theme

        self.console = Console(file=self.out, highlight=False, theme=rich_theme())
        self.live = Live(console=self.console, get_renderable=self._table,
                         refresh_per_second=4, transient=True, redirect_stdout=False,
                         redirect_stderr=False)
        self.live.start()

    def stop(self) -> None:
        self.live.stop()

    def note(self, text: str) -> None:
        self.drain()
        self._above(f"tmclsh: {text}", "tmcl.warn")

    def lines(self, record: Record, stream: str, lines: list[str]) -> None:
        if stream == "out":
            self.hidden = True  # results: the table shows how far each unit is
            return
        for line in lines:
            self._above(f"[{record.unit.label}] {line}", "")

    def _above(self, text: str, style: str) -> None:
        from rich.text import Text

        if self.err.isatty():
            self._send_held()  # (what came before it, first)
            self.console.print(Text(text, style=style or ""), soft_wrap=True)
        else:
            self._write(self.err, text + "\n")

    def finish(self, records: list[Record]) -> None:
        self.drain()
        self.console.print(self._table(final=True))
        if self.hidden and not self.log_dir:
            self.note("results are not shown beside the table: --log-dir DIR keeps each "
                      "unit's; in a pipe (| cat) every line is shown with its unit")

    def _table(self, final: bool = False):
        from rich.table import Table

        table = Table(title="units" if not final else "summary", title_justify="left",
                      expand=False)
        for name, justify in (("unit", "right"), ("link", "left"), ("module", "left"),
                              ("firmware", "left"), ("line", "right"), ("checks ok", "right"),
                              ("checks failed", "right"), ("errors", "right"),
                              ("result", "left"), ("time", "right"), ("last error", "left")):
            table.add_column(name, justify=justify,  # type: ignore[arg-type]
                             overflow="fold" if name == "last error" else "ellipsis")
        for r in self.records.values():
            passed, failed, errors = r.counts
            style = {"passed": "tmcl.ok", "failed": "tmcl.error", "no module": "tmcl.error",
                     "refused": "tmcl.error", "stopped": "tmcl.warn"}.get(r.result, "")
            table.add_row(str(r.unit.number), r.unit.where, r.module or "-", r.firmware or "-",
                          r.reached, str(passed), str(failed), str(errors), r.result,
                          f"{r.seconds:.1f} s", _short(r.last_error or r.why_not),
                          style=style)
        return table


LAST_ERROR_WIDTH = 72  # the summary table's last column (the JSON summary has it whole)


def _short(text: str, width: int = LAST_ERROR_WIDTH) -> str:
    return text if len(text) <= width else text[:width - 3].rstrip() + "..."


def plain_table(records: list[Record]) -> str:
    """The summary table as text (a pipe, a file, stderr under --json)."""
    head = ("unit", "link", "module", "firmware", "line", "checks ok", "checks failed",
            "errors", "result", "time", "last error")
    rows = [head]
    for r in records:
        passed, failed, errors = r.counts
        rows.append((str(r.unit.number), r.unit.where, r.module or "-", r.firmware or "-",
                     r.reached, str(passed), str(failed), str(errors), r.result,
                     f"{r.seconds:.2f} s", _short(r.last_error or r.why_not or "")))
    widths = [max(len(row[i]) for row in rows) for i in range(len(head))]
    right = {0, 4, 5, 6, 7, 9}
    return "".join("  ".join(cell.rjust(w) if i in right else cell.ljust(w)
                             for i, (cell, w) in enumerate(zip(row, widths))).rstrip() + "\n"
                   for row in rows)


def make_view(args: argparse.Namespace, units: list[Unit]) -> View:
    log_dir = Path(args.log_dir).expanduser() if getattr(args, "log_dir", None) else None
    if args.json:
        return JsonView(units, log_dir)
    if sys.stdout.isatty():
        return TableView(units, log_dir)
    return PrefixView(units, log_dir)
