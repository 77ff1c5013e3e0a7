"""Stop means stop: the shell's one stop (``ops.stop.stop_everything``) stops a running stored
program before MST, reads every motor's actual speed back, and says "stopped" only for motors
that read 0 -- checked against the simulator through a pty, and against a small module
written here from the manual's byte tables whose motor ignores MST.
"""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from tmclsh.tmcl import asm
from tmclsh.ops import program
from tmclsh.ops import stop as stop_ops
from tmclsh.client.text import LineClient
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session
from tmclsh.link import open_serial

from conftest import ROOT, patience, read_until, tmclsh_env
from responder import Responder, fields, reply, version_reply

# a stored program that keeps the motor turning: MST alone is undone a moment later
KEEPS_TURNING = "Loop:\n    ROR 0, 20000\n    WAIT TICKS, 0, 2\n    JA Loop\n"


@pytest.fixture
def pty_module(pty_sim):
    sim, path = pty_sim
    c = LineClient(open_serial(path), module="TMCM-1311", timeout=0.3)
    yield c, sim
    c.close()


def start_program(c: LineClient) -> None:
    program.upload(c, asm.assemble(KEEPS_TURNING, c.require_module()))
    program.run(c)
    c.wait_until(lambda: c.value("GAP 3, 0") > 0, timeout=3)


def test_mst_alone_is_undone_by_a_running_program(pty_module):
    """Why the stop exists: the reason 'stopped' used to be a lie."""
    c, _ = pty_module
    start_program(c)
    c.execute("MST 0")
    time.sleep(0.3)
    assert c.value("GAP 3, 0") != 0
    assert program.status(c).state == "run"


def test_stop_everything_stops_the_program_then_the_motor(pty_module):
    c, _ = pty_module
    start_program(c)
    report = stop_ops.stop_everything(c)
    assert report.program == "stopped" and report.stopped == [0] and report.ok
    time.sleep(0.3)  # nothing drives it again
    assert c.value("GAP 3, 0") == 0 and program.status(c).state == "stop"


def test_stop_everything_without_a_program(pty_module):
    c, _ = pty_module
    c.execute("ROR 0, 30000")
    report = stop_ops.stop_everything(c)
    assert report.program == "not running" and report.stopped == [0] and report.ok
    assert c.value("GAP 3, 0") == 0


def test_stopall_says_what_reads_back(pty_module, capsys):
    c, _ = pty_module
    start_program(c)
    s = Session(c, Output())
    s.run_line(".stopall")
    out = capsys.readouterr().out
    assert "stored program stopped; stopped motor 0 (MST; speed reads 0)" in out
    assert c.value("GAP 3, 0") == 0


def test_stopall_json_gives_the_report(pty_module, capsys):
    import json

    c, _ = pty_module
    c.execute("ROR 0, 30000")
    s = Session(c, Output(json_mode=True))
    s.run_line(".stopall")
    (obj,) = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert obj == {"program": "not running", "stopped": [0], "turning": {}, "unknown": {}}


# -- an independent module whose motor ignores MST ---------------------------------------------

class StubbornModule(Responder):
    """TMCM-1311 at address 1 on a pty (tests/responder.py: the manual's byte tables only),
    136 type 0 with its version string. It answers 135 (application status) with 0
    (stopped), GGP 129 with 0 (not in download mode), MST with 100 and does nothing, GAP 3
    (actual speed) with 1000, always; any other command status 100 with the value it got."""

    SPEED = 1000

    def answer(self, raw: bytes) -> bytes | None:
        addr, cmd, typ, _, value = fields(raw)
        if addr != 1:
            return None
        if cmd == 136 and typ == 0:  # the version string: host address, 8 characters
            return version_reply("1311V111")
        if cmd == 10 and typ == 129:  # GGP 129: not in download mode
            value = 0
        elif cmd == 135:
            value = 0
        elif cmd == 6 and typ == 3:
            value = self.SPEED
        return reply(cmd, value)


@pytest.fixture
def stubborn():
    m = StubbornModule()
    yield m
    m.close()


def test_a_motor_that_keeps_turning_is_named(stubborn):
    p = subprocess.run([sys.executable, "-m", "tmclsh", "--port", stubborn.path, "-m", "TMCM-1311",
                        "-c", ".stopall"], capture_output=True, text=True, timeout=30,
                       env=tmclsh_env(), cwd=str(ROOT))
    assert "motor 0 did NOT stop: it still turns at speed 1000 after MST" in p.stderr
    assert "stopped motor" not in p.stdout + p.stderr
    assert p.returncode == 1
    cmds = stubborn.commands()
    cmds = cmds[cmds.index(135):]  # after what the connection asks (136, GGP 129)
    assert cmds[:2] == [135, 3] and cmds.count(6) >= 2  # status, MST, speed read back (again)


# -- leaving the shell -----------------------------------------------------------------------

