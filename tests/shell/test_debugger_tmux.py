"""The program debugger as a person uses it: ``python -m tmclsh --sim`` in tmux, typed at with
send-keys, read back with capture-pane. Skipped where tmux is missing.

Uploads the TMCM-1311 manual's timer-interrupt example (§5.6.5), steps through its first
instructions (an empty line repeats the step), runs to a breakpoint, stops and resets.
"""

from __future__ import annotations

import pytest

from manuals import listing
from tmux import needs_tmux

TIMER_EXAMPLE = listing("tmcm1311-timer-interrupt")

pytestmark = needs_tmux


@pytest.fixture
def pane(terminal, tmp_path):
    return terminal(cwd=tmp_path, width=150, height=50, history=300)


def test_step_break_continue_stop_reset_in_a_terminal(pane, tmp_path):
    (tmp_path / "timer.tmc").write_text(TIMER_EXAMPLE, encoding="utf-8")
    pane.start("--sim", "TMCM-1311")
    pane.wait("TMCM-1311:1>")

    pane.line(".upload timer.tmc")
    pane.wait("[y/N]")
    pane.line("y")
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
