"""``.watch``: poll expressions over module reads and show them live.

    .watch pos=GAP 1, 0; speed=GAP 3, 0; in0=GIO 0, 0 --interval 0.1 --until "pos >= 5000"

* ``poll(session, items)`` reads once (identical reads within a sample are sent once) and
  gives a ``Sample`` (the sampling is ``ops/watch.py``, on a client; here on the session); ``WatchState.add(sample)`` folds it into a frozen ``Snapshot``;
  ``render(snapshot) -> Table`` is pure (no bus I/O) and runs at a fixed refresh rate.
* On a terminal: a rich ``Live`` table with value, min, max, rate of change, a sparkline of
  recent values, changed values highlighted. Under ``--json`` or when stdout is not a
  terminal: one JSON object per sample, ``{"t": seconds, "values": {name: number}}``
  (``null`` for a value whose read failed in that sample).
* An answer in doubt is never shown as the module's value. On a line that brings a reply
  twice, the copy may be taken for the next request's answer (same command, same layout);
  the client finds that out when the real answer comes while nothing waits for it
  (``Doubts.suspect_seqs``). A read found so during its sample (by a later read's request)
  is read again at once, then one 136 type 1 exchange lets the line's last answer arrive;
  the sample's last read is judged by the next sample's first request, so a sample is shown
  one sample late (the last one after a 136 type 1 exchange). A value still in doubt is
  shown as ``?`` (the CSV too; JSON: ``null`` and ``"suspect": [names]``) and is left out
  of min, max, rate, the sparkline and ``.plot``. No exchange is added while nothing is in
  doubt.
* Keys (when stdin is a terminal; read through prompt_toolkit's input in raw mode, so the
  Windows console works as a POSIX terminal does; restored on exit): ``s`` or space stops
  everything (the stored program if it runs, MST to every motor, speeds read back: the
  shell's one stop, stop.py) and keeps watching; Ctrl-C does the same
  and ends the watch; ``q`` or Esc ends the watch quietly (motors keep running). Ctrl-C (a
  key in raw mode, a signal otherwise) is taken between reads, so a transaction is never
  cut in half; a second one interrupts at once.
* A lost link (the port is gone) shows as "link lost: REASON" in the table; the watch keeps
  trying to reconnect every ``RECONNECT_EVERY`` seconds and samples again once it is back.
"""

from __future__ import annotations

import csv
import errno
import math
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from ...base import clock, files
from ...base.errors import TmclError, TransportError, ValidationError  # noqa: F401
from ...base.edges import terminal_gone
from ...base.interrupts import hung_up
from ...ops import watch as sampling
from ...ops.watch import Item, Reading, Sample, SendClock
from ..lang import expr, lines, script
from . import plot
from ..lang import options
from ..lang.commands import command, options_of
from ..lang.session import reconnected

if TYPE_CHECKING:
    from ..lang.session import Session

Number = int | float

DEFAULT_INTERVAL = 0.1  # seconds between samples
REFRESH_HZ = 10  # table redraws per second, at most
SPARK_WIDTH = 24  # samples shown in the sparkline
RATE_WINDOW = 1.0  # seconds over which the change rate is measured
LOG_LIMIT = 200_000  # samples kept for .plot
_BLOCKS = "▁▂▃▄▅▆▇█"
_KEY_HELP = "s/space: stop all  ·  Ctrl-C: stop all and end  ·  q: end (motors keep running)"
_KEY_HELP_SHORT = "s: stop all · ^C: stop, end · q: end"
_NO_KEYS_HELP = "Ctrl-C: stop all and end"
STOP_KEYS = "sS "  # stop the program and every motor, keep watching
QUIT_KEYS = "qQ"  # end the watch quietly (so does Esc)
RECONNECT_EVERY = 0.5  # s between reconnection attempts after the link was lost


# -- what is watched, on the session (the sampling itself is ops/watch.py) -------------------

def parse_items(session: Session, text: str) -> list[Item]:
    """``pos=GAP 1, 0; GIO 0, 0`` -> items, ``${...}`` substituted first."""
    return sampling.parse_items(session.client, text, session.expand)


