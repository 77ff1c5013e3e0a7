"""Scripts (tmclsh.shell.lang.script) against the simulator: variables, expressions with module
reads, checks, waits, blocks, includes, errors with FILE:LINE and exit status, summary,
stdin, recording and history.
"""

from __future__ import annotations

import io
import json
import re
import subprocess
import sys
import textwrap
import time

import pytest

from conftest import ROOT, patience, tmclsh_env
from tmclsh.cli import main as cli
from tmclsh.client.text import LineClient
from tmclsh.base.errors import ValidationError
from tmclsh.shell.lang import script
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session
from tmclsh.link import open_sim


@pytest.fixture
def sim(fast_client):
    """A fast simulated TMCM-1311 (module time 20x real time) behind a client."""
    return fast_client


@pytest.fixture
def session(sim):
    return Session(sim, Output())


@pytest.fixture
def json_session(sim):
    return Session(sim, Output(json_mode=True))


def write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text).lstrip())
    return path


def run(session, path):
    return script.run_file(session, str(path))


def simulator(session):
    return session.client.transport.simulator


# -- variables, expressions and module reads ------------------------------------------------

def test_variables_expressions_and_reads(session, tmp_path, capsys):
    path = write(tmp_path, "vars.tmcl", """
        # comments: '#' and '//' lines, and '//' after a line
        // another comment
        .let speed = 1000
        SAP 4, 0, ${speed}          // written as 1000
        SAP 5, 0, ${speed * 2 + 1}
        .let p = GAP 4, 0           // a value read from the module
        .let half = p / 2
        .echo p=${p} half=${half} accel=${GAP 5, 0} gio=${GIO 8, 1 / 10}
        """)
    assert run(session, path) == 0
    out = capsys.readouterr().out
    assert simulator(session).param("axis", 4) == 1000
    assert simulator(session).param("axis", 5) == 2001
    assert session.variables == {"speed": 1000, "p": 1000, "half": 500.0}
    assert "p=1000 half=500 accel=2001 gio=24" in out


def test_expect_passes_and_fails_with_expected_and_actual(session, tmp_path, capsys):
    path = write(tmp_path, "check.tmcl", """
        SAP ActualPosition, 0, 4800
        .expect GAP 1, 0 == 4800
        .expect GAP 1, 0 == 5000
        .echo not reached
        """)
    assert run(session, path) == script.EXIT_FAILED
    cap = capsys.readouterr()
    assert "passed: GAP 1, 0 == 4800" in cap.out
    assert f"{path}:3: expectation failed: GAP 1, 0 == 5000 (GAP 1, 0 is 4800)" in cap.err
    assert "not reached" not in cap.out
    assert session.stats.checks_passed == 1 and session.stats.checks_failed == 1
    # the summary: commands, checks, time
    assert "check.tmcl: 3 commands sent, 1 check passed, 1 failed, 0 errors" in cap.out


def test_summary_counts_shell_commands_that_talked_to_the_module(session, tmp_path, capsys):
    # ".run" and ".stop" drive the stored program without a TMCL line: a summary of
    # "0 commands sent" would tell the reader the module was not touched
    path = write(tmp_path, "prog.tmcl", """
        .echo start
        .run
        .status
        .stop
        .let x = 1
        """)
    assert run(session, path) == 0
    out = capsys.readouterr().out
    assert ("prog.tmcl: 0 commands sent and 3 shell commands that talked to the module, "
            "0 checks passed") in out, out
    assert session.stats.commands == 0


def test_an_unterminated_substitution_is_a_syntax_error(session, tmp_path, capsys):
    # it was printed (or sent) as it stood, and the script passed
    path = write(tmp_path, "unterm.tmcl", """
        SAP 4, 0, 1000
        .echo ${GAP 1, 0
        """)
    assert run(session, path) == script.EXIT_USAGE
    cap = capsys.readouterr()
    assert f"{path}:2: unterminated ${{...}}: a '}}' is missing" in cap.err
    assert simulator(session).param("axis", 4) != 1000  # nothing was sent
    with pytest.raises(ValidationError, match="unterminated"):
        session.run_line(".echo a ${1} b ${2")
    assert "a 1" not in capsys.readouterr().out


