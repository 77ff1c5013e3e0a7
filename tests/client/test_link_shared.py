"""Two modules at one address are found by the client itself (issue 31, "Safe on a shared
line"): every request brings two replies from there. A line that copies a reply now and then
(the simulator's ``dup`` and ``dup-late`` faults) is no such finding.

The two modules are ``tests/responder.py``'s (written from the manual, no tmclsh inside):
back to back, and with the second one slower to answer; the faulty line is the simulator's."""

from __future__ import annotations

import random
import time

import pytest
from conftest import patience

from tmclsh.base.errors import TmclError
from tmclsh.client.core import Client
from tmclsh.client.ledger import SHARED_AFTER, Doubles
from tmclsh.link import open_serial
from tmclsh.tmcl.frames import Request

from responder import TwoAtOneAddress

GAP, SGP = 6, 9


@pytest.fixture
def two(request):
    made = []

    def make(**kw) -> tuple[Client, TwoAtOneAddress]:
        m = TwoAtOneAddress(**kw)
        c = Client(open_serial(m.path), timeout=0.5)
        made.append((c, m))
        return c, m
    yield make
    for c, m in made:
        c.close()
        m.close()


def _settle(c: Client, m: TwoAtOneAddress | None = None, replies: int = 0) -> None:
    """Let the last reply behind the last answer come, and take it in. The client watches
    the line for two frames' time after its last answer; a second module held up longer by a
    busy machine than its ``offset`` would be missed there, which is no finding of this test:
    so the module model is first waited for (generous bound) until it has sent ``replies``."""
    if m is not None:
        deadline = time.monotonic() + patience(10)
        while m.replied < replies and time.monotonic() < deadline:
            time.sleep(0.005)
    c._doubts.confirm_last()


@pytest.mark.parametrize("versions", [None, ("1311V111", "1311V111")],
                         ids=["two-types", "alike"])
@pytest.mark.parametrize("offset", [0.0, 0.03], ids=["back-to-back", "slower-second"])
def test_two_modules_at_one_address_are_found_by_the_client(two, offset, versions):
    c, m = two(offset=offset, versions=versions)
    notes: list[str] = []
    c.add_tracer(lambda d, raw, what: notes.append(what) if d == "note" else None)
    for motor in range(SHARED_AFTER):  # (two alike are found by counting: this many)
        c.request(Request(1, GAP, 1, motor % 3, 0))
    # (both modules answer every frame the client sent, its judge's questions too: an
    # answer that may be a copy of the one before is asked again)
    _settle(c, m, 2 * c.stats["sent"])
    assert c.shared == {1}
    assert c.take_shared() == [1] and c.take_shared() == []  # told once
    assert any("two modules answer at address 1" in str(n) for n in notes)


def test_a_single_module_beside_them_is_not_called_shared(two):
    c, m = two(alone=(2,))
    for _ in range(6):
        c.request(Request(2, GAP, 1, 0, 0))
    _settle(c)
    assert c.shared == frozenset()
    for _ in range(SHARED_AFTER):
        c.request(Request(1, GAP, 1, 0, 0))
    _settle(c)
    assert c.shared == {1}


def _drive(c: Client, n: int) -> None:
    for v in range(n):
        try:
            c.request(Request(1, SGP, 0, 2, v))
        except TmclError:
            pass
    _settle(c)


@pytest.mark.parametrize("rates", [{"dup": 0.1}, {"dup-late": 0.1},
                                   {"dup": 0.05, "dup-late": 0.05}])
def test_a_line_that_copies_replies_is_no_shared_address(pty_sim, rates):
    sim, path = pty_sim
    sim.faults.rng = random.Random(31)
    sim.faults.rates = rates
    c = Client(open_serial(path), module="TMCM-1311", timeout=0.3)
    try:
        _drive(c, 300)
        assert c.stats["unsolicited"] > 5  # (the line did copy replies)
        assert c.shared == frozenset()
    finally:
        c.close()


@pytest.mark.parametrize("fault", ["dup_next", "dup_late_next"])
def test_copies_of_fewer_replies_in_a_row_than_the_rule_asks_are_no_finding(pty_sim, fault):
    """One reply fewer copied in a row than ``SHARED_AFTER``: not shared; every one: shared
    (a line that copies every reply cannot be told from two modules that agree)."""
    sim, path = pty_sim
    c = Client(open_serial(path), module="TMCM-1311", timeout=0.3)
    try:
        _drive(c, 3)
        setattr(sim.faults, fault, SHARED_AFTER - 1)
        _drive(c, 12)
        assert c.shared == frozenset()
        setattr(sim.faults, fault, 4 * SHARED_AFTER)
        _drive(c, 12)
        assert c.shared == {1}
    finally:
        c.close()


def test_the_rule_counts_replies_not_matches():
    """The second reply taken for the next request's answer (a slow second module) still
    counts: as many replies again as requests, over the last SHARED_AFTER."""
    d = Doubles()
    req = Request(1, GAP, 1, 0, 0)
    found = []
    for _ in range(SHARED_AFTER):
        found += [d.answered(req), d.extra(1)]
    assert [f for f in found if f is not None] == [1]
    one = Doubles()
    for n in range(4 * SHARED_AFTER):  # every other request copied: never
        assert one.answered(req) is None
        if n % 2:
            assert one.extra(1) is None
    assert one.shared == set()


def test_two_different_answers_to_136_from_one_address_are_found_at_once():
    """A module answers 136 type 1 the same every time, and a line's copy of it is the same:
    two different answers from one address are two modules (another type or firmware)."""
    from tmclsh.tmcl.frames import Reply

    ask = Request(1, 136, 1, 0, 0)
    first = Reply(2, 1, 100, 136, 0x051F0101)
    other = Reply(2, 1, 100, 136, 0x04890130)
    d = Doubles()
    assert d.answered(ask, first) is None and d.extra(1, first) is None  # a copy: nothing
    assert d.answered(ask, first) is None
    assert d.extra(1, other) == 1 and d.shared == {1}
    moved = Doubles()  # another module there after the link was reopened: not two
    moved.answered(ask, first)
    moved.forget_versions()
    assert moved.answered(ask, other) is None and moved.shared == set()
