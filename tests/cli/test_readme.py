"""The README stays truthful: it starts with the two set-up commands, .ci/run runs them, and
every command line, shell command, script and program it shows works as shown."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from tmclsh.tmcl import asm
from tmclsh.cli import main as cli
from tmclsh.client import connect as connection
from tmclsh.tmcl.modules import load
from tmclsh.shell.lang import commands

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text(encoding="utf-8")
CI = (ROOT / ".ci" / "run").read_text(encoding="utf-8")

INSTALL_AND_START = "python3 -m venv .venv && .venv/bin/pip install -e . && .venv/bin/tmclsh"
INSTALL_AND_TEST = ("python3 -m venv .venv && .venv/bin/pip install -e '.[test]' && "
                    ".venv/bin/python -m pytest -n 4")


def code_blocks(text: str = README) -> list[str]:
    return re.findall(r"^ *```[\w]*\n(.*?)^ *```", text, re.M | re.S)


def code_spans(text: str = README) -> list[str]:
    prose = re.sub(r"^ *```.*?^ *```", "", text, flags=re.M | re.S)
    return re.findall(r"`([^`\n]+)`", prose)


def block_after(marker: str) -> str:
    rest = README.split(marker, 1)[1]
    return code_blocks(rest)[0]


# -- the set-up commands ----------------------------------------------------------------------

def test_readme_starts_with_the_two_setup_commands():
    lines = README.splitlines()
    assert lines[0].startswith("```")
    assert lines[1] == INSTALL_AND_START
    assert lines[2] == INSTALL_AND_TEST
    assert lines[3] == "```"


def test_ci_runs_the_readme_commands_verbatim():
    assert CI.startswith("#!/usr/bin/env bash")
    assert "set -euo pipefail" in CI
    run = [ln for ln in CI.splitlines() if not ln.lstrip().startswith("#")]
    first, second = README.splitlines()[1:3]
    assert any(f"( {second} )" in ln for ln in run), ".ci/run does not run the README's tests"
    # piped input is no person: without a module attached it must ask for the simulator
    assert any(f"( {first} --sim )" in ln for ln in run), \
        ".ci/run does not run the README's first line (with --sim)"


def test_ci_fails_when_no_test_ran():
    assert "passed" in CI and "exit 1" in CI  # it checks pytest's summary line


# -- command lines ------------------------------------------------------------------------

def tmclsh_command_lines() -> list[str]:
    found = [s for s in code_spans() if s.startswith("tmclsh ") or s == "tmclsh"]
    for block in code_blocks():
        lines = block.splitlines()
        i = 0
        while i < len(lines):
            line = lines[i].strip()
            if line.startswith("$ tmclsh"):
                line = line.removeprefix("$ ")
                while True:  # a quoted -c argument may go on over several lines
                    try:
                        shlex.split(line)
                        break
                    except ValueError:
                        i += 1
                        line += "\n" + lines[i]
                found.append(line)
            i += 1
    return found


def argv_of(line: str) -> list[str]:
    lexer = shlex.shlex(line, posix=True, punctuation_chars="|<>;")
    lexer.whitespace_split = True
    words = []
    for word in lexer:
        if word in ("|", "<", ">", ">>", ";", "<(") or word.startswith(("|", ">", "<")):
            break
        words.append(word)
    return words[1:]


def test_no_inline_code_crosses_a_line():
    prose = re.sub(r"^ *```.*?^ *```", "", README, flags=re.M | re.S)
    odd = [line for line in prose.splitlines() if line.count("`") % 2]
    assert not odd, f"a `code span` is split over lines (the checks below would miss it): {odd}"


def test_readme_has_command_lines():
    assert len(tmclsh_command_lines()) > 20


@pytest.mark.parametrize("line", tmclsh_command_lines())
def test_every_command_line_in_the_readme_parses(line):
    if "[CONNECTION]" in line:
        pytest.skip("a synopsis, not a command")
    argv = argv_of(line)
    try:
        cli.build_parser().parse_args(argv)
    except SystemExit as exc:
        pytest.fail(f"README shows `{line}`, which tmclsh rejects (exit {exc.code})")


# -- shell commands and TMCL lines ----------------------------------------------------------

DOT = re.compile(r"(?<![\w/.~}-])(\.[a-z][\w-]*)(?![\w/.-])")


def dot_commands() -> set[str]:
    names = set()
    for text in (*code_blocks(), *code_spans()):
        for line in text.splitlines():
            if line.lstrip().startswith(("//", "#")) or "-m venv .venv" in line:
                continue  # comments in scripts and programs; the set-up commands
            names.update(DOT.findall(line))
    return names


def test_every_shell_command_the_readme_uses_exists():
    commands.load_all()
    used = dot_commands()
    assert {".watch", ".upload", ".step", ".param"} <= used
    missing = sorted(n for n in used if commands.find(n) is None)
    assert not missing, f"README uses shell commands that do not exist: {missing}"


def prompt_lines() -> list[str]:
    return [m.group(1) for block in code_blocks()
            for m in re.finditer(r"^TMCM-\d+:\d+(?: \[[^]]*\])?> (.+)$", block, re.M)]


def test_every_tmcl_line_at_the_readme_prompt_is_valid():
    module = load("TMCM-1311")
    lines = prompt_lines()
    assert len(lines) > 15
    for line in lines:
        word = line.split()[0]
        if word.startswith(".") or word in ("help", "quit", "exit"):
            assert commands.find(word) is not None, line
            continue
        if line == "SAP 4, 0, -5":  # the transcript's deliberate mistake
            with pytest.raises(Exception, match="out of range"):
                asm.encode(asm.parse_line(line), module, direct=True)
            continue
        asm.encode(asm.parse_line(line), module, direct=True)


# -- the tour runs as shown -----------------------------------------------------------------

def tmclsh(*args: str, cwd: Path, stdin: str | None = None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith("TMCLSH_")}
    env.update(NO_COLOR="1", XDG_CONFIG_HOME=str(cwd / "config"), XDG_STATE_HOME=str(cwd / "state"),
               PYTHONPATH=os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])]))
    return subprocess.run([sys.executable, "-m", "tmclsh", *args], cwd=cwd, env=env, input=stdin,
                          capture_output=True, text=True, timeout=120)


def block_with(text: str) -> str:
    return next(b for b in code_blocks() if text in b)


def normalise(text: str) -> str:
    """Timings differ from run to run, and so does the number of polls a .wait sends."""
    return re.sub(r"\d+\.\d+ s|\d+/s|\d+ commands sent", "#", text)


def test_the_tour_script_passes(tmp_path):
    script = block_after("Save this as\n`check.tmcl`:")
    (tmp_path / "check.tmcl").write_text(script)
    out = tmclsh("--sim", "-f", "check.tmcl", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    shown = block_with("$ tmclsh --sim -f check.tmcl").splitlines()[1:]
    got = normalise(out.stdout + out.stderr)
    for line in shown:
        assert normalise(line) in got, f"README shows {line!r}; tmclsh printed:\n{got}"


def test_the_tour_program_uploads_and_steps(tmp_path):
    program = block_after("Save a program as `pingpong.tmc`:")
    (tmp_path / "pingpong.tmc").write_text(program)
    out = tmclsh("asm", "pingpong.tmc", "--hex", "-o", "pingpong.hex", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    out = tmclsh("disasm", "pingpong.hex", cwd=tmp_path)
    assert out.returncode == 0 and "JA" in out.stdout
    # the README's session up to .continue (after .run the simulator's timing decides)
    shown = block_with("> .upload pingpong.tmc").split("> .run")[0]
    typed = re.findall(r"^TMCM-\d+:\d+(?: \[[^]]*\])?> (.+)$", shown, re.M)
    out = tmclsh("--sim", "--yes", "-c", "\n".join(typed), cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    got = normalise(out.stdout)
    for line in shown.splitlines():
        if re.match(r"TMCM-\d+:\d+", line) or "[y/N]" in line:
            continue  # prompts, and the question only asked at the prompt
        assert normalise(line) in got, f"README shows {line!r}; tmclsh printed:\n{got}"


def test_the_tour_watch_pipes_json(tmp_path):
    import json

    out = tmclsh("--sim", "-c", "MVP ABS, 0, 20000\n.watch pos=GAP 1, 0; speed=GAP 3, 0 "
                 "--count 3 --interval 0.05", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    samples = [json.loads(ln) for ln in out.stdout.splitlines() if ln.startswith("{")]
    assert len(samples) == 3 and set(samples[0]["values"]) == {"pos", "speed"}


def test_the_ascii_mode_rescue_works(tmp_path):
    out = tmclsh("--sim", "--ascii", "-c", ".mode binary --keep", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "binary" in out.stdout


def test_the_first_command_piped_needs_sim_as_ci_gives_it(tmp_path):
    """What the README's first line ends with: the installed `tmclsh`, no module attached,
    fed a line on stdin as .ci/run does. Piped input is no person at the prompt: without
    --sim it exits 3 (the interactive fallback is tested in a terminal, tests/client/test_connect.py)."""
    exe = Path(sys.executable).with_name("tmclsh")
    if not exe.exists():
        pytest.skip("tmclsh is not installed beside this Python")
    if connection.trinamic_ports():
        pytest.skip("a Trinamic module is attached; this test wants the simulator")
    env = {k: v for k, v in os.environ.items() if not k.startswith("TMCLSH_")}
    env.update(NO_COLOR="1", XDG_CONFIG_HOME=str(tmp_path), XDG_STATE_HOME=str(tmp_path))
    out = subprocess.run([str(exe)], input="GAP ActualPosition, 0\n", capture_output=True,
                         text=True, timeout=120, env=env, cwd=tmp_path)
    assert out.returncode == 3 and out.stdout == ""
    assert "no module found" in out.stderr and "--sim" in out.stderr
    out = subprocess.run([str(exe), "--sim"], input="GAP ActualPosition, 0\n",
                         capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "ActualPosition = 0" in out.stdout


def test_the_bridge_paragraph_sends_pytrinamic_to_the_pty_not_a_socket_url():
    """PyTrinamic's serial interface opens a device path; a socket:// URL fails there."""
    para = README[README.index("To see a program's traffic"):]
    para = para[:para.index("\n\n")]
    assert "PyTrinamic" in para
    pty = para.index("--pty")
    assert pty < para.index("PyTrinamic") < para.index("socket://")
    man = (ROOT / "man" / "tmclsh.1").read_text(encoding="utf-8")
    assert "PyTrinamic's serial interface opens a device path" in man
