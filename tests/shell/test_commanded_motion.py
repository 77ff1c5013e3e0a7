"""What tmclsh told the motors counts when it leaves, not only what ActualSpeed reads: a real
motor reads 0 for a moment after ROR, and a stalled one reads 0 while the module still holds
its target speed. The module here is tests/responder.py's plain TMCM-1311 (written from the
manual's byte tables): it accepts every command and reads 0 for every value, ActualSpeed
too, as a motor that has not started (or stalls) does."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from conftest import ROOT, tmclsh_env
from responder import Responder
from tmux import needs_tmux


@pytest.fixture
def still_motor():
    module = Responder()
    yield module
    module.close()


def run(module: Responder, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tmclsh", "--port", module.path,
                           "--timeout", "2", *args], capture_output=True, text=True,
                          timeout=60, env=tmclsh_env(), cwd=str(ROOT))


def test_c_says_a_motor_it_told_to_turn_is_left_turning_though_it_reads_0(still_motor):
    p = run(still_motor, "-c", "ROR 0, 1000")
    assert p.returncode == 0, p.stderr
    assert ("tmclsh: note: motor 0 was told to turn (ROR 0, 1000: target speed 1000); it "
            "reads speed 0; left running (.stopall stops everything)") in p.stderr, p.stderr


def test_json_says_it_on_stdout_too(still_motor):
    p = run(still_motor, "--json", "-c", "ROL 0, 300")
    objects = [json.loads(x) for x in p.stdout.splitlines()]
    left = [o["left_running"] for o in objects if "left_running" in o]
    assert left == [{"program_running": False, "turning": {}, "slowing": [],
                     "commanded": {"0": {"line": "ROL 0, 300", "target_speed": -300,
                                         "speed": 0}}}], p.stdout
    assert "left running" in p.stderr


@pytest.mark.parametrize("lines", ["ROR 0, 1000; MST 0", "ROR 0, 1000; ROR 0, 0",
                                   "SAP TargetSpeed, 0, 800; SAP TargetSpeed, 0, 0"])
def test_a_motor_it_stopped_again_is_not_said_to_be_left(still_motor, lines):
    p = run(still_motor, "-c", lines)
    assert p.returncode == 0, p.stderr
    assert "left running" not in p.stderr and "told to turn" not in p.stderr, p.stderr


def test_a_target_speed_written_counts_as_told_to_turn(still_motor):
    p = run(still_motor, "-c", "SAP TargetSpeed, 0, 800")
    assert "motor 0 was told to turn (SAP TargetSpeed, 0, 800: target speed 800)" in p.stderr


@needs_tmux
def test_ctrl_d_after_ror_asks_first_though_the_speed_reads_0(still_motor, terminal):
    term = terminal(height=30)
    term.start("--port", still_motor.path, "--timeout", "2")
    term.wait("TMCM-1311:1>")
    term.run("ROR 0, 1000", "rotating right")
    term.keys("C-d")
    screen = term.wait("Leave the shell?")
    assert "Motor 0 was told to turn (ROR 0, 1000: target speed 1000)" in screen, screen
    term.keys("Down", "Down", "Enter")  # cancel: the shell stays
    term.wait("TMCM-1311:1>", more_than=2)
    term.keys("C-d")
    term.wait("Leave the shell?", more_than=1)
    term.keys("Enter")  # stop everything first: MST, and the record is cleared by it
    screen = term.wait("EXIT=0")
    assert "leaving: stopped motor 0" in screen, screen
    mst = [raw for raw in still_motor.log if len(raw) == 9 and raw[1] == 3]
    assert mst, "no MST reached the module"


def test_a_position_move_that_has_not_ended_counts_too(still_motor):
    """TargetPositionReached reads 0 here, as for a motor stalled on its way."""
    p = run(still_motor, "--json", "-c", "MVP ABS, 0, 5000")
    left = [json.loads(x)["left_running"] for x in p.stdout.splitlines()
            if "left_running" in x]
    assert left and left[0]["commanded"] == {"0": {"line": "MVP ABS, 0, 5000", "speed": 0}}
    assert ("motor 0 was told to move (MVP ABS, 0, 5000) and has not reached its target"
            in p.stderr), p.stderr


def test_a_position_move_the_module_says_has_ended_is_forgotten():
    from tmclsh.client.connect import connect
    from tmclsh.ops.stop import activity

    with connect(sim="TMCM-1311") as client:
        client.execute("MVP ABS, 0, 200")
        assert 0 in client.motion.motors()
        client.wait_until(lambda: client.value("GAP TargetPositionReached, 0") == 1,
                          timeout=30, interval=0.05)  # (raises at the timeout)
        assert activity(client).idle
        assert not client.motion  # the module said it has ended: forgotten


def test_every_unit_says_what_it_left_turning(tmp_path):
    modules = [Responder(), Responder()]
    try:
        p = subprocess.run([sys.executable, "-m", "tmclsh", "--port", modules[0].path,
                            "--port", modules[1].path, "--timeout", "2", "--json",
                            "-c", "ROR 0, ${unit}00"], capture_output=True, text=True,
                           timeout=60, env=tmclsh_env(), cwd=str(ROOT))
        left = {o["unit"]: o["left_running"]["commanded"]["0"]["target_speed"]
                for o in map(json.loads, p.stdout.splitlines()) if "left_running" in o}
        assert left == {1: 100, 2: 200}, p.stdout + p.stderr
    finally:
        for m in modules:
            m.close()