def test_expect_names_both_sides_when_the_right_one_is_computed(session, tmp_path, capsys):
    path = write(tmp_path, "sides.tmcl", """
        .let target = 100
        .repeat 2 as port
          SIO ${port}, 2, 1
        .end
        .expect GIO (port), 2 == target - 99 - port
        """)
    assert run(session, path) == 1
    err = capsys.readouterr().err
    assert "sides.tmcl:5: expectation failed: GIO (port), 2 == target - 99 - port " \
           "(GIO 1, 2 is 1, target - 99 - port is 0)" in err


def test_wait_polls_until_the_motor_arrives(session, tmp_path):
    path = write(tmp_path, "wait.tmcl", """
        SAP 4, 0, 100000
        SAP 5, 0, 1000000
        MVP ABS, 0, 20000
        .wait GAP TargetPositionReached, 0 == 1 --timeout 5 --interval 0.01
        .expect GAP ActualPosition, 0 == 20000
        """)
    t0 = time.monotonic()
    assert run(session, path) == 0
    assert time.monotonic() - t0 < patience(3)


def test_wait_timeout_is_an_error_with_the_last_value(session, tmp_path, capsys):
    path = write(tmp_path, "timeout.tmcl", """
        .let wanted = 1
        .wait GIO 1, 0 == wanted --timeout 0.2 --interval 0.02
        .echo after
        """)
    t0 = time.monotonic()
    assert run(session, path) == script.EXIT_FAILED
    assert 0.2 <= time.monotonic() - t0 < patience(1.5)
    cap = capsys.readouterr()
    assert (f"{path}:2: timed out after 0.2 s waiting for GIO 1, 0 == wanted "
            "(GIO 1, 0 is 0, wanted is 1)") in cap.err
    assert "after" not in cap.out


def test_wait_sees_an_input_change(session, tmp_path):
    import threading

    path = write(tmp_path, "input.tmcl", ".wait GIO 1, 0 == 1 --timeout 3 --interval 0.01\n")
    threading.Timer(0.1, simulator(session).set_input, (0, 1, 1)).start()
    assert run(session, path) == 0


def test_sleep(session, tmp_path):
    path = write(tmp_path, "sleep.tmcl", ".let s = 0.1\n.sleep s * 2\n")
    t0 = time.monotonic()
    assert run(session, path) == 0
    assert 0.2 <= time.monotonic() - t0 < patience(1)


# -- blocks and includes ----------------------------------------------------------------

def test_repeat_nests_and_counts_from_zero(session, tmp_path, capsys):
    path = write(tmp_path, "loops.tmcl", """
        .repeat 2 as i
          .repeat 3 as j
            .echo ${i}.${j}
          .end
        .end
        .let n = 0
        .repeat 0
          .echo never
        .end
        """)
    assert run(session, path) == 0
    assert capsys.readouterr().out.split()[:6] == ["0.0", "0.1", "0.2", "1.0", "1.1", "1.2"]


def test_if_elif_else(session, tmp_path, capsys):
    path = write(tmp_path, "if.tmcl", """
        .repeat 3 as k
          .if k == 0
            .echo zero
          .elif k == 1 and GIO 8, 1 > 100
            .echo one
          .else
            .echo many
          .end
        .end
        """)
    assert run(session, path) == 0
    assert capsys.readouterr().out.split()[:3] == ["zero", "one", "many"]


def test_source_is_relative_to_the_including_script(session, tmp_path, capsys):
    sub = tmp_path / "lib"
    sub.mkdir()
    write(sub, "set.tmcl", ".let x = 41\n.source more.tmcl\n")
    write(sub, "more.tmcl", ".let x = x + 1\n")
    main = write(tmp_path, "main.tmcl", ".source lib/set.tmcl\n.echo x=${x}\n")
    assert run(session, main) == 0
    assert "x=42" in capsys.readouterr().out


