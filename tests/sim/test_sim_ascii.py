"""The simulator's ASCII interface (TMCM-1311 §4.4, TMCM-351 §5.6): entering and leaving,
echo modes, line editing, addressing, replies and status codes."""

from __future__ import annotations

import time

import pytest

from tmclsh.tmcl.frames import Reply, Request, Status
from tmclsh.sim import Simulator


def collect(sim, until: bytes = b"", timeout: float = 1.0, quiet: float = 0.05) -> bytes:
    """Everything the module sends until ``until`` has arrived (or it stays quiet)."""
    data = b""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        chunk = sim.read(quiet)
        data += chunk
        if until and data.endswith(until):
            break
        if not chunk and not until:
            break
    return data


def binary(sim, op, type_=0, motor=0, value=0, address=1) -> Reply:
    sim.write(Request(address, op, type_, motor, value).to_bytes())
    data = b""
    deadline = time.monotonic() + 1
    while len(data) < 9 and time.monotonic() < deadline:
        data += sim.read(deadline - time.monotonic())
    return Reply.from_bytes(data)


def enter(sim, address=1) -> None:
    reply = binary(sim, 139, address=address)
    assert reply.ok and sim.ascii_active


@pytest.fixture
def sim():
    s = Simulator("TMCM-1311")
    yield s
    s.close()


def test_enter_with_139_reply_first_then_echo_each_character(sim):
    enter(sim)
    sim.write(b"AGAP 4, 0\r")
    out = collect(sim, until=b"BA 100 51200\r")
    assert out == b"AGAP 4, 0\r" + b"BA 100 51200\r"


def test_manual_examples_accepted(sim):
    enter(sim)
    sim.write(b"A MVP ABS, 0, 50000\r")  # the reply value echoes the request's value
    assert collect(sim, until=b"0\r").endswith(b"\rBA 100 50000\r")
    sim.write(b"AROL 0, 500\r")
    assert collect(sim, until=b"0\r").endswith(b"BA 100 500\r")
    sim.write(b"A MST 0\r")
    assert collect(sim, until=b"0\r").endswith(b"BA 100 0\r")


def test_negative_values_and_parameter_names(sim):
    enter(sim)
    sim.write(b"ASAP ActualPosition, 0, -5000\r")
    collect(sim, until=b"BA 100 0\r")
    sim.write(b"AGAP 1, 0\r")
    assert collect(sim, until=b"\r", timeout=0.3).endswith(b"BA 100 -5000\r")


def test_backspace_erases_with_echo(sim):
    enter(sim)
    sim.write(b"AGAX\x08P 4, 0\r")
    out = collect(sim, until=b"BA 100 51200\r")
    assert out == b"AGAX\b \bP 4, 0\r" + b"BA 100 51200\r"
    sim.write(b"AGAP 5\x7f4, 0\r")
    assert collect(sim, until=b"51200\r") == b"AGAP 5\b \b4, 0\rBA 100 51200\r"


def test_echo_whole_line_after_cr(sim):
    assert binary(sim, 9, 67, 0, 16).ok
    enter(sim)
    sim.write(b"AGAP 4")
    assert collect(sim) == b""
    sim.write(b", 0\r")
    assert collect(sim, until=b"51200\r") == b"AGAP 4, 0\rBA 100 51200\r"
    sim.write(b"AGAPX\x08 4, 0\r")
    assert collect(sim, until=b"51200\r") == b"AGAP 4, 0\rBA 100 51200\r"


def test_no_echo(sim):
    assert binary(sim, 9, 67, 0, 32).ok
    enter(sim)
    sim.write(b"AGAP 4, 0\r")
    assert collect(sim, until=b"51200\r") == b"BA 100 51200\r"


def test_crlf_and_lf_line_ends(sim):
    assert binary(sim, 9, 67, 0, 32).ok
    enter(sim)
    sim.write(b"AGAP 4, 0\r\nAGAP 5, 0\n")
    assert collect(sim, until=b"BA 100 51200\rBA 100 51200\r") == \
        b"BA 100 51200\rBA 100 51200\r"


def test_bin_replies_first_then_binary(sim):
    enter(sim)
    sim.write(b"ABIN\r")
    assert collect(sim, until=b"BA 100 0\r") == b"ABIN\rBA 100 0\r"
    assert not sim.ascii_active
    assert binary(sim, 6, 4).value == 51200


def test_bin_and_binary_frame_in_one_write(sim):
    assert binary(sim, 9, 67, 0, 32).ok
    enter(sim)
    sim.write(b"ABIN\r" + Request(1, 6, 4).to_bytes())
    out = collect(sim, until=Reply(2, 1, 100, 6, 51200).to_bytes())
    assert out == b"BA 100 0\r" + Reply(2, 1, 100, 6, 51200).to_bytes()


