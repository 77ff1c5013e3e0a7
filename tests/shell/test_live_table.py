"""The live table never sets the traffic's pace: a terminal that stops reading loses
redraws and lines (counted), while what the readers give the table still goes in at once
and is counted; the table as it ends reaches the terminal once it reads again."""

from __future__ import annotations

import re
import threading

from conftest import patience
from responder import reply
from tmclsh.base.spill import SpillWriter
from tmclsh.ops.monitor import RX, TX, Monitor, SerialPair
from tmclsh.shell.features.livetable import LINES, LiveTable
from tmclsh.shell.render import Styled


def request(addr: int, cmd: int, typ: int = 0, motor: int = 0, value: int = 0) -> bytes:
    body = bytes([addr, cmd, typ, motor]) + (value & 0xFFFFFFFF).to_bytes(4, "big")
    return body + bytes([sum(body) & 0xFF])


class StuckTerminal:
    """A terminal whose reader stopped (a paused screen, ``Ctrl-S``) until ``go``."""

    def __init__(self) -> None:
        self.reading = threading.Event()
        self.got: list[str] = []

    def write(self, text: str) -> int:
        self.reading.wait()
        self.got.append(text)
        return len(text)

    def flush(self) -> None:
        pass


def test_a_terminal_that_stops_reading_loses_lines_counted_never_the_traffic():
    term = StuckTerminal()
    out = SpillWriter(term)
    monitor = Monitor()
    pair = SerialPair(monitor)
    table = LiveTable(monitor, out, refresh=0.005)
    table.start()
    n = 3 * LINES
    fed = threading.Event()

    def traffic() -> None:
        for i in range(n):
            t = 1000.0 + i * 0.001
            for item in pair.feed(TX, request(1, 6, 4), t) + pair.feed(RX, reply(6, i), t):
                table.take(item)
            table.line(Styled(f"line {i:05d}"))
        fed.set()

    thread = threading.Thread(target=traffic, daemon=True)
    thread.start()
    assert fed.wait(patience(60)), "the table held up the traffic while nobody read"
    assert table.dropped > 0
    term.reading.set()
    table.stop()
    out.close()
    text = "".join(term.got)
    shown = len(set(re.findall(r"line \d{5}", text)))
    assert shown + table.dropped == n and out.dropped == 0
    last = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", text.rsplit("exchanges", 1)[1])
    assert re.search(rf"│\s*{n} │", last)  # the table as it ended: every exchange counted
    assert f"GAP 4, 0 = {n - 1}" in last  # (no module known: the command that reads it)


class Terminal:
    """A terminal that takes everything at once."""

    def __init__(self) -> None:
        self.got: list[str] = []

    def write(self, text: str) -> int:
        self.got.append(text)
        return len(text)

    def flush(self) -> None:
        pass


def test_the_table_follows_traffic_that_never_pauses():
    """Each redraw that had lines to show printed them under the table as it was when it
    started: with traffic that never paused (a master polling every 50 ms) the table read
    "(no exchange yet)" until Ctrl-C. Every redraw draws the counts as they are."""
    term = Terminal()
    monitor = Monitor()
    pair = SerialPair(monitor)
    table = LiveTable(monitor, term, clock=None, refresh=0.0)
    table.start()
    for i in range(3):
        t = 1000.0 + i * 0.05
        for item in pair.feed(TX, request(1, 6, 1), t) + pair.feed(RX, reply(6, i), t):
            table.take(item)
        table.line(Styled(f"line {i}"))
        mark = len(term.got)
        table.tick()  # (a redraw with a line to show, as every one is while traffic flows)
        drawn = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", "".join(term.got[mark:]))
        assert f"line {i}" in drawn
        assert "(no exchange yet)" not in drawn, drawn
        assert re.search(rf"│@1\s*│\s*{i + 1} │", drawn), drawn
    table.stop()
