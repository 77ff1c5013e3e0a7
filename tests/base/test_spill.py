"""A hand-off that never makes its giver wait (base/spill.py): what a bridge and a live
monitor show, and a live -o file, go through one, so a reader that stops reading or a slow
disk costs counted lines, never the wire's pace."""

from __future__ import annotations

import threading
import time

from tmclsh.base.spill import Spill, SpillWriter


class Stuck:
    """A stream whose reader stopped reading: every write blocks until ``go`` is set."""

    def __init__(self) -> None:
        self.go = threading.Event()
        self.got: list[str] = []

    def write(self, text: str) -> int:
        self.go.wait(60)
        self.got.append(text)
        return len(text)

    def flush(self) -> None:
        pass


def test_writes_to_a_stream_nobody_reads_return_at_once_and_are_counted():
    stream = Stuck()
    out = SpillWriter(stream, bound=100)
    start = time.monotonic()
    for i in range(1000):
        out.write(f"line {i}\n")
    assert time.monotonic() - start < 5  # (generous: a blocked write would take 60 s)
    stream.go.set()  # the reader reads again: what was kept reaches it, in order
    dropped = out.close(timeout=30)
    assert len(stream.got) + dropped == 1000 and dropped >= 1000 - 101
    assert stream.got == sorted(stream.got, key=lambda line: int(line.split()[1]))
    assert stream.got[0] == "line 0\n"


def test_a_slow_taker_loses_the_newest_counted_and_keeps_the_order():
    taken: list[int] = []
    release = threading.Event()

    def slow(n: int) -> None:
        release.wait(60)
        taken.append(n)

    spill = Spill(slow, bound=10, poll=0.001)
    put = [spill.put(n) for n in range(50)]
    release.set()
    assert spill.close() == put.count(False) >= 39
    assert taken == [n for n, kept in zip(range(50), put) if kept]
