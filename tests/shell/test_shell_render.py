"""Replies for people (words, units, bits) and for programs (JSON), and the trace format.

Pure: results are built by hand, nothing is sent.
"""

from __future__ import annotations

import pytest

from tmclsh.tmcl import asm
from tmclsh.client.text import Result
from tmclsh.tmcl.modules import load
from tmclsh.tmcl.frames import Reply, Request
from tmclsh.tmcl.modules import type1_of as binary_version
from tmclsh.shell.render import (render_event, render_result, result_json,
                                 value_text, version_text)
from tmclsh.shell.render import describe_instruction
from tmclsh.shell.features.trace import decode_hex, format_frame

M = load("TMCM-1311")
M1640 = load("TMCM-1640")


def result(line: str, status: int = 100, value: int = 0, module=M, **kw) -> Result:
    enc = asm.encode(asm.parse_line(line), module, direct=True)
    ins = enc.instruction
    return Result(line, enc, Reply(2, 1, status, ins.opcode, value, **kw))


def text(line: str, status: int = 100, value: int = 0, module=M) -> str:
    return render_result(result(line, status, value, module), module).plain


def test_json_object_in_design_order():
    obj = result_json(result("GAP 1, 0", value=-5000))
    assert obj == {"line": "GAP 1, 0", "op": 6, "type": 1, "motor": 0, "value": 0,
                   "status": 100, "reply": -5000}
    assert list(obj) == ["line", "op", "type", "motor", "value", "status", "reply"]


def test_json_error_status_adds_error():
    obj = result_json(result("SAP 4, 0, 1000", status=4))
    assert obj["status"] == 4 and obj["error"] == "invalid value"


def test_reads_show_name_value_and_unit():
    assert text("GAP 4, 0", value=1000) == "MaxPositioningSpeed = 1000 pps"
    assert text("GAP MicrostepResolution, 0", value=8) == \
        "MicrostepResolution = 8 (256 microsteps)"
    assert text("GGP 66, 0", value=1) == "SerialAddress = 1"


def test_writes_say_what_was_done():
    assert text("SAP 4, 0, 1000") == "ok: MaxPositioningSpeed set to 1000 pps"
    assert text("MVP ABS, 0, 90000") == "ok: motor 0 moving to 90000 µsteps"
    assert text("MVP REL, 0, -10") == "ok: motor 0 moving by -10 µsteps"
    assert text("ROR 0, 500") == "ok: motor 0 rotating right at 500 pps"
    # MST only sets the target speed to 0 (manual 5.7.3): the motor ramps down from there
    assert text("MST 0") == "ok: motor 0 stopping (target speed 0; it ramps down)"
    # ROL with a negative speed turns right; speed 0 stops
    assert text("ROL 0, -1000") == "ok: motor 0 rotating right at 1000 pps (ROL with a " \
                                   "negative speed)"
    assert text("ROR 0, -7") == "ok: motor 0 rotating left at 7 pps (ROR with a negative speed)"
    assert text("ROL 0, 5") == "ok: motor 0 rotating left at 5 pps"
    assert text("ROR 0, 0") == "ok: motor 0 stopping (speed 0; it ramps down)"
    assert text("SIO 3, 2, 1") == "ok: OUT_3 set to 1"


def test_error_status_in_words():
    assert text("SAP 4, 0, 1000", status=5).startswith("error 5: configuration EEPROM locked")
    assert "GP 73" in text("SAP 4, 0, 1000", status=5)
    assert text("GAP 4, 0", status=3).startswith("error 3: wrong type")


def test_bit_fields_are_decoded():
    out = text("GAP StatusWord, 0", value=0b1001)
    first, *bits = out.splitlines()
    assert first == "StatusWord = 9  (bits 0, 3 set)"
    assert bits == ["  bit  0  target reached", "  bit  3  position mode"]
    assert text("GAP StatusWord, 0", value=0) == "StatusWord = 0  (no bits set)"
    assert "bit  0  start up in ASCII mode" in text("GGP ASCIIMode, 0", value=17)


def test_all_inputs_at_once():
    assert text("GIO 255, 0", value=0b101) == (
        "inputs = 5  (0b00000101)  AIN_0=1 IN_1=0 IN_2=1 IN_3=0 AIN_4=0 IN_5=0 IN_6=0 IN_7=0")


