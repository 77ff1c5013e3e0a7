"""A session that set a motor moving at one address and went on at another (``.address``)
is told of each address it left something running at when it ends: the note at the end of
``-c``/``-f``, the question at Ctrl-D. Only addresses the session talked to are asked.
Against modules written from the manual (tests/responder.py: every value reads 0, so a
motor told to turn reads still, as one that has not started) and the simulator's bus."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from conftest import ROOT, patience, tmclsh_env
from responder import Responder
from tmux import needs_tmux


class Bus(Responder):
    """Plain TMCM-1311s at addresses 1, 2 and 3 on one line; ``deaf`` addresses answer no
    more once a frame to address 2 went by (a module unplugged while the session worked
    elsewhere)."""

    addresses = frozenset({1, 2, 3})

    def __init__(self, **kw):
        super().__init__(**kw)
        self.deaf: set[int] = set()
        self.at_two = False

    def answer(self, raw: bytes) -> bytes | None:
        self.at_two = self.at_two or raw[0] == 2
        if self.at_two and raw[0] in self.deaf:
            return None
        return super().answer(raw)


@pytest.fixture
def bus():
    module = Bus()
    yield module
    module.close()


def run(path: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tmclsh", "--port", path, *args],
                          capture_output=True, text=True, timeout=patience(60),
                          env=tmclsh_env(), cwd=str(ROOT))


def to(module: Responder, address: int) -> list[bytes]:
    return [raw for raw in module.log if len(raw) == 9 and raw[0] == address]


def test_the_note_names_the_address_left_turning(bus):
    p = run(bus.path, "--timeout", "2", "-c", "ROR 0, 1000; .address 2; GAP 1, 0")
    assert p.returncode == 0, p.stderr
    assert ("tmclsh: note: address 1: motor 0 was told to turn (ROR 0, 1000: target speed "
            "1000); it reads speed 0; left running (.stopall at address 1 stops everything)"
            ) in p.stderr, p.stderr
    assert "address 2: motor" not in p.stderr, p.stderr  # (nothing going on there)
    assert not to(bus, 3), "an address the session never talked to was asked"


def test_json_names_each_address(bus):
    p = run(bus.path, "--timeout", "2", "--json", "-c",
            "ROR 0, 1000; .address 2; ROL 0, 300")
    left = {o["address"]: o["left_running"]["commanded"]["0"]["line"]
            for o in map(json.loads, p.stdout.splitlines()) if "left_running" in o}
    assert left == {1: "ROR 0, 1000", 2: "ROL 0, 300"}, p.stdout + p.stderr
    assert not to(bus, 3)


def test_an_address_left_that_no_longer_answers_is_still_named(bus):
    bus.deaf.add(1)
    p = run(bus.path, "--timeout", "0.3", "-c", "ROR 0, 1000; .address 2; GAP 1, 0")
    assert p.returncode == 0, p.stderr
    note = [line for line in p.stderr.splitlines() if "note: address 1:" in line]
    assert note and "motor 0 was told to turn (ROR 0, 1000: target speed 1000); its speed "\
        "could not be read (" in note[0], p.stderr
    assert "Traceback" not in p.stderr


def test_the_simulated_bus_says_both_motors_turn(make_pty_sim):
    from tmclsh.sim import SimBus, Simulator

    sims = [Simulator("TMCM-1311", a) for a in (1, 2)]
    _, path = make_pty_sim(target=SimBus(sims))
    p = run(path, "-c", "ROR 0, 1000; .address 2; ROR 0, 500; .address 1; .address 2")
    assert p.returncode == 0, p.stderr
    assert "note: address 2: motor 0 turns (speed" in p.stderr, p.stderr
    assert "note: address 1: motor 0 turns (speed" in p.stderr, p.stderr
    assert [s.param("axis", 3, 0) for s in sims] != [0, 0]  # left so, as the note says


def test_one_address_is_said_as_before(bus):
    p = run(bus.path, "--timeout", "2", "-c", "ROR 0, 1000")
    assert ("tmclsh: note: motor 0 was told to turn (ROR 0, 1000: target speed 1000); it "
            "reads speed 0; left running (.stopall stops everything)") in p.stderr, p.stderr
    assert not to(bus, 2) and not to(bus, 3)


@needs_tmux
def test_ctrl_d_asks_about_the_address_left_and_stops_it_there(bus, terminal):
    term = terminal(height=30)
    term.start("--port", bus.path, "--timeout", "2")
    term.wait("TMCM-1311:1>")
    term.run("ROR 0, 1000", "rotating right")
    term.run(".address 2", "address 2: TMCM-1311")
    term.keys("C-d")
    screen = term.wait("Leave the shell?")
    assert "Address 1: motor 0 was told to turn (ROR 0, 1000: target speed 1000)" in screen
    term.keys("Down", "Down", "Enter")  # cancel: the shell stays, at address 2
    term.wait("TMCM-1311:2>", more_than=1)
    assert not to(bus, 3)
    term.keys("C-d")
    term.wait("Leave the shell?", more_than=1)
    term.keys("Enter")  # stop everything first: at address 2, then at address 1
    screen = term.wait("EXIT=0")
    assert "leaving: address 1: stopped motor 0" in screen, screen
    assert [raw for raw in to(bus, 1) if raw[1] == 3], "no MST reached address 1"
    assert not to(bus, 3)


@needs_tmux
def test_ctrl_c_at_the_prompt_stops_the_address_left_too(bus, terminal):
    """The banner says Ctrl-C stops all motors: at the address in use, then at each address
    the session left a motor told to move at, and the prompt stays where it was."""
    term = terminal(height=30)
    term.start("--port", bus.path, "--timeout", "2")
    term.wait("TMCM-1311:1>")
    term.run("ROR 0, 1000", "rotating right")
    term.run(".address 2", "address 2: TMCM-1311")
    term.keys("C-c")
    screen = term.wait("Ctrl-C: address 1: stopped motor 0")
    assert "Ctrl-C: stopped motor 0" in screen, screen  # (address 2's own stop first)
    assert [raw for raw in to(bus, 1) if raw[1] == 3], "no MST reached address 1"
    term.run("GAP 1, 0", "ActualPosition")
    assert "TMCM-1311:2>" in term.screen()
    term.quit()  # (nothing left running: no question)
    assert not to(bus, 3)