def default_items(session: Session) -> list[Item]:
    return sampling.default_items(session.client)


def poll(session: Session, items: Sequence[Item], t: float) -> Sample:
    """One sample on the session (``ops.watch.poll``): its variables, its reads counted."""
    reading = _reading(session, items, t)
    reading.settle(confirm=True)
    return reading.sample()


def _reading(session: Session, items: Sequence[Item], t: float,
             clock: SendClock | None = None, start: float | None = None) -> Reading:
    return Reading(session.client, items, t, clock, start, variables=session.variables,
                   counted=expr.SessionContext(session).counted)


# -- snapshots ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Series:
    name: str
    value: Number | None
    previous: Number | None
    minimum: Number | None
    maximum: Number | None
    rate: float | None  # units per second
    history: tuple[Number, ...]
    error: str | None = None
    suspect: bool = False  # the last sample's answer was in doubt (shown as "?")

    @property
    def changed(self) -> bool:
        return self.previous is not None and self.value is not None and self.value != self.previous


@dataclass(frozen=True)
class Snapshot:
    series: tuple[Series, ...]
    t: float = 0.0
    samples: int = 0
    rate_hz: float = 0.0
    interval: float = DEFAULT_INTERVAL
    note: str = ""
    keys: bool = False
    failed_reads: int = 0
    lost: str | None = None
    doubtful_reads: int = 0  # values in doubt (shown "?", not counted as failed)


class WatchState:
    """Folds samples in (min/max, recent history, a log for .plot); ``snapshot()`` freezes
    the current state for rendering, which happens at the refresh rate, not per sample."""

    def __init__(self, items: Sequence[Item], interval: float, keys: bool = False):
        """``keys``: whether key presses are read (the table then shows the key help)."""
        self.names = [i.name for i in items]
        self.interval = interval
        self.keys = keys
        self.samples = 0
        self.failed_reads = 0
        self.doubtful_reads = 0
        self.note = ""
        self.lost: str | None = None  # "link lost" reason while the link is down
        self.first_t: float | None = None
        self.last: dict[str, Number | None] = {n: None for n in self.names}
        self.prev: dict[str, Number | None] = {n: None for n in self.names}
        self.min: dict[str, Number | None] = {n: None for n in self.names}
        self.max: dict[str, Number | None] = {n: None for n in self.names}
        self.errors: dict[str, str | None] = {n: None for n in self.names}
        self.suspect: dict[str, bool] = {n: False for n in self.names}
        self.recent: dict[str, deque[tuple[float, Number]]] = {
            n: deque(maxlen=max(SPARK_WIDTH, 512)) for n in self.names}
        self.log = plot.Log(list(self.names))
        self.t = 0.0

    def add(self, sample: Sample) -> None:
        self.samples += 1
        self.t = sample.t
        if self.first_t is None:
            self.first_t = sample.t
        for n in self.names:
            v = sample.values.get(n)
            self.errors[n] = sample.errors.get(n)
            self.suspect[n] = n in sample.suspect
            if v is None:  # (a value in doubt is no value: not in min, max, rate or history)
                if self.suspect[n]:
                    self.doubtful_reads += 1
                else:
                    self.failed_reads += 1
                continue
            self.prev[n], self.last[n] = self.last[n], v
            self.min[n] = v if self.min[n] is None else min(self.min[n], v)  # type: ignore[type-var]
            self.max[n] = v if self.max[n] is None else max(self.max[n], v)  # type: ignore[type-var]
            self.recent[n].append((sample.times.get(n, sample.t), v))
        self.log.add(sample.t, sample.values)
        if len(self.log.t) > LOG_LIMIT:
            half = LOG_LIMIT // 2
            del self.log.t[:half]
            for vals in self.log.values.values():
                del vals[:half]

    def rate(self, name: str) -> float | None:
        recent = self.recent[name]
        if len(recent) < 2:
            return None
        t1, v1 = recent[-1]
        t0, v0 = recent[-2]
        for t, v in reversed(recent):
            if t1 - t > RATE_WINDOW:
                break
            t0, v0 = t, v
        return None if t1 == t0 else (v1 - v0) / (t1 - t0)

    def snapshot(self) -> Snapshot:
        span = self.t - (self.first_t or 0.0)
        hz = (self.samples - 1) / span if span > 0 else 0.0
        series = tuple(
            Series(n, self.last[n] if self.errors[n] is None and not self.suspect[n] else None,
                   self.prev[n], self.min[n], self.max[n], self.rate(n),
                   tuple(v for _, v in list(self.recent[n])[-SPARK_WIDTH:]), self.errors[n],
                   self.suspect[n])
            for n in self.names)
        return Snapshot(series, self.t, self.samples, hz, self.interval, self.note, self.keys,
                        self.failed_reads, self.lost, self.doubtful_reads)


