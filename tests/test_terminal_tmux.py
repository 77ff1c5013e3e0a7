"""``.ascii`` tried as a person would: the real program in a tmux pane, keys typed, the screen
read back. The module is a simulator served on a pty in this process. Skips without tmux."""

from __future__ import annotations

import pytest
from conftest import tmclsh_env
from tmux import Terminal, needs_tmux

pytestmark = needs_tmux


def prompt_line(screen: str) -> str:
    lines = [ln.rstrip() for ln in screen.splitlines() if ln.startswith("ascii A>")]
    return lines[-1] if lines else ""


@pytest.fixture
def served(make_pty_sim):
    return make_pty_sim()


@pytest.fixture
def pane(terminal, tmp_path):
    """``pane(*args)``: ``python -m tmclsh ARGS`` in a 100x30 terminal."""
    env = tmclsh_env(NO_COLOR="1", XDG_STATE_HOME=str(tmp_path), TERM="xterm")
    keep = ("PYTHONPATH", "NO_COLOR", "XDG_STATE_HOME", "TERM", "TMCLSH_CONFIG", "PATH", "HOME")

    def start(*args: str) -> Terminal:
        t = terminal(env={k: v for k, v in env.items() if k in keep}, width=100, height=30,
                     timeout=10, unset=("TMCLSH_PORT", "TMCLSH_CAN", "TMCLSH_PROFILE",
                                        "TMCLSH_MODULE", "TMCLSH_ADDRESS"))
        t.start(*args)
        return t

    return start


def test_line_mode(served, pane):
    sim, path = served
    p = pane("--port", path, "-c", ".ascii")
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
    p.wait_for(lambda screen: prompt_line(screen) == "ascii A> GAP 1")
    p.keys(", 0", "Enter")
    screen = p.wait("ascii A> GAP 1, 0\nBA 100 -5000")
    assert "AGAP" not in screen  # the module's echo is not shown twice
    p.hex("1d")  # Ctrl-]
    p.wait("send BIN (module back to binary mode)? [Y/n]")
    p.keys("Enter")
    p.wait("EXIT=0")
    assert "--- BIN sent: module in binary mode" in p.screen()
    assert not sim.ascii_active


def test_raw_mode_backspace(served, pane):
    sim, path = served
    p = pane("--port", path, "-c", ".ascii --raw --no-bin")
    p.wait("Ctrl-]: back to the shell")
    p.keys("ASAP 1, 0, 7", "Enter")
    p.wait("ASAP 1, 0, 7\nBA 100 7   ok, value 7")
    p.keys("AGAX", "BSpace", "P 1, 0", "Enter")  # the module erases the X itself
    screen = p.wait("AGAP 1, 0\nBA 100 7   ok, value 7")
    assert "AGAP 1, 0\nBA 100 7" in screen
    p.hex("1d")  # Ctrl-]
    p.wait("EXIT=0")
    assert "module stays in ASCII mode" in p.screen()
    assert sim.ascii_active
