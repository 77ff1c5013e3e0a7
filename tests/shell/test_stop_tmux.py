"""Ctrl-C stops a running stored program, tried as a person does it: tmclsh in a real terminal
(tmux) on a simulated module behind a pty, whose motor the test reads directly. The program
keeps re-issuing ROR, so MST alone would be undone a moment later.

Skipped when tmux is not installed.
"""

from __future__ import annotations

import re
import time

import pytest

from tmux import needs_tmux

pytestmark = needs_tmux

PROGRAM = "Loop:\n    ROR 0, 20000\n    WAIT TICKS, 0, 2\n    JA Loop\n"


@pytest.fixture
def bench(make_pty_sim, terminal, tmp_path):
    """(terminal running the shell on the pty, simulator); the program is uploaded and runs."""
    sim, path = make_pty_sim()
    prog = tmp_path / "turn.tmc"
    prog.write_text(PROGRAM)
    term = terminal(width=110, height=30, timeout=10.0)
    term.start("--port", path, "-m", "TMCM-1311")
    term.wait("TMCM-1311:1>")
    return term, sim, prog


def speed(sim) -> int:
    return sim.param("axis", 3, 0)


def run_program(term, sim, prog) -> None:
    term.run(f".upload {prog} --yes", "uploaded")
    term.line(".run")
    # the prompt back after the .run line (a count of prompts races the one after .upload)
    term.wait_for(re.compile(r"> \.run *\n(?:[^\n]*\n)*?TMCM-1311:1[^>\n]*>"))
    deadline = time.monotonic() + 5
    while speed(sim) == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert speed(sim) > 0 and sim.program_state == 1


def still_stopped(sim) -> None:
    time.sleep(0.5)  # a running program would have started the motor again by now
    assert speed(sim) == 0 and sim.program_state == 0


def test_ctrl_c_at_the_prompt_stops_the_program_and_the_motor(bench):
    term, sim, prog = bench
    run_program(term, sim, prog)
    term.keys("C-c")
    term.wait("Ctrl-C: stored program stopped; stopped motor 0 (MST; speed reads 0)")
    still_stopped(sim)
    term.run("GAP ActualSpeed, 0", "ActualSpeed = 0")
    term.quit()  # nothing turns: Ctrl-D leaves without a question


def test_ctrl_c_in_a_watch_stops_the_program_and_the_motor(bench):
    term, sim, prog = bench
    run_program(term, sim, prog)
    term.line(".watch speed=GAP 3, 0 --interval 0.05")
    term.wait_for(re.compile(r"│ speed\s+│\s+\d+ │(.*\n)*.*Ctrl-C: stop all and end"))
    term.keys("C-c")
    screen = term.wait("watch: stored program stopped; stopped motor 0 (MST; speed reads 0)")
    assert "ended by Ctrl-C" in screen
    still_stopped(sim)
    term.quit()


def test_s_in_a_watch_stops_and_q_ends_it_quietly(bench):
    term, sim, prog = bench
    run_program(term, sim, prog)
    term.line(".watch speed=GAP 3, 0 --interval 0.05")
    term.wait("s/space: stop all")
    term.keys("s")
    term.wait("stored program stopped; stopped motor 0 (MST; speed reads 0) at")
    still_stopped(sim)
    term.keys("q")
    screen = term.wait("TMCM-1311:1>", more_than=2)  # the prompt, without [run]
    assert "watch: stored program stopped" not in screen  # q itself says nothing more
    term.quit()


def test_leaving_while_the_motor_turns_asks_first(bench):
    term, sim, _ = bench
    term.run("ROR 0, 20000", "rotating right")
    term.keys("C-d")
    screen = term.wait("Leave the shell?")
    assert "Motor 0 turns" in screen and "leave it running" in screen
    term.keys("Down", "Down", "Enter")  # cancel
    term.wait("TMCM-1311:1>", more_than=2)
    assert speed(sim) != 0
    term.line(".quit")
    term.wait("Leave the shell?", more_than=1)
    term.keys("Enter")  # the first choice: stop everything first
    screen = term.wait("EXIT=0")
    assert "leaving: stopped motor 0 (MST; speed reads 0)" in screen
    assert speed(sim) == 0


def test_the_leave_menu_takes_a_number_and_keeps_the_safe_default(bench):
    """Issue 35: typing 3 only moved the selection; after one "cancel" the menu started on
    it the next time instead of on "stop everything first"."""
    term, sim, _ = bench
    term.run("ROR 0, 20000", "rotating right")
    term.keys("C-d")
    term.wait("Leave the shell?")
    term.keys("3")  # cancel, chosen by its number: no Enter
    term.wait("TMCM-1311:1>", more_than=2)
    assert speed(sim) != 0
    term.keys("C-d")
    screen = term.wait("Leave the shell?", more_than=1)
    menu = screen[screen.rindex("Leave the shell?"):]
    assert re.search(r">\s*1\.\s*stop everything first", menu), menu  # the safe default
    term.keys("Enter")
    screen = term.wait("EXIT=0")
    assert "leaving: stopped motor 0 (MST; speed reads 0)" in screen
    assert speed(sim) == 0