# -- rendering (pure) ----------------------------------------------------------------------

def sparkline(values: Sequence[Number], width: int = SPARK_WIDTH) -> str:
    """Unicode blocks scaled between the shown values' min and max (flat: a middle block)."""
    vals = [v for v in values if v is not None and math.isfinite(v)][-width:]
    if not vals:
        return ""
    lo, hi = min(vals), max(vals)
    if hi == lo:
        return _BLOCKS[3] * len(vals)
    top = len(_BLOCKS) - 1
    return "".join(_BLOCKS[round((v - lo) / (hi - lo) * top)] for v in vals)


def _fmt_value(s: Series) -> str:
    return "error" if s.error is not None else "?" if s.suspect else _fmt(s.value)


def _fmt(value: Number | None) -> str:
    if value is None:
        return "—"
    return expr.format_number(value)


def _fmt_rate(rate: float | None) -> str:
    if rate is None:
        return ""
    if rate == 0:
        return "0"
    if abs(rate) >= 100:
        return f"{rate:+.0f}"
    if abs(rate) >= 1:
        return f"{rate:+.1f}"
    return f"{rate:+.3g}"


def render(snapshot: Snapshot, width: int | None = None):
    """The live table for one snapshot (pure: no I/O); ``width`` is the terminal's, which the
    sparkline gives way to so the numbers are never cut."""
    from rich.table import Table
    from rich.text import Text

    spark = SPARK_WIDTH
    if width is not None:
        cells = [(s.name, _fmt_value(s), _fmt(s.minimum),
                  _fmt(s.maximum), _fmt_rate(s.rate)) for s in snapshot.series]
        heads = ("name", "value", "min", "max", "rate /s")
        used = sum(max([len(h)] + [len(c[i]) for c in cells]) + 3 for i, h in enumerate(heads))
        spark = max(6, min(SPARK_WIDTH, width - used - 4))

    title = (f"watch  {snapshot.samples} samples  t={snapshot.t:.1f} s  "
             f"{snapshot.rate_hz:.1f}/s (interval {snapshot.interval:g} s)")
    caption_parts = []
    if snapshot.lost:
        caption_parts.append(f"link lost: {snapshot.lost} (reconnecting...)")
    if snapshot.note:
        caption_parts.append(snapshot.note)
    if snapshot.failed_reads:
        caption_parts.append(f"{snapshot.failed_reads} failed reads")
    if snapshot.doubtful_reads:
        caption_parts.append(f"{snapshot.doubtful_reads} answers in doubt (shown ?: the line "
                             "brought a reply nothing was waiting for)")
    key_help = _KEY_HELP if width is None or width >= len(_KEY_HELP) else _KEY_HELP_SHORT
    caption_parts.append(key_help if snapshot.keys else _NO_KEYS_HELP)
    # one caption line per note, and wide enough that the key help never wraps
    min_width = max(len(title), *(len(c) for c in caption_parts))
    table = Table(title=title, caption="\n".join(caption_parts), title_justify="left",
                  caption_justify="left", expand=False,
                  min_width=min(min_width, width) if width is not None else min_width)
    table.add_column("name", style="tmcl.name", no_wrap=True)
    table.add_column("value", justify="right", no_wrap=True)
    table.add_column("min", justify="right", style="tmcl.note", no_wrap=True)
    table.add_column("max", justify="right", style="tmcl.note", no_wrap=True)
    table.add_column("rate /s", justify="right", no_wrap=True)
    table.add_column("recent", no_wrap=True, min_width=spark)
    for s in snapshot.series:
        if snapshot.lost:
            value = Text("link lost", style="tmcl.error")
        elif s.error is not None:
            value = Text("error", style="tmcl.error")
        elif s.suspect:
            value = Text("?", style="tmcl.warn")
        else:
            value = Text(_fmt(s.value), style="tmcl.changed" if s.changed else "tmcl.value")
        table.add_row(s.name, value, _fmt(s.minimum), _fmt(s.maximum), _fmt_rate(s.rate),
                      Text(sparkline(s.history, spark), style="tmcl.ok"))
    return table


