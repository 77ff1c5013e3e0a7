"""Issue 33: none of the technician's three jobs (``replace``, ``scan --expect``, ``replay``)
sends a byte to a module it was not asked to touch. Each runs on a line that also holds a
bystander: a module written from the manual (tests/responder.py) at an address the job was
not given, which frames what it hears in nines without searching (``nines=True``: any stray
byte would put it out of step for good). After each job the bystander has had no request
addressed to it, and a request to it by hand (raw pyserial) still gets its right answer."""

from __future__ import annotations

import struct
import subprocess
import sys

import pytest
import serial

from conftest import ROOT, patience, tmclsh_env
from fieldmodule import FieldModule
from responder import Module, SharedLine
from test_replay_session import LineModule, capture, fill, session

BYSTANDER = 9
GAP = 6


def bystander(line: SharedLine) -> Module:
    m = Module(version="1311V111", address=BYSTANDER, nines=True, line=line)
    m.values[(4, 0, False)] = 4321
    return m


def untouched(line: SharedLine, m: Module) -> None:
    """Nothing was addressed to it, and it is still in step: a GAP by hand is answered."""
    assert m.got == [], m.got[:5]
    body = struct.pack(">BBBBi", BYSTANDER, GAP, 4, 0, 0)
    with serial.Serial(line.path, 9600, timeout=patience(5)) as port:
        port.reset_input_buffer()
        port.write(body + bytes([sum(body) & 0xFF]))
        got = port.read(9)
    assert len(got) == 9 and struct.unpack(">i", got[4:8])[0] == 4321, got.hex(" ")
    assert m.got == [(GAP, 4, 0, 0)]


def tmclsh(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tmclsh", *args], capture_output=True,
                          text=True, env=tmclsh_env(), cwd=str(ROOT), timeout=patience(300),
                          stdin=subprocess.DEVNULL)


def test_replay_touches_only_the_addresses_of_the_capture(tmp_path):
    line = SharedLine()
    try:
        module = LineModule(line=line)
        fill(module)
        other = bystander(line)
        requests = session(300)
        cap = str(tmp_path / "session.txt")
        capture(line.path, cap, requests)  # (the bystander was on the line all along)
        other.got.clear()  # (nothing is addressed to it: checked below all the same)
        done = tmclsh("replay", cap, "--port", line.path, "--yes", "--json")
        assert done.returncode == 0, done.stderr
        assert len(module.got) >= 2 * len(requests)  # (the session, then its replay)
        untouched(line, other)
    finally:
        line.close()


def test_scan_expect_touches_only_the_addresses_it_scans(tmp_path):
    line = SharedLine()
    try:
        Module(version="1311V111", address=1, line=line)
        other = bystander(line)
        inv = tmp_path / "line.toml"
        # address 2 missing, expected in ASCII mode: its silence is asked in ASCII too
        inv.write_text("".join(
            f'[[module]]\naddress = {a}\ntype = "TMCM-1311"\nfirmware = "1311V111"\n'
            f'mode = "{mode}"\n\n' for a, mode in ((1, "binary"), (2, "ascii"))))
        done = tmclsh("scan", "--port", line.path, "--from", "1", "--to", "4",
                      "--timeout", "0.3", "--expect", str(inv))
        assert done.returncode == 1, done.stdout + done.stderr
        assert "nothing answered" in done.stdout, done.stdout
        untouched(line, other)
    finally:
        line.close()


def test_replace_touches_only_the_old_and_the_new_module(tmp_path):
    """Both on lines shared with a bystander. (The firmware step is left out: the bootloader
    talks at another baud rate, which a bystander on the same line hears as noise whatever
    tmclsh sends; the line models here hear every rate.)"""
    old_line, new_line = SharedLine(), SharedLine()
    try:
        old = FieldModule("1311V111", line=old_line)
        old.values[("axis", 4, 0)] = 1234
        old.stored[0] = (27, 0, 0, 100)  # WAIT TICKS, 0, 100
        old.stored[1] = (22, 0, 0, 0)  # JA 0
        new = FieldModule("1311V111", line=new_line)
        watching = bystander(old_line), bystander(new_line)
        done = tmclsh("replace", "--from", old_line.path, "--to", new_line.path, "--yes",
                      "--timeout", "0.5")
        assert done.returncode == 0, done.stdout + done.stderr
        assert "replaced:" in done.stdout
        assert new.values[("axis", 4, 0)] == 1234 and new.program() == old.program()
        untouched(old_line, watching[0])
        untouched(new_line, watching[1])
    finally:
        old_line.close()
        new_line.close()


def test_replace_on_one_line_names_the_addresses():
    """Old and new module on one line, at 2 and 3, beside the bystander: only they are
    touched, and the report says which modules it means (the port alone does not)."""
    line = SharedLine()
    try:
        old = FieldModule("1311V111", address=2, line=line)
        old.values[("axis", 4, 0)] = 1234
        new = FieldModule("1311V111", address=3, line=line)
        watching = bystander(line)
        done = tmclsh("replace", "--from", line.path, "--from-address", "2", "--to",
                      line.path, "--to-address", "3", "--yes", "--timeout", "0.5")
        assert done.returncode == 0, done.stdout + done.stderr
        assert f"replaced: {line.path} address 2 -> {line.path} address 3" in done.stdout
        assert new.values[("axis", 4, 0)] == 1234
        untouched(line, watching)
    finally:
        line.close()


def test_the_bystander_would_notice(tmp_path):
    """The check can fail: one request to the bystander's address is seen."""
    line = SharedLine()
    try:
        other = bystander(line)
        body = struct.pack(">BBBBi", BYSTANDER, GAP, 1, 0, 0)
        with serial.Serial(line.path, 9600, timeout=patience(5)) as port:
            port.write(body + bytes([sum(body) & 0xFF]))
            assert len(port.read(9)) == 9
        with pytest.raises(AssertionError):
            untouched(line, other)
    finally:
        line.close()