def test_leaving_while_a_motor_turns_asks(pty_module, capsys):
    from tmclsh.shell.repl.app import may_leave

    c, _ = pty_module
    s = Session(c, Output(), interactive=True)
    asked = []

    def choose(answer):
        def pick(question, options):
            asked.append(question)
            assert [v for v, _ in options] == ["stop", "leave", "cancel"]
            return answer
        return pick

    s.choose = choose("cancel")
    assert may_leave(s)  # nothing going on: no question
    assert asked == []
    c.execute("ROR 0, 30000")
    c.wait_until(lambda: c.value("GAP 3, 0") > 0, timeout=3)
    assert not may_leave(s)
    assert asked and "Motor 0 turns" in asked[0]
    s.choose = choose("leave")
    assert may_leave(s) and c.value("GAP 3, 0") != 0
    s.choose = choose("stop")
    assert may_leave(s)
    assert c.value("GAP 3, 0") == 0
    assert "leaving: stopped motor 0 (MST; speed reads 0)" in capsys.readouterr().out


@pytest.mark.parametrize("start", ["ROR 0, 30000", "SAP 2, 0, 30000"])  # (velocity mode)
def test_a_script_that_leaves_a_motor_turning_says_so(run_tmclsh, start):
    p = run_tmclsh("--sim", "-c", f"{start}\n.sleep 0.2")
    assert p.returncode == 0
    assert "note: motor 0 turns (speed" in p.stderr and "left running" in p.stderr
    quiet = run_tmclsh("--sim", "-c", "GAP 1, 0")
    assert "note:" not in quiet.stderr


def test_a_script_in_ascii_mode_that_leaves_a_motor_turning_says_so_too(run_tmclsh):
    """The sent-only tracer that notices a start was told ASCII lines as text (not the
    request), so in ASCII mode a motor left turning went unmentioned."""
    p = run_tmclsh("--sim", "--ascii", "-c", "ROR 0, 30000\n.sleep 0.2")
    assert p.returncode == 0, p.stderr
    assert "note: motor 0 turns (speed" in p.stderr and "left running" in p.stderr
    quiet = run_tmclsh("--sim", "--ascii", "-c", "GAP 1, 0")
    assert "note:" not in quiet.stderr


def test_ctrl_c_in_a_script_stops_the_program(tmp_path):
    """SIGINT while -f runs: the stored program is stopped, then the motor, read back."""
    from tmclsh.sim import Simulator
    from tmclsh.sim.serve import serve_pty

    sim = Simulator("TMCM-1311")
    server = serve_pty(sim)
    try:
        prog = tmp_path / "turn.tmc"
        prog.write_text(KEEPS_TURNING)
        script = tmp_path / "s.tmcl"
        script.write_text(f".upload {prog} --yes\n.run\n.sleep 30\n")
        p = subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", server.path,
                              "-m", "TMCM-1311", "-f", str(script)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env=tmclsh_env(), cwd=str(ROOT))
        # the .run has said where the program runs (the module's state alone came before
        # tmclsh had taken the answer in: Ctrl-C landed on line 2); then the .sleep begins
        shown = read_until(p, lambda text: "\nrun @1 " in "\n" + text and text.endswith("\n"))
        assert sim.program_state == 1
        time.sleep(0.3)  # (from the .run's last line to the .sleep's first: a few steps)
        p.send_signal(2)
        out, err = p.communicate(timeout=patience(20))
        out = shown + out
        assert p.returncode == 130
        assert "stored program stopped; stopped motor 0 (MST; speed reads 0)" in err, err
        # how far the script got, as a run that ends says it
        assert out.splitlines()[-1].startswith(f"{script}: interrupted (Ctrl-C) at line 3 "
                                               "after "), out
        assert sim.program_state == 0 and sim.param("axis", 3, 0) == 0
    finally:
        server.close()
        sim.close()


def test_ascii_terminal_ctrl_c_stops_the_program_and_says_what_reads_back(pty_module):
    """Ctrl-C in the .ascii terminal sent MST only and said "motors stopped: 0": the stored
    program drove the motor again a moment later."""
    from tmclsh.client.ascii import AsciiLink
    from tmclsh.shell.features import terminal as tm
    from tmclsh.shell.features import termview as tv

    c, _ = pty_module
    start_program(c)
    link = AsciiLink.attach(c)
    try:
        notes: list[str] = []
        term = tm.Terminal(Session(c, Output()), link, tm.TerminalOptions(), notes.append,
                           tv.Painter(color=False))
        term.stop_motors()
        assert "".join(notes).strip() == ("--- stored program stopped; stopped motor 0 "
                                          "(MST; speed reads 0)")
        time.sleep(0.3)  # nothing drives it again
        assert link.command("GAP 3, 0").value == 0
    finally:
        link.detach(send_bin=True)
    assert program.status(c).state == "stop"


def test_a_run_ending_on_mst_says_the_motor_slows_down_not_left_running(pty_sim, tmp_path):
    """After MST the motor ramps down with nothing driving it: "left running (.stopall stops
    everything)" sent a technician for a stop the module was already doing."""
    _, path = pty_sim
    r = subprocess.run([sys.executable, "-m", "tmclsh", "--port", path, "-m", "TMCM-1311",
                        "-c", "SAP 5, 0, 2000; ROR 0, 50000; .sleep 0.5; MST 0"],
                       capture_output=True, text=True, timeout=30, env=tmclsh_env(),
                       cwd=str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert "ok: motor 0 stopping (target speed 0; it ramps down)" in r.stdout
    (note,) = [x for x in r.stderr.splitlines() if "note:" in x]
    assert "motor 0 slows down (speed " in note and "target speed 0) as the run ends" in note
    assert "left running" not in note
