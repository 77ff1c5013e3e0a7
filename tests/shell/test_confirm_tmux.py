"""Confirmations in a real terminal: the same keys everywhere ([y/N] and Enter), and no empty
prompt left behind by the answer. Skipped where tmux is missing."""

from __future__ import annotations

import re

import pytest

from tmux import needs_tmux

pytestmark = needs_tmux

PROMPT = re.compile(r"^TMCM-1311:1(?: \[[^]]*\])?>(.*)$", re.M)


@pytest.fixture
def term(terminal):
    return terminal(height=40)


def prompts(screen: str) -> list[str]:
    return [m.group(1).strip() for m in PROMPT.finditer(screen)]


def test_confirmations_take_y_and_enter_and_leave_no_empty_prompt(term):
    term.start("--sim", "TMCM-1311")
    term.wait("TMCM-1311:1>")

    # an EEPROM write: y and Enter agree
    term.line("STAP MaxPositioningSpeed, 0")
    term.wait("permanently in the module's EEPROM? [y/N]")
    term.line("y")
    term.wait("stored in EEPROM")
    # n and Enter refuse; Enter alone is the default: no
    term.line("STAP MaxAcceleration, 0")
    term.wait("[y/N]", more_than=1)
    term.line("n")
    term.wait("cancelled; nothing was sent")
    term.line("RSGP 0, 2")  # not a confirmation: a plain command in between
    # (its answer awaited, as a person would: a line typed ahead on a busy machine is
    # echoed by the terminal before the next prompt, which is not what this is about)
    term.wait("restored from EEPROM")
    term.line("STGP 0, 2")
    term.wait("[y/N]", more_than=2)
    term.keys("Enter")
    screen = term.wait("cancelled; nothing was sent", more_than=1)
    term.line("GAP 4, 0")
    screen = term.wait("MaxPositioningSpeed = ")
    screen = term.wait_for(lambda s: prompts(s)[-1:] == [""], what="no prompt after GAP")

    # one prompt per typed line and the one waiting: none empty but the last
    seen = prompts(screen)
    assert seen == ["STAP MaxPositioningSpeed, 0", "STAP MaxAcceleration, 0", "RSGP 0, 2",
                    "STGP 0, 2", "GAP 4, 0", ""], screen
    # the answers stand on the question's line
    assert re.search(r"EEPROM\? \[y/N\] y$", screen, re.M), screen
    assert re.search(r"EEPROM\? \[y/N\] n$", screen, re.M), screen
    term.quit()


def test_the_ascii_terminal_asks_the_same_way(term):
    term.start("--sim", "TMCM-1311")
    term.wait("TMCM-1311:1>")
    term.line(".ascii")
    term.wait("Ctrl-]")
    term.hex("1d")  # Ctrl-]: leave
    term.wait("send BIN (module back to binary mode)? [Y/n]")
    term.keys("Enter")  # Enter alone: the default, yes
    screen = term.wait_for(lambda s: prompts(s)[-1:] == [""], what="no prompt after .ascii")
    assert prompts(screen) == [".ascii", ""], screen
    term.quit()
