"""A reply is only ever the answer to its request, also when the line duplicates replies.

The simulator's ``dup`` fault sends a reply twice, back to back (the copy is on the line
before the next request goes out); ``dup-late`` sends the copy after the next request has
arrived, ahead of that request's own reply. Every request writes a unique value (SGP of a user
variable: the reply carries the value written), so a reply taken for another request shows.

* back to back: the copy is discarded before the next request; no wrong value, ever;
* after the next send: no client can tell the copy from the answer (same command, same
  layout), but the real answer then arrives when no request is outstanding: the link is
  resynchronised and the value taken is reported as suspect. No wrong value goes unreported.
"""

from __future__ import annotations

import copy
import itertools
import json
import random
import subprocess
import sys

import pytest

from tmclsh.client.text import LineClient
from tmclsh.base.errors import TmclError
from tmclsh.tmcl.frames import Request
from tmclsh.sim.device import RATE_KINDS, parse_rates
from tmclsh.link import open_serial

from conftest import ROOT, tmclsh_env

SGP = 9


def drive(c: LineClient, n: int) -> tuple[set[int], set[int], int]:
    """``n`` SGPs with unique values: (replies with a wrong value, replies reported suspect,
    failed requests), by ``Client._replies`` number."""
    unique = itertools.count(1000)
    wrong: set[int] = set()
    suspect: set[int] = set()
    failed = 0
    for _ in range(n):
        v = next(unique)
        try:
            reply = c.request(Request(1, SGP, 0, 2, v))
        except TmclError:
            failed += 1
            continue
        if reply.value != v:
            wrong.add(c._replies)
        suspect |= {s.seq for s in c._doubts.take_suspects()}
    c.request(Request(1, SGP, 0, 2, 0))  # the last displaced answer is found by the next request
    suspect |= {s.seq for s in c._doubts.take_suspects()}
    return wrong, suspect, failed


@pytest.fixture
def dup_client(pty_sim):
    sim, path = pty_sim
    sim.faults.rng = random.Random(7)
    c = LineClient(open_serial(path), module="TMCM-1311", timeout=0.2)
    yield c, sim
    c.close()


def test_back_to_back_copies_are_never_taken(dup_client):
    c, sim = dup_client
    sim.faults.rates = {"dup": 0.05}
    wrong, suspect, failed = drive(c, 1000)
    assert not wrong and not failed
    assert not suspect  # a copy of the answer taken does not cast doubt on it
    # the copies were seen, counted, and (most) dropped before the request after them
    assert c.stats["unsolicited"] > 20 and c.stats["flushed"] >= 9 * 20


def test_late_copies_never_give_an_unreported_wrong_value(dup_client):
    c, sim = dup_client
    sim.faults.rates = {"dup-late": 0.05}
    wrong, suspect, failed = drive(c, 500)
    assert wrong, "the fault did nothing: the test proves nothing"
    assert wrong <= suspect, f"wrong values not reported: {sorted(wrong - suspect)}"
    assert len(suspect - wrong) <= len(wrong) // 10  # and hardly a false alarm


def test_counted_duplicates(dup_client):
    c, sim = dup_client
    assert c.request(Request(1, SGP, 0, 2, 5)).value == 5
    sim.faults.dup_next = 1
    assert c.request(Request(1, SGP, 0, 2, 6)).value == 6
    assert c.request(Request(1, SGP, 0, 2, 7)).value == 7  # the copy of 6 was dropped first
    assert c.stats["flushed"] == 9 and not c._doubts.take_suspects()
    sim.faults.dup_late_next = 1
    assert c.request(Request(1, SGP, 0, 2, 8)).value == 8
    assert c.request(Request(1, SGP, 0, 2, 9)).value == 8  # indistinguishable: the copy
    assert c.request(Request(1, SGP, 0, 2, 10)).value == 10  # ... but the answer to 9 came after
    (s,) = c._doubts.take_suspects()
    assert s.request.value == 9 and s.reply.value == 8


def dup_first(sim, opcode: int, fault: str) -> None:
    """The first reply to ``opcode`` gets ``fault`` (not the replies the connection asks for
    before the script runs)."""
    send, done = sim._send_reply, []

    def sending(channel, module, op, ans):
        if op == opcode and not done:
            done.append(True)
            setattr(sim.faults, fault, 1)
        send(channel, module, op, ans)

    sim._send_reply = sending


