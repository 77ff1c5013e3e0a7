"""Issue 12's hand-picked inputs, one or more of each class, through ``tmclsh -c``, ``-f``
and the REPL: each ends in one error line (or works), never a traceback or "internal error",
with the documented exit status.

The classes: expression functions given the wrong arguments; durations, intervals and counts
beyond any real use; very long or deeply nested expressions; user text that looks like rich
markup; files that cannot be written; inputs without end; numbers Python refuses; settings on
the command line, in variables and in profiles; broken configuration files.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from conftest import ROOT, tmclsh_env
from test_repl import repl  # noqa: F401  (the REPL on a pipe, as in test_repl)

DIGITS = "9" * 5000
NESTED = "(" * 500 + "1" + ")" * 500
SUM = "+".join(["1"] * 500)
LONG_SUM = "+".join(["1"] * 999)

# (line, exit status of `tmclsh --sim -c LINE`, text the error must contain or None: works)
LINES = [
    # wrong arity and kind of function arguments
    (".let x = min(5)", 0, None),
    (".let x = min()", 1, "min() takes 1..16 arguments"),
    (".let x = abs(1, 2)", 1, "abs() takes 1 argument"),
    (".let x = bit(1.5, 2)", 1, "bit()"),
    (".let x = round()", 1, "round() takes 1 argument"),
    (".let x = max(" + ", ".join(["1"] * 17) + ")", 1, "max() takes 1..16 arguments"),
    # durations, intervals and counts
    (".sleep 1e300", 1, ".sleep: must be a number of seconds from 0 to 86400"),
    (".sleep 86401", 1, "from 0 to 86400"),
    (".sleep -1", 1, "from 0 to 86400"),
    (".wait GAP 1, 0 == 0 --interval 1e300", 1, "--interval: must be a number of seconds"),
    (".wait GAP 1, 0 == 1 --timeout nan", 1, "--timeout: must be a number of seconds"),
    (".wait GAP 1, 0 == 5 --timeout 0.2 --interval 86400", 1, "timed out after 0.2 s"),
    (".repeat 1e999", 1, "number 1e999 is too large"),
    (".repeat 10000000\nGAP 1, 0\n.end", 1, ".repeat count: must be a whole number from 0 to"),
    (".watch GAP 1, 0 --count 1e999", 1, "--count: must be a whole number from 1 to"),
    (".watch GAP 1, 0 --interval 1e300 --count 1", 1, "--interval: must be"),
    (".step 99999999999999999999", 1, ".step N: must be a whole number from 1 to"),
    (".plot --width 1e9", 1, "--width: must be a whole number"),
    # long and deeply nested expressions
    (f"SAP 4, 0, {SUM}", 1, "expression has more than 128 operators (column"),
    (f".let x = {NESTED}", 1, "expression nested too deeply (column"),
    (f".let x = {LONG_SUM}", 1, "expression has more than 128 operators (column"),
    (".let x = " + "not " * 300 + "1", 1, "nested too deeply"),
    (".let x = " + "1+" * 1500 + "1", 1, "longer than 2000 characters"),
    # user text shown through rich
    (".param [/]", 0, None),
    (".params axis [/]", 0, None),
    (".param [bold]x", 1, "'[bold]x'"),
    (".echo [/] [bold]", 0, None),
    (".help [/]", 1, "'[/]'"),
    # files that cannot be written
    (".record /dev/full\nGAP 1, 0", 1, "cannot write /dev/full: No space left on device"),
    (".record /nonexistent/dir/x.tmcl", 1, "cannot write /nonexistent/dir/x.tmcl: no such folder /nonexistent/dir"),
    (".watch GAP 1, 0 --count 1 --csv /dev/full", 1, "cannot write /dev/full"),
    (".watch GAP 1, 0 --count 1 --csv /nonexistent/x.csv", 1, "cannot write /nonexistent/x.csv"),
    (".echo hi > /dev/full", 1, "cannot write /dev/full"),
    (".dump /dev/full", 1, "cannot write /dev/full"),
    # inputs without end
    (".source /dev/zero", 1, "/dev/zero: script larger than 16 MiB"),
    (".upload /dev/zero", 1, "/dev/zero: program larger than 16 MiB"),
    (".plot /dev/zero", 1, "/dev/zero: CSV file larger than 16 MiB"),
    (".source /", 1, "cannot read /: it is a directory"),
    # numbers Python refuses
    (f".let x = {DIGITS}", 1, "longer than 2000 characters"),
    (f"SAP 4, 0, {DIGITS}", 1, "line longer than 4096 characters"),
    (f"SAP 4, 0, {DIGITS[:100]}", 1, "is too long"),
    (f".let x = {DIGITS[:100]}", 1, "is too long"),
    (f".sleep {DIGITS[:100]}", 1, "is too long"),
    (f".param {DIGITS}", 1, "no parameter matches"),
    (f".help {DIGITS}", 1, "no help topic"),
    (f".history {DIGITS}", 1, "must be a whole number from 1 to"),
    (f".step {DIGITS}", 1, "must be a whole number from 1 to"),
    (f".dump --count {DIGITS}", 1, "must be a number"),
]


def _one_error_line(stderr: str, expected: str | None) -> None:
    assert "Traceback" not in stderr and "internal error" not in stderr, stderr
    rows = [r for r in stderr.splitlines() if r.strip()]
    if expected is None:
        assert not [r for r in rows if "error" in r], stderr
    else:
        assert len(rows) == 1, f"not one line:\n{stderr[:2000]}"
        assert expected in rows[0], rows[0][:500]


def _ids(cases):
    return [c[0][:40].replace("\n", "; ") for c in cases]


@pytest.fixture
def env(tmp_path):
    return tmclsh_env(XDG_CONFIG_HOME=str(tmp_path / "config"))


def _tmclsh(*args: str, env: dict, cwd, stdin=None, timeout: float = 60):
    return subprocess.run([sys.executable, "-m", "tmclsh", *args], capture_output=True,
                          text=True, timeout=timeout, env=env, cwd=str(cwd), stdin=stdin)


@pytest.mark.parametrize("line, status, expected", LINES, ids=_ids(LINES))
def test_hostile_lines_with_c(line, status, expected, env, tmp_path):
    r = _tmclsh("--sim", "-y", "-c", line, env=env, cwd=tmp_path)
    _one_error_line(r.stderr, expected)
    # -c's lines (TMCL, and shell commands' arguments) are checked before the first is
    # sent: what the check finds is exit 2
    checked = r.stderr.endswith("(nothing was sent: every line is checked first)\n")
    assert checked or not (line.startswith("SAP") and expected is not None), r.stderr
    assert not checked or expected is not None, r.stderr
    assert r.returncode == (2 if checked else status), r.stderr


@pytest.mark.parametrize("line, status, expected", LINES, ids=_ids(LINES))
def test_hostile_lines_with_f(line, status, expected, env, tmp_path):
    script = tmp_path / "s.tmcl"
    script.write_text(line + "\n")
    r = _tmclsh("--sim", "-y", "-f", str(script), env=env, cwd=tmp_path)
    _one_error_line(r.stderr, expected)
    if expected is not None:
        assert r.stderr.startswith(f"{script}:"), r.stderr[:300]  # FILE:LINE: message
    # a script is checked before it runs: what the check finds is exit 2, nothing sent
    checked = "not run (" in r.stdout and "nothing was sent)" in r.stdout
    assert r.returncode == (2 if checked else status), (r.stdout[-300:], r.stderr[:300])


def test_hostile_lines_in_the_repl(repl):
    """Typed at the prompt, each line answers with one error line (or works) and the prompt
    comes back; the REPL never says "internal error"."""
    repl.start()
    for line, status, expected in LINES:
        if "\n" in line or len(line) > 1200:
            continue  # blocks are typed line by line elsewhere; the prompt is one line here
        repl.wait_prompt()
        typed = len(repl.session.history)
        mark = len(repl.screen.text())
        repl.type(line + "\r")
        deadline = time.monotonic() + 20
        while len(repl.session.history) == typed and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.05)
        repl.wait_prompt()  # the line has run and the prompt is back
        shown = repl.screen.text()[mark:]
        assert "internal error" not in shown and "Traceback" not in shown, shown[-2000:]
        if expected is not None:
            errors = [r for r in shown.splitlines() if r.startswith("error:")]
            assert len(errors) == 1 and expected in errors[0], (line[:60], shown[-1500:])
    assert repl.quit() == 0


# -- settings: options, variables and profiles take the same values -----------------------

SETTINGS = [
    # (option, value, variable, profile key, message)
    ("--timeout", "nan", "TMCLSH_TIMEOUT", "timeout", "must be a number of seconds from 0.001 to 60"),
    ("--timeout", "1e300", "TMCLSH_TIMEOUT", "timeout", "must be a number of seconds from 0.001 to 60"),
    ("--timeout", "0", "TMCLSH_TIMEOUT", "timeout", "must be a number of seconds from 0.001 to 60"),
    ("--baud", "0", "TMCLSH_BAUD", "baud", "must be one of 9600, 14400"),
    ("--baud", "-5", "TMCLSH_BAUD", "baud", "must be one of 9600, 14400"),
    ("--baud", "12345678901234567890", "TMCLSH_BAUD", "baud", "must be one of 9600"),
    ("--retries", "-1", "TMCLSH_RETRIES", "retries", "must be a whole number from 0 to 10"),
    ("--address", "256", "TMCLSH_ADDRESS", "address", "must be a whole number from 0 to 255"),
    ("--can-id", "99999", "TMCLSH_CAN_ID", "can_id", "must be a whole number from 0 to 2047"),
]


def _toml_value(text: str) -> str:
    return {"nan": "nan", "1e300": "1e300"}.get(text, text)


@pytest.mark.parametrize("option, value, var, key, message", SETTINGS,
                         ids=[f"{s[0]}={s[1]}" for s in SETTINGS])
def test_bad_settings_from_all_three_sources(option, value, var, key, message, env, tmp_path):
    on_line = _tmclsh("--sim", option, value, "-c", "GAP 1, 0", env=env, cwd=tmp_path)
    from_env = _tmclsh("--sim", "-c", "GAP 1, 0", env={**env, var: value}, cwd=tmp_path)
    conf = tmp_path / "p.toml"
    conf.write_text(f"[profiles.x]\n{key} = {_toml_value(value)}\n")
    from_profile = _tmclsh("--sim", "--profile", "x", "-c", "GAP 1, 0",
                           env={**env, "TMCLSH_CONFIG": str(conf)}, cwd=tmp_path)
    for r in (on_line, from_env, from_profile):
        assert r.returncode == 2, r.stderr
        assert "Traceback" not in r.stderr
        assert message in r.stderr.splitlines()[-1], r.stderr
    assert f"{option}: {message}" in on_line.stderr
    assert f"{var}: {message}" in from_env.stderr
    assert f"[profiles.x] {key}: {message}" in from_profile.stderr
    assert len(from_env.stderr.splitlines()) == 1 and len(from_profile.stderr.splitlines()) == 1


def test_the_limits_are_in_help_and_man_page(env, tmp_path):
    out = _tmclsh("--help", env=env, cwd=tmp_path).stdout
    assert "0.001..60 s" in " ".join(out.split())  # --timeout
    man = (ROOT / "man" / "tmclsh.1").read_text()
    assert ".SH LIMITS" in man and "86400" in man


def test_config_nested_too_deep_and_config_a_directory(env, tmp_path):
    deep = tmp_path / "deep.toml"
    deep.write_text("a = " + "[" * 3000 + "]" * 3000 + "\n")
    r = _tmclsh("--sim", "-c", "GAP 1, 0", env={**env, "TMCLSH_CONFIG": str(deep)}, cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.strip() == f"tmclsh: {deep}:1: values nested more than 16 deep"
    (tmp_path / "config" / "tmclsh" / "config.toml").mkdir(parents=True)
    env.pop("TMCLSH_CONFIG")
    r = _tmclsh("--sim", "-c", "GAP 1, 0", env=env, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().endswith("config.toml: the config file is a directory")


# -- files: no traceback, the old file intact, the path and the reason in the message ------

def test_asm_and_disasm_on_endless_and_unwritable_files(env, tmp_path):
    src = tmp_path / "p.tmc"
    src.write_text("SAP 4, 0, 1000\nSTOP\n")
    for args, message in [
        (("asm", "/dev/zero"), "/dev/zero: program larger than 16 MiB; not read"),
        (("disasm", "/dev/zero"), "image larger than the TMCM-1311's program memory"),
        (("asm", str(src), "-o", "/dev/full"), "cannot write /dev/full: No space left"),
        (("asm", str(src), "-o", "/nonexistent/p.bin"), "cannot write /nonexistent/p.bin"),
        (("asm", "/"), "cannot read /: it is a directory"),
    ]:
        r = _tmclsh(*args, env=env, cwd=tmp_path)
        assert r.returncode == 1, (args, r.stderr)
        assert r.stderr.count("\n") == 1 and message in r.stderr, (args, r.stderr)
    long = tmp_path / "long.tmc"
    long.write_text(f"SAP 4, 0, {SUM}\nN = {NESTED}\n")
    r = _tmclsh("asm", str(long), env=env, cwd=tmp_path)
    assert r.returncode == 1 and "long.tmc:1:" in r.stderr and "128 operators" in r.stderr


def test_a_failed_write_leaves_the_old_file(env, tmp_path):
    """asm -o onto a file in a folder that becomes read-only: refused, old bytes kept, no
    temporary file left behind."""
    if os.geteuid() == 0:
        pytest.skip("root writes into read-only folders")
    src = tmp_path / "p.tmc"
    src.write_text("SAP 4, 0, 1000\n")
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    target = out_dir / "p.bin"
    target.write_bytes(b"old")
    out_dir.chmod(0o500)
    try:
        r = _tmclsh("asm", str(src), "-o", str(target), env=env, cwd=tmp_path)
    finally:
        out_dir.chmod(0o700)
    assert r.returncode == 1 and f"cannot write {target}" in r.stderr
    assert target.read_bytes() == b"old" and os.listdir(out_dir) == ["p.bin"]


def test_endless_stdin_script_is_refused_line_by_line(env, tmp_path):
    with open("/dev/zero", "rb") as zero:
        r = _tmclsh("--sim", "-f", "-", env=env, cwd=tmp_path, stdin=zero)
    assert r.returncode == 2, r.stderr
    assert "<stdin>:1: line longer than 65,536 characters" in r.stderr
    assert "Traceback" not in r.stderr


def test_f_dash_still_streams_line_by_line(env, tmp_path):
    """-f - runs each line as it arrives: the first line's answer comes before the input
    ends."""
    p = subprocess.Popen([sys.executable, "-m", "tmclsh", "--sim", "-f", "-"], env=env,
                         cwd=str(tmp_path), stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    try:
        assert p.stdin is not None and p.stdout is not None
        p.stdin.write("GAP 1, 0\n")
        p.stdin.flush()
        first = p.stdout.readline()
        assert "ActualPosition" in first
        p.stdin.close()
        assert p.wait(30) == 0
    finally:
        p.kill()


def test_plot_of_a_csv_whose_names_look_like_markup(env, tmp_path):
    (tmp_path / "m.csv").write_text("t,[/],[bold]x\n0,1,5\n1,2,6\n")
    r = _tmclsh("--sim", "-c", ".plot m.csv", env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "─ [/]  (2 samples)" in r.stdout and "─ [bold]x  (2 samples)" in r.stdout


def test_blocks_nested_without_end_of_the_stack(env, tmp_path):
    deep = tmp_path / "deep.tmcl"
    deep.write_text("\n".join([".repeat 1"] * 600 + ["GAP 1, 0"] + [".end"] * 600) + "\n")
    r = _tmclsh("--sim", "-f", str(deep), env=env, cwd=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip() == f"{deep}:33: blocks nested more than 32 deep"
    r = _tmclsh("--sim", "-c", deep.read_text(), env=env, cwd=tmp_path)
    assert r.returncode == 1 and r.stderr.strip() == "error: <input>:33: blocks nested more than 32 deep"
