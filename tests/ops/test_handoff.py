"""The hand-off between a bridge's forwarding and its describing (ops/handoff.py): every event
comes out as it went in, whatever the pipe's reads cut; a full pipe never makes the
forwarding wait; the describer, in its own process, outlives whatever ends the bridge's."""

from __future__ import annotations

import os
import threading
import time

import pytest
from conftest import patience
from hypothesis import given, settings
from hypothesis import strategies as st

from tmclsh.link.base import CanFrame
from tmclsh.ops.handoff import (BEHIND, CAN_RX, CAN_TX, CAPTURE, DONE, END, FINISH, LEFT, LOST,
                                NOISE,
                                PIPE_BUF, RX, START, TX, Describer, LocalPipe, Pipe, Unpacker,
                                pack)

times = st.floats(min_value=0, max_value=4e9, allow_nan=False)
serial_events = st.tuples(st.sampled_from([TX, RX, NOISE]), st.binary(max_size=3 * PIPE_BUF),
                          times)
can_events = st.builds(lambda k, t, i, d, e, r, m: (k, CanFrame(t, i, d, e, r, m)),
                       st.sampled_from([CAN_TX, CAN_RX]), times,
                       st.integers(0, (1 << 29) - 1), st.binary(max_size=8), st.booleans(),
                       st.booleans(), st.booleans())
words = st.one_of(st.just((START,)), st.just((END,)), st.just((DONE,)),
                  st.builds(lambda n: (FINISH, n), st.integers(0, 10**9)),
                  st.builds(lambda s: (LOST, s), st.text(max_size=200)),
                  st.builds(lambda a: (LEFT, {"started": a, "download": [], "ascii": a}),
                            st.lists(st.integers(0, 255), max_size=5)))
events = st.one_of(serial_events, can_events, words,
                   st.builds(lambda e: (CAPTURE, e), st.one_of(serial_events, can_events)))


@settings(max_examples=200, deadline=None)
@given(st.lists(events, max_size=30), st.data())
def test_every_event_comes_out_as_it_went_in_whatever_the_reads_cut(evs, data):
    blob = b"".join(r for e in evs for r in pack(e))
    assert all(len(r) <= PIPE_BUF for e in evs for r in pack(e))  # (each written whole)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(blob)), max_size=8)))
    unpacker, got = Unpacker(), []
    for a, b in zip([0, *cuts], [*cuts, len(blob)]):
        got += unpacker.feed(blob[a:b])
    # a long chunk comes out as consecutive pieces of the same kind and time
    it = iter(got)
    for e in evs:
        n = len(pack(e))
        pieces = [next(it) for _ in range(n)]
        inner = e[1] if e[0] == CAPTURE else e
        if inner[0] in (TX, RX, NOISE):
            body = [p[1] if e[0] != CAPTURE else p[1][1] for p in pieces]
            assert b"".join(body) == inner[1]
            assert all((p if e[0] != CAPTURE else p[1])[2] == inner[2] for p in pieces)
        else:
            assert pieces == [e]
    assert next(it, None) is None


def test_a_full_pipe_takes_nothing_more_and_never_waits():
    pipe = Pipe()
    chunk = (TX, bytes(range(9)), 1.0)
    counts: list[int] = []

    def fill() -> None:
        put = 0
        while pipe.put(chunk):
            put += 1
        for _ in range(1000):
            assert pipe.put(chunk) is False  # (nobody reads: refused, not waited for)
        counts.append(put)

    filler = threading.Thread(target=fill, daemon=True)
    filler.start()
    filler.join(60)
    assert not filler.is_alive(), "a put waited for a reader"
    (put,) = counts
    assert pipe.dropped == 1001
    # beyond the pipe's own room, BEHIND bytes waited in this process
    assert put * (9 + 11) >= BEHIND
    # what went in comes out whole and in order, and after that the pipe takes again
    got = []
    while True:
        pipe.catch_up()
        more = pipe.take(0)
        if not more:
            break
        got += more
    assert len(got) == put and all(e == chunk for e in got)
    assert pipe.waiting == 0
    assert pipe.put((RX, b"\x02", 2.0)) and pipe.take(1) == [(RX, b"\x02", 2.0)]
    pipe.close()


