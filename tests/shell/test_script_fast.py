"""The script runner's fast path for plain TMCL lines (Session.run_plain) and its held
output: the same lines, counts, hooks and errors as line-by-line ``run_line``, results and
errors in order in one file, and results out before a command waits."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time

from tmclsh.shell.lang import script
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session

SCRIPT = """\
GAP 1, 0
SAP 4, 0, 1234   # a comment
GAP 4, 0
99 0, 0, 0
GIO 0, 0 // another
SAP 4, 0, 777
GAP 4, 0
MST 0
.echo between
GAP 4, 0
"""


def _recorded(session: Session) -> list[tuple[str, str]]:
    calls: list[tuple[str, str]] = []
    session.recorders.append(lambda line, outcome: calls.append((line, outcome)))
    return calls


def test_a_script_prints_counts_and_records_what_its_lines_do_one_by_one(fast_client, tmp_path,
                                                                      capsys):
    path = tmp_path / "s.tmcl"
    path.write_text(SCRIPT)
    # line by line through run_line, as -c runs them
    slow = Session(fast_client, Output(), keep_going=True)
    slow_calls = _recorded(slow)
    for line in SCRIPT.splitlines():
        try:
            slow.run_line(line)
        except Exception:  # the status error of line 4, reported below by the script
            pass
    slow_out = capsys.readouterr().out
    # the same lines as a script (the fast path for all but .echo)
    fast = Session(fast_client, Output(), keep_going=True)
    fast_calls = _recorded(fast)
    assert script.run_file(fast, str(path)) == script.EXIT_FAILED
    cap = capsys.readouterr()
    lines = cap.out.splitlines()
    assert lines[:-1] == slow_out.splitlines()
    assert "MaxPositioningSpeed = 1234 pps" in lines and "MaxPositioningSpeed = 777 pps" in lines
    assert lines[-1].startswith(f"{path}: 9 commands sent, 0 checks passed, 0 failed, 1 error,")
    assert f"{path}:4: module answered status 2" in cap.err
    assert fast_calls == slow_calls
    assert (fast.stats.commands, fast.stats.errors) == (slow.stats.commands, slow.stats.errors)
    assert fast.last_result is not None and fast.last_result.line == "GAP 4, 0"
    assert fast.history == []  # what was typed, not what the script ran


def test_json_objects_are_those_of_single_lines(fast_client, tmp_path, capsys):
    path = tmp_path / "s.tmcl"
    path.write_text(SCRIPT)
    slow = Session(fast_client, Output(json_mode=True), keep_going=True)
    for line in SCRIPT.splitlines():
        try:
            slow.run_line(line)
        except Exception:
            pass
    slow_out = capsys.readouterr().out
    fast = Session(fast_client, Output(json_mode=True), keep_going=True)
    assert script.run_file(fast, str(path)) == script.EXIT_FAILED
    out = capsys.readouterr().out
    assert out == slow_out


def _tmclsh(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "tmclsh", "--sim", *args], text=True, **kw)


def test_results_and_errors_keep_their_order_in_one_file(tmp_path):
    path = tmp_path / "order.tmcl"
    path.write_text("GAP 4, 0\n" * 50 + "99 0, 0, 0\n" + "GAP 1, 0\n" * 50)
    out = tmp_path / "out.txt"
    with open(out, "w") as f:
        proc = _tmclsh("--keep-going", "-f", str(path), stdout=f, stderr=subprocess.STDOUT)
        assert proc.wait(60) == 1
    lines = out.read_text().splitlines()
    assert lines[:50] == ["MaxPositioningSpeed = 51200 pps"] * 50
    assert lines[50].startswith("error 2: ")  # the result line, then where it was
    assert lines[51].startswith(f"{path}:51: module answered status 2")
    assert lines[52:102] == ["ActualPosition = 0 µsteps"] * 50
    assert lines[102].startswith(f"{path}: 101 commands sent")


def test_results_reach_a_pipe_before_a_command_waits(tmp_path):
    path = tmp_path / "wait.tmcl"
    path.write_text(textwrap.dedent("""\
        GAP 4, 0
        .sleep 20
        """))
    start = time.monotonic()
    proc = _tmclsh("-f", str(path), stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline() == "MaxPositioningSpeed = 51200 pps\n"
        # long before the sleep ends: the line was not held until the end
        assert time.monotonic() - start < 15
    finally:
        proc.kill()
        proc.wait()


def test_a_line_met_again_is_the_same_step_and_a_block_still_gets_its_own(fast_client):
    """Parser.nodes takes a physical line it has met as a plain line whole; inside a block
    the same text still belongs to the block, and a command or two lines on one are never
    taken that way."""
    session = Session(fast_client, Output())
    lines = ["GAP 1, 0", "GAP 1, 0  # again", "GAP 1, 0", ".repeat 2", "GAP 1, 0", ".end",
             "GAP 1, 0", "GAP 1, 0; GAP 4, 0", "GAP 1, 0; GAP 4, 0", ".echo x", ".echo x",
             "GAP 1, 0"]
    nodes = list(script.Parser(session, "s.tmcl", None).nodes(lines))
    shape = [(type(n).__name__, n.line, n.text, getattr(n, "plain", None)) for n in nodes]
    assert shape == [
        ("Step", 1, "GAP 1, 0", "GAP 1, 0"), ("Step", 2, "GAP 1, 0", "GAP 1, 0"),
        ("Step", 3, "GAP 1, 0", "GAP 1, 0"), ("Repeat", 4, ".repeat 2", None),
        ("Step", 7, "GAP 1, 0", "GAP 1, 0"),
        ("Step", 8, "GAP 1, 0", "GAP 1, 0"), ("Step", 8, "GAP 4, 0", "GAP 4, 0"),
        ("Step", 9, "GAP 1, 0", "GAP 1, 0"), ("Step", 9, "GAP 4, 0", "GAP 4, 0"),
        ("Step", 10, ".echo x", None), ("Step", 11, ".echo x", None),
        ("Step", 12, "GAP 1, 0", "GAP 1, 0")]
    assert [(n.line, n.text) for n in nodes[3].body] == [(5, "GAP 1, 0")]
