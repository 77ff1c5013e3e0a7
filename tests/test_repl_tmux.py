"""The real program in a real terminal: ``python -m tmclsh --sim`` inside tmux, typed at with
send-keys, read back with capture-pane. Skipped where tmux is missing.

Each test uses its own tmux server (``-L``) and session name, killed in a finally.
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

pytestmark = pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")

ROOT = Path(__file__).resolve().parents[1]


class Tmux:
    def __init__(self, tmp_path: Path, env: dict[str, str] | None = None, width: int = 120,
                 height: int = 36):
        self.socket = f"tmclsh-test-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self.name = "tmclsh"
        self.tmp = tmp_path
        self.env = {"XDG_STATE_HOME": str(tmp_path / "state"),
                    "XDG_CONFIG_HOME": str(tmp_path / "config"),
                    "PYTHONPATH": str(ROOT), "TERM": "xterm-256color", **(env or {})}
        self.width, self.height = width, height

    def tmux(self, *args: str, check: bool = True) -> str:
        proc = subprocess.run(["tmux", "-L", self.socket, *args], capture_output=True,
                              text=True, timeout=20)
        if check and proc.returncode:
            raise AssertionError(f"tmux {' '.join(args)}: {proc.stderr}")
        return proc.stdout

    def start(self, *argv: str) -> None:
        env = " ".join(f"{k}={_quote(v)}" for k, v in self.env.items())
        # -u COLUMNS/LINES: the test runner may export them; the pane's size must win
        cmd = (f"cd {_quote(str(ROOT))} && env -u COLUMNS -u LINES {env} "
               f"{_quote(sys.executable)} -m tmclsh "
               f"{' '.join(argv)}; echo EXIT=$?; sleep 60")
        self.tmux("-f", "/dev/null", "new-session", "-d", "-s", self.name,
                  "-x", str(self.width), "-y", str(self.height), cmd)

    def keys(self, *keys: str) -> None:
        self.tmux("send-keys", "-t", self.name, *keys)

    def type(self, text: str) -> None:
        self.tmux("send-keys", "-t", self.name, "-l", text)

    def screen(self) -> str:
        return self.tmux("capture-pane", "-p", "-t", self.name)

    def wait(self, text: str, timeout: float = 15.0) -> str:
        deadline = time.monotonic() + timeout
        screen = ""
        while time.monotonic() < deadline:
            screen = self.screen()
            if text in screen:
                return screen
            time.sleep(0.05)
        raise AssertionError(f"{text!r} not on the screen:\n{screen}")

    def quit(self, keys: tuple[str, ...] = ("C-d",)) -> None:
        """Leave and see the exit status. A key typed while the shell is between two prompts
        (the terminal briefly in cooked mode) can be eaten by the tty, as it would be for a
        person; then the key is typed again."""
        for _ in range(3):
            self.keys(*keys)
            try:
                self.wait("EXIT=0", timeout=3)
                return
            except AssertionError:
                continue
        raise AssertionError(f"the shell did not exit:\n{self.screen()}")

    def kill(self) -> None:
        self.tmux("kill-server", check=False)


def _quote(s: str) -> str:
    return "'" + s.replace("'", "'\\''") + "'"


@pytest.fixture
def term(tmp_path):
    t = Tmux(tmp_path)
    try:
        yield t
    finally:
        t.kill()


def test_a_session_as_a_person_types_it(term):
    term.start("--sim")
    term.wait("TMCM-1311:1>")
    screen = term.wait("trace off")  # the toolbar is drawn just after the prompt
    assert "TMCM-1311 at address 1" in screen and "SIMULATED" in screen
    # the toolbar, on the last line
    toolbar = screen.rstrip().splitlines()[-1]
    assert "SIMULATED" in toolbar and "TMCM-1311 @1" in toolbar and "binary" in toolbar
    assert "trace off" in toolbar

    term.type("SAP 4, 0, 1000")
    term.keys("Enter")
    term.wait("ok: MaxPositioningSpeed set to 1000 pps")
    term.type("GAP 4, 0")
    term.keys("Enter")
    term.wait("MaxPositioningSpeed = 1000 pps")

    # completion: the first Tab takes the best match and the menu shows both
    term.type("GAP MaxPos")
    term.keys("Tab")
    screen = term.wait("MaxPossibleCurrent")
    assert "TMCM-1311:1> GAP MaxPositioningSpeed" in screen
    menu = [line for line in screen.splitlines() if "AP 4 ·" in line or "AP 15 ·" in line]
    assert len(menu) == 2
    assert "MaxPositioningSpeed" in menu[0] and "0..327679999 pps" in menu[0]
    assert "MaxPossibleCurrent" in menu[1]
    term.type(", 0")
    term.keys("Enter")
    screen = term.wait("TMCM-1311:1> GAP MaxPositioningSpeed, 0")
    term.wait("MaxPositioningSpeed = 1000 pps\nTMCM-1311:1>")

    term.type("help 140")
    term.keys("Enter")
    screen = term.wait("256 microsteps")
    assert "AP 140" in screen and "MicrostepResolution" in screen

    # a refused line: one error line, and with the trace on nothing went out
    term.type(".trace on")
    term.keys("Enter")
    term.wait("trace on")
    term.type("SAP 140, 0, 99")
    term.keys("Enter")
    screen = term.wait("error: 99 is out of range")
    after = screen[screen.index("SAP 140, 0, 99"):]
    assert "tx>" not in after
    term.type("GAP 4, 0")
    term.keys("Enter")
    term.wait("tx> 01 06 04 00 00 00 00 00 0b")
    term.wait("trace on | Tab complete")  # the toolbar follows

    term.quit()


def test_ctrl_c_stops_a_turning_motor(term):
    term.start("--sim")
    term.wait("TMCM-1311:1>")
    term.type("ROR 0, 20000")
    term.keys("Enter")
    term.wait("rotating right at 20000 pps")
    term.keys("C-c")
    term.wait("Ctrl-C: stopped motor 0 (MST)")
    term.type("quit")
    term.quit(("Enter",))


def test_dumb_terminal_and_no_color(tmp_path):
    t = Tmux(tmp_path, env={"TERM": "dumb", "NO_COLOR": "1"})
    try:
        t.start("--sim")
        t.wait("TMCM-1311:1>")
        t.type("GAP MaxPos")
        t.keys("Tab")
        t.wait("GAP MaxPositioningSpeed")  # completion runs in the background: wait as a person would
        t.type(", 0")
        t.keys("Enter")
        screen = t.wait("MaxPositioningSpeed = ")
        assert "GAP MaxPositioningSpeed, 0" in screen
        t.quit()
    finally:
        t.kill()
