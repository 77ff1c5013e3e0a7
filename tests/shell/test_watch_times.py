"""``.watch --csv`` times (issue 23, section 3): each value's time is the time it was read,
and a row's values were read together or the row says it is not. Against the simulator on a
pty with its random faults (dropped replies, so reads are retried; replies held back), an axis
turning at a constant speed is the witness: the position read at a time must be where the
axis was then, so two positions and their times give back the speed."""

from __future__ import annotations

import csv
import random
from datetime import datetime

import pytest

from tmclsh.client.text import LineClient
from tmclsh.link import open_serial
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session
from tmclsh.sim import output

SPEED = 20000  # pps
# steps: 0.2 s of motion, for the scheduling of a busy machine between a request's time and
# the module's reading (30 ms seen under load 12); a retried read carrying its first
# attempt's time, the fault this catches, is 0.5 s = 10000 steps off
SLACK = 4000


@pytest.fixture
def faulty(make_pty_sim, monkeypatch):
    """A session on a turning TMCM-1311 whose replies are then dropped (10 %) or held back
    0.1..0.35 s (10 %), seeded; the client's timeout 0.5 s, so a dropped reply is a retry."""
    monkeypatch.setattr(output, "RANDOM_DELAY", (0.1, 0.35))
    sim, path = make_pty_sim()
    client = LineClient(open_serial(path), module="TMCM-1311", timeout=0.5, retries=3)
    session = Session(client, Output(), yes=True)
    session.run_line("SAP 5, 0, 2000000")
    session.run_line(f"ROR 0, {SPEED}")
    session.run_line(f".wait GAP 3, 0 == {SPEED} --timeout 5")
    sim.faults.rng = random.Random(2301)
    sim.faults.rates = {"drop": 0.1, "delay": 0.1}
    yield session, sim
    sim.faults.rates = {}
    session.run_line("MST 0")
    client.close()


def test_each_value_carries_the_time_it_was_read(faulty, tmp_path):
    session, sim = faulty
    log = tmp_path / "w.csv"
    # a and b read the same position through two different reads (not sent once as one)
    session.run_line(f".watch a=GAP 1, 0; speed=GAP 3, 0; b=GAP ActualPosition, 0 "
                     f"--count 24 --interval 0.05 --csv {log}")
    assert session.client.stats["retries"] >= 1  # the faults hit: reads were retried
    with open(log, newline="") as fh:
        header, *rows = list(csv.reader(fh))
    assert header == ["time", "t", "a", "speed", "b", "together", "t(a)", "t(speed)", "t(b)"]
    assert len(rows) == 24
    row = [dict(zip(header, r)) for r in rows]
    positions = []  # (time read, position) of every position read
    for r in row:
        # the row's clock time is its t (its first read), never the time it was written
        assert r["t"] == min((r[c] for c in ("t(a)", "t(speed)", "t(b)") if r[c]), key=float)
        for name in ("a", "b"):
            if r[name] not in ("", "?"):
                positions.append((float(r[f"t({name})"]), int(r[name])))
        times = [float(r[c]) for c in ("t(a)", "t(speed)", "t(b)") if r[c]]
        if r["together"] == "yes":
            assert max(times) - min(times) < 0.1
    wall = [datetime.fromisoformat(r["time"]).timestamp() for r in row]
    for r, w in zip(row, wall):
        assert abs((w - wall[0]) - (float(r["t"]) - float(row[0]["t"]))) < 0.002
    # within rows and across them: every two positions and their times give back the speed
    # (a retried read carrying its first attempt's time would be 0.5 s = 10000 steps off)
    positions.sort()
    assert len(positions) >= 40
    worst = 0.0
    for (t0, p0), (t1, p1) in zip(positions, positions[1:]):
        expected = SPEED * (t1 - t0)
        worst = max(worst, abs((p1 - p0) - expected) - 0.02 * expected)
    assert worst <= SLACK, f"a position is {worst:.0f} steps off the time it carries"
    t0, p0 = positions[0]
    for t1, p1 in positions[1:]:  # and against the first one, over the whole run
        expected = SPEED * (t1 - t0)
        assert abs((p1 - p0) - expected) <= 0.02 * expected + SLACK


def test_plot_of_a_watch_log_draws_the_values_not_their_times(client, tmp_path):
    from tmclsh.shell.features import plot

    s = Session(client, Output())
    log = tmp_path / "run.csv"
    s.run_line("ROR 0, 100000")
    s.run_line(f".watch pos=GAP 1, 0; in0=GIO 0, 0 --count 3 --interval 0.01 --csv {log}")
    got = plot.read_csv(log)
    assert got.names == ["pos", "in0"] and len(got.t) == 3
