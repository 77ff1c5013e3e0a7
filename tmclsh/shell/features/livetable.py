"""The live table of ``monitor`` and ``bridge`` on a terminal: one row per module at the
bottom of the screen (ops/tally.py counts it), the line stream scrolling above it, as
python-can's viewer shows a CAN bus per id but by TMCL module.

The table never sets the pace of the traffic. What the readers give it costs a lock and a
few counts; the lines and the table are drawn by rich's ``Live`` a few times a second,
each redraw (the lines that came since and the table) rendered into memory and handed over
as one write. Live traffic goes through the run's ``SpillWriter`` (shell/features/monitor.py
``live_output``) on a thread of its own: while the terminal has not taken the last redraw,
no new one is made (a slow terminal loses redraws, never frames), and lines beyond
``LINES`` waiting for a redraw are dropped and counted with the lines the writer dropped. A
log is read at the reader's pace instead: its lines wait for the terminal, none dropped.
"""

from __future__ import annotations

import io
import os
import sys
import threading
import time
from typing import Any

from ...base.errors import UsageError
from ...ops.monitor import Item, Monitor
from ...ops.tally import Row, Tally
from ...tmcl.modules import Module
from ..render import Styled, describe_instruction, rich_theme, took, value_text

REFRESH = 0.25  # s between redraws
LINES = 2000  # lines that may wait for the next redraw before the newest are dropped
VALUES = 6  # last values shown per module (the latest changed)


def wanted(args, json_mode: bool) -> bool:
    """``--table``/``--no-table``; unsaid: on a terminal, not with ``--json`` (a program
    reading the output gets it as it was)."""
    table = getattr(args, "table", None)
    if table and json_mode:
        raise UsageError("--table is drawn for people: not with --json")
    if table is None:
        try:
            return not json_mode and sys.stdout.isatty()
        except (AttributeError, ValueError):
            return False
    return table