# -- keys ----------------------------------------------------------------------------------

def _stream_gone(stream: TextIO) -> bool:
    try:
        return terminal_gone(stream.fileno())
    except (OSError, ValueError, AttributeError):  # (no descriptor: a replaced stdin)
        return False


class Keys:
    """Single key presses from a terminal stdin, through prompt_toolkit's input (the POSIX
    terminal and the Windows console alike), in raw mode: Ctrl-C arrives as the key "\x03".

    Inactive (``wait`` just sleeps) when stdin is not a terminal.
    """

    def __init__(self, stream: TextIO | None = None):
        self.stream = stream if stream is not None else sys.stdin
        self._input = None
        self._mode = None

    def __enter__(self) -> Keys:
        try:
            if self.stream is None or not self.stream.isatty():
                if self.stream is not None and _stream_gone(self.stream):
                    raise hung_up()  # (gone before the watch began: as below in wait)
                return self
            from prompt_toolkit.input import create_input

            inp = create_input(self.stream)
            mode = inp.raw_mode()
            mode.__enter__()
            self._input, self._mode = inp, mode
        except (OSError, ValueError, AttributeError, NotImplementedError):
            self._input = self._mode = None
        return self

    def __exit__(self, *exc: object) -> None:
        if self._mode is not None:
            self._mode.__exit__(None, None, None)
        self._input = self._mode = None

    @property
    def active(self) -> bool:
        return self._input is not None

    def wait(self, timeout: float) -> str:
        """Wait up to ``timeout`` seconds; return the keys pressed (possibly several): single
        characters, "\x1b" for Esc; arrows and other sequences are left out."""
        if self._input is None:
            clock.sleep(timeout)  # (in slices: a unit's stop lands within one)
            return ""
        from prompt_toolkit.keys import Keys as Key

        deadline = time.monotonic() + max(0.0, timeout)
        while True:
            presses = self._input.read_keys() or self._input.flush_keys()
            text = "".join("\x1b" if p.key == Key.Escape else p.data for p in presses
                           if p.key == Key.Escape or len(p.data) == 1)
            left = deadline - time.monotonic()
            if self._input.closed and not text:
                # the terminal's reads ended: it went away (a key in raw mode is never
                # an end of input), and no SIGHUP came: the hang-up's stop ends the run
                raise hung_up()
            if text or left <= 0:
                return text
            time.sleep(min(0.01, left))


class _Interrupt:
    """Turns the first Ctrl-C into a flag checked between reads; the second raises."""

    def __init__(self) -> None:
        self.requested = False
        self._old = None

    def __enter__(self) -> _Interrupt:
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handle)
        return self

    def _handle(self, signum, frame) -> None:
        self.press()

    def press(self) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __exit__(self, *exc: object) -> None:
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)


# -- the command ---------------------------------------------------------------------------



