"""The program debugger as a person uses it: ``python -m tmclsh --sim`` in tmux, typed at with
send-keys, read back with capture-pane. Skipped where tmux is missing.

Uploads the TMCM-1311 manual's timer-interrupt example (§5.6.5), steps through its first
instructions (an empty line repeats the step), runs to a breakpoint, stops and resets.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from test_program_sim import TIMER_EXAMPLE

pytestmark = pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")

ROOT = Path(__file__).resolve().parents[1]


def _quote(s: str) -> str:
    return "'" + s.replace("'", "'\\''") + "'"


class Pane:
    def __init__(self, tmp_path: Path):
        self.socket = f"tmclsh-dbg-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self.tmp = tmp_path
        self.env = {"XDG_STATE_HOME": str(tmp_path / "state"),
                    "XDG_CONFIG_HOME": str(tmp_path / "config"),
                    "PYTHONPATH": str(ROOT), "TERM": "xterm-256color"}

    def tmux(self, *args: str, check: bool = True) -> str:
        proc = subprocess.run(["tmux", "-L", self.socket, *args], capture_output=True,
                              text=True, timeout=20)
        if check and proc.returncode:
            raise AssertionError(f"tmux {' '.join(args)}: {proc.stderr}")
        return proc.stdout

    def start(self, *argv: str) -> None:
        env = " ".join(f"{k}={_quote(v)}" for k, v in self.env.items())
        cmd = (f"cd {_quote(str(self.tmp))} && env -u COLUMNS -u LINES {env} "
               f"{_quote(sys.executable)} -m tmclsh {' '.join(argv)}; echo EXIT=$?; sleep 60")
        self.tmux("-f", "/dev/null", "new-session", "-d", "-s", "dbg", "-x", "150", "-y", "50",
                  cmd)

    def line(self, text: str) -> None:
        self.tmux("send-keys", "-t", "dbg", "-l", text)
        self.tmux("send-keys", "-t", "dbg", "Enter")

    def screen(self) -> str:
        return self.tmux("capture-pane", "-p", "-t", "dbg", "-S", "-300")

    def wait(self, text: str, timeout: float = 15.0, more_than: int = 0) -> str:
        """Wait until ``text`` is on the screen more than ``more_than`` times."""
        deadline = time.monotonic() + timeout
        screen = ""
        while time.monotonic() < deadline:
            screen = self.screen()
            if screen.count(text) > more_than:
                return screen
            time.sleep(0.05)
        raise AssertionError(f"{text!r} not on the screen:\n{screen}")

    def run(self, line: str, *expect: str, timeout: float = 15.0) -> str:
        """Type ``line`` and wait for a new occurrence of each of ``expect``."""
        before = self.screen()
        self.line(line)
        screen = before
        for text in expect:
            screen = self.wait(text, timeout, before.count(text))
        return screen

    def kill(self) -> None:
        self.tmux("kill-server", check=False)


@pytest.fixture
def pane(tmp_path):
    p = Pane(tmp_path)
    try:
        yield p
    finally:
        p.kill()


def test_step_break_continue_stop_reset_in_a_terminal(pane, tmp_path):
    (tmp_path / "timer.tmc").write_text(TIMER_EXAMPLE, encoding="utf-8")
    pane.start("--sim", "TMCM-1311")
    pane.wait("TMCM-1311:1>")

    pane.line(".upload timer.tmc")
    pane.wait("(y/n")
    pane.tmux("send-keys", "-t", "dbg", "y")
    pane.wait("uploaded 15 instructions from timer.tmc to 0..14; verified: read back identical")

    pane.run(".step", "step @1  timer.tmc:2  SGP 0, 3, 1000")
    pane.run("", "step @2  timer.tmc:3  EI 0")  # an empty line steps again
    pane.run(".step 2", "step @3  timer.tmc:4  EI 255", "step @4  timer.tmc:8  SIO 3, 2, 1")
    pane.wait("program step @4")  # the toolbar

    pane.run(".display GGP 0, 2", "1: GGP 0, 2 = 0")
    pane.run(".break 12", "breakpoint 1 at @8  timer.tmc:12  JA Loop")
    pane.run(".continue", "breakpoint 1, step @8  timer.tmc:12  JA Loop", "  1: GGP 0, 2 = 0")
    screen = pane.run(".list", "->B")
    assert "Loop:" in screen and "@8" in screen

    pane.run(".stop", "stop @8  timer.tmc:12")
    pane.run(".reset", "reset @0  timer.tmc:1  VECT 0, Timer0Irq")
    pane.run(".status", "reset @0")
    pane.wait("program reset")
    pane.line(".quit")
    pane.wait("EXIT=0")
