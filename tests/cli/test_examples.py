"""The example scripts in scripts/*.tmcl run against the simulator with the expected output.

Motion examples run in process on a fast simulator (module time 20x); the others run the way
a new user runs them: ``tmclsh -f scripts/NAME.tmcl`` in a subprocess, default connection.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tmclsh.shell.lang import script
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = ROOT / "scripts"
EXAMPLES = sorted(p.name for p in SCRIPTS.glob("*.tmcl"))


@pytest.fixture
def fast(fast_client):
    """A fast simulated TMCM-1311 (module time 20x real time) behind a client."""
    return fast_client


def run_example(client, name, capsys):
    code = script.run_file(Session(client, Output()), str(SCRIPTS / name))
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def tmclsh(*args, cwd=None, stdin=None):
    env = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1", COLUMNS="120")
    return subprocess.run([sys.executable, "-m", "tmclsh", *args], cwd=cwd or ROOT, env=env,
                          input=stdin, capture_output=True, text=True, timeout=60)


def test_every_example_is_covered_and_parses(fast):
    assert {"homing.tmcl", "move_check.tmcl", "io_test.tmcl", "backup.tmcl"} <= set(EXAMPLES)
    session = Session(fast, Output())
    for name in EXAMPLES:
        path = SCRIPTS / name
        list(script.Parser(session, name, SCRIPTS).nodes(path.read_text().splitlines()))


def test_homing(fast, capsys):
    sim = fast.transport.simulator
    sim.set_switch_position(0, "ref", -30000)  # the switch sits 30000 µsteps to the left
    fast.execute("SAP ActualPosition, 0, 12345")
    code, out, err = run_example(fast, "homing.tmcl", capsys)
    assert code == 0, err
    assert "searching the reference switch of motor 0 ..." in out
    assert "passed: GAP ActualPosition, 0 == 0" in out
    assert "motor 0 homed" in out
    assert "2 checks passed, 0 failed, 0 errors" in out
    assert fast.value("GAP ActualPosition, 0") == 0
    assert fast.value("GAP ReferenceSearchMode, 0") == 1


def test_homing_without_a_switch_times_out_and_stops_the_search(fast, capsys, tmp_path):
    # the same script with a short timeout on a rig without a reference switch
    fast.transport.simulator.set_switch_position(0, "ref", None)
    text = (SCRIPTS / "homing.tmcl").read_text().replace("--timeout 60", "--timeout 0.3")
    path = tmp_path / "homing.tmcl"
    path.write_text(text)
    line = next(i for i, t in enumerate(text.splitlines(), 1) if t.startswith(".wait"))
    code = script.run_file(Session(fast, Output()), str(path))
    cap = capsys.readouterr()
    assert code == 1
    assert f"{path}:{line}: timed out after 0.3 s waiting for RFS STATUS, 0 == 0" in cap.err
    assert ".onerror: RFS STOP, 0" in cap.out
    assert fast.value("RFS STATUS, 0") == 0  # the handler stopped the search


def test_move_check(fast, capsys):
    code, out, err = run_example(fast, "move_check.tmcl", capsys)
    assert code == 0, err
    for pos in (51200, 102400, 153600):
        assert f"GAP ActualPosition, 0 is {pos}" in out
    assert "motor 0 reached every position" in out
    assert "4 checks passed, 0 failed, 0 errors" in out
    assert fast.value("GAP ActualPosition, 0") == 0


def test_io_test_as_a_new_user_runs_it():
    proc = tmclsh("--sim", "-f", "scripts/io_test.tmcl")
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    for port in range(8):
        assert f"passed: GIO (port), 2 == 1 (GIO {port}, 2 is 1)" in out
        assert f"passed: GIO (port), 2 == 0 (GIO {port}, 2 is 0)" in out
    assert "digital inputs (IN_0..IN_7 as bits): 0" in out
    assert "supply voltage: 24 V" in out
    assert "scripts/io_test.tmcl: 35 commands sent, 17 checks passed, 0 failed, 0 errors" in out


def test_backup_writes_a_script_that_restores(tmp_path):
    # backup from a module with non-default settings ...
    setup = "SAP 4, 0, 123456\nSAP 6, 0, 128\nSAP 140, 0, 4\nSGP 2, 2, -77\n"
    proc = tmclsh("--sim", "-c", setup + f".source {SCRIPTS / 'backup.tmcl'}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "saved 8 axis parameters and 4 user variables to params-restore.tmcl" in proc.stdout
    restore = (tmp_path / "params-restore.tmcl").read_text().splitlines()
    assert restore[0].startswith("# params-restore.tmcl: written by backup.tmcl")
    assert "SAP MaxPositioningSpeed, 0, 123456" in restore
    assert "SAP MaxCurrent, 0, 128" in restore
    assert "SAP MicrostepResolution, 0, 4" in restore
    assert "SGP 2, 2, -77" in restore
    assert all(line.startswith(("#", "SAP ", "SGP ", ".echo")) for line in restore)
    # ... and the restore script puts them back into a fresh (default) module
    proc = tmclsh("--sim", "--json", "-c", ".source params-restore.tmcl\nGAP 4, 0\nGAP 6, 0\nGAP 140, 0\n"
                  "GGP 2, 2", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    replies = [json.loads(line) for line in proc.stdout.splitlines() if '"reply"' in line]
    assert [r["reply"] for r in replies[-4:]] == [123456, 128, 4, -77]


def test_homing_as_a_new_user_runs_it():
    # the built-in simulator is laid out like a bench rig: a reference switch below 0
    p = tmclsh("--sim", "-f", "scripts/homing.tmcl")
    assert p.returncode == 0, p.stderr
    assert "motor 0 homed" in p.stdout