def parse_args(session: Session, args: str, *, names: bool = True):
    """``.watch`` arguments -> (items, interval, count, until, csv path); no bus I/O.

    ``names=False`` (a script's check before it runs) skips checking that ``--until`` names
    only watched values or variables: variables set earlier in the script do not exist yet.
    """
    _refuse_line_after_options(args)
    rest, opts = options.parse(args, options_of(".watch"))
    interval = options.float_value(opts, "--interval", DEFAULT_INTERVAL,
                                   limit="watch_interval")
    count = options.int_value(opts, "--count", None, minimum=1)
    assert interval is not None
    items = parse_items(session, rest) if rest else default_items(session)
    until = None
    if "--until" in opts:
        until = expr.parse(session.expand(str(opts["--until"])))
        known = {i.name for i in items} | set(session.variables)
        unknown = [n for n in until.names() if n not in known]
        if unknown and names:
            raise ValidationError(f"--until uses {unknown[0]!r}, which is neither watched nor a "
                                  f"variable (watched: {', '.join(i.name for i in items)})")
        expr.validate(session, until)
    csv_path = Path(str(opts["--csv"])).expanduser() if "--csv" in opts else None
    return items, interval, count, until, csv_path


def _refuse_line_after_options(args: str) -> None:
    """A ';' after the options cannot separate expressions (they come first): it was meant
    to start the next command, which .watch would otherwise take into an option's value
    (``--count 2;``) or its expressions."""
    import re

    names = "|".join(o.name[2:] for o in options_of(".watch"))
    first = re.search(r"(?:^|\s)--(?:" + names + r")\b", args)
    if first is None:
        return
    cut = next((i for i in lines.separators(args) if i > first.start()), None)
    if cut is not None:
        before, after = args[:cut].strip(), args[cut + 1:].strip()
        raise ValidationError(
            f"{after!r} after ';' follows the watch's options; .watch takes the rest of "
            f"its line, ';' separating its expressions (before the options). To run "
            f"{after!r} after the watch, put it on a line of its own:\n  .watch {before}"
            f"\n  {after}")


def check_watch(session: Session, args: str) -> None:
    parse_args(session, script.blank_substitutions(args), names=False)





@dataclass
class WatchResult:
    samples: int
    elapsed: float
    reason: str  # count, until, key, interrupt, pipe
    stops: list = field(default_factory=list)  # ops.stop.StopReport of each stop, in order
    reread: int = 0  # answers found in doubt within their sample and read again
    doubtful: dict[str, int] = field(default_factory=dict)  # name -> samples it was in doubt


class _Csv:
    """The samples as CSV, written beside the file and put in its place when the watch
    ends (a full disk stops the watch with an error and leaves the old file as it was).

    A row: ``time`` (the clock when its first value was read) and ``t`` (the same in seconds
    since the watch began), the values, ``together`` (yes: read back to back; no: a retry, a
    slow answer or a read again came between them) and ``t(NAME)`` for each value, the
    moment it was read (rows are written once judged, so never the moment of writing)."""

    def __init__(self, path: Path, names: Sequence[str], wall_start: float):
        self.fh = files.atomic_writer(path, newline="")
        self.writer = csv.writer(self.fh)
        self.writer.writerow(["time", "t", *names, "together", *(f"t({n})" for n in names)])
        self.fh.flush()
        self.names = names
        self.wall_start = wall_start  # time.time() at the watch's t = 0

    def write(self, sample: Sample) -> None:
        when = datetime.fromtimestamp(self.wall_start + sample.t)
        self.writer.writerow([when.isoformat(timespec="milliseconds"), f"{sample.t:.4f}",
                              *("?" if n in sample.suspect else "" if sample.values.get(n) is None
                                else sample.values[n] for n in self.names),
                              "yes" if sample.together else "no",
                              *(f"{sample.times[n]:.4f}" if n in sample.times else ""
                                for n in self.names)])
        self.fh.flush()

    def close(self) -> None:
        self.fh.commit()