def test_the_copy_is_traced_as_discarded(pty_sim):
    sim, path = pty_sim
    dup_first(sim, 6, "dup_next")
    p = subprocess.run([sys.executable, "-m", "tmclsh", "--port", path, "-m", "TMCM-1311",
                        "--trace", "-c", "GAP 4, 0; GAP 4, 0"], capture_output=True, text=True,
                       timeout=30, env=tmclsh_env(), cwd=str(ROOT))
    assert p.returncode == 0, p.stderr
    assert "discarded before the request" in p.stderr
    assert p.stdout.count("MaxPositioningSpeed = 51200") == 2


def test_a_suspect_answer_is_reported_in_json_and_fails_the_run(pty_sim, tmp_path):
    sim, path = pty_sim
    script = tmp_path / "s.tmcl"
    script.write_text("SGP 0, 2, 11\nSGP 0, 2, 12\nSGP 0, 2, 13\n")
    dup_first(sim, SGP, "dup_late_next")
    p = subprocess.run([sys.executable, "-m", "tmclsh", "--port", path, "-m", "TMCM-1311",
                        "--json", "-f", str(script)], capture_output=True, text=True,
                       timeout=30, env=tmclsh_env(), cwd=str(ROOT))
    objs = [json.loads(x) for x in p.stdout.splitlines()]
    assert [o.get("reply") for o in objs if "op" in o] == [11, 11, 13]
    # said in the record of the line itself (a 136 after it brought the displaced answer
    # before the next line ran), not in a warning after it
    doubtful = [o for o in objs if o.get("in_doubt")]
    assert [o["line"] for o in doubtful] == ["SGP 0, 2, 12"]
    assert "another request" in doubtful[0]["warning"]
    assert not [o for o in objs if o.get("suspect")]
    assert all("simulated" not in o for o in objs)  # a pty: tmclsh cannot know
    assert p.returncode == 1


def test_a_suspect_answer_to_a_shell_command_names_its_line(pty_sim, tmp_path):
    """The displaced answer was read by a shell command (a ``${...}`` in .echo, not a TMCL
    line): the warning names that line and where it is, not 'an earlier answer'. (A .expect
    reads such an answer again itself: tests/client/test_answers_in_doubt.py.)"""
    sim, path = pty_sim
    script = tmp_path / "s.tmcl"
    script.write_text("SGP 0, 2, 11\nSGP 1, 2, 22\nGGP 0, 2\n.echo ${GGP 1, 2}\n"
                      "GGP 0, 2\n")
    send, seen = sim._send_reply, []

    def sending(channel, module, op, ans):  # the .echo's GGP 1, 2 (answering 22)
        if op == 10 and ans.value == 22 and not seen:
            seen.append(op)
            other = copy.copy(ans)
            other.value = 99  # another answer first, a copy of none (a copy is read again)
            send(channel, module, op, other)
        send(channel, module, op, ans)

    sim._send_reply = sending
    p = subprocess.run([sys.executable, "-m", "tmclsh", "--port", path, "-m", "TMCM-1311",
                        "--keep-going", "-f", str(script)], capture_output=True, text=True,
                       timeout=30, env=tmclsh_env(), cwd=str(ROOT))
    warnings = [x for x in p.stderr.splitlines() if "another request" in x]
    # (the GGP 0, 2 before it, same command, is in doubt too: the late answer may have
    # shifted both)
    assert any("the answer to '.echo ${GGP 1, 2}' (" in w and ":4)" in w for w in warnings), \
        p.stderr
    assert p.returncode == 1


# -- tmclsh sim --faults -------------------------------------------------------------------------

def test_parse_rates():
    assert parse_rates("drop=0.1, corrupt=0.05,dup=1,dup-late=0") == {
        "drop": 0.1, "corrupt": 0.05, "dup": 1.0, "dup-late": 0.0}
    for bad in ("drop=2", "nonsense", "drop", "drop=x", "", "drop=-0.1", "teleport=0.5"):
        with pytest.raises(ValueError):
            parse_rates(bad)


@pytest.mark.parametrize("bad", ["drop=2", "nonsense", ""])
def test_sim_faults_bad_input_is_a_usage_error(run_tmclsh, bad):
    p = run_tmclsh("sim", "--pty", "--faults", bad)
    assert p.returncode == 2 and p.stdout == ""
    last = p.stderr.strip().splitlines()[-1]
    assert last.startswith("tmclsh sim: error: argument --faults: ") and "Traceback" not in p.stderr


