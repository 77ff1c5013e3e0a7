"""The Python examples in examples/ (the README's "From Python" points at them) run as a user
runs them, against the simulator: ``python examples/NAME.py sim``."""

from __future__ import annotations

import subprocess
import sys

import pytest

from bootmodel import hex_image
from conftest import ROOT, tmclsh_env

EXAMPLES = ROOT / "examples"


def _run(name: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(EXAMPLES / name), *args], capture_output=True,
                          text=True, env=tmclsh_env(), cwd=str(ROOT), timeout=120)


def example(name: str, *args: str) -> str:
    run = _run(name, *args)
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr and "Warning" not in run.stderr, run.stderr
    return run.stdout


def test_every_example_is_tested_here():
    tested = {"identify.py", "read_write.py", "move.py", "backup_restore.py",
              "firmware_check.py"}
    assert {p.name for p in EXAMPLES.glob("*.py")} == tested


def test_connect_and_identify():
    out = example("identify.py", "sim")
    assert out.splitlines() == ["TMCM-1311 at address 1 on SIMULATED TMCM-1311",
                                "firmware 1311V111", "1 motor(s); position now 0"]


def test_read_and_write_by_name():
    out = example("read_write.py", "sim").splitlines()
    assert out[0] == "MaxPositioningSpeed: 51200 -> 1200"
    assert out[2].startswith("refused, nothing sent: 12 is out of range for AP 140")
    assert out[3] == "the module said no: module answered status 5: configuration EEPROM locked"


def test_move_and_wait_for_the_position():
    assert example("move.py", "sim").splitlines() == ["reached 3200 (from 0)"]


def test_back_up_and_restore():
    out = example("backup_restore.py", "sim").splitlines()
    assert out[0].startswith("backed up ") and int(out[0].split()[2]) > 10
    assert "more are its place on the line" in out[0]
    assert out[1].startswith("changed since: MaxPositioningSpeed ") and out[1].endswith(" -> 777")
    assert out[2] == "restored 1; differences now: 0"


@pytest.mark.parametrize("version, last", [
    ("1311V112", "would update it to 1311V112"),
    ("1311V111", "it runs this version already"),
    ("0351V112", "refused: "),
])
def test_check_a_firmware_image(tmp_path, version, last):
    image = tmp_path / f"{version}.hex"
    image.write_text(hex_image(version, 5000))
    out = example("firmware_check.py", str(image), "sim").splitlines()
    assert out[0].startswith(f"image {image}: 5000 bytes at 0x") and f"['{version}']" in out[0]
    assert out[1] == "module TMCM-1311 runs 1311V111"
    assert out[2].startswith(last)


def failing(name: str, *args: str) -> str:
    run = _run(name, *args)
    assert run.returncode == 1 and "Traceback" not in run.stderr, run.stderr
    assert run.stdout == "" and len(run.stderr.strip().splitlines()) == 1, run.stderr
    return run.stderr


def test_an_image_cut_short_is_one_line_and_no_module_is_asked(tmp_path):
    text = hex_image("1311V112", 5000)
    cut = tmp_path / "cut.hex"
    cut.write_text(text[: text.rindex(":", 0, len(text) // 2)])  # whole records, no end record
    err = failing("firmware_check.py", str(cut), str(tmp_path / "no-such-port"))
    assert err.startswith(f"firmware_check: {cut}")


@pytest.mark.parametrize("name", ["identify.py", "read_write.py", "move.py",
                                  "backup_restore.py"])
def test_no_module_there_is_one_line(tmp_path, name):
    err = failing(name, str(tmp_path / "no-such-port"))
    assert "no such port" in err
