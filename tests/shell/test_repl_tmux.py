"""The real program in a real terminal: ``python -m tmclsh --sim`` inside tmux, typed at with
send-keys, read back with capture-pane. Skipped where tmux is missing.

Each test uses its own tmux server (tests/tmux.py), killed afterwards.
"""

from __future__ import annotations

import pytest

from tmux import needs_tmux

pytestmark = needs_tmux


@pytest.fixture
def term(terminal):
    return terminal()


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
    term.wait("Ctrl-C: stopped motor 0 (MST; speed reads 0)")
    term.type("quit")
    term.quit(("Enter",))


def test_dumb_terminal_and_no_color(terminal):
    t = terminal(env={"TERM": "dumb", "NO_COLOR": "1"})
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


def test_a_second_tab_keeps_the_only_completion(term):
    """SAP offers only writable parameters: 'SAP MaxPos' has one match. A second Tab (as in
    bash) put back 'SAP MaxPos'; it must keep the completion and close the menu."""
    term.start("--sim")
    term.wait("trace off")
    term.type("SAP MaxPos")
    term.keys("Tab")
    term.wait("TMCM-1311:1> SAP MaxPositioningSpeed")
    term.keys("Tab")  # the second
    term.type(", 0, 1000")
    term.keys("Enter")
    screen = term.wait("ok: MaxPositioningSpeed set to 1000 pps")
    assert "TMCM-1311:1> SAP MaxPositioningSpeed, 0, 1000" in screen
