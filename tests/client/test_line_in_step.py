"""Nothing tmclsh sends leaves a module's framing out of step (issue 31): the ASCII probes of
the bring-up and of scan reach every binary module on the line, and a module that counts
what it hears in nines, with no receive timeout (the manuals describe none), answers nothing
once a byte count is not a multiple of nine, not even at its own address.

The line is tests/responder.py's ``SharedLine``, written from the manuals, not the simulator
(which discards a partial frame after a pause and searches for frames, so it would find its
step again by itself): a binary module at address 5 that frames in nines, and one in ASCII
mode at address 3 that must do nothing it was not asked to.
"""

from __future__ import annotations

import json

import pytest

from responder import AsciiModeModule, Module, SharedLine

GGP, GP_ADDRESS = 10, 66


@pytest.fixture
def line():
    bus = SharedLine()
    binary = Module(version="1311V111", address=5, nines=True, line=bus)
    binary.values[(GP_ADDRESS, 0, True)] = 5
    ascii_module = AsciiModeModule(address=3, line=bus)
    yield bus, binary, ascii_module
    bus.close()


def answers_at_5(run_tmclsh, bus, binary) -> None:
    """The module at 5 is in step: it answers GGP 66 there."""
    assert binary.held == b""  # (at a frame boundary: nothing of a frame waiting)
    p = run_tmclsh("--port", bus.path, "-a", "5", "--timeout", "0.5", "-c", "GGP 66, 0")
    assert p.returncode == 0, p.stderr
    assert p.stdout.split()[-1:] == ["5"], (p.stdout, p.stderr)
    assert (GGP, GP_ADDRESS, 0, 0) in binary.got


def untouched(ascii_module, before: list[bytes]) -> None:
    """The module in ASCII mode was asked nothing and holds no line for it."""
    mine = [t for t in ascii_module.log if t.lstrip(b" ").startswith(b"C")]
    assert mine == before
    assert not ascii_module.held.lstrip(b" ").startswith(b"C")
    assert ascii_module.ascii and ascii_module.modes == ["ascii"]


RUNS = {
    "absent address": ["-a", "1", "--timeout", "0.3", "-c", "GAP 1, 0"],
    "absent address, --ascii": ["-a", "1", "--ascii", "--timeout", "0.3", "-c", "GAP 1, 0"],
    "scan": ["scan", "--to", "8", "--timeout", "0.3"],  # (a busy machine: a long wait)
}


@pytest.mark.parametrize("run", RUNS.values(), ids=RUNS.keys())
def test_a_probe_leaves_a_module_without_receive_timeout_in_step(run_tmclsh, line, run):
    bus, binary, ascii_module = line
    p = run_tmclsh("--port", bus.path, *run)
    assert p.returncode == (0 if run[0] == "scan" else 3), p.stderr
    if run[0] == "scan":
        assert [ln.split()[:2] for ln in p.stdout.splitlines()] == [["address", "5"]]
    else:  # nothing at 1: it was looked for in ASCII mode too
        assert any(t.lstrip(b" ").startswith(b"A") for t in ascii_module.log)
    untouched(ascii_module, [])
    answers_at_5(run_tmclsh, bus, binary)
    untouched(ascii_module, [])


def test_scan_ascii_pass_leaves_both_modules_as_they_were(run_tmclsh, line):
    """The ASCII pass finds the module at 3 (it steps out of ASCII mode for the 136 that
    names it, and back) and the one at 5 stays in step."""
    bus, binary, ascii_module = line
    p = run_tmclsh("scan", "--ascii", "--port", bus.path, "--to", "8", "--timeout", "0.3",
                   "--json")
    assert p.returncode == 0, p.stderr
    rows = {r["address"]: r for r in map(json.loads, p.stdout.splitlines())}
    assert sorted(rows) == [3, 5] and rows[3]["mode"] == "ascii"
    assert ascii_module.ascii and ascii_module.modes == ["ascii", "binary", "ascii"]
    assert not ascii_module.held.lstrip(b" ").startswith(b"C")
    asked = [t for t in ascii_module.log if t.lstrip(b" ").startswith(b"C")]
    answers_at_5(run_tmclsh, bus, binary)
    untouched_since = [t for t in ascii_module.log if t.lstrip(b" ").startswith(b"C")]
    assert untouched_since == asked


def test_address_switch_to_an_absent_address_leaves_the_line_in_step(run_tmclsh, line):
    """``.address 1`` looks for a module there (binary and ASCII), finds none and stays at
    5, which still answers in the same session."""
    bus, binary, ascii_module = line
    p = run_tmclsh("--port", bus.path, "-a", "5", "--timeout", "0.3", "--keep-going",
                   "-c", ".address 1\nGGP 66, 0")
    assert p.returncode != 0 and "address 1" in p.stderr, p.stderr
    assert p.stdout.split()[-1:] == ["5"], (p.stdout, p.stderr)
    untouched(ascii_module, [])
    answers_at_5(run_tmclsh, bus, binary)


def test_lines_typed_in_the_ascii_terminal_keep_binary_modules_in_step(run_tmclsh, line):
    """The ``.ascii`` terminal (line mode; here its lines come from a pipe) pads a typed
    line as tmclsh pads its own: a binary module that frames in nines, listening on the
    same line, is still in step after it and answers at its own address."""
    bus, binary, _ = line
    other = AsciiModeModule(address=4, line=bus)
    other.ascii, other.modes = False, ["binary"]
    p = run_tmclsh("--port", bus.path, "-a", "4", "--timeout", "0.5", "-c", ".ascii --bin",
                   input="GGP 67, 0\nDGGP 67, 0\n")
    assert p.returncode == 0, p.stderr
    assert other.modes == ["binary", "ascii", "binary"]
    typed = [t for t in other.log if t.lstrip(b" ").startswith(b"D") and b"GGP" in t]
    # (the mode probe's line and the two typed: each whole nine-byte blocks with its CR)
    assert len(typed) == 3 and all((len(t) + 1) % 9 == 0 for t in typed), typed
    answers_at_5(run_tmclsh, bus, binary)