def test_error_in_an_included_file_names_that_file(session, tmp_path, capsys):
    inner = write(tmp_path, "inner.tmcl", ".let a = 1\n.expect a == 2\n")
    outer = write(tmp_path, "outer.tmcl", ".source inner.tmcl\n.echo after\n")
    assert run(session, outer) == 1
    cap = capsys.readouterr()
    assert f"{inner}:2: expectation failed: a == 2" in cap.err
    assert "after" not in cap.out


# -- errors: syntax (nothing sent), module error, keep-going ------------------------------

@pytest.mark.parametrize("body, line, message", [
    ("GAP 1, 0\nSAP 4, 0\n", 2, "SAP needs a value"),
    ("GAP 1, 0\nFOO 1, 2\n", 2, "unknown command 'FOO'"),
    ("SAP 4, 0, 1000\n.nosuch 3\n", 2, "unknown shell command '.nosuch'"),
    (".let x = (1 + \n", 1, "expression ends too early"),
    (".expect GAP 1, 0 = 5\n", 1, "write '=='"),
    (".repeat 2\nGAP 1, 0\n", 1, ".repeat has no matching .end"),
    ("GAP 1, 0\n.end\n", 2, ".end without .repeat or .if"),
    (".if 1\n.else\n.else\n.end\n", 3, ".else after .else"),
    (".wait GAP 8, 0 == 1 --timout 3\n", 1, "unknown option --timout"),
    (".expect GAP 99, 0 == 1\n", 1, "GAP 99, 0"),
    (".source nowhere.tmcl\n", 1, "no such file"),
    (".let and = 1\n", 1, "reserved word"),
])
def test_syntax_errors_stop_before_anything_is_sent(session, tmp_path, capsys, body, line,
                                                    message):
    path = write(tmp_path, "bad.tmcl", "MVP ABS, 0, 1000\n" + body)
    sent = session.client.stats["sent"]
    assert run(session, path) == script.EXIT_USAGE
    err = capsys.readouterr().err
    assert f"{path}:{line + 1}: " in err and message in err, err
    assert session.client.stats["sent"] == sent  # the MVP on line 1 never went out
    assert simulator(session).param("axis", 0) == 0


def test_module_error_reply_stops_with_file_and_line(session, tmp_path, capsys):
    path = write(tmp_path, "status.tmcl", "GAP 1, 0\n99 0, 0, 0\n.echo after\n")
    assert run(session, path) == script.EXIT_FAILED
    cap = capsys.readouterr()
    assert f"{path}:2: module answered status 2" in cap.err
    assert "after" not in cap.out


def test_keep_going_runs_on_and_still_fails(session, tmp_path, capsys):
    session.keep_going = True
    path = write(tmp_path, "kg.tmcl", """
        .expect 1 == 2
        99 0, 0, 0
        .echo reached the end
        """)
    assert run(session, path) == script.EXIT_FAILED
    cap = capsys.readouterr()
    assert "kg.tmcl:1: expectation failed" in cap.err and "kg.tmcl:2: module answered" in cap.err
    assert "reached the end" in cap.out
    assert "0 checks passed, 1 failed, 1 error," in cap.out


def test_onerror_runs_when_the_script_stops(session, tmp_path, capsys):
    path = write(tmp_path, "onerr.tmcl", """
        .onerror MST 0
        ROR 0, 50000
        .expect GAP ActualSpeed, 0 < 0
        """)
    assert run(session, path) == 1
    assert "onerr.tmcl:1: .onerror: MST 0" in capsys.readouterr().out
    time.sleep(0.2)
    assert session.client.value("GAP 2, 0") == 0  # target speed: stopped by the handler
    assert session.state.onerror is None


def test_quit_ends_a_script_without_error(session, tmp_path, capsys):
    path = write(tmp_path, "q.tmcl", ".echo one\nquit\n.echo two\n")
    assert run(session, path) == 0
    out = capsys.readouterr().out
    assert "one" in out and "two" not in out


