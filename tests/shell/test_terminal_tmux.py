"""``.ascii`` tried as a person would: the real program in a tmux pane, keys typed, the screen
read back. The module is a simulator served on a pty in this process. Skips without tmux."""

from __future__ import annotations

import re

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


def raw_terminal(pane, path: str, options: str = "") -> Terminal:
    """``.ascii --raw OPTIONS`` in a pane, once it says how to get back."""
    p = pane("--port", path, "-c", f".ascii --raw {options}".rstrip())
    p.wait("Ctrl-]: back to the shell")
    return p


def menu(p: Terminal, key: str, shown: str) -> str:
    """Pick ``key`` from the Ctrl-T menu and wait until ``shown`` is on the screen."""
    p.hex("14")  # Ctrl-T
    p.keys(key)
    return p.wait(shown)


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
    p = raw_terminal(pane, path, "--no-bin")
    p.keys("ASAP 1, 0, 7", "Enter")
    p.wait("ASAP 1, 0, 7\nBA 100 7   ok, value 7")
    p.keys("AGAX", "BSpace", "P 1, 0", "Enter")  # the module erases the X itself
    screen = p.wait("AGAP 1, 0\nBA 100 7   ok, value 7")
    assert "AGAP 1, 0\nBA 100 7" in screen
    p.hex("1d")  # Ctrl-]
    p.wait("EXIT=0")
    assert "module stays in ASCII mode" in p.screen()
    assert sim.ascii_active


def test_bin_typed_in_the_terminal_is_noticed(served, pane):
    sim, path = served
    p = pane("--port", path)
    p.wait("trace off")
    p.keys(".ascii", "Enter")
    p.wait("ascii A>")
    p.keys("GAP 1, 0", "Enter")
    p.wait("BA 100 0   ok, value 0")
    p.keys("BIN", "Enter")
    p.wait("--- module left ASCII mode (BIN): back to the shell on the binary link")
    assert not sim.ascii_active
    screen = p.wait("TMCM-1311:1>", more_than=1)  # the shell's prompt again, not the terminal's
    assert "send BIN" not in screen  # nothing to ask: the module is in binary mode already
    p.keys("GAP 1, 0", "Enter")  # the binary link answers
    p.wait("ActualPosition = 0")
    p.wait_for(lambda s: "binary" in s.splitlines()[-1])  # the toolbar
    p.keys("C-d")
    p.wait("EXIT=0")


def test_quit_typed_in_the_terminal_leaves_it(served, pane):
    sim, path = served
    p = pane("--port", path, "-c", ".ascii --bin")
    p.wait("ascii A>")
    p.keys(".quit", "Enter")
    p.wait("EXIT=0")
    screen = p.screen()
    assert "--- BIN sent: module in binary mode" in screen
    assert "error" not in screen  # .quit was not sent to the module
    assert not sim.ascii_active


def test_raw_mode_quit(served, pane):
    sim, path = served
    p = raw_terminal(pane, path, "--no-bin")
    p.keys(".quit", "Enter")
    p.wait("EXIT=0")
    assert "module stays in ASCII mode" in p.screen()
    assert "error" not in p.screen()  # the module forgot the typed word (backspaces)


def test_raw_mode_bin(served, pane):
    sim, path = served
    p = raw_terminal(pane, path)
    p.keys("ABIN", "Enter")
    p.wait("--- module left ASCII mode (BIN): back to the shell on the binary link")
    p.wait("EXIT=0")
    assert not sim.ascii_active


def hex_seen(screen: str) -> str:
    """The bytes of the hex view's lines (``41 47 ...  |AG..|``), joined."""
    after = screen.split("--- hex view on", 1)[-1]
    rows = re.findall(r"^((?:[0-9a-f]{2} )*[0-9a-f]{2}) +\|", after, re.M)
    return " ".join(rows)


def test_the_ctrl_t_menu(served, pane, tmp_path):
    sim, path = served
    log = tmp_path / "session.log"
    lines = tmp_path / "lines.tmcl"
    lines.write_text("# set and read back\nSAP 4, 0, 777\n\nGAP 4, 0\n")
    p = pane("--port", path, "-c", ".ascii --no-bin")
    p.wait("ascii A>")
    p.hex("14")  # Ctrl-T
    p.wait("Ctrl-T: e echo [off] · h hex [off] · t time [off] · f log [off] · u send file")
    p.keys("?")
    p.wait("f  log the session to a file (again: stop logging) [off]")
    menu(p, "t", "--- timestamps on")
    p.keys("GAP 1, 0", "Enter")
    screen = p.wait("BA 100 0   ok, value 0")
    assert re.search(r"\[\d\d:\d\d:\d\d\.\d{3}\] BA 100 0   ok, value 0", screen)
    menu(p, "t", "--- timestamps off")
    menu(p, "h", "--- hex view on")
    p.keys("GAP 1, 0", "Enter")
    p.wait_for(lambda s: "42 41 20 31 30 30 20 30 0d" in hex_seen(s),
               what="the reply's bytes not shown")  # BA 100 0 CR, in however many reads
    menu(p, "h", "--- hex view off")
    menu(p, "f", "log the session to file:")
    p.type(str(log))
    p.keys("Enter")
    # (a long temporary path wraps at the terminal's edge: read the screen's lines joined)
    p.wait_for(lambda s: f"--- logging the session to {log}" in s.replace("\n", ""),
               what="the logging line not on the screen")
    menu(p, "u", "send the lines of file:")
    p.type(str(lines))
    p.keys("Enter")
    p.wait("--- sent 2 of 2 lines")
    screen = p.screen()
    assert "BA 100 777   ok, value 777" in screen
    assert screen.count("BA 100 777") == 2  # SAP and GAP, each answered
    menu(p, "e", "--- local echo on")
    p.keys("GAP 4, 0", "Enter")
    p.wait("A        GAP 4, 0")  # the line as sent (padded to whole nine-byte blocks)
    menu(p, "f", f"--- log closed: {log}")
    p.hex("14")  # the menu, then Enter: Enter does its job and the menu is gone
    p.keys("Enter")
    p.keys("SAP 4, 0, 4321", "Enter")  # typed as a line, S not taken for the menu
    p.wait("BA 100 4321   ok, value 4321")
    assert "no such menu entry" not in p.screen()
    p.hex("1d")
    p.wait("EXIT=0")
    text = log.read_text()
    assert "BA 100 777   ok, value 777" in text and "\x1b" not in text
    assert sim.ascii_active  # --no-bin