def test_139_and_ascii_in_one_write(sim):
    assert binary(sim, 9, 67, 0, 32).ok
    sim.write(Request(1, 139).to_bytes() + b"AGAP 4, 0\r")
    out = collect(sim, until=b"51200\r")
    assert out == Reply(2, 1, 100, 139, 0).to_bytes() + b"BA 100 51200\r"


def test_start_up_in_ascii_mode():
    with Simulator("TMCM-1311", ascii_startup=True) as s:
        assert s.ascii_active
        s.write(b"AGGP 67, 0\r")
        assert collect(s, until=b"\r", timeout=0.5).endswith(b"BA 100 1\r")


def test_start_up_mode_persists_in_gp67(sim):
    assert binary(sim, 9, 67, 0, 33).ok  # start in ASCII, no echo (stored by SGP itself)
    assert binary(sim, 11, 67, 0).ok
    sim.reset()
    assert sim.ascii_active
    sim.write(b"AGAP 4, 0\r")
    assert collect(sim, until=b"51200\r") == b"BA 100 51200\r"


def test_run_and_stop_program(sim):
    assert binary(sim, 132).ok
    for req in (Request(1, 22, 0, 0, 0),):  # Loop: JA Loop
        assert binary(sim, req.opcode, req.type, req.motor, req.value).status == Status.LOADED
    assert binary(sim, 133).ok
    assert binary(sim, 9, 67, 0, 32).ok
    enter(sim)
    sim.write(b"ARUN\r")
    assert collect(sim, until=b"\r") == b"BA 100 0\r"
    assert sim.program_state == 1
    sim.write(b"ASTOP\r")
    assert collect(sim, until=b"\r") == b"BA 100 0\r"
    assert sim.program_state == 0


def test_address_3_and_other_addresses_ignored():
    with Simulator("TMCM-1311", address=3) as s:
        enter(s, address=3)
        s.write(b"AGAP 4, 0\r")
        assert collect(s) == b""  # not for us: no echo, no reply
        s.write(b"  CGAP 4, 0\r")
        assert collect(s, until=b"51200\r") == b"CGAP 4, 0\rBC 100 51200\r"


def test_host_address_other_than_2():
    with Simulator("TMCM-351", host_address=5) as s:
        enter(s)
        s.write(b"AGAP 4, 2\r")
        assert collect(s, until=b"\r", timeout=0.5).endswith(b"EA 100 1000\r")


def test_typed_wrong_address_then_backspace(sim):
    enter(sim)
    sim.write(b"B\x08AGAP 4, 0\r")
    assert collect(sim, until=b"51200\r") == b"AGAP 4, 0\rBA 100 51200\r"


@pytest.mark.parametrize("text, expected, value", [
    ("AFOO 1, 2\r", Status.INVALID_COMMAND, 0),
    ("A 136 0\r", Status.INVALID_COMMAND, 0),  # raw numbers are binary-mode only
    ("A\r", Status.INVALID_COMMAND, 0),
    ("AGAP 4 0 0\r", Status.INVALID_COMMAND, 0),  # not a command line
    ("ACALC ADD, 1\r", Status.COMMAND_NOT_AVAILABLE, 1),  # program-only
    ("AWAIT TICKS, 0, 5\r", Status.COMMAND_NOT_AVAILABLE, 5),
    ("ASAC 0, 0, 0\r", Status.COMMAND_NOT_AVAILABLE, 0),  # another module's command
    ("AMVP XYZ, 0, 1\r", Status.WRONG_TYPE, 1),  # a refused command echoes its value
    ("AGAP 99, 0\r", Status.WRONG_TYPE, 0),
    ("ASAP 8, 0, 1\r", Status.WRONG_TYPE, 1),  # read-only
    ("AGAP\r", Status.WRONG_TYPE, 0),
    ("AROR 3, 100\r", Status.INVALID_VALUE, 100),  # no motor 3
    ("ASAP 4, 0, -5\r", Status.INVALID_VALUE, -5),
    ("AMVP ABS, 0\r", Status.INVALID_VALUE, 0),  # value missing
    ("ASIO 0, 2, 7\r", Status.INVALID_VALUE, 7),
])
def test_ascii_status_codes(sim, text, expected, value):
    assert binary(sim, 9, 67, 0, 32).ok
    enter(sim)
    sim.write(text.encode())
    assert collect(sim, until=b"\r", timeout=0.5) == f"BA {int(expected)} {value}\r".encode()


def test_1640_has_no_ascii_mode():
    with Simulator("TMCM-1640") as s:
        assert binary(s, 139).status == Status.INVALID_COMMAND
        assert not s.ascii_active
    with pytest.raises(ValueError):
        Simulator("TMCM-1640", ascii_startup=True)


def test_ascii_faults(sim):
    assert binary(sim, 9, 67, 0, 32).ok
    enter(sim)
    sim.faults.truncate_next = 1
    sim.write(b"AGAP 4, 0\r")
    assert collect(sim) == b"BA 100"
    sim.write(b"AGAP 4, 0\r")
    assert collect(sim, until=b"\r") == b"BA 100 51200\r"