def run_watch(session: Session, items: Sequence[Item], *, interval: float = DEFAULT_INTERVAL,
              count: int | None = None, until: expr.Expression | None = None,
              csv_path: Path | None = None, live: bool | None = None,
              keys: Keys | None = None,
              emit: Callable[[Mapping[str, object]], None] | None = None) -> WatchResult:
    """Poll ``items`` every ``interval`` s until ``count`` samples, ``until`` holds, a key or
    Ctrl-C; show a live table (``live``) or emit one JSON object per sample."""
    out = session.out
    if live is None:
        live = not out.json and out.is_terminal
    w = _Watch(session, items, interval, count, until, emit or out.emit)
    sink = (_Csv(csv_path, [i.name for i in items], w.wall_start) if csv_path is not None
            else None)
    w.sink = sink
    untrace = session.client.add_tracer(w.clock, sent_only=True)
    try:
        with (keys if keys is not None else Keys()) as w.keys, _Interrupt() as w.intr:
            w.state.keys = w.keys.active
            session.state.watch_log = w.state.log
            w.view = _Live(session, w.state) if live else None
            try:
                w.result.reason = w.run()
            finally:
                if w.view is not None:
                    w.view.close()
    finally:
        untrace()
        if sink is not None:
            sink.close()
    w.result.samples = w.state.samples
    w.result.elapsed = time.monotonic() - w.start
    return w.result


class _Live:
    def __init__(self, session: Session, state: WatchState):
        from rich.live import Live

        self.state = state
        self.console = session.out.console
        self.live = Live(render(state.snapshot(), self.console.width), console=self.console,
                         auto_refresh=False, transient=False)
        self.live.start()
        self.last = 0.0

    def update(self, force: bool = False) -> None:
        """Redraw from a fresh snapshot, at most REFRESH_HZ times a second."""
        now = time.monotonic()
        if force or now - self.last >= 1.0 / REFRESH_HZ:
            self.live.update(render(self.state.snapshot(), self.console.width), refresh=True)
            self.last = now

    def close(self) -> None:
        self.live.update(render(self.state.snapshot(), self.console.width), refresh=True)
        self.live.stop()


