"""An answer is judged before anyone sees it: never a wrong value shown as a plain answer.

A line that repeats replies late puts a copy of the last answer ahead of the next one: same
module, same command, so it is taken for the next request's answer, whose own answer comes
behind it. The client takes an answer that is byte for byte one it took lately for another
request as possibly such a copy (``Ledger.may_be_a_copy``) and judges it before returning it
(``Client._judge``): a reading is asked again until two answers agree with nothing against
them; anything else is followed by a 136 whose reply comes after the displaced answer.

Through real bytes (the simulator on a pty; tmclsh in its own process where a script runs),
the faults scripted or drawn from the simulator's own random faults with fixed seeds.
scripts/fault_trial.py runs the long version (2,000 reads per mix, the machine loaded).
"""

from __future__ import annotations

import copy
import json
import random
import subprocess
import sys

import pytest

from tmclsh.client.ledger import Ledger
from tmclsh.client.text import LineClient
from tmclsh.link import open_serial
from tmclsh.base.errors import TmclTimeoutError
from tmclsh.tmcl.frames import Reply, Request

from conftest import ROOT, tmclsh_env

sys.path.insert(0, str(ROOT / "scripts"))
import fault_trial  # noqa: E402

GGP, SGP, GAP = 10, 9, 6


def tmclsh(path: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tmclsh", "--port", path, "-m", "TMCM-1311",
                           *args], capture_output=True, text=True, timeout=120,
                          env=tmclsh_env(), cwd=str(ROOT))


def every_time_after(sim, first_value: int, value: int, extra: list[int]) -> list[int]:
    """Each reply to a GGP answering ``value`` is preceded by replies carrying ``extra``
    (a copy of the GGP answer before it: ``first_value``). Returns the list of such replies."""
    send, seen = sim._send_reply, []

    def sending(channel, module, op, ans):
        if op == GGP and ans.value == value:
            seen.append(op)
            for v in extra:
                other = copy.copy(ans)
                other.value = v
                send(channel, module, op, other)
        send(channel, module, op, ans)

    sim._send_reply = sending
    return seen


@pytest.fixture
def client(pty_sim):
    sim, path = pty_sim
    c = LineClient(open_serial(path), module="TMCM-1311", timeout=0.3)
    c.execute("SGP 0, 2, 11")
    c.execute("SGP 1, 2, 22")
    yield c, sim
    c.close()


# -- the ledger ----------------------------------------------------------------------------------

def _reply(value: int, opcode: int = GGP) -> Reply:
    return Reply(2, 1, 100, opcode, value)


def test_a_late_answer_that_is_no_copy_casts_doubt_on_the_whole_run_since_in_step():
    """Cause (a) of the issue: one late answer shifts a run of reads of one command; every
    answer since requests and replies were last known in step is in doubt, not the last."""
    led = Ledger()
    led.took(Request(1, 9, 0, 2, 5), _reply(5, 9))  # another command: the run starts after
    for n in range(5):
        led.took(Request(1, GGP, n, 2, 0), _reply(100 + n))
    shifted = led.unsolicited(_reply(999), b"")
    assert [s.request.type for s in shifted] == [0, 1, 2, 3, 4]
    assert led.unsolicited(_reply(998), b"") == []  # each reported once


def test_doubt_starts_at_the_answer_that_may_be_a_copy():
    led = Ledger()
    for n in range(3):
        led.took(Request(1, GGP, n, 2, 0), _reply(100 + n))
    q = Request(1, GGP, 7, 2, 0)
    assert led.may_be_a_copy(q, _reply(102))  # the answer to type 2, again, for type 7
    assert not led.may_be_a_copy(Request(1, GGP, 2, 2, 0), _reply(102))  # same question
    assert not led.may_be_a_copy(q, _reply(101))  # a copy comes right behind its reply
    led.took(q, _reply(102), copy=True)
    led.took(Request(1, GGP, 8, 2, 0), _reply(107))
    assert [s.request.type for s in led.unsolicited(_reply(108), b"")] == [7, 8]


def test_a_copy_of_the_last_answer_arriving_first_hides_no_evidence_behind_it():
    """Cause (b): a byte-identical copy of the answer just returned made the line "opaque",
    and the real answer that followed was then ignored."""
    led = Ledger()
    led.took(Request(1, GGP, 0, 2, 0), _reply(11))
    led.took(Request(1, GGP, 1, 2, 0), _reply(11), copy=True)
    assert led.unsolicited(_reply(11), b"") == []  # a copy of the last: proves nothing
    (s,) = led.unsolicited(_reply(22), b"")  # ... the real answer behind it still counts
    assert s.request.type == 1 and s.reply.value == 11


