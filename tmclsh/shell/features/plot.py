"""``.plot``: a one-shot chart of a logged CSV or of the last watch, drawn with braille dots.

Pure parts: ``braille(xs, ys, width, height)`` gives the chart's text rows, ``render(log)``
the rich renderable; nothing here talks to the module.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ...base import files
from ...base.errors import ValidationError
from ..lang import expr, options
from ..lang.commands import command, options_of

if TYPE_CHECKING:
    from ..lang.session import Session

Number = int | float

# braille cell: dot (column, row) -> bit; rows 0..3 top to bottom, columns 0..1
_DOTS = ((0x01, 0x08), (0x02, 0x10), (0x04, 0x20), (0x40, 0x80))
_BRAILLE = 0x2800


@dataclass
class Log:
    """Samples: a time axis and one value list per name (None where a sample failed)."""

    names: list[str]
    t: list[float] = field(default_factory=list)
    values: dict[str, list[Number | None]] = field(default_factory=dict)
    source: str = "last watch"

    def __post_init__(self) -> None:
        for n in self.names:
            self.values.setdefault(n, [])

    def add(self, t: float, sample: dict[str, Number | None]) -> None:
        self.t.append(t)
        for n in self.names:
            self.values[n].append(sample.get(n))


def braille(xs: Sequence[float], ys: Sequence[Number | None], width: int, height: int,
            y_range: tuple[float, float] | None = None) -> list[str]:
    """Rows of braille characters (``width`` cells wide, ``height`` rows) showing ys over xs.

    Consecutive points are joined by a vertical run in each column, so steps stay visible.
    """
    if width < 1 or height < 1:
        raise ValueError("width and height must be positive")
    cols, rows = width * 2, height * 4
    grid = [[0] * width for _ in range(height)]
    pts = [(x, y) for x, y in zip(xs, ys) if y is not None and math.isfinite(y)]
    if not pts:
        return ["".join(chr(_BRAILLE) for _ in range(width)) for _ in range(height)]
    x0, x1 = min(p[0] for p in pts), max(p[0] for p in pts)
    y0, y1 = y_range if y_range is not None else (min(p[1] for p in pts), max(p[1] for p in pts))

    def px(x: float) -> int:
        return 0 if x1 == x0 else round((x - x0) / (x1 - x0) * (cols - 1))

    def py(y: float) -> int:  # 0 = top row
        if y1 == y0:
            return rows // 2
        return (rows - 1) - round((min(max(y, y0), y1) - y0) / (y1 - y0) * (rows - 1))

    def dot(c: int, r: int) -> None:
        grid[r // 4][c // 2] |= _DOTS[r % 4][c % 2]

    prev: tuple[int, int] | None = None
    for x, y in pts:
        c, r = px(x), py(y)
        if prev is not None and abs(c - prev[0]) <= 1:
            lo, hi = sorted((prev[1], r))
            for rr in range(lo, hi + 1):
                dot(c, rr)
        elif prev is not None:  # a gap in x: draw the straight line between the points
            (pc, pr), steps = prev, c - prev[0]
            for k in range(1, steps + 1):
                dot(pc + k, round(pr + (r - pr) * k / steps))
        dot(c, r)
        prev = (c, r)
    return ["".join(chr(_BRAILLE | cell) for cell in row) for row in grid]


def _num(value: Number) -> str:
    return expr.format_number(value) if isinstance(value, int) or abs(value) >= 1e-3 or \
        value == 0 else f"{value:.3g}"


def render(log: Log, width: int = 60, height: int = 8, names: Sequence[str] | None = None):
    """One panel per series: braille chart, y range on the left, time range below."""
    from rich.console import Group
    from rich.panel import Panel
    from rich.text import Text

    panels = []
    chosen = list(names) if names else log.names
    for name in chosen:
        ys = log.values.get(name)
        if ys is None:
            raise ValidationError(f"no series {name!r} (have: {', '.join(log.names)})")
        good = [y for y in ys if y is not None]
        if not good:
            panels.append(Panel(Text("no values", style="tmcl.note"), title=Text(name),
                                title_align="left"))
            continue
        lo, hi = min(good), max(good)
        top, bottom = _num(hi), _num(lo)
        pad = max(len(top), len(bottom))
        rows = braille(log.t, ys, width, height)
        body = Text()
        for i, row in enumerate(rows):
            label = top if i == 0 else bottom if i == len(rows) - 1 else ""
            body.append(f"{label:>{pad}} {'┤' if label else '│'}", style="tmcl.note")
            body.append(row, style="tmcl.value")
            body.append("\n")
        t0, t1 = (log.t[0], log.t[-1]) if log.t else (0.0, 0.0)
        left, right = f"{t0:.1f} s", f"{t1:.1f} s"
        body.append(" " * (pad + 2) + left + right.rjust(width - len(left)), style="tmcl.note")
        panels.append(Panel(body, title=Text(f"{name}  ({len(good)} samples)"), title_align="left",
                            expand=False))
    return Group(*panels)


def _time_of(column: str, header: Sequence[str]) -> bool:
    return column.startswith("t(") and column.endswith(")") and column[2:-1] in header


def read_csv(path: Path) -> Log:
    """A CSV with a ``t`` column (seconds; else the first numeric column) and value columns."""
    if not path.exists():
        raise ValidationError(f"no such file: {path}")
    text = files.read_text(path, what="CSV file")  # bounded: not /dev/zero to the end
    try:
        rows = list(csv.reader(io.StringIO(text, newline="")))
    except csv.Error as exc:
        raise ValidationError(f"{path}: not a CSV file ({exc})") from None
    if len(rows) < 2:
        raise ValidationError(f"{path}: no samples (a header and at least one row needed)")
    header = [h.strip() for h in rows[0]]

    def num(text: str) -> Number | None:
        text = text.strip()
        if not text:
            return None
        try:
            return int(text)
        except ValueError:
            try:
                return float(text)
            except ValueError:
                return None

    numeric = [i for i, _ in enumerate(header)
               if any(num(r[i]) is not None for r in rows[1:] if i < len(r))]
    if "t" in header:
        xi = header.index("t")
    elif numeric:
        xi = numeric[0]
    else:
        raise ValidationError(f"{path}: no numeric column")
    # (a watch's log: "t(pos)" is when pos was read, a time, not a series of its own)
    cols = [i for i in numeric if i != xi and not _time_of(header[i], header)]
    if not cols:
        raise ValidationError(f"{path}: no value columns besides {header[xi]!r}")
    log = Log([header[i] for i in cols], source=str(path))
    for r in rows[1:]:
        x = num(r[xi]) if xi < len(r) else None
        if x is None:
            continue
        log.add(float(x), {header[i]: (num(r[i]) if i < len(r) else None) for i in cols})
    return log




@command(".plot")
def cmd_plot(session: Session, args: str) -> None:
    rest, opts = options.parse(args, options_of(".plot"))
    width = options.int_value(opts, "--width", max(20, min(100, session.out.console.width - 14)),
                            minimum=10, limit="plot_size")
    height = options.int_value(opts, "--height", 6, minimum=2, limit="plot_size")
    if rest:
        log = read_csv(Path(rest.strip("\"'")).expanduser())
    else:
        last = session.state.watch_log
        if not isinstance(last, Log) or not last.t:
            raise ValidationError("nothing to plot: run .watch first, or give a CSV file")
        log = last
    only = [n.strip() for n in str(opts["--only"]).split(",")] if "--only" in opts else None
    assert width is not None and height is not None
    renderable = render(log, width, height, only)
    if session.out.json:
        session.out.info(".plot draws for people; under --json it prints nothing on stdout")
        return
    session.out.print(renderable)