class _Watch:
    """The polling loop: sample, show, check the end conditions, wait (reading keys)."""

    def __init__(self, session: Session, items: Sequence[Item], interval: float,
                 count: int | None, until: expr.Expression | None,
                 emit: Callable[[Mapping[str, object]], None]):
        self.session, self.items, self.interval = session, items, interval
        self.count, self.until, self.emit = count, until, emit
        self.state = WatchState(items, interval)
        self.result = WatchResult(0, 0.0, "interrupt")
        self.sink: _Csv | None = None
        self.view: _Live | None = None
        self.pending: Reading | None = None  # read, shown once its last answer is judged
        self.keys = Keys()
        self.intr = _Interrupt()
        self.clock = SendClock()
        self.start = time.monotonic()
        self.wall_start = time.time()  # (the CSV's clock column: the same moment)

    def run(self) -> str:
        """Returns why the watch ended: count, until, key, interrupt or pipe.

        A sample is shown once its answers are judged (``Reading.settle``): its last read
        by the next sample's first request, so it is shown one sample late; one that ends
        the watch after a 136 type 1 exchange."""
        next_at = self.start
        doubt = expr.can_doubt(self.session)
        while not self.intr.requested:
            self.session.time_left()  # raises at the session's time limit, if it has one
            if self.state.lost is not None and not self._reconnect():
                ended = self._wait(time.monotonic() + RECONNECT_EVERY)
                if ended is not None:
                    return self._end(ended)
                continue
            reading = _reading(self.session, self.items, time.monotonic() - self.start,
                               self.clock, self.start)
            if self.pending is not None:  # judged by this sample's requests
                ended = self._deliver(self.pending, followed=True, until=False)
                if ended is not None:
                    return ended
            if reading.lost is not None:
                self._lost(reading.lost)
                continue
            if self.state.samples == 0 and len(reading.errors) == len(self.items):
                # nothing readable at all: an error, not a watch of dashes
                raise TmclError(next(iter(reading.errors.values())))
            if doubt:  # what already waits, taken in (no exchange, no wait): the last
                try:  # read's own answer, if it was displaced
                    self.session.client.poll()
                except TransportError as exc:  # the cable pulled since this sample was read
                    self._lost(str(exc))
                    continue
            reading.settle(confirm=False)  # in doubt already: read again within the sample
            # --until on the values as read: an answer found in doubt later can only make it
            # false (not judged on), so a sample it does not end need not be judged now
            held = self.until is not None and self._until(reading.sample())
            last = held or self.count is not None and self.state.samples + 1 >= self.count
            if reading.judged or last or not doubt:
                ended = self._deliver(reading, confirm=True, until=held)
                if ended is not None:
                    return ended
            else:
                self.pending = reading
            # the next sample is due one interval after this one began; polling slower than
            # the interval starts the next at once, without a backlog of samples
            next_at = max(next_at + self.interval, time.monotonic())
            left = self.session.time_left()
            if left is not None:
                next_at = min(next_at, time.monotonic() + left)
            ended = self._wait(next_at)
            if ended is not None:
                return self._end(ended)
        return self._end("interrupt")

    def _deliver(self, reading: Reading, *, confirm: bool = False, followed: bool = False,
                 until: bool = False) -> str | None:
        """Judge a sample's answers, then show, log and emit it; "count", "until" or "pipe"
        if the watch ends with it. ``followed``: requests have gone out since (the next
        sample's): an answer found in doubt now is marked, not read again (too late).
        ``until``: whether --until held on the values as read (asked again if judging
        changed them)."""
        self.pending = None
        before = reading.reread
        reading.settle(confirm=confirm and self.state.lost is None, again=not followed,
                       followed=followed)
        sample = reading.sample()
        self.result.reread += reading.reread
        if sample.lost is not None:  # (while reading an answer in doubt again)
            self._lost(sample.lost)
            return None
        for name in sample.suspect:
            self.result.doubtful[name] = self.result.doubtful.get(name, 0) + 1
        self.state.add(sample)
        if self.sink is not None:
            self.sink.write(sample)
        if self.view is not None:
            self.view.update()
        else:
            obj: dict[str, object] = {"t": round(sample.t, 4), "values": sample.values}
            if not sample.together:  # (each value's own time, as the CSV gives it)
                obj["together"] = False
                obj["times"] = {n: round(v, 4) for n, v in sample.times.items()}
            if sample.suspect:
                obj["suspect"] = list(sample.suspect)
            try:
                self.emit(obj)
            except BrokenPipeError:
                return "pipe"
        if self.count is not None and self.state.samples >= self.count:
            return "count"
        if until and (reading.reread != before or sample.suspect):
            until = self._until(sample)
        if until:
            return "until"
        return None

    def _lost(self, reason: str) -> None:
        self.state.lost = reason
        if self.view is not None:
            self.view.update(force=True)
        else:
            self.session.out.err.print(f"watch: link lost: {reason}; reconnecting",
                                       style="tmcl.warn", markup=False)

    def _end(self, reason: str) -> str:
        stopped = False
        if reason == "interrupt":
            self._stop_all()  # Ctrl-C is the safety key here too
            stopped = True
        if self.pending is not None:  # shown too, judged first
            pending, self.pending = self.pending, None
            if self._deliver(pending, confirm=not stopped, followed=stopped,
                             until=False) == "pipe":
                return "pipe"
        return reason

    def _reconnect(self) -> bool:
        """One attempt to bring the lost link back (unless something else did); True when it
        is."""
        if not self.session.client.connected and self.session.reconnect() is not None:
            return False
        lost, self.state.lost = self.state.lost, None
        self.state.note = (f"{reconnected(self.session.client)} at "
                           f"{time.monotonic() - self.start:.1f} s (lost: {lost})")
        if self.view is None:
            self.session.out.err.print(f"watch: {self.state.note}", style="tmcl.note",
                                       markup=False)
        return True

    def _until(self, sample: Sample) -> bool:
        if any(n in sample.suspect for n in self.until.names()):
            return False  # (not judged on a value in doubt)
        values = {k: v for k, v in sample.values.items() if v is not None}
        try:
            return bool(self.until.evaluate(expr.SessionContext(self.session, extra=values)))
        except expr.ExprError as exc:
            raise ValidationError(f"--until: {exc}") from None

    def _wait(self, next_at: float) -> str | None:
        """Sleep until ``next_at`` in short slices, acting on keys and Ctrl-C meanwhile."""
        while True:
            left = next_at - time.monotonic()
            if left > 0 or self.keys.active:
                pressed = self.keys.wait(min(max(left, 0.0), 0.05))
                if pressed == "\x1b":  # Esc alone (not the start of an arrow key's sequence)
                    return "key"
                for key in pressed:  # several keys may arrive at once: act on each
                    if key == "\x03":  # Ctrl-C typed in raw mode: as the signal would be
                        self.intr.press()
                    elif key in STOP_KEYS:
                        self._stop_all()
                    elif key in QUIT_KEYS:
                        return "key"
            if self.intr.requested:
                return "interrupt"
            if time.monotonic() >= next_at:
                return None

    def _stop_all(self) -> None:
        """The shell's one stop (a lost link brought back first, program, motors, read
        back), said in the table's caption."""
        from .stop import ToNotes, stop_all

        said: list[str] = []
        report = stop_all(self.session.client, ToNotes(said.append), session=self.session)
        if report is not None:
            self.result.stops.append(report)
            if self.session.client.connected:
                self.state.lost = None  # (brought back for the stop)
        at = f"at {time.monotonic() - self.start:.1f} s"
        done = [s for s in said if not s.startswith("reconnected")]  # (what the stop did)
        first = done[0] if done else "stop"
        self.state.note = "; ".join([*[s for s in said if s not in done],
                                     f"{first} {at}", *done[1:]])
        if self.view is not None:
            self.view.update(force=True)
        else:
            self.session.out.err.print(f"watch: {self.state.note}", style="tmcl.warn",
                                       markup=False)