def test_the_in_process_pipe_is_bounded_as_a_pipe_is():
    pipe = LocalPipe(bound=1000)
    while pipe.put((TX, bytes(9), 1.0)):
        pass
    assert pipe.dropped == 1
    assert sum(len(r) for e in pipe.take(0) for r in pack(e)) <= 1000
    pipe.close()
    assert pipe.take(0) is None


@pytest.mark.parametrize("fork", [True, False], ids=["process", "thread"])
def test_the_describer_runs_in_its_own_process_and_answers(tmp_path, fork):
    """Forked where there is ``fork``; on a thread of the bridge's process where there is
    not (Windows), with the same records."""
    seen = tmp_path / "seen"

    def run(notes, back):
        got = []
        while (more := notes.take(5)) is not None:
            for e in more:
                if e[0] == END:
                    back.send((LEFT, {"pid": os.getpid(), "n": len(got)}))
                elif e[0] == FINISH:
                    seen.write_text(repr(got))
                    return
                else:
                    got.append(e)

    d = Describer(run, fork=fork)
    d.start()
    for i in range(100):
        assert d.notes.put((TX, bytes([i]), float(i)))
    assert d.notes.send((END,))
    said = d.wait_for(LEFT, 20)
    assert said is not None and said[1]["n"] == 100
    assert (said[1]["pid"] != os.getpid()) == fork
    d.notes.send((FINISH, 0))
    assert d.join(20)
    assert seen.read_text() == repr([(TX, bytes([i]), float(i)) for i in range(100)])


def test_the_describer_ends_when_the_bridge_has_gone(tmp_path):
    """The bridge's side closed without a word (its process killed): the describer sees the
    end of its notes and finishes on its own (no process left behind)."""
    seen = tmp_path / "seen"

    def run(notes, back):
        n = 0
        while (more := notes.take(5)) is not None:
            n += len(more)
        seen.write_text(str(n))

    d = Describer(run)
    d.start()
    d.notes.put((RX, b"x", 0.0))
    d.notes.close()
    assert d.join(20)
    assert seen.read_text() == "1"


def test_while_traffic_flows_the_reader_waits_on_nothing_a_put_would_wake(monkeypatch):
    """A reader waiting on the pipe is woken by each put, and the wake-up is the putter's
    cost (the forwarding's, a chunk at a time): while what it reads keeps coming, the
    reader reads in its rhythm instead, and waits on the pipe again only once nothing has
    come for ``quiet`` seconds."""
    import select as select_module

    pipe = Pipe(rhythm=0.001, quiet=0.05)
    waits: list[float] = []
    real = select_module.select

    def counted(r, w, x, timeout=None):
        if pipe._r in r:
            waits.append(time.monotonic())
        return real(r, w, x, timeout)

    monkeypatch.setattr(select_module, "select", counted)
    assert pipe.put((TX, b"\x01", 1.0))
    assert pipe.take(5) == [(TX, b"\x01", 1.0)]
    assert len(waits) == 1  # (nothing was coming: it waited)
    for i in range(2, 40):
        assert pipe.put((RX if i % 2 else TX, bytes([i]), float(i)))
        last = time.monotonic()
        assert pipe.take(5) == [(RX if i % 2 else TX, bytes([i]), float(i))]
    assert len(waits) == 1  # (it came on: read in the rhythm, no wait on the pipe)
    deadline = time.monotonic() + 20
    while len(waits) == 1:
        assert pipe.take(0) == []
        assert time.monotonic() < deadline
    assert waits[1] - last >= 0.05  # (waiting on the pipe again once it was quiet)
    assert pipe.put((TX, b"\x02", 2.0)) and pipe.take(5) == [(TX, b"\x02", 2.0)]
    pipe.close()
    assert pipe.take(0) is None


