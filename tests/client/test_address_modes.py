"""``.address`` on a line where modules are in different modes: each module is met in the
mode it is in and left in the mode it was found in. The ASCII mode tmclsh drove one module
in is that module's: it neither carries over to the next address (a 139 to a module nobody
asked to switch; a TMCM-1161, which has none, refused as "has no ASCII mode") nor is it
restored at exit on whichever address the client last talked to.

The line is tests/responder.py's ``SharedLine`` (written from the manuals, not the
simulator): at 3 a TMCM-1311 in its ASCII mode (GP 67 makes it start there), at 4 a
TMCM-1311 in binary mode, at 5 a module with no ASCII mode.
"""

from __future__ import annotations

import pytest

from responder import AsciiModeModule, Module, SharedLine


@pytest.fixture
def line():
    bus = SharedLine()
    in_ascii = AsciiModeModule(address=3, line=bus)
    in_binary = AsciiModeModule(address=4, line=bus)
    in_binary.ascii, in_binary.modes = False, ["binary"]
    no_ascii = Module(address=5, nines=True, line=bus)
    yield bus, in_ascii, in_binary, no_ascii
    bus.close()


def run(run_tmclsh, bus, *args):
    return run_tmclsh("--port", bus.path, "--timeout", "0.5", *args)


def test_from_a_module_in_ascii_mode_to_binary_ones(run_tmclsh, line):
    bus, in_ascii, in_binary, no_ascii = line
    p = run(run_tmclsh, bus, "-a", "3", "-c", ".address 4; GGP 66, 0; .address 5; GGP 66, 0")
    assert p.returncode == 0, p.stderr
    assert "has no ASCII mode" not in p.stderr
    assert in_binary.modes == ["binary"] and not in_binary.ascii  # never sent 139
    assert in_ascii.ascii and in_ascii.modes[-1] == "ascii"  # left as found
    assert (10, 66, 0, 0) in no_ascii.got and no_ascii.held == b""


def test_ascii_asked_is_undone_on_the_module_it_was_asked_for(run_tmclsh, line):
    bus, in_ascii, in_binary, _ = line
    p = run(run_tmclsh, bus, "-a", "4", "--ascii", "-c", ".address 3; GGP 67, 0")
    assert p.returncode == 0, p.stderr
    assert in_binary.modes == ["binary", "ascii", "binary"] and not in_binary.ascii
    assert in_ascii.ascii and in_ascii.modes[-1] == "ascii"


def test_mode_binary_then_another_address(run_tmclsh, line):
    """``.mode binary`` on the module found in ASCII mode: at exit it goes back to ASCII
    mode, it alone; the binary module the client turned to is not sent 139."""
    bus, in_ascii, in_binary, _ = line
    p = run(run_tmclsh, bus, "-a", "3", "-c", ".mode binary; .address 4; GGP 66, 0")
    assert p.returncode == 0, p.stderr
    assert in_binary.modes == ["binary"] and not in_binary.ascii
    assert in_ascii.ascii and in_ascii.modes[-1] == "ascii"


def test_ascii_asked_goes_on_to_the_next_address(run_tmclsh, line):
    """--ascii asked for ASCII mode: the module found in it already and the next one are
    both driven through it; each is left in the mode it was found in."""
    bus, in_ascii, in_binary, _ = line
    p = run(run_tmclsh, bus, "-a", "3", "--ascii", "-c", ".address 4; .mode")
    assert p.returncode == 0, p.stderr
    assert "mode: ASCII mode" in p.stdout, p.stdout
    assert in_binary.modes == ["binary", "ascii", "binary"] and not in_binary.ascii
    assert in_ascii.ascii and in_ascii.modes[-1] == "ascii"