# -- through real bytes --------------------------------------------------------------------------

def test_a_copy_taken_for_a_read_is_read_again_before_it_is_returned(client):
    c, sim = client
    sim.faults.dup_late_next = 1  # the answer to GGP 0 (11) again, after the next request
    assert c.value("GGP 0, 2") == 11
    assert c.value("GGP 1, 2") == 22
    assert not c._doubts.take_suspects()
    # the copy was sent, and the answer behind it came while nothing waited for it (as
    # evidence against the copy, or as a copy of the answer read again: timing decides)
    assert sim.faults.dup_late_next == 0 and c.stats["unsolicited"] >= 1


def test_the_copy_is_found_when_the_answer_behind_it_is_lost_too(client):
    """The double fault no single read can see: the copy is taken, and the answer behind
    it never comes. Reading again gives the module's value; two reads agree."""
    c, sim = client
    sim.faults.dup_late_next = 1
    assert c.value("GGP 0, 2") == 11
    send = sim._send_reply
    dropped = []

    def sending(channel, module, op, ans):
        if op == GGP and ans.value == 22 and not dropped:
            dropped.append(ans)  # its own answer: lost (the copy of 11 still goes)
            sim._send_late_copies()
            return
        send(channel, module, op, ans)

    sim._send_reply = sending
    assert c.value("GGP 1, 2") == 22
    assert dropped and not c._doubts.take_suspects()
    assert c.stats["unsolicited"] == 0  # nothing showed it but the value read again


def test_a_copy_then_the_real_answer_after_another_copy_is_still_found(client):
    """The real answer comes behind two copies of the last answer (cause (b) on the wire)."""
    c, sim = client
    assert c.value("GGP 0, 2") == 11
    seen = every_time_after(sim, 11, 22, [11, 11])
    c2 = c.execute("GGP 1, 2")
    assert seen
    # every read of it brings the copies first: never two agreeing answers with nothing
    # against them, so it is returned in doubt, never as a plain 11
    assert c2.value == 22 or [s.seq for s in c._doubts.take_suspects()] == [c._replies]


def test_a_line_that_brings_the_same_copy_first_every_time_is_said_in_the_line(pty_sim,
                                                                                tmp_path):
    """Reading again agrees with the copy each time, but the real answer behind it speaks
    against it each time: the value is shown with its doubt in the same line and record,
    the run fails."""
    sim, path = pty_sim
    every_time_after(sim, 11, 22, [11])
    script = tmp_path / "s.tmcl"
    script.write_text("SGP 0, 2, 11\nSGP 1, 2, 22\nGGP 0, 2\nGGP 1, 2\n")
    text = tmclsh(path, "-f", str(script))
    print(text.stdout, text.stderr)
    lines = text.stdout.splitlines()[:4]
    assert "in doubt" in lines[3] and "in doubt" not in "".join(lines[:3])
    assert text.returncode == 1
    js = tmclsh(path, "--json", "-f", str(script))
    records = [json.loads(x) for x in js.stdout.splitlines()]
    (rec,) = [r for r in records if r.get("line") == "GGP 1, 2"]
    assert rec["in_doubt"] is True and "in doubt" in rec["warning"]
    assert js.returncode == 1


def test_from_python_an_answer_left_in_doubt_says_so_in_its_result(client):
    """The API path: ``LineClient.execute`` returned the copy as a plain answer (its
    ``Result.in_doubt`` was never set outside the shell); it stays a suspect as well."""
    c, sim = client
    assert c.execute("GGP 0, 2").value == 11
    every_time_after(sim, 11, 22, [11])
    r = c.execute("GGP 1, 2")
    assert r.value == 11 and r.in_doubt
    assert [s.seq for s in c._doubts.take_suspects()] == [c._replies]
    assert not c.execute("GGP 0, 2").in_doubt


def test_a_write_that_may_have_taken_a_copy_is_followed_by_a_marker(client):
    """SGP is not sent twice to judge it: a 136 follows, and the displaced answer, coming
    before the 136's reply, makes the answer a suspect at once (not one line later)."""
    c, sim = client
    sim.faults.dup_late_next = 1
    assert c.execute("SGP 3, 2, 5").value == 5
    r = c.request(Request(1, SGP, 4, 2, 5))  # the reply to SGP 3 (5) again, then its own
    assert r.value == 5
    (s,) = c._doubts.take_suspects()
    assert s.seq == c._replies and s.request.type == 4


@pytest.mark.parametrize("mix", ["dup-late=0.15", "dup=0.1,dup-late=0.1",
                                 "dup-late=0.1,drop=0.03", "dup-late=0.1,garbage=0.1"])