# -- JSON, stdin, CLI ---------------------------------------------------------------------

def test_json_errors_are_objects_and_the_summary_goes_to_stderr(json_session, tmp_path,
                                                                 capsys):
    path = write(tmp_path, "j.tmcl", "GAP 4, 0\n.expect GAP 4, 0 == 1\n")
    assert run(json_session, path) == 1
    cap = capsys.readouterr()
    objs = [json.loads(line) for line in cap.out.splitlines()]
    assert objs[0]["line"] == "GAP 4, 0" and objs[0]["reply"] == 51200
    assert objs[1]["line"] == ".expect GAP 4, 0 == 1"
    assert objs[1]["error"].startswith(f"{path}:2: expectation failed")
    assert "j.tmcl: 2 commands sent" in cap.err


def test_json_syntax_errors_name_the_line_refused(json_session, tmp_path, capsys):
    """A script refused before the run says which line, as a run-time error does (it said
    "line": null); a file that cannot be read at all blames no line."""
    inner = write(tmp_path, "inner.tmcl", "GAP 1, 0\nGAP 999, 0\n")
    cases = {"GAP 1, 0\nSAP 4, 0\n": "SAP 4, 0",
             "GAP 1, 0\n.repeat 2\nGAP 4, 0\n": ".repeat 2",
             ".frob\n": ".frob",
             f".source {inner}\n": "GAP 999, 0"}
    for i, (text, refused) in enumerate(cases.items()):
        path = write(tmp_path, f"s{i}.tmcl", text)
        assert run(json_session, path) == 2
        (obj,) = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
        assert obj["line"] == refused and "error" in obj, text
    assert run(json_session, str(tmp_path / "missing.tmcl")) == 2
    (obj,) = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert obj["line"] is None and "missing.tmcl" in obj["error"]


def test_stdin_runs_blocks_as_they_complete(session, monkeypatch, capsys):
    monkeypatch.setattr(sys, "stdin", io.StringIO(".repeat 2 as i\n.echo ${i}\n.end\n"
                                                  "GAP 4, 0\n.expect 1 == 0\n.echo no\n"))
    assert script.run_file(session, "-") == 1
    cap = capsys.readouterr()
    assert cap.out.split()[:2] == ["0", "1"]
    assert "<stdin>:5: expectation failed" in cap.err


def test_cli_exit_status_and_located_errors(tmp_path, capsys):
    ok = write(tmp_path, "ok.tmcl", "SAP 4, 0, 777\n.expect GAP 4, 0 == 777\n")
    bad = write(tmp_path, "bad.tmcl", "GAP 1, 0\n.expect GAP 4, 0 == 1\n")
    syntax = write(tmp_path, "syntax.tmcl", "GAP 1, 0\nSAP 4, 0\n")
    assert cli.main(["--sim", "-f", str(ok)]) == 0
    assert cli.main(["--sim", "-f", str(bad)]) == 1
    assert f"{bad}:2: expectation failed" in capsys.readouterr().err
    assert cli.main(["--sim", "-f", str(syntax)]) == 2
    assert cli.main(["--sim", "-f", str(tmp_path / "missing.tmcl")]) == 2
    err = capsys.readouterr().err
    assert f"{syntax}:2: " in err and "no such file" in err


def test_cli_dash_reads_stdin(monkeypatch, capsys):
    monkeypatch.setattr(sys, "stdin", io.StringIO("SAP 4, 0, 1234\nGAP 4, 0\n"))
    assert cli.main(["--sim", "--json", "-f", "-"]) == 0
    objs = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [o["reply"] for o in objs][-1] == 1234


def test_a_bad_line_from_stdin_after_lines_were_sent_is_exit_1(monkeypatch, capsys):
    """Exit 2 says nothing was sent; stdin sends each line as it comes, so a bad one after
    others is a failed run (as in -c)."""
    monkeypatch.setattr(sys, "stdin", io.StringIO("SAP 4, 0, 1234\nSAP 4, 0\n"))
    assert cli.main(["--sim", "-f", "-"]) == 1
    assert "stopped (syntax error) after 1 command sent" in capsys.readouterr().out
    monkeypatch.setattr(sys, "stdin", io.StringIO("SAP 4, 0\nGAP 4, 0\n"))
    assert cli.main(["--sim", "-f", "-"]) == 2  # the first line: nothing sent