@command(".watch")
def cmd_watch(session: Session, args: str) -> None:
    items, interval, count, until, csv_path = parse_args(session, args)
    result = run_watch(session, items, interval=interval, count=count, until=until,
                       csv_path=csv_path)
    rate = result.samples / result.elapsed if result.elapsed > 0 else 0.0
    text = f"watch: {result.samples} samples in {result.elapsed:.1f} s ({rate:.1f}/s)"
    if result.reason == "interrupt":
        text += "; ended by Ctrl-C"
    elif result.reason == "until":
        text += f"; {until} became true"
    if csv_path is not None:
        text += f"; logged to {csv_path}"
    if result.reread:
        text += (f"; {result.reread} answer{'s' if result.reread != 1 else ''} in doubt "
                 "read again")
    if out_is_pipe(session):
        session.out.err.print(text, style="tmcl.note", markup=False)
    else:
        session.out.info(text)
    if result.doubtful:
        # not shown as values, but the run is no clean pass either (as a suspect answer)
        n = sum(result.doubtful.values())
        session.stats.suspects += n
        names = ", ".join(f"{k} {v}x" for k, v in result.doubtful.items())
        warning = (f"watch: {n} value{'s' if n != 1 else ''} in doubt, shown as ? and left "
                   f"out of min, max and rate ({names}): the line brought replies nothing "
                   "was waiting for, so those answers may have been another request's")
        if session.out.json:
            session.out.emit({"watch": ".watch", "suspect": True, "warning": warning})
        else:
            session.out.warn(f"warning: {warning}")
    if result.stops and result.reason == "interrupt":  # Ctrl-C's stop, said below the table
        from .stop import say_report

        say_report(session.out, result.stops[-1], "watch")
    if result.reason == "pipe":  # the run's reader has gone: the run ends as on any line
        raise BrokenPipeError(errno.EPIPE, "the output's reader went away")
    if result.reason == "interrupt" and not session.interactive:
        # at the prompt Ctrl-C ends the watch and the prompt comes back; in -c/-f it ends
        # the run as on any other line: the next line would set the motors moving again
        raise KeyboardInterrupt


def out_is_pipe(session: Session) -> bool:
    """Samples went to stdout as JSON: keep status text on stderr."""
    return session.out.json or not session.out.is_terminal