def test_no_wrong_value_is_shown_as_a_plain_answer_under_random_faults(mix):
    """400 reads of values that differ (runs of the same command) under the simulator's
    random faults, in tmclsh -f --json: every wrong value shown must carry its doubt in its
    own record. (The issue's mixes, 2,000 reads each, loaded: scripts/fault_trial.py.)"""
    counts, _ = fault_trial.trial(mix, 400, seed=3)
    assert counts["reads"] >= 380, counts
    assert counts["wrong, unflagged"] == 0 and counts["wrong, later"] == 0, counts
    assert counts["right, flagged"] <= 4, counts


def test_the_api_path_flags_every_wrong_value_too():
    """The same through the Python API (``fault_trial.py --api``: tmclsh.connect and
    LineClient.execute in a process of their own; ``Result.in_doubt`` is the flag)."""
    counts, _ = fault_trial.trial("dup=0.1,dup-late=0.1", 200, seed=3, api=True)
    assert counts["reads"] >= 190, counts
    assert counts["wrong, unflagged"] == 0 and counts["wrong, later"] == 0, counts


def test_the_trial_counts_a_wrong_value_it_is_shown():
    """The trial's judge is no test that cannot fail: a wrong plain record counts."""
    values = {"GGP 0, 2": 11}
    assert fault_trial.judge([{"line": "GGP 0, 2", "reply": 22}], values)[
        "wrong, unflagged"] == 1
    assert fault_trial.judge([{"line": "GGP 0, 2", "reply": 22, "in_doubt": True}], values)[
        "wrong, in line"] == 1
    assert fault_trial.judge([{"line": "GGP 0, 2", "reply": 22},
                              {"line": "GGP 0, 2", "suspect": True}], values)[
        "wrong, later"] == 1


def test_a_line_check_is_not_answered_by_an_earlier_checks_late_reply(pty_sim):
    """Both kinds of 136 reply may still be on their way (two earlier checks of the line
    went unanswered), and a read's reply is held back behind them. The check made now must
    not take an earlier check's late reply for its own: the read's reply behind it would
    then be taken for the next read's answer (seen in the fault trial under long delays)."""
    sim, path = pty_sim
    c = LineClient(open_serial(path), module="TMCM-1311", timeout=0.15, retries=0)
    try:
        c.execute("SAP 5, 0, 22222")
        c.execute("SAP 7, 0, 50")
        send = sim._send_reply
        held: list[tuple] = []
        state = {"hold": True, "after": None}

        def sending(channel, module, op, ans):
            if state["hold"]:
                held.append((channel, module, op, copy.copy(ans)))
                return
            if state["after"] is not None:
                # the replies held so far come in order, the rest with the next request
                for args in held[:state["after"]]:
                    send(*args)
                del held[:state["after"]]
                state["after"] = None
                held.append((channel, module, op, copy.copy(ans)))
                return
            for args in held:
                send(*args)
            held.clear()
            send(channel, module, op, ans)

        sim._send_reply = sending
        with pytest.raises(TmclTimeoutError):
            c.request(Request(1, GGP, 0, 2, 0))  # its reply is held: it may come late
        for _ in range(2):  # each check of the line fails (a 136 of each kind is late)
            with pytest.raises(TmclTimeoutError):
                c.request(Request(1, GGP, 1, 2, 0))
        with pytest.raises(TmclTimeoutError):
            c.request(Request(1, GAP, 5, 0, 0))  # another command: sent, reply held
        assert c._ledger.marker(1) is None
        # the next check of the line gets the first two held replies (GGP 0's, the first
        # 136's); everything else comes with the request after it
        state.update(hold=False, after=2)
        assert c.request(Request(1, GAP, 7, 0, 0)).value == 50
        assert c.request(Request(1, GAP, 5, 0, 0)).value == 22222
    finally:
        sim._send_reply = send
        c.close()


def test_on_the_ascii_line_a_copy_of_a_line_checks_answer_may_be_taken_for_any_read():
    """A line check's answer (GGP 76: the host address) names no command in ASCII: a copy of
    it, arriving first, is taken for the next read (ActualSpeed = 2 on a stopped motor, seen
    in a trial). On the binary link the check is a 136, which no other request takes."""
    led = Ledger()
    led.took_marker(Request(1, 136, 1, 0, 0), _reply(2, 136))
    assert not led.may_be_a_copy(Request(1, 6, 3, 0, 0), _reply(2, 6))
    led.by_command = False
    led.took_marker(Request(1, GGP, 76, 0, 0), _reply(2))
    assert led.may_be_a_copy(Request(1, 6, 3, 0, 0), _reply(2, 6))
    assert not led.may_be_a_copy(Request(1, 6, 3, 0, 0), _reply(0, 6))