def test_scaled_units_and_port_names():
    assert text("GIO 8, 1", value=240) == "SupplyVoltage = 24.0 V  (240 × 1/10 V)"
    assert text("GIO 1, 0", value=1) == "IN_1 = 1"


def test_unsigned_parameters():
    p = M.axis(25)  # 0..4294967295 ms
    assert value_text(-1, p) == "4294967295 ms"


def test_version_string_and_binary_layouts():
    r = result("136 0, 0, 0")
    r = Result(r.line, r.encoded, Reply(2, 1, 100, 136, 0, version="1311V111"))
    assert render_result(r, M).plain == "firmware 1311V111"
    assert version_text(0x051F6F00, M) == (
        "05 1F 6F 00: module type 1311 (05 1F), version 111 (6F 00, low byte first)")
    # the TMCM-1640 manual: version low, version high, type low, type high
    v = int.from_bytes(bytes((210, 0, 1640 & 0xFF, 1640 >> 8)), "big")
    assert binary_version(v, M1640) == (1640, 210)


def test_event_line():
    assert render_event(Reply(2, 1, 128, 138, 0b101)) == \
        "event: target position reached (motor 0, 2)"


# -- trace -------------------------------------------------------------------------------

def test_trace_lines():
    req = Request(1, 6, 4, 0, 0)
    tx = format_frame("tx", req.to_bytes(), req, M, now=0).plain
    assert tx.endswith(" tx> 01 06 04 00 00 00 00 00 0b  GAP 4, 0  // MaxPositioningSpeed  @1")
    rep = Reply(2, 1, 100, 6, 1000)
    rx = format_frame("rx", rep.to_bytes(), rep, M, req, now=0).plain
    assert rx.endswith("<rx 02 01 64 06 00 00 03 e8 58  100 ok, GAP value 1000 "
                       "(MaxPositioningSpeed = 1000 pps)")
    assert format_frame("note", b"", "resynchronising", M, now=0).plain.endswith(
        "--  resynchronising")


def test_control_commands_are_named():
    from tmclsh.tmcl.frames import Instruction

    assert describe_instruction(Instruction(136, 1), M) == "136 firmware version (type 1)"
    assert describe_instruction(Instruction(138, 0, 0, 0), M) == \
        "138 target position reached event"


@pytest.mark.parametrize("hextext, kind, fragment", [
    ("01 06 04 00 00 00 00 00 0b", "request", "GAP 4, 0"),
    ("0x02,0x01,0x64,0x06,0x00,0x00,0x03,0xe8,0x58", "reply", "100 ok, GAP value 1000"),
    ("reply 02 01 04 06 00 00 00 00 0d", "reply", "4 invalid value"),
    ("02 31 33 31 31 56 31 31 31", "136 reply (version string)", "'1311V111'"),
    ("31 33 31 31 56 31 31 31", "136 reply on CAN", "'1311V111'"),
    ("reply 01 64 06 00 00 03 e8", "CAN reply data", "100 ok, GAP value 1000"),
    ("04 00 00 00 01 5f 90", "instruction", "MVP ABS, 0, 90000"),
])
def test_decode_readings(hextext, kind, fragment):
    ((_, readings),) = decode_hex(hextext, M)
    assert any(r.kind.startswith(kind) and fragment in r.text for r in readings), readings


def test_decode_several_frames_and_checksums():
    frames = decode_hex("01 06 04 00 00 00 00 00 0b 02 01 64 06 00 00 03 e8 59", M)
    assert len(frames) == 2
    assert frames[0][1][0].checksum.startswith("ok")
    reply = next(r for r in frames[1][1] if r.kind == "reply")
    assert reply.checksum == "WRONG: 0x59, should be 0x58"


def test_a_time_of_day_worded_once_a_second_reads_as_worded_each_time():
    """``timestamp`` keeps the last second's clock (a log has thousands of frames a second):
    every time, in order or not, across second boundaries, reads as worded afresh."""
    import time

    from tmclsh.shell.features.trace import timestamp

    times = [1_700_000_000 + k / 7 for k in range(40)] + [1_700_000_000.9999, 1_700_000_001.0,
                                                         1_600_000_000.5, 1_700_000_000.25]
    for t in times:
        assert timestamp(t) == (time.strftime("%H:%M:%S", time.localtime(t))
                                + f".{int(t * 1000) % 1000:03d}")
