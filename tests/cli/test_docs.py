"""The man page: generated from the parser, the registry and the data files; the committed
copy is up to date and names every option, subcommand and shell command; groff renders it
without warnings; `tmclsh --help` and `.help` agree with it; the package installs it."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from tmclsh.cli import main as cli, docs
from tmclsh.cli.doc_roff import _inline
from tmclsh.base import config
from tmclsh.shell.lang import commands

ROOT = Path(__file__).resolve().parents[2]
MAN = ROOT / "man" / "tmclsh.1"


@pytest.fixture(scope="module")
def man() -> str:
    return MAN.read_text(encoding="utf-8")


def roff(text: str) -> str:
    return _inline(text)


def all_flags() -> list[str]:
    top, subs = docs.describe()
    return sorted({f for cmd in (top, *subs) for o in cmd.options for f in o.flags})


# -- the committed page cannot drift --------------------------------------------------------

def test_committed_man_page_is_generated(man):
    assert man == docs.manpage(), "man/tmclsh.1 is out of date: run scripts/gen-docs"


def test_every_option_is_in_the_man_page(man):
    for flag in all_flags():
        assert f"\\fB{roff(flag)}\\fR" in man, f"{flag} is missing from man/tmclsh.1"


def test_every_subcommand_is_in_the_man_page(man):
    top, subs = docs.describe()
    assert {s.name for s in subs} >= set(cli.SUBCOMMANDS)
    for name in cli.SUBCOMMANDS:
        assert f"\n.SS {name}\n" in man, f"subcommand {name} is missing from man/tmclsh.1"
        assert f"\\fBtmclsh {name}\\fR" in man  # and in the synopsis


def test_every_shell_command_is_in_the_man_page(man):
    commands.load_all()
    for cmd in commands.all_commands():
        assert re.search(rf"^\\fB{re.escape(roff(cmd.name))}\\fR", man, re.M), (
            f"shell command {cmd.name} is missing from man/tmclsh.1: run scripts/gen-docs")
        for alias in cmd.aliases:
            assert alias in man


def test_every_instruction_module_setting_and_variable_is_in_the_man_page(man):
    from tmclsh.tmcl.instructions import all_instructions

    for spec in all_instructions():
        assert f"\\fB{spec.mnemonic}\\fR" in man
    for module in docs.module_names():
        assert module in man
    for key in (*config.SETTING_KEYS, *config.CONNECTION_KEYS):
        assert f"\\fB{key}\\fR" in man, key
    for var in (*config.ENVIRONMENT, *config.OTHER_ENVIRONMENT):
        assert f"\\fB{var}\\fR" in man, var


def test_exit_statuses_match_the_code(man):
    section = man.split(".SH EXIT STATUS", 1)[1].split("\n.SH ", 1)[0]
    codes = [int(c) for c in re.findall(r"^\\fB(\d+)\\fR$", section, re.M)]
    import signal

    assert codes == [cli.EXIT_OK, cli.EXIT_FAILED, cli.EXIT_USAGE, cli.EXIT_CONNECT, 130,
                     128 + signal.SIGHUP, 128 + signal.SIGTERM]  # tests/shell/test_signals.py
    from tmclsh.shell.lang import main as shell_main, script

    assert (script.EXIT_OK, script.EXIT_FAILED, script.EXIT_USAGE) == (
        cli.EXIT_OK, cli.EXIT_FAILED, cli.EXIT_USAGE)

    assert (shell_main.EXIT_OK, shell_main.EXIT_FAILED, shell_main.EXIT_CONNECT) == (
        cli.EXIT_OK, cli.EXIT_FAILED, cli.EXIT_CONNECT)


def test_usage_error_exits_2(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["--no-such-option"])
    assert exc.value.code == cli.EXIT_USAGE == 2


# -- generated, not typed -----------------------------------------------------------------

def test_a_new_option_and_subcommand_appear(monkeypatch):
    parser = cli.build_parser()
    parser.add_argument("--frobnicate", metavar="N", help="a brand-new option")
    page = docs.manpage(parser)
    assert "\\fB\\-\\-frobnicate\\fR \\fIN\\fR" in page and "A brand-new option." in page


def test_a_new_shell_command_appears(monkeypatch):
    monkeypatch.setitem(commands.REGISTRY, ".frob", commands.Command(
        ".frob", "frob", ".frob [N]", "frobnicate N times", aliases=(".fr",),
        category="testing", details="First paragraph.\n\nSecond  paragraph."))
    page = docs.manpage()
    assert ".SS Testing\n.TP\n\\fB.frob\\fR [N]\nFrobnicate N times.\nAlso .fr.\n" in page
    assert ".IP\nFirst paragraph.\n.IP\nSecond paragraph.\n" in page


def test_roff_escaping():
    assert docs._esc("--port") == "\\-\\-port"
    assert docs._esc("TMCM-1311 and read-only") == "TMCM-1311 and read-only"
    assert docs._esc(".help\n'quoted") == "\\&.help\n\\&'quoted"
    assert docs._b(".help") == "\\fB.help\\fR"
    assert docs._esc("a\\b") == "a\\eb"


# -- rendering ----------------------------------------------------------------------------

@pytest.mark.skipif(shutil.which("groff") is None, reason="groff is not installed")
def test_groff_renders_without_warnings():
    out = subprocess.run(["groff", "-man", "-ww", "-z", str(MAN)], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0 and out.stderr == "", out.stderr
    text = subprocess.run(["groff", "-man", "-Tutf8", "-ww", str(MAN)], capture_output=True,
                          text=True, timeout=60, env={**os.environ, "LC_ALL": "C.UTF-8"})
    assert text.stderr == ""
    plain = re.sub(r".\x08", "", text.stdout)
    for heading in ("NAME", "SYNOPSIS", "DESCRIPTION", "OPTIONS", "SUBCOMMANDS", "SHELL LANGUAGE",
                    "SHELL COMMANDS", "CONFIGURATION", "ENVIRONMENT", "FILES", "EXIT STATUS",
                    "EXAMPLES"):
        assert re.search(rf"^{heading}$", plain, re.M), heading


# -- --help and .help agree with the page ---------------------------------------------------

def test_help_agrees_with_the_man_page(man):
    parser = cli.build_parser()
    helptext = parser.format_help()
    for flag in re.findall(r"(?<![\w-])(--?[a-zA-Z][\w-]*)", helptext):
        if flag in ("-", "--"):
            continue
        assert f"\\fB{roff(flag)}\\fR" in man, f"--help shows {flag}, the man page does not"
    for name in cli.SUBCOMMANDS:
        assert name in helptext
    top, subs = docs.describe(parser)
    for sub in subs:
        assert roff(docs._sentence(sub.help)) in man


def test_dot_help_agrees_with_the_man_page(man):
    """`.help --json` lists the registry; every command it lists is in the man page."""
    import json

    commands.load_all()
    if commands.find(".help") is None:
        pytest.skip(".help is not registered yet")
    out = subprocess.run([sys.executable, "-m", "tmclsh", "--sim", "--json", "-c", ".help"],
                         capture_output=True, text=True, timeout=120, cwd=ROOT,
                         env={**os.environ, "NO_COLOR": "1"})
    assert out.returncode == 0, out.stderr
    listed = {c["name"] for c in json.loads(out.stdout.splitlines()[0])["commands"]}
    assert listed == {c.name for c in commands.all_commands()}
    for name in listed:
        assert re.search(rf"^\\fB{re.escape(name)}\\fR", man, re.M), (
            f".help lists {name}, the man page does not: run scripts/gen-docs")
    section = man.split(".SH SHELL COMMANDS", 1)[1].split("\n.SH ", 1)[0]
    in_man = set(re.findall(r"^\\fB(\.[\w-]+)\\fR", section, re.M))
    assert in_man == listed, "the man page lists shell commands that .help does not"


# -- installed with the package -------------------------------------------------------------

def test_pyproject_installs_the_generated_files():
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())
    files = {f for fs in data["tool"]["setuptools"]["data-files"].values() for f in fs}
    assert files == set(docs.OUTPUTS)
    for rel in files:
        assert (ROOT / rel).is_file(), rel


def test_wheel_contains_man_page_and_completions(tmp_path):
    """Build a wheel from a copy of the tree and look under .data/data/share."""
    pytest.importorskip("setuptools")
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    for name in ("tmclsh", "man", "completions"):
        shutil.copytree(ROOT / name, src / name,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    import importlib.util

    # without the wheel package (setuptools < 70.1 needs it) let pip fetch the build backend
    isolation = [] if importlib.util.find_spec("wheel") else ["--use-pep517"]
    cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path / "dist")]
    if not isolation:
        cmd.append("--no-build-isolation")
    out = subprocess.run([*cmd, str(src)], capture_output=True, text=True, timeout=600)
    if out.returncode != 0 and re.search(r"No matching distribution|Could not find a version|"
                                         r"connection|Network is unreachable", out.stderr, re.I):
        pytest.skip(f"cannot fetch the build backend: {out.stderr.strip().splitlines()[-1]}")
    assert out.returncode == 0, out.stderr
    wheel = next((tmp_path / "dist").glob("tmclsh-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    for target, rel in (("share/man/man1/tmclsh.1", "man/tmclsh.1"),
                        ("share/bash-completion/completions/tmclsh", "completions/tmclsh"),
                        ("share/zsh/site-functions/_tmclsh", "completions/_tmclsh"),
                        ("share/fish/vendor_completions.d/tmclsh.fish", "completions/tmclsh.fish")):
        member = next((n for n in names if n.endswith(".data/data/" + target)), None)
        assert member, f"{target} not in {wheel.name}"
        assert zipfile.ZipFile(wheel).read(member) == (ROOT / rel).read_bytes()
    assert "tmclsh/base/default.toml" in names

