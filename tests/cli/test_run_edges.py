"""The edges of a run are the same whatever the command (issue 32): an error that ends a run
under ``--json`` leaves one shape of record on stdout, ``{"line": ..., "error": "...",
"exit": N}`` (DESIGN.md), with the exit status the process ends with; the status is decided
in one place (``errors.exit_status``); a reader that goes away (``| head``) ends the run
quietly."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from bootmodel import START, hex_image
from conftest import ROOT, tmclsh_env
from tmclsh.base import errors
from tmclsh.base.edges import error_record
from tmclsh.cli import main as cli

MISSING = "/dev/tmclsh-i32-no-such-port"


@pytest.fixture
def quiet_config(monkeypatch):
    monkeypatch.setenv("TMCLSH_CONFIG", "/nonexistent/tmclsh-test-config.toml")
    for name in ("TMCLSH_PORT", "TMCLSH_CAN", "TMCLSH_SIM", "TMCLSH_PROFILE"):
        monkeypatch.delenv(name, raising=False)


def _last_record(capsys) -> dict:
    out = capsys.readouterr().out.strip().splitlines()
    assert out, "nothing on stdout"
    return json.loads(out[-1])


def _image(tmp_path, text: str | None = None) -> str:
    path = tmp_path / "fw.hex"
    path.write_text(hex_image("1311V112", 2000, START) if text is None else text)
    return str(path)


RUNS = {
    "-c": lambda img: ["--port", MISSING, "--json", "-c", "GAP 1, 0"],
    "-f": lambda img: ["--port", MISSING, "--json", "-f", img],
    "scan": lambda img: ["scan", "--port", MISSING, "--to", "1", "--json"],
    "firmware": lambda img: ["firmware", img, "--port", MISSING, "--check", "--json"],
    "monitor": lambda img: ["monitor", "--port", MISSING, "--json", "--count", "1"],
    "bridge": lambda img: ["bridge", "--tcp", "127.0.0.1:0", "--port", MISSING, "--json"],
}


@pytest.mark.parametrize("name", RUNS)
def test_every_command_ends_with_one_error_record(name, quiet_config, capsys, tmp_path):
    status = cli.main(RUNS[name](_image(tmp_path)))
    record = _last_record(capsys)
    assert list(record)[0] == "line" and record["line"] is None, record
    assert MISSING in record["error"], record
    assert record["exit"] == status != 0, (status, record)


def test_a_refused_firmware_image_is_the_same_record(quiet_config, capsys, tmp_path):
    status = cli.main(["firmware", _image(tmp_path, "not a hex file\n"), "--port", MISSING,
                       "--json", "--yes"])
    record = _last_record(capsys)
    assert status == errors.EXIT_USAGE
    assert record == {"line": None, "error": record["error"], "exit": errors.EXIT_USAGE}
    assert "nothing was sent" in record["error"]


def test_an_error_record_names_its_line_and_fields_before_the_error():
    assert list(error_record("bad", 3, line="GAP 1, 0", check="x")) == [
        "line", "check", "error", "exit"]
    assert error_record("bad") == {"line": None, "error": "bad"}


@pytest.mark.parametrize("exc, status", [
    (KeyboardInterrupt(), errors.EXIT_INTERRUPTED),
    (errors.UsageError("--can wants IFACE:CHANNEL"), errors.EXIT_USAGE),
    (errors.ConnectError("no module found"), errors.EXIT_CONNECT),
    (errors.NoAnswerError("no answer"), errors.EXIT_CONNECT),
    (errors.TransportError("port gone"), errors.EXIT_FAILED),
    (errors.ValidationError("value out of range"), errors.EXIT_FAILED),
    (OSError("disk full"), errors.EXIT_FAILED),
])
def test_the_exit_status_of_an_error_is_decided_once(exc, status):
    assert errors.exit_status(exc) == status


@pytest.mark.parametrize("args", [["modules"], ["--sim", "-c", "GAP 1, 0; GAP 1, 0"]])
def test_a_reader_that_goes_away_ends_the_run_quietly(args):
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", *args], cwd=str(ROOT),
                            env=tmclsh_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL)
    proc.stdout.close()  # (the reader gone before the first line, as `| head -0`)
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) in (0, 1), err
    assert "Traceback" not in err and "Broken pipe" not in err, err
