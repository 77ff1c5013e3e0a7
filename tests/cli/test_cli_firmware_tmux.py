"""``tmclsh firmware`` in a real terminal: the question before the erase, the progress bar
with rate and time left, Ctrl-C in the middle saying where the module stands and the command
that completes it, and that command run. Skipped where tmux is missing."""

from __future__ import annotations

import re

import pytest

from bootmodel import hex_image
from tmclsh.sim import Simulator
from tmclsh.sim.boot import Bootloader
from tmclsh.sim.serve import serve_pty
from tmux import needs_tmux

pytestmark = needs_tmux


@pytest.fixture
def served():
    sim = Simulator("TMCM-1311")
    sim.faults.delay = 0.0005  # every reply a little late: the bar is there long enough
    server = serve_pty(sim)
    yield sim, server.path
    server.close()
    sim.close()


def test_update_asks_shows_progress_and_survives_ctrl_c(terminal, served, tmp_path):
    sim, path = served
    image = tmp_path / "TMCM-1311_V1.20.hex"
    image.write_text(hex_image("1311V120", 120_000, Bootloader.START))
    term = terminal(width=110, height=30)
    term.start("firmware", str(image), "--port", path)
    term.wait("[y/N]")
    assert "from 1311V111 to 1311V120" in term.screen().replace("\n", "")
    term.line("y")
    # the bar: bytes written of the whole, the rate, the time left
    screen = term.wait_for(re.compile(r"writing .* \d+(\.\d+)?/120\.0 kB .*kB/s \d:\d\d:\d\d"),
                           timeout=20)
    term.keys("C-c")
    screen = term.wait("EXIT=130", timeout=20)
    flat = screen.replace("\n", "")
    assert "tmclsh: interrupted" in screen
    assert "its firmware is erased (" in flat and "of 120000 bytes written)" in flat
    assert sim.in_bootloader
    assert f"to complete the update, run: tmclsh firmware {image} --port {path}" in flat
    term.kill()

    term = terminal(width=110, height=30)
    sim.faults.delay = 0.0
    term.start("firmware", str(image), "--port", path, "--yes")
    screen = term.wait("EXIT=0", timeout=60)
    assert "in its bootloader (1311B100): an earlier update did not complete" in screen
    assert re.search(r"updated the TMCM-1311 from its bootloader .* to 1311V120",
                     screen.replace("\n", ""))
    assert not sim.in_bootloader and sim.version_string == "1311V120"
