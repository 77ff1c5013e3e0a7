"""The bash, zsh and fish completions: generated from the parser, committed up to date, and
working in the real shells (each shell's test is skipped when that shell is not installed)."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import time
import uuid
from pathlib import Path

import pytest

from tmclsh.cli import main as cli, docs
from tmclsh.cli import completions
from tmclsh.cli.doc_model import can_interfaces

ROOT = Path(__file__).resolve().parents[2]
BASH = ROOT / "completions" / "tmclsh"
ZSH = ROOT / "completions" / "_tmclsh"
FISH = ROOT / "completions" / "tmclsh.fish"
SCRIPTS = {"bash": BASH, "zsh": ZSH, "fish": FISH}

CONFIG = """\
[settings]
color = "never"

[profiles.bench]
port = "/dev/ttyACM0"

[ profiles."rs485" ]
port = "/dev/ttyUSB0"
baud = 115200
"""


@pytest.fixture()
def home(tmp_path: Path) -> dict[str, str]:
    """An environment whose config file defines the profiles bench and rs485."""
    (tmp_path / "xdg" / "tmclsh").mkdir(parents=True)
    (tmp_path / "xdg" / "tmclsh" / "config.toml").write_text(CONFIG)
    env = {k: v for k, v in os.environ.items() if not k.startswith("TMCLSH_")}
    env.update(HOME=str(tmp_path), XDG_CONFIG_HOME=str(tmp_path / "xdg"), TERM="xterm")
    return env


def committed_can_interfaces() -> list[str]:
    m = re.search(r"^_tmclsh_can\(\) \{\n\s+printf '%s:\\n' (.*)$", BASH.read_text(), re.M)
    assert m, "no CAN interface list in completions/tmclsh"
    return m.group(1).split()


def flags(parser=None) -> list[str]:
    top, subs = docs.describe(parser)
    return sorted({f for cmd in (top, *subs) for o in cmd.options for f in o.flags})


# -- generated, and up to date ---------------------------------------------------------------

@pytest.mark.parametrize("shell", docs.SHELLS)
def test_committed_script_is_generated(shell, monkeypatch):
    # the CAN interface names come from the installed python-can; compare the rest exactly
    monkeypatch.setattr(completions, "can_interfaces", committed_can_interfaces)
    assert SCRIPTS[shell].read_text() == docs.completion_script(shell), (
        f"{SCRIPTS[shell].relative_to(ROOT)} is out of date: run scripts/gen-docs")


def test_can_interfaces_come_from_python_can():
    from can.interfaces import VALID_INTERFACES

    committed = committed_can_interfaces()
    assert {"socketcan", "virtual", "pcan", "slcan"} <= set(committed)
    assert can_interfaces() == sorted(VALID_INTERFACES)


@pytest.mark.parametrize("shell", docs.SHELLS)
def test_every_option_subcommand_and_module_is_offered(shell):
    text = SCRIPTS[shell].read_text()
    for flag in flags():
        name = flag.lstrip("-")
        assert re.search(rf"(?<![\w-]){re.escape(flag if shell != 'fish' else name)}(?![\w-])", text), (
            f"{flag} missing from the {shell} completion")
    top, subs = docs.describe()
    for sub in subs:
        assert re.search(rf"\b{sub.name}\b", text)
    for module in docs.module_names():
        assert module in text


def test_completions_option_prints_the_committed_script(capsys, monkeypatch):
    monkeypatch.setattr(completions, "can_interfaces", committed_can_interfaces)
    for shell in docs.SHELLS:
        assert cli.main(["--completions", shell]) == 0
        assert capsys.readouterr().out == SCRIPTS[shell].read_text()


def test_unknown_shell_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["--completions", "tcsh"])
    assert exc.value.code == 2
    with pytest.raises(ValueError):
        docs.completion_script("tcsh")


def test_a_new_option_appears_without_editing_the_generator():
    parser = cli.build_parser()
    parser.add_argument("--frobnicate", metavar="N", help="a brand-new option")
    for shell in docs.SHELLS:
        assert "frobnicate" in docs.completion_script(shell, parser)


# -- bash -----------------------------------------------------------------------------------

def bash_complete(words: list[str], env: dict[str, str], script: Path = BASH) -> list[str]:
    """COMPREPLY for COMP_WORDS=words (the last is the word being completed), as bash splits
    them (':' and '=' are separate words, as with the default COMP_WORDBREAKS)."""
    code = (f"source {shlex.quote(str(script))}\n"
            f"COMP_WORDS=({' '.join(shlex.quote(w) for w in words)})\n"
            f"COMP_CWORD={len(words) - 1}\n"
            f"COMP_LINE={shlex.quote(' '.join(words))}; COMP_POINT=${{#COMP_LINE}}\n"
            "_tmclsh\n"
            "printf '%s\\n' \"${COMPREPLY[@]}\"\n")
    out = subprocess.run(["bash", "--norc", "--noprofile", "-c", code], env=env,
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    assert out.stderr == ""
    return [w for w in out.stdout.split("\n") if w]


@pytest.fixture()
def needs_bash():
    if shutil.which("bash") is None:
        pytest.skip("bash is not installed")


def test_bash_registers_the_function(needs_bash, home):
    out = subprocess.run(["bash", "--norc", "-c", f"source {BASH}; complete -p tmclsh"],
                         env=home, capture_output=True, text=True, timeout=30)
    assert out.stdout.strip() == "complete -F _tmclsh tmclsh"


@pytest.mark.parametrize("words, expected", [
    (["tmclsh", "--pro"], ["--profile"]),
    (["tmclsh", "--ke"], ["--keep-going"]),
    (["tmclsh", "as"], ["asm"]),
    (["tmclsh", ""], ["asm", "disasm", "sim", "ports", "modules", "scan", "firmware",
                       "replace", "monitor", "replay", "bridge"]),
    (["tmclsh", "--profile", ""], ["bench", "rs485"]),
    (["tmclsh", "--profile", "=", "r"], ["rs485"]),
    (["tmclsh", "-m", "TMCM-13"], ["TMCM-1311"]),
    (["tmclsh", "--sim", ""], ["TMCM-1311", "TMCM-1640", "TMCM-351"]),
    (["tmclsh", "--sim", "--js"], ["--json"]),
    (["tmclsh", "--completions", ""], ["bash", "zsh", "fish"]),
    (["tmclsh", "--can", "socketc"], ["socketcan:", "socketcand:"]),
    (["tmclsh", "--can", "socketcan", ":"], []),
    (["tmclsh", "--port", "rfc"], ["rfc2217://"]),
    (["tmclsh", "--port", "rfc2217", ":"], ["//"]),  # bash keeps "rfc2217:" and adds "//"
    (["tmclsh", "asm", "--ou"], ["--output"]),
    (["tmclsh", "asm", "-m", "TMCM-3"], ["TMCM-351"]),
    (["tmclsh", "scan", "--pro"], ["--profile"]),
    (["tmclsh", "scan", "--profile", "b"], ["bench"]),
    (["tmclsh", "sim", "--can", "virt"], ["virtual:"]),
    (["tmclsh", "--port", "/dev/ttyACM0", "--tr"], ["--trace"]),
    (["tmclsh", "-a", "3", "sc"], ["scan"]),
    (["tmclsh", "replay", "--as"], ["--as-captured"]),
])
def test_bash_completes(needs_bash, home, words, expected):
    assert bash_complete(words, home) == expected


def test_bash_completes_files_for_scripts(needs_bash, home, tmp_path):
    (tmp_path / "setup.tmcl").write_text("GAP 1, 0\n")
    got = bash_complete(["tmclsh", "-f", str(tmp_path / "set")], home)
    assert got == [str(tmp_path / "setup.tmcl")]
    got = bash_complete(["tmclsh", "asm", str(tmp_path / "set")], home)
    assert got == [str(tmp_path / "setup.tmcl")]


def test_bash_without_a_config_file_offers_no_profiles(needs_bash, home, tmp_path):
    home["XDG_CONFIG_HOME"] = str(tmp_path / "nowhere")
    assert bash_complete(["tmclsh", "--profile", ""], home) == []
    home["TMCLSH_CONFIG"] = str(tmp_path / "xdg" / "tmclsh" / "config.toml")
    assert bash_complete(["tmclsh", "--profile", ""], home) == ["bench", "rs485"]


# -- zsh and fish ---------------------------------------------------------------------------

@pytest.fixture()
def needs_zsh():
    if shutil.which("zsh") is None:
        pytest.skip("zsh is not installed")


@pytest.fixture()
def needs_fish():
    if shutil.which("fish") is None:
        pytest.skip("fish is not installed")


def test_zsh_script_loads_with_compinit(needs_zsh, home, tmp_path):
    fdir = tmp_path / "zfunc"
    fdir.mkdir()
    shutil.copy(ZSH, fdir / "_tmclsh")
    code = (f"fpath=({fdir} $fpath); autoload -Uz compinit; compinit -u -D; "
            "print -r -- $_comps[tmclsh]")
    out = subprocess.run(["zsh", "-f", "-c", code], env=home, capture_output=True, text=True,
                         timeout=30)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "_tmclsh"
    # sourced after compinit (what 'source <(tmclsh --completions zsh)' does) it registers too
    code = f"autoload -Uz compinit; compinit -u -D; source {ZSH}; print -r -- $_comps[tmclsh]"
    out = subprocess.run(["zsh", "-f", "-c", code], env=home, capture_output=True, text=True,
                         timeout=30)
    assert out.stdout.strip() == "_tmclsh", out.stderr


class Tmux:
    """A shell in a detached tmux session on a private server: type, press Tab, read the screen."""

    def __init__(self, command: list[str], env: dict[str, str]):
        self.socket = f"tmclsh-test-{uuid.uuid4().hex[:8]}"
        self.env = env
        self._tmux("new-session", "-d", "-x", "200", "-y", "50", "-s", "t", shlex.join(command))

    def _tmux(self, *args: str) -> str:
        out = subprocess.run(["tmux", "-L", self.socket, *args], env=self.env,
                             capture_output=True, text=True, timeout=30)
        assert out.returncode == 0, out.stderr
        return out.stdout

    def send(self, *keys: str) -> None:
        self._tmux("send-keys", "-t", "t", *keys)

    def screen(self) -> str:
        return self._tmux("capture-pane", "-p", "-t", "t")

    def wait_for(self, pattern: str, timeout: float = 10.0) -> str:
        deadline = time.monotonic() + timeout
        while True:
            text = self.screen()
            if re.search(pattern, text, re.M):
                return text
            if time.monotonic() > deadline:
                raise AssertionError(f"{pattern!r} never appeared; screen:\n{text}")
            time.sleep(0.1)

    def close(self) -> None:
        subprocess.run(["tmux", "-L", self.socket, "kill-server"], env=self.env,
                       capture_output=True, timeout=30)


def test_zsh_completes_interactively(needs_zsh, home, tmp_path):
    if shutil.which("tmux") is None:
        pytest.skip("tmux is not installed")
    fdir = tmp_path / "zfunc"
    fdir.mkdir()
    shutil.copy(ZSH, fdir / "_tmclsh")
    t = Tmux(["zsh", "-f"], home)
    try:
        t.send(f"PS1='ready%% '; fpath=({fdir} $fpath); autoload -Uz compinit; "
               "compinit -u -D; clear", "Enter")
        t.wait_for(r"^ready%\s*$")
        t.send("tmclsh --keep-g", "Tab")
        t.wait_for(r"^ready% tmclsh --keep-going\s*$")
        t.send("C-u", "tmclsh --profile ", "Tab")
        t.wait_for(r"bench\s+rs485")
        t.send("C-u", "tmclsh asm --ou", "Tab")
        t.wait_for(r"^ready% tmclsh asm --output=$")
        t.send("C-u", "tmclsh -m TMCM-35", "Tab")
        t.wait_for(r"^ready% tmclsh -m TMCM-351\s*$")
    finally:
        t.close()


def fish_complete(line: str, env: dict[str, str]) -> list[str]:
    out = subprocess.run(["fish", "--no-config", "-c",
                          f"source {shlex.quote(str(FISH))}; complete -C {shlex.quote(line)}"],
                         env=env, capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    return sorted(w.split("\t")[0] for w in out.stdout.splitlines())


@pytest.mark.parametrize("line, expected", [
    ("tmclsh --pro", ["--profile"]),
    ("tmclsh --profile ", ["bench", "rs485"]),
    ("tmclsh --sim ", ["TMCM-1311", "TMCM-1640", "TMCM-351"]),
    ("tmclsh --completions ", ["bash", "fish", "zsh"]),
    ("tmclsh --can socketc", ["socketcan:", "socketcand:"]),
    ("tmclsh --port rfc", ["rfc2217://"]),
    ("tmclsh sc", ["scan"]),
    ("tmclsh asm --h", ["--help", "--hex"]),
    ("tmclsh scan --pro", ["--profile"]),
])
def test_fish_completes(needs_fish, home, line, expected):
    assert fish_complete(line, home) == expected


def test_fish_does_not_offer_top_level_options_to_subcommands(needs_fish, home):
    assert "--trace" not in fish_complete("tmclsh asm --", home)
    assert "--trace" in fish_complete("tmclsh --", home)
