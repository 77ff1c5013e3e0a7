"""A watch tried the way a person does it: in a real terminal (tmux), while the simulated
motor moves; 's' stops the motor, 'q' ends the watch, the terminal comes back intact.

Skipped when tmux is not installed.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")

ROOT = Path(__file__).resolve().parent.parent


class Tmux:
    def __init__(self, socket: Path):
        self.socket = str(socket)

    def __call__(self, *args: str) -> str:
        return subprocess.run(["tmux", "-S", self.socket, *args], capture_output=True,
                              text=True, timeout=10, check=True).stdout

    def screen(self) -> str:
        return self("capture-pane", "-p", "-t", "watch")

    def wait_for(self, pattern: str, timeout: float = 10.0) -> str:
        deadline = time.monotonic() + timeout
        while True:
            text = self.screen()
            if re.search(pattern, text):
                return text
            if time.monotonic() > deadline:
                raise AssertionError(f"{pattern!r} did not appear; screen:\n{text}")
            time.sleep(0.05)


def value(screen: str, name: str) -> int:
    m = re.search(rf"│ {name}\s+│\s+(-?\d+) │", screen)
    assert m, screen
    return int(m.group(1))


def test_watch_while_the_motor_moves(tmp_path):
    run = tmp_path / "run.sh"
    run.write_text(
        f"cd {ROOT}\n"
        f"PYTHONPATH={ROOT} NO_COLOR=1 {sys.executable} -m tmclsh --sim -c 'ROR 0, 20000\n"
        ".watch pos=GAP 1, 0; speed=GAP 3, 0; in0=GIO 0, 0 --interval 0.05'\n"
        "echo EXIT=$?\nstty -a | grep -o ' -\\?icanon'\nsleep 30\n")
    tmux = Tmux(tmp_path / "tmux.sock")
    tmux("new-session", "-d", "-s", "watch", "-x", "110", "-y", "30", f"sh {run}")
    try:
        first = tmux.wait_for(r"samples.*\n(.*\n)*│ pos .*\n(.*\n)*s/space: stop motors")
        time.sleep(0.4)
        second = tmux.screen()
        assert value(second, "pos") > value(first, "pos")  # live: the motor moves on screen
        assert value(second, "speed") > 0
        assert "q/Ctrl-C: end watch (motors keep running)" in second

        tmux("send-keys", "-t", "watch", "s")
        stopped = tmux.wait_for(r"MST sent to motor 0 at")
        deadline = time.monotonic() + 5
        while value(stopped, "speed") != 0 and time.monotonic() < deadline:
            time.sleep(0.1)
            stopped = tmux.screen()
        assert value(stopped, "speed") == 0  # the ramp down, seen in the table
        tmux("send-keys", "-t", "watch", "q")
        done = tmux.wait_for(r"EXIT=\d+\n.*icanon")
        assert "EXIT=0" in done
        assert re.search(r"watch: \d+ samples in [\d.]+ s .*MST sent to motor\(s\) 0", done)
        assert " icanon" in done  # the terminal is back in line mode (cbreak undone)
    finally:
        subprocess.run(["tmux", "-S", str(tmp_path / "tmux.sock"), "kill-server"],
                       capture_output=True)
