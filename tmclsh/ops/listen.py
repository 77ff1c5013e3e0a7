"""Where a monitor listens: a CAN bus, a serial tap, a python-can log, a serial capture.

Each source reads its wire or file and hands what it reads to a reader of ops/monitor.py,
yielding what that returns, a list of items per step (empty when nothing came within
``tick``, so the caller gets to check its count, duration and Ctrl-C at least that often).
``capture``: every frame or chunk is also written there as it was heard, before it is
read. Nothing here prints, and nothing is ever sent.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from ..link.base import CanFrame, CanTransport, StreamTransport
from .capture import read_capture
from .monitor import CanReader, Item, Monitor, SerialPair, SerialTap

TICK = 0.1  # s a source waits for the wire before it hands back control
QUIET = 0.1  # s of silence after which bytes that are no frame yet are a partial frame


def quiet_time(baud: int | None) -> float:
    """How long a serial line must be silent before a partial frame is called one: twenty
    characters' time at its baud rate, at least ``QUIET`` (USB adapters deliver in bursts)."""
    return max(QUIET, 200 / baud) if baud else QUIET


def can_bus(transport: CanTransport, reader: CanReader, *,
            capture: Callable[[CanFrame], None] | None = None,
            tick: float = TICK) -> Iterator[list[Item]]:
    """Every frame on a live bus (``transport``: a python-can link, opened)."""
    listen = transport.listen  # type: ignore[attr-defined]
    while True:
        f = listen(tick)
        if f is None:
            yield reader.quiet(time.time())
            continue
        if capture is not None:
            capture(f)
        yield reader.feed(f.t, f.arbitration_id, f.data, extended=f.extended, error=f.error,
                          remote=f.remote)


def can_log(frames: Iterator[CanFrame], reader: CanReader, *,
            capture: Callable[[CanFrame], None] | None = None) -> Iterator[list[Item]]:
    """Every frame of a log (``link.canlog.read_log``), at the log's own times; at its end
    the requests still waiting are unanswered."""
    feed = reader.feed
    t = 0.0
    for f in frames:
        t = f.t
        if capture is not None:
            capture(f)
        yield feed(t, f.arbitration_id, f.data, extended=f.extended, error=f.error,
                   remote=f.remote)
    yield reader.end(t)


def serial_tap(transport: StreamTransport, tap: SerialTap, *, quiet: float = QUIET,
               capture: Callable[[float, bytes], None] | None = None
               ) -> Iterator[list[Item]]:
    """Every byte a serial line carries (``transport``: opened, only ever read)."""
    settled = True
    read = transport.read_some
    while True:
        data = read(quiet)
        now = time.time()
        if not data:
            yield tap.monitor.expire(now) if settled else tap.quiet(now)
            settled = True
            continue
        if capture is not None:
            capture(now, data)
        settled = False
        yield tap.feed(data, now)


def serial_capture(path: str | Path, monitor: Monitor, *,
                   quiet: float = QUIET) -> Iterator[list[Item]]:
    """A capture file (ops/capture.py) read again: a tap's chunks, or a bridge's two
    directions; a silence longer than ``quiet`` between chunks is a silence on the line."""
    return serial_chunks(read_capture(path), monitor, quiet=quiet)


def serial_chunks(chunks: Iterable[tuple[float, str | None, bytes]], monitor: Monitor, *,
                  quiet: float = QUIET) -> Iterator[list[Item]]:
    """Chunks of a serial line as ``(time, tx/rx or None, bytes)``, however they were kept
    (a capture file, a transcript's frames), read as a capture is."""
    tap: SerialTap | None = None
    pair: SerialPair | None = None
    last: float | None = None
    for t, direction, data in chunks:
        if last is not None and t - last > quiet:
            if tap is not None:
                yield tap.quiet(last + quiet)
            if pair is not None:
                yield pair.quiet(last + quiet)
        last = t
        if direction is None:
            tap = tap or SerialTap(monitor)
            yield tap.feed(data, t)
        else:
            pair = pair or SerialPair(monitor)
            yield pair.feed(direction, data, t)
    end = (last or 0.0) + quiet
    yield (tap.end(end) if tap is not None else []) + (pair.end(end) if pair is not None
                                                       else monitor.finish())
