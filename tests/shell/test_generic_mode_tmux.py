"""Generic mode as a person sees it: a module whose type tmclsh has no data for, in a real
terminal (tmux), answering from a responder written from the manual."""

from __future__ import annotations

import re

import pytest

from responder import TcpModule
from tmux import needs_tmux

pytestmark = needs_tmux


@pytest.fixture
def module_1161():
    m = TcpModule(version="1161V130")
    yield m
    m.close()


def test_banner_toolbar_and_numbers_at_the_prompt(terminal, module_1161, tmp_path):
    term = terminal(env={"XDG_CONFIG_HOME": str(tmp_path / "cfg"), "TMCLSH_CONFIG": "/dev/null"})
    term.start("--port", module_1161.url)
    screen = term.wait("trace off")
    assert "TMCM-1161 (no parameter data: numbers only)" in screen  # the banner
    assert screen.count("no parameter data for this module") == 1  # told once
    toolbar = screen.rstrip().splitlines()[-1]
    assert "TMCM-1161 (no parameter data: numbers only)" in toolbar
    term.type("SAP 4, 0, 1500")
    term.keys("Enter")
    term.type("GAP 4, 0")
    term.keys("Enter")
    # the reply line itself (the typed SAP line holds "1500" too): GAP 4 has been answered
    term.wait_for(re.compile(r"(?m)^1500\s*$"))
    assert module_1161.got[-1] == (6, 4, 0, 0)
    term.type("GAP MaxPositioningSpeed, 0")
    term.keys("Enter")
    term.wait("by number")
    assert module_1161.got[-1] == (6, 4, 0, 0)  # the refused name sent nothing
