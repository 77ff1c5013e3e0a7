"""Captures of a serial line: the bytes as they were read, with their times, as text lines
that ``tmclsh monitor --log`` replays (CAN captures are python-can logs: link/canlog.py).

    # tmclsh capture of a serial line: time (s since the epoch), tx/rx where the link tells, bytes in hex
    1718000000.123456 01 06 04 00 00 00 00 00 0b
    1718000000.124101 rx 02 01 64 06 00 00 03 e8 58

A tap on a bus hears both directions at once and writes no direction; a bridge writes ``tx``
(from the master to the module) and ``rx`` (back). Lines starting with ``#`` are comments.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path

from ..base.errors import ValidationError
from ..base.files import AtomicWriter, FileError, stream_lines

HEADER = ("# tmclsh capture of a serial line: time (s since the epoch), tx/rx where the link "
          "tells, bytes in hex\n")
DIRECTIONS = ("tx", "rx")
FLUSH = 0.5  # s between pushes of what is written to the disk (a full disk shows early)


class CaptureWriter:
    """Chunks of bytes written as they come; the file replaces ``path`` when closed (an
    interrupted run keeps what it heard: ``close`` is called on the way out)."""

    def __init__(self, path: str | Path):
        self.path = path
        self._out = AtomicWriter(path)
        self._out.write(HEADER)
        self._flushed = time.monotonic()

    def write(self, t: float, data: bytes, direction: str | None = None) -> None:
        where = f" {direction}" if direction else ""
        self._out.write(f"{t:.6f}{where} {data.hex(' ')}\n")
        now = time.monotonic()
        if now - self._flushed > FLUSH:
            self._out.flush()
            self._flushed = now

    def flush(self) -> None:
        self._out.flush()
        self._flushed = time.monotonic()

    def close(self) -> None:
        self._out.commit()


def read_capture(path: str | Path) -> Iterator[tuple[float, str | None, bytes]]:
    """``(time, direction or None, bytes)`` for every line of a capture file."""
    try:
        fh = open(path, encoding="utf-8", errors="strict")
    except OSError as exc:
        raise FileError(f"cannot read {path}: {exc.strerror or exc}") from None
    with fh:
        no = seen = 0
        for no, line in enumerate(stream_lines(fh, str(path)), 1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            words = text.split()
            try:
                t = float(words[0])
                direction = words[1] if len(words) > 1 and words[1] in DIRECTIONS else None
                data = bytes.fromhex("".join(words[2 if direction else 1:]))
            except ValueError:
                raise ValidationError(
                    f"{path}:{no}: not a line of a serial capture (time, then bytes in hex) "
                    "nor a CAN log python-can reads (named .asc, .blf, .trc, .log, .csv, ...)"
                ) from None
            if not math.isfinite(t):
                raise ValidationError(f"{path}:{no}: the time {words[0][:40]!r} is not seconds")
            seen += 1
            yield t, direction, data
    if not seen:
        raise ValidationError(f"{path}: no captured bytes in it (no line of a time and "
                              "bytes in hex)")
