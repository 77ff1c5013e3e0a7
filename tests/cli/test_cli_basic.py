"""The command line as a program sees it: ``-c``, ``--json``, ``--trace``, exit codes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parents[2]


def tmclsh(*args: str, stdin: str | None = None, tmp: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith("TMCLSH_")}
    env.update(XDG_CONFIG_HOME=str(tmp / "config"), XDG_STATE_HOME=str(tmp / "state"),
               PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "tmclsh", *args], input=stdin,
                          capture_output=True, text=True, timeout=60, cwd=ROOT, env=env)


def test_json_lines_are_the_design_contract(tmp_path):
    p = tmclsh("--sim", "-c", "SAP 4, 0, 1000; GAP 4, 0", "--json", tmp=tmp_path)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert len(lines) == 2
    sap, gap = (json.loads(line) for line in lines)
    # key order as DESIGN.md prints it; on the simulator every object says so
    keys = ["line", "op", "type", "motor", "value", "status", "reply", "simulated"]
    assert list(sap) == keys and list(gap) == keys
    assert lines[1] == ('{"line": "GAP 4, 0", "op": 6, "type": 4, "motor": 0, "value": 0, '
                        '"status": 100, "reply": 1000, "simulated": true}')
    expected_sap = ('{"line": "SAP 4, 0, 1000", "op": 5, "type": 4, "motor": 0, '
                    '"value": 1000, "status": 100, "reply": 1000, "simulated": true}')
    assert lines[0] == expected_sap


def test_json_error_object_and_exit_status(tmp_path):
    # ${...} is checked when its line runs: an error in the middle of the run
    p = tmclsh("--sim", "-c", "GAP 4, 0; SAP 140, 0, ${99}; GAP 1, 0", "--json", tmp=tmp_path)
    assert p.returncode == 1
    objs = [json.loads(line) for line in p.stdout.splitlines()]
    assert objs[0]["line"] == "GAP 4, 0" and objs[0]["status"] == 100
    assert objs[1] == {"line": "SAP 140, 0, ${99}",
                       "error": "99 is out of range for AP 140 MicrostepResolution: "
                                "allowed 0..8", "simulated": True}
    assert len(objs) == 2  # a -c run stops at the first error


def test_c_lines_are_all_checked_before_the_first_is_sent(tmp_path):
    # a typo at the end of a jig's -c line left the move of its first line running
    p = tmclsh("--sim", "-c", "MVP ABS, 0, 100000; SPA 4, 0, 5", "--trace", tmp=tmp_path)
    assert p.returncode == 2
    trace, rest = trace_and_rest(p.stderr)
    assert not [x for x in trace if "tx> " in x and "MVP" in x], trace
    assert rest == ["error: unknown command 'SPA'; did you mean SGP, SAP, STOP? (nothing "
                    "was sent: every line is checked first)"], rest
    p = tmclsh("--sim", "--json", "-c", "GAP 1, 0; .nosuch; GAP 1, 0", tmp=tmp_path)
    assert p.returncode == 2
    assert [json.loads(x) for x in p.stdout.splitlines()] == [
        {"line": ".nosuch", "error": "unknown shell command '.nosuch'; type .help for the list",
         "simulated": True}]


def trace_and_rest(stderr: str) -> tuple[list[str], list[str]]:
    """--trace's lines (a time, then tx>/<rx/!!/--) and the others."""
    trace = [x for x in stderr.splitlines() if x[13:17] in ("tx> ", "<rx ", "!!  ", "--  ")]
    return trace, [x for x in stderr.splitlines() if x not in trace]


def test_trace_on_stderr_and_nothing_sent_for_bad_input(tmp_path):
    p = tmclsh("--sim", "-c", "GAP 4, 0", "--trace", tmp=tmp_path)
    assert p.returncode == 0
    trace, _ = trace_and_rest(p.stderr)
    # the connect's own frames come first: 136 (what module), GP 129 (download mode?)
    assert "136 firmware version" in trace[0] and "version '1311V111'" in trace[1]
    assert "DownloadMode" in trace[2]
    assert "tx> 01 06 04 00 00 00 00 00 0b  GAP 4, 0  // MaxPositioningSpeed" in p.stderr
    assert "<rx 02 01 64 06" in p.stderr
    assert "tx>" not in p.stdout and "MaxPositioningSpeed = " in p.stdout
    p = tmclsh("--sim", "-c", "SAP 140, 0, 99", "--trace", tmp=tmp_path)
    assert p.returncode == 2
    trace, rest = trace_and_rest(p.stderr)
    assert rest == ["error: 99 is out of range for AP 140 MicrostepResolution: allowed 0..8 "
                    "(nothing was sent: every line is checked first)"]
    assert not [x for x in trace if "SAP" in x]  # nothing of the line was sent


def test_eeprom_write_needs_yes_in_scripts(tmp_path):
    p = tmclsh("--sim", "-c", "STAP MaxPositioningSpeed, 0", "--trace", tmp=tmp_path)
    assert p.returncode == 1
    trace, _ = trace_and_rest(p.stderr)
    assert "--yes" in p.stderr and not [x for x in trace if "STAP" in x]
    p = tmclsh("--sim", "-c", "STAP MaxPositioningSpeed, 0", "--yes", tmp=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "stored in EEPROM" in p.stdout


def test_help_from_the_command_line(tmp_path):
    p = tmclsh("--sim", "-c", "help SAP", tmp=tmp_path)
    assert p.returncode == 0
    assert "Set axis parameter" in p.stdout


def test_stdin_that_is_not_a_terminal_runs_as_a_script(tmp_path):
    p = tmclsh("--sim", stdin="SAP 4, 0, 321\nGAP 4, 0\n", tmp=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "MaxPositioningSpeed = 321 pps" in p.stdout


def test_a_shell_run_is_read_without_the_subcommands_parsers_and_says_the_same(capsys):
    """``-c``, ``-f`` and the prompt are read by a parser without the eleven subcommands'
    parsers (most of what the parser costs at every start); a subcommand, help, an error,
    ``--man`` (abbreviated too) and ``--completions`` by the whole one, with its words."""
    import argparse

    import pytest

    from tmclsh.cli.options import SUBCOMMANDS, build_parser, read_command_line

    def subparsers(parser: argparse.ArgumentParser) -> set[str]:
        return {name for a in parser._actions if isinstance(a, argparse._SubParsersAction)
                for name in a.choices}

    parser, args = read_command_line(["--port", "/dev/ttyACM0", "-c", "GAP 1, 0"])
    assert subparsers(parser) == set() and args.command == "GAP 1, 0" and args.subcommand is None
    parser, args = read_command_line(["-c", "scan"])  # (a word that is a subcommand's name)
    assert args.command == "scan"
    for argv in (["scan"], ["ports"], ["--ma"], ["--completions", "bash"]):
        parser, _ = read_command_line(argv)
        assert subparsers(parser) == set(SUBCOMMANDS), argv
    for argv in (["--help"], ["--baud", "fast", "-c", "GAP 1, 0"], ["bogus"]):
        with pytest.raises(SystemExit) as read:
            read_command_line(argv)
        said = capsys.readouterr()
        with pytest.raises(SystemExit) as whole:
            build_parser().parse_args(argv)
        assert (read.value.code, said) == (whole.value.code, capsys.readouterr()), argv