class LiveTable:
    """``take`` counts an item, ``line`` holds a line for the next redraw; ``start`` and
    ``stop`` put the table on the screen and leave its last state there.

    ``out``: where the redraws go (a ``SpillWriter`` for live traffic: redraws are drawn on
    a thread of this table's own; else the terminal itself, drawn by ``tick`` on the
    reader's thread). ``clock``: the time the rate is taken at (None: the traffic's own,
    for a log)."""

    def __init__(self, monitor: Monitor, out: Any, *, clock=time.time, color: str = "auto",
                 refresh: float = REFRESH):
        self.tally = Tally(monitor.module_for)
        self.out = out
        self.clock = clock
        self.refresh = refresh
        self.dropped = 0  # lines not shown: the terminal did not keep up
        self._color = color
        self._lines: list[Styled] = []
        self._lock = threading.Lock()
        self._drawing = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._live = None
        self._buffer = io.StringIO()
        self._drawn = 0.0
        self._spill = hasattr(out, "dropped")  # (a SpillWriter: drawn on a thread of its own)

    # -- what the readers give ---------------------------------------------------------------
    def take(self, item: Item) -> None:
        with self._lock:
            self.tally.take(item)

    def line(self, line: Styled) -> None:
        with self._lock:
            if self._spill and len(self._lines) >= LINES:
                self.dropped += 1
                return
            self._lines.append(line)

    def tick(self) -> None:
        """On the reader's thread (a log): redraw when it is time, or when lines pile up."""
        if self._thread is None and self._live is not None and (
                len(self._lines) >= LINES or time.monotonic() - self._drawn >= self.refresh):
            self._draw()

    # -- the screen --------------------------------------------------------------------------
    def start(self) -> None:
        from rich.live import Live

        self._live = Live(self._table([]), console=self._console(), auto_refresh=False,
                          redirect_stdout=False, redirect_stderr=False, transient=False)
        self._live.start()
        self._flush()
        self._drawn = time.monotonic()
        if self._spill:
            self._thread = threading.Thread(target=self._redraws, name="live-table",
                                            daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """The last lines and the table as it ends, left on the screen (once)."""
        if self._live is None:
            return
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None
        self._draw(final=True)
        with self._drawing:
            self._live.stop()
            self._flush()
        self._live = None

    def abandon(self) -> None:
        """Stop drawing without the last draw (what is below the table is not ours any
        more): the cursor shown again, and that is all."""
        live = self._live
        if live is None:
            return
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None
        self._live = None
        try:
            self.out.write("\x1b[?25h")
        except (OSError, ValueError):
            pass

    def _redraws(self) -> None:
        while not self._stop.wait(self.refresh):
            if self.out.waiting:  # (the terminal has not taken the last one: skip this)
                continue
            self._draw()

    def _draw(self, final: bool = False) -> None:
        with self._lock:
            lines, self._lines = self._lines, []
            now = self.clock() if self.clock is not None else None
            rows = self.tally.rows(now)
        with self._drawing:
            live = self._live
            if live is None:
                return
            console = live.console
            console.size = self._size()
            # (refreshed even when lines follow: rich's print draws the table as of the last
            # refresh below them, so traffic that never pauses would leave it as it began)
            live.update(self._table(rows, final), refresh=True)
            if lines:
                console.print(*lines, sep="\n", soft_wrap=True)
            self._flush()
        self._drawn = time.monotonic()

    def _flush(self) -> None:
        text = self._buffer.getvalue()
        if text:
            self._buffer.seek(0)
            self._buffer.truncate()
            self.out.write(text)
            if not self._spill:
                self.out.flush()

    def _size(self) -> tuple[int, int]:
        try:
            size = os.get_terminal_size(self.out.fileno())
            return size.columns, size.lines
        except (OSError, ValueError, AttributeError):
            return 100, 30

    def _console(self):
        """A console as the terminal's (its colours), that renders into memory."""
        from rich.console import Console

        from ..render import _console

        real = _console(color=self._color)
        width, height = self._size()
        return Console(file=self._buffer, force_terminal=True, force_interactive=True,
                       color_system=real.color_system, no_color=real.no_color,
                       theme=rich_theme(), markup=False, highlight=False, width=width,
                       height=height, legacy_windows=False)

    def _table(self, rows: list[Row], final: bool = False):
        return table_of(rows, self.tally.module_for, self.dropped, final)


def table_of(rows: list[Row], module_for, dropped: int = 0, final: bool = False):
    """The rich table of ``rows``: one row per module (``module_for``: its module, for
    the words of its commands)."""
    from rich.table import Table
    from rich.text import Text

    table = Table(title=None, caption=_caption(dropped, final), caption_justify="left",
                  expand=False, show_edge=True, pad_edge=False)
    table.add_column("module", no_wrap=True)
    table.add_column("exchanges", justify="right")
    table.add_column("per s", justify="right")
    table.add_column("errors")
    table.add_column("slowest")
    table.add_column("last values")
    for row in rows:
        name = Text(row.where, style="tmcl.name")
        if row.module:
            name.append(f" {row.module}", style="tmcl.note")
        table.add_row(name, str(row.exchanges), f"{row.per_second:.1f}", _errors(row),
                      _slowest(row, module_for(row.address)), _values(row))
    if not rows:
        table.add_row(Text("(no exchange yet)", style="tmcl.note"), "", "", "", "", "")
    return table


def _caption(dropped: int, final: bool) -> str | None:
    parts = []
    if not final:
        parts.append("per module; Ctrl-C ends")
    if dropped:
        parts.append(f"{dropped} lines not shown (the terminal did not keep up)")
    return "; ".join(parts) or None


def _errors(row: Row):
    from rich.text import Text

    out = Text()
    counts = [(name, n) for name, n in sorted(row.errors.items())]
    if row.unanswered:
        counts.append(("unanswered", row.unanswered))
    if row.unpaired:
        counts.append(("reply without its request", row.unpaired))
    for i, (name, n) in enumerate(counts):
        if i:
            out.append("\n")
        out.append(f"{name} x{n}", style="tmcl.status.error")
    return out


def _slowest(row: Row, module: Module | None) -> str:
    """As the summary says it: the time, the request in the line stream's words."""
    s = row.slowest
    return "" if s is None else f"{took(s.latency)}  {describe_instruction(s.instruction, module)}"


def _values(row: Row):
    from rich.text import Text

    values = row.values
    latest = {id(v) for v in sorted(values, key=lambda v: v.t)[-VALUES:]}
    out = Text()
    for i, v in enumerate(v for v in values if id(v) in latest):
        if i:
            out.append("\n")
        out.append(v.name, style="tmcl.name")
        out.append(f" = {value_text(v.value, v.param)}")
    if len(values) > VALUES:
        out.append(f"\n(+{len(values) - VALUES} more)", style="tmcl.note")
    return out