# -- ${expression}, blocks and .source typed at the prompt (or in -c) ---------------------

def test_dollar_expressions_in_any_line(session):
    session.variables["v"] = 10
    session.run_line("SAP 4, 0, ${v * 100 + GAP 5, 0 - GAP 5, 0}")
    assert simulator(session).param("axis", 4) == 1000


def test_blocks_typed_line_by_line(session, capsys):
    for line in [".repeat 2 as i", ".if i == 1", ".echo one", ".else", ".echo zero", ".end",
                 ".end"]:
        session.run_line(line)
    assert capsys.readouterr().out.split() == ["zero", "one"]
    assert session.state.capture is None
    assert session.history[-1] == ".end" and len(session.history) == 7  # as typed, once


def test_c_lines_with_a_block(capsys):
    assert cli.main(["--sim", "-c", ".repeat 3 as i\n.echo n${i}\n.end"]) == 0
    assert capsys.readouterr().out.split() == ["n0", "n1", "n2"]


def test_source_from_the_prompt_reports_and_fails_once(session, tmp_path, capsys):
    path = write(tmp_path, "s.tmcl", ".echo hi\n.expect 0\n")
    with pytest.raises(script.ScriptError) as info:
        session.run_line(f".source {path}")
    assert info.value.shown  # the runner already printed it with FILE:LINE
    cap = capsys.readouterr()
    assert "hi" in cap.out and f"{path}:2: expectation failed: 0 (value 0)" in cap.err


def test_source_with_a_bad_line_5_says_nothing_ran(session, tmp_path):
    """A file is checked whole before its first line runs: its error says that nothing of
    it was sent, as -f's 'not run (...; nothing was sent)' does."""
    path = write(tmp_path, "s.tmcl", "SAP 4, 0, 1000\nGAP 4, 0\n.echo four\n\n"
                                     "SAP 4, 0, -7\n")
    sent = session.client.stats["sent"]
    with pytest.raises(script.ScriptError) as info:
        session.run_line(f".source {path}")
    assert str(info.value).startswith(f"{path}:5: -7 is out of range")
    assert str(info.value).endswith(f"({path} not run: nothing was sent)")
    assert session.client.stats["sent"] == sent


def test_end_outside_a_block(session):
    with pytest.raises(Exception, match="without an open .repeat"):
        session.run_line(".end")


# -- .echo to files, .record, .history ------------------------------------------------------