def test_a_reader_behind_reads_on_without_its_pause():
    """A read that found the pipe full is followed by the next at once, not after the
    rhythm's pause: what waited comes out whole and in order."""
    pipe = Pipe(rhythm=30.0)  # (a pause a test would notice)
    chunk = (TX, bytes(range(9)), 1.0)
    put = 0
    while pipe.waiting == 0:
        assert pipe.put(chunk)
        put += 1
    got: list[tuple] = []
    deadline = time.monotonic() + 20
    while len(got) < put:
        assert time.monotonic() < deadline, "a read behind paused"
        got += pipe.take(5)
        pipe.catch_up()
    assert got == [chunk] * put
    pipe.close()


def _woken(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        return int(next(line for line in fh if line.startswith("voluntary_ctxt_switches"))
                   .split()[1])


@pytest.mark.skipif(not os.path.exists(f"/proc/{os.getpid()}/status"),
                    reason="counts the describer's wake-ups in /proc")
def test_the_describer_wakes_in_its_rhythm_not_at_every_chunk():
    """Chunks put a tenth of its rhythm apart: the describing process is woken about once a
    rhythm (its reads), not once a chunk (a wake-up the forwarding pays for). The bound
    follows the time the puts took, so a busy machine only loosens it."""
    rhythm = 0.002

    def run(notes, back):
        while (more := notes.take(5)) is not None:
            if any(e[0] == FINISH for e in more):
                return

    d = Describer(run, rhythm=rhythm)
    d.start()
    pid = d._pid
    assert pid is not None
    d.notes.put((TX, b"\x00", 0.0))
    n = 1000
    before, start = _woken(pid), time.monotonic()
    for i in range(n):
        t = time.perf_counter() + rhythm / 10
        assert d.notes.put((TX if i % 2 else RX, bytes(9), float(i)))
        while time.perf_counter() < t:
            pass
    took = time.monotonic() - start
    woken = _woken(pid) - before
    d.notes.send((FINISH, 0))
    assert d.join(patience(20))
    # a read a rhythm, and once the puts paused longer than that a wait on the pipe and
    # another read: at most two wake-ups a rhythm's time, against one a chunk
    assert woken <= 2 * took / rhythm + 5, (woken, took)


def test_the_describer_stops_giving_way_to_work_that_does_not_end(monkeypatch):
    """A yield that brought the core back within a moment gave it to something woken for
    the traffic: the describer gives way at each chunk. A yield that took long gave it to
    work that never ends (a busy machine): yielding at each chunk would starve the
    describer behind the wire, so it describes on without giving way for a while."""
    from tmclsh.ops import handoff

    clock = [100.0]
    yields: list[float] = []

    def yield_(cost: float) -> None:
        yields.append(clock[0])
        clock[0] += cost

    monkeypatch.setattr(handoff, "_clock", lambda: clock[0])
    monkeypatch.setattr(handoff, "_resume", 0.0)
    monkeypatch.setattr(handoff, "_yield", lambda: yield_(0.00002))  # (a forwarding hop)
    for _ in range(5):
        handoff.give_way()
        clock[0] += 0.00003
    assert len(yields) == 5
    monkeypatch.setattr(handoff, "_yield", lambda: yield_(0.004))  # (a busy loop's slice)
    handoff.give_way()
    assert len(yields) == 6
    for _ in range(100):  # (within HOGGED_FOR: no more yields)
        clock[0] += 0.0005
        handoff.give_way()
    assert len(yields) == 6
    clock[0] += handoff.HOGGED_FOR
    monkeypatch.setattr(handoff, "_yield", lambda: yield_(0.00002))
    handoff.give_way()
    handoff.give_way()
    assert len(yields) == 8  # (tried again, and the core came back at once: giving way)