def test_sim_help_lists_every_fault(run_tmclsh):
    text = " ".join(run_tmclsh("sim", "--help").stdout.split())
    assert "--faults-seed" in text
    for kind in RATE_KINDS:
        assert kind in text


def test_tmclsh_sim_faults_seen_with_raw_pyserial():
    """``tmclsh sim --pty --faults dup=1``: every reply comes twice, seen with plain pyserial
    (no tmclsh client involved); the same seed misbehaves the same way."""
    import serial

    p = subprocess.Popen([sys.executable, "-m", "tmclsh", "sim", "--pty", "--faults", "dup=1",
                          "--faults-seed", "3"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, env=tmclsh_env(), cwd=str(ROOT))
    try:
        path = p.stdout.readline().strip()
        frame = bytes([1, 6, 4, 0, 0, 0, 0, 0])  # GAP 4, 0
        frame += bytes([sum(frame) & 0xFF])
        with serial.Serial(path, 9600, timeout=1) as port:
            port.write(frame)
            got = port.read(18)
        assert len(got) == 18 and got[:9] == got[9:]
        assert got[:4] == bytes([2, 1, 100, 6])
    finally:
        p.terminate()
        p.wait(10)


def test_a_displaced_answer_that_arrives_damaged_still_casts_doubt(dup_client):
    c, sim = dup_client
    assert c.request(Request(1, SGP, 0, 2, 20)).value == 20
    sim.faults.dup_late_next = 1
    assert c.request(Request(1, SGP, 0, 2, 21)).value == 21
    sim.faults.corrupt_next = 1  # the real answer to 22 comes damaged, after the copy of 21
    assert c.request(Request(1, SGP, 0, 2, 22)).value == 21
    (s,) = c._doubts.take_suspects()  # (found by the marker the copy is judged with)
    assert s.request.value == 22 and s.reply.value == 21
    assert c.request(Request(1, SGP, 0, 2, 23)).value == 23


# -- upload's verify on a line that brings answers twice --------------------------------------

def _late_copy_of_read(sim, nth: int) -> None:
    """The reply to the ``nth`` 134 (program memory read) comes again, after the next
    request: that read takes the copy, and its own answer comes while nothing waits."""
    send, reads = sim._send_reply, []

    def sending(channel, module, op, ans):
        if op == 134:
            reads.append(op)
            if len(reads) == nth:
                sim.faults.dup_late_next = 1
        send(channel, module, op, ans)

    sim._send_reply = sending


def test_verify_does_not_take_a_copy_of_the_cell_before_for_a_match(pty_client):
    """Cell 2 holds something else; the copy of cell 1's answer read as cell 2 matched what
    was uploaded, and verify said identical."""
    from tmclsh.ops.program import verify_image
    from tmclsh.tmcl.frames import Instruction

    c = pty_client
    same, other = Instruction(4, 0, 0, 1000), Instruction(4, 0, 0, 2000)
    c.sim.load_program([same, same, other])
    _late_copy_of_read(c.sim, 2)
    mm = verify_image(c, [same, same, same])
    assert mm is not None and (mm.address, mm.actual, mm.doubtful) == (2, other, False)


def test_verify_does_not_call_a_copy_of_the_cell_before_a_difference(pty_client):
    from tmclsh.ops.program import verify_image
    from tmclsh.tmcl.frames import Instruction

    c = pty_client
    prog = [Instruction(4, 0, 0, 1000), Instruction(4, 0, 0, 2000), Instruction(3, 0, 0, 0)]
    c.sim.load_program(prog)
    _late_copy_of_read(c.sim, 1)
    assert verify_image(c, prog) is None


def test_verify_on_a_line_that_keeps_doubling_answers_is_no_pass(pty_client):
    """Every answer comes twice, the copy after the next request: a read-back cannot be told
    apart from the frame before it, so nothing may pass as verified."""
    from tmclsh.ops.program import verify_image
    from tmclsh.tmcl.frames import Instruction

    c = pty_client
    prog = [Instruction(4, 0, 0, 1000)] * 3
    c.sim.load_program(prog)
    c.sim.faults.rates = {"dup-late": 1.0}
    assert verify_image(c, prog) is not None
