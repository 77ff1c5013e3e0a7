"""A second reading of the link layer (client, connection, program): each test drives the
client through real bytes against a small module written here from the manual's byte tables
(tests/responder.py), and shows one way a technician on a flaky line could be misled.
"""

from __future__ import annotations

import pytest

from tmclsh import program
from tmclsh.client import Client
from tmclsh.transport import open_serial

from responder import OK, Module, fields

SPEED = 3  # AP 3 ActualSpeed


class Axes(Module):
    """A three-motor module (the TMCM-351's version string) whose actual speeds (AP 3) the
    test sets in ``values``; MST zeroes a motor's speed unless it is in ``ignores_mst``; no
    stored program runs (135 answers 0, 128 is accepted).

    ``dup_late``: (command, type, motor) whose reply is sent once more, right before the
    answer to the next request: a copy delayed on the line (what the simulator's dup-late
    fault does), so the client takes the copy for the next request's answer."""

    def __init__(self, **kw):
        super().__init__(version="0351V103", **kw)
        self.ignores_mst: set[int] = set()
        self.dup_late: set[tuple[int, int, int]] = set()
        self._copy = b""

    def speeds(self, *values: int) -> None:
        for m, v in enumerate(values):
            self.values[(SPEED, m, False)] = v

    def respond(self, command, type_, motor, value):
        if command == 3:  # MST
            self.got.append((command, type_, motor, value))
            if motor not in self.ignores_mst:
                self.values[(SPEED, motor, False)] = 0
            return OK, 0
        if command in (128, 135):
            self.got.append((command, type_, motor, value))
            return OK, 0
        return super().respond(command, type_, motor, value)

    def answer(self, raw):
        out = super().answer(raw)
        copy, self._copy = self._copy, b""
        _, cmd, typ, motor, _ = fields(raw)
        if out is not None and (cmd, typ, motor) in self.dup_late:
            self.dup_late.discard((cmd, typ, motor))
            self._copy = out
        return copy + out if out is not None else None


@pytest.fixture
def axes():
    m = Axes()
    c = Client(open_serial(m.path), module="TMCM-351", timeout=0.3, retries=1)
    yield c, m
    c.close()
    m.close()


def test_a_displaced_answer_equal_to_an_older_one_is_still_suspect(axes):
    """GAP 3,2 takes a late copy of GAP 3,1's answer (0); its own answer (5000) then comes
    when nothing waits for it. That it equals the answer of an *older* request (GAP 3,0)
    does not make the 0 shown for motor 2 right: it must be reported as suspect."""
    c, m = axes
    m.speeds(5000, 0, 5000)
    m.dup_late.add((6, SPEED, 1))
    assert c.value("GAP 3, 0") == 5000
    assert c.value("GAP 3, 1") == 0
    shown = c.value("GAP 3, 2")
    seq = c.replies
    c.value("GAP 3, 0")  # the next request finds the answer that came late
    suspects = c.take_suspects()
    assert shown == 5000 or any(s.seq == seq for s in suspects), (shown, suspects)


def test_stop_never_says_stopped_on_a_copy_of_another_motors_zero(axes):
    """The last speed read takes a late copy of the one before (motor 1: 0) while motor 2
    still turns: "stopped" for motor 2 would be a lie."""
    c, m = axes
    m.speeds(0, 3000, 5000)
    m.ignores_mst.add(2)
    m.dup_late.add((6, SPEED, 1))
    report = program.stop_everything(c, settle=0.3)
    assert 2 not in report.stopped, report
    assert not report.ok
    assert report.turning.get(2) == 5000 or 2 in report.unknown, report


def test_stop_never_says_stopped_when_the_copy_equals_an_older_answer(axes):
    """As above, with the displaced answer (5000) equal to an earlier read (motor 0's)."""
    c, m = axes
    m.speeds(5000, 3000, 5000)
    m.ignores_mst.update({0, 2})
    m.dup_late.add((6, SPEED, 1))
    report = program.stop_everything(c, settle=0.3, sleep=lambda s: None)
    assert 2 not in report.stopped, report
    assert report.turning.get(0) == 5000
    assert report.turning.get(2) == 5000 or 2 in report.unknown, report
