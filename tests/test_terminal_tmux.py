"""``.ascii`` tried as a person would: the real program in a tmux pane, keys typed, the screen
read back. The module is a simulator served on a pty in this process. Skips without tmux."""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import tmclsh_env

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")


class Pane:
    def __init__(self, command: str, tmp: Path):
        self.socket = f"tmclsh-test-{os.getpid()}-{id(self)}"
        self.name = "t"
        env = tmclsh_env(NO_COLOR="1", XDG_STATE_HOME=str(tmp), TERM="xterm")
        exports = " ".join(f"{k}={shlex.quote(v)}" for k, v in env.items()
                           if k in ("PYTHONPATH", "NO_COLOR", "XDG_STATE_HOME", "TERM",
                                    "TMCLSH_CONFIG", "PATH", "HOME"))
        unset = " ".join(f"-u {k}" for k in ("TMCLSH_PORT", "TMCLSH_CAN", "TMCLSH_PROFILE",
                                             "TMCLSH_MODULE", "TMCLSH_ADDRESS"))
        self.tmux("new-session", "-d", "-s", self.name, "-x", "100", "-y", "30",
                  f"cd {shlex.quote(str(ROOT))} && env {unset} {exports} {command}; "
                  "echo EXIT=$?; sleep 30")

    def tmux(self, *args: str) -> str:
        return subprocess.run(["tmux", "-L", self.socket, *args], capture_output=True,
                              text=True, timeout=10).stdout

    def keys(self, *keys: str) -> None:
        self.tmux("send-keys", "-t", self.name, *keys)

    def ctrl_bracket(self) -> None:
        self.tmux("send-keys", "-t", self.name, "-H", "1d")

    def screen(self) -> str:
        return self.tmux("capture-pane", "-t", self.name, "-p")

    def wait(self, text: str, timeout: float = 10) -> str:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            screen = self.screen()
            if text in screen:
                return screen
            time.sleep(0.05)
        raise AssertionError(f"{text!r} did not appear; the screen:\n{self.screen()}")

    def wait_for(self, predicate, timeout: float = 10) -> str:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            screen = self.screen()
            if predicate(screen):
                return screen
            time.sleep(0.05)
        raise AssertionError(f"condition not met; the screen:\n{self.screen()}")

    @staticmethod
    def prompt_line(screen: str) -> str:
        lines = [ln.rstrip() for ln in screen.splitlines() if ln.startswith("ascii A>")]
        return lines[-1] if lines else ""

    def close(self) -> None:
        self.tmux("kill-server")


@pytest.fixture
def served(make_pty_sim):
    return make_pty_sim()


@pytest.fixture
def pane(tmp_path):
    made = []

    def factory(command: str) -> Pane:
        p = Pane(command, tmp_path)
        made.append(p)
        return p

    yield factory
    for p in made:
        p.close()


def tmclsh(path: str, *args: str) -> str:
    return " ".join(shlex.quote(a) for a in (sys.executable, "-m", "tmclsh", "--port", path,
                                             *args))


def test_line_mode(served, pane):
    sim, path = served
    p = pane(tmclsh(path, "-c", ".ascii"))
    p.wait("ascii A>")
    p.keys("SAP 1, 0, -5000", "Enter")
    p.wait("BA 100 -5000   ok, value -5000")
    p.keys("GAP 1, 0", "Enter")
    p.wait("BA 100 -5000   ok, value -5000")
    p.keys("XYZ", "Enter")
    p.wait("BA 2 0   error 2: invalid command")
    p.keys("GAP act", "Tab")  # complete a parameter name to its number
    p.wait("1 ActualPosition")  # the menu, with the names as meta
    p.keys("Tab")
    p.wait_for(lambda screen: p.prompt_line(screen) == "ascii A> GAP 1")
    p.keys(", 0", "Enter")
    screen = p.wait("ascii A> GAP 1, 0\nBA 100 -5000")
    assert "AGAP" not in screen  # the module's echo is not shown twice
    p.ctrl_bracket()
    p.wait("send BIN (module back to binary mode)? [Y/n]")
    p.keys("Enter")
    p.wait("EXIT=0")
    assert "--- BIN sent: module in binary mode" in p.screen()
    assert not sim.ascii_active


def test_raw_mode_backspace(served, pane):
    sim, path = served
    p = pane(tmclsh(path, "-c", ".ascii --raw --no-bin"))
    p.wait("Ctrl-]: back to the shell")
    p.keys("ASAP 1, 0, 7", "Enter")
    p.wait("ASAP 1, 0, 7\nBA 100 7   ok, value 7")
    p.keys("AGAX", "BSpace", "P 1, 0", "Enter")  # the module erases the X itself
    screen = p.wait("AGAP 1, 0\nBA 100 7   ok, value 7")
    assert "AGAP 1, 0\nBA 100 7" in screen
    p.ctrl_bracket()
    p.wait("EXIT=0")
    assert "module stays in ASCII mode" in p.screen()
    assert sim.ascii_active