def test_echo_redirects(session, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    session.run_line(".echo first > out.txt")
    session.run_line(".echo second ${1 + 1} >> out.txt")
    session.run_line('.echo "a > b" >> out.txt')
    assert (tmp_path / "out.txt").read_text() == "first\nsecond 2\na > b\n"


def test_record_replays_as_is(session, tmp_path, capsys):
    rec = tmp_path / "rec.tmcl"
    lines = [f".record {rec}", ".let s = 3000", "SAP 4, 0, ${s}", "GAP 4, 0", "GAPP 1, 0",
             ".repeat 2 as i", "SAP 5, 0, ${1000 + i}", ".end", ".watch GAP 1, 0 --count 1",
             ".record off"]
    for line in lines:
        try:
            session.run_line(line)
        except Exception:
            pass
    text = rec.read_text()
    body = [line for line in text.splitlines() if not line.startswith("# recorded")
            and not line.startswith("# replay")]
    assert body == [".let s = 3000", "SAP 4, 0, ${s}", "GAP 4, 0    // = 3000",
                    body[3], ".repeat 2 as i", "SAP 5, 0, ${1000 + i}", ".end",
                    "# .watch GAP 1, 0 --count 1    // view, not replayed"]
    assert body[3].startswith("# GAPP 1, 0    // error: ") and "GAPP" in body[3]
    # replay in a fresh simulator: same end state
    fresh = LineClient(open_sim("TMCM-1311", 1, speed=20), module="TMCM-1311", timeout=0.5)
    try:
        assert script.run_file(Session(fresh, Output()), str(rec)) == 0
        assert fresh.value("GAP 4, 0") == 3000 and fresh.value("GAP 5, 0") == 1001
    finally:
        fresh.close()


def test_history(session, capsys):
    session.run_line("GAP 4, 0")
    session.run_line(".let a = 1")
    capsys.readouterr()
    session.run_line(".history")
    assert capsys.readouterr().out.split("\n")[:2] == ["   1  GAP 4, 0", "   2  .let a = 1"]
    session.run_line(".history 1")
    assert capsys.readouterr().out.strip() == "3  .history"


# -- progress --------------------------------------------------------------------------------

def test_progress_only_for_long_scripts_on_a_terminal(session, tmp_path):
    short = list(script.Parser(session, "s", tmp_path).nodes(["GAP 1, 0"] * 3))
    long = list(script.Parser(session, "l", tmp_path).nodes(
        [".repeat 10", "GAP 1, 0", "GAP 3, 0", ".end"]))
    assert script.count_steps(long) == (20, False)
    assert script._progress(session, "l", long) is None  # captured stdout: not a terminal
    session.out.console.is_terminal  # noqa: B018 - the property the decision reads
    from rich.console import Console

    session.out.console = Console(force_terminal=True, file=io.StringIO())
    assert script._progress(session, "s", short) is None
    assert script._progress(session, "l", long) is not None
    watch = list(script.Parser(session, "w", tmp_path).nodes(
        ["GAP 1, 0"] * 30 + [".watch GAP 1, 0 --count 1"]))
    assert script._progress(session, "w", watch) is None  # a live view inside: no bar


def test_c_checks_a_commands_arguments_before_anything_is_sent(tmp_path):
    """-c checks every line before the first is sent, shell commands' arguments included:
    a watch that swallows the line after it (its ';' separates expressions) must not leave
    the motor of the line before it turning (it did: ROR ran, then the watch failed)."""
    from tmclsh.sim import Simulator
    from tmclsh.sim.serve import serve_pty

    sim = Simulator("TMCM-1311")
    server = serve_pty(sim)
    try:
        p = subprocess.run([sys.executable, "-m", "tmclsh", "--port", server.path, "-c",
                            "ROR 0, 3000; .watch pos=GAP 1, 0 --count 3; MST 0"],
                           capture_output=True, text=True, timeout=60, env=tmclsh_env(),
                           cwd=str(ROOT))
        assert p.returncode == 2, p.stderr
        assert "nothing was sent" in p.stderr and "ok:" not in p.stdout
        assert sim.param("axis", 3, 0) == 0
    finally:
        server.close()
        sim.close()


def test_record_stop_ends_the_recording_and_is_never_a_file_name(session, tmp_path,
                                                                  monkeypatch, capsys):
    """Issue 35: `.record stop` started a recording into a file named `stop`."""
    monkeypatch.chdir(tmp_path)
    rec = tmp_path / "rec.tmcl"
    session.run_line(f".record {rec}")
    session.run_line("GAP 4, 0")
    session.run_line(".record stop")
    assert session.state.record is None and not (tmp_path / "stop").exists()
    assert "GAP 4, 0" in rec.read_text()
    capsys.readouterr()
    session.run_line(".record stop")  # not recording: said, and still no file
    said = capsys.readouterr()
    assert "not recording" in said.out + said.err
    assert session.state.record is None and not (tmp_path / "stop").exists()


def test_wait_says_when_the_condition_was_reached(session, capsys):
    """Issue 35: `.wait` printed nothing when it succeeded."""
    capsys.readouterr()
    session.run_line(".wait GAP 1, 0 == 0 --timeout 10")
    out = capsys.readouterr().out
    assert re.search(r"^reached after \d+\.\d\d s: GAP 1, 0 == 0 \(", out, re.M), out
