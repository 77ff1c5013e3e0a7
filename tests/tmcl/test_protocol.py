"""Frames on the wire: serial and CAN framing, checksums, status codes, special replies."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tmclsh.base.errors import ChecksumError, FrameError
from tmclsh.tmcl.decoder import FRAME_PIECE, WHOLE, FrameDecoder, is_version_string
from tmclsh.tmcl.frames import (INSTRUCTION_LEN, INT32_MAX, INT32_MIN, SERIAL_FRAME_LEN,
                             STATUS_TEXT, UINT32_MAX, Control, Instruction, Reply, ReplyKind,
                             Request, Status, checksum, parse_hex, reply_kind,
                             status_ok, status_text, to_signed32)

byte = st.integers(0, 255)
int32 = st.integers(INT32_MIN, INT32_MAX)
statuses = st.sampled_from(list(Status))
requests = st.builds(Request, byte, byte, byte, byte, int32)
replies = st.builds(Reply, byte, byte, statuses, byte, int32)
instructions = st.builds(Instruction, byte, byte, byte, int32)


# -- checksum ---------------------------------------------------------------------------------

def test_checksum_is_the_8_bit_sum() -> None:
    # TMCM-351 §5.7.2 ROL 1, 1200: $01 $02 $00 $01 $00 $00 $04 $b0 -> $b8
    assert checksum(bytes.fromhex("01 02 00 01 00 00 04 b0")) == 0xB8
    assert checksum(b"") == 0
    assert checksum(bytes([0xFF, 0x01])) == 0x00  # wraps at 8 bits


@given(st.binary(max_size=64))
def test_checksum_matches_definition(data: bytes) -> None:
    assert checksum(data) == sum(data) % 256


def test_request_frame_layout() -> None:
    # TMCM-1311 §5.7.4: MVP ABS, 0, 90000 to module 1
    frame = Request(1, 4, 0, 0, 90000).to_bytes()
    assert frame == bytes([0x01, 0x04, 0x00, 0x00, 0x00, 0x01, 0x5F, 0x90, 0xF5])
    assert len(frame) == SERIAL_FRAME_LEN


# -- Request ----------------------------------------------------------------------------------

@given(requests)
def test_request_round_trip(req: Request) -> None:
    frame = req.to_bytes()
    assert len(frame) == SERIAL_FRAME_LEN and frame[-1] == checksum(frame[:-1])
    assert Request.from_bytes(frame) == req
    assert Request.from_can(req.address, req.to_can()) == req


@given(requests, st.integers(0, SERIAL_FRAME_LEN - 1), st.integers(1, 255))
def test_request_with_a_corrupted_byte_is_refused(req: Request, pos: int, delta: int) -> None:
    frame = bytearray(req.to_bytes())
    frame[pos] = (frame[pos] + delta) % 256
    with pytest.raises(ChecksumError):
        Request.from_bytes(bytes(frame))


def test_unsigned_and_signed_values_are_one_value() -> None:
    assert Request(1, 4, 1, 0, 0xFFFFFC18) == Request(1, 4, 1, 0, -1000)
    assert Request(1, 4, 1, 0, 0xFFFFFC18).value == -1000
    assert Instruction(4, 1, 0, UINT32_MAX).value == -1
    assert Reply(2, 1, 100, 6, UINT32_MAX).value == -1


@pytest.mark.parametrize("kwargs, field", [
    ({"address": 256}, "address"), ({"opcode": -1}, "opcode"), ({"type": 300}, "type"),
    ({"motor": 256}, "motor/bank"), ({"value": UINT32_MAX + 1}, "value"),
    ({"value": INT32_MIN - 1}, "value"), ({"value": 1.5}, "value"),
])
def test_request_validates_its_fields(kwargs: dict, field: str) -> None:
    args = {"address": 1, "opcode": 6, "type": 1, "motor": 0, "value": 0, **kwargs}
    with pytest.raises(ValueError, match=field):
        Request(**args)


def test_frames_of_the_wrong_length_are_refused() -> None:
    with pytest.raises(FrameError, match="9 bytes"):
        Request.from_bytes(bytes(8))
    with pytest.raises(FrameError, match="7 bytes"):
        Instruction.from_bytes(bytes(9))
    with pytest.raises(FrameError):
        Reply.from_bytes(bytes(10))
    with pytest.raises(FrameError):
        Reply.from_can(2, bytes(8))


# -- Reply ------------------------------------------------------------------------------------

@given(replies)
def test_reply_round_trip(reply: Reply) -> None:
    frame = reply.to_bytes()
    assert frame[-1] == checksum(frame[:-1])
    assert Reply.from_bytes(frame) == reply
    assert Reply.from_can(reply.host, reply.to_can()) == reply
    assert len(reply.to_can()) == INSTRUCTION_LEN


def test_reply_with_bad_checksum() -> None:
    frame = bytearray(Reply(2, 1, 100, 6, 711).to_bytes())
    frame[8] ^= 1
    with pytest.raises(ChecksumError, match="checksum"):
        Reply.from_bytes(bytes(frame))


def test_reply_validates_its_fields() -> None:
    with pytest.raises(ValueError, match="status"):
        Reply(2, 1, 256, 6, 0)
    with pytest.raises(ValueError, match="value"):
        Reply(2, 1, 100, 6, 2**32)
    with pytest.raises(ValueError, match="8 characters"):
        Reply(2, 1, 100, 136, version="1311V1")


# -- status codes -----------------------------------------------------------------------------

def test_status_texts() -> None:
    # the manuals' status table (§4.2.1 / §5.2.1) plus the 138 event status
    assert {int(s) for s in Status} == {1, 2, 3, 4, 5, 6, 100, 101, 128}
    assert set(STATUS_TEXT) == set(Status)
    assert status_text(1) == "wrong checksum"
    assert status_text(5) == "configuration EEPROM locked"
    assert status_text(100) == "ok"
    assert status_text(101) == "loaded into program memory"
    assert status_text(7) == "unknown status 7"
    assert [s for s in range(256) if status_ok(s)] == [100, 101, 128]
    assert not Reply(2, 1, 4, 5, 0).ok and Reply(2, 1, 4, 5, 0).status_text == "invalid value"
    assert Reply(2, 1, 128, 138, 1).is_event


# -- special replies --------------------------------------------------------------------------

def test_reply_kind_of_each_request() -> None:
    assert reply_kind(136, 0) == ReplyKind.VERSION_STRING
    assert reply_kind(136, 1) == ReplyKind.NORMAL
    assert reply_kind(134, 0) == ReplyKind.MEMORY
    assert reply_kind(137, 0) == ReplyKind.NONE
    assert Request(1, 6, 1, 0).reply_kind == ReplyKind.NORMAL


@pytest.mark.parametrize("text", ["1311V107", "1640V200"])  # the manuals' examples
def test_version_string_reply(text: str) -> None:
    frame = bytes([2]) + text.encode()  # host address + 8 characters, no checksum
    reply = Reply.from_bytes(frame, ReplyKind.VERSION_STRING, module=1)
    assert (reply.host, reply.module, reply.version) == (2, 1, text)
    assert reply.opcode == Control.GET_VERSION and reply.ok
    assert reply.to_bytes() == frame
    dec = FrameDecoder(2)
    dec.feed(frame)
    assert dec.next(whole=lambda w: is_version_string(w, 2)) == (WHOLE, frame)
    can = Reply.from_can(2, text.encode(), ReplyKind.VERSION_STRING, module=1)
    assert can == reply and can.to_can() == text.encode()


def test_version_string_reply_refuses_binary_bytes() -> None:
    with pytest.raises(FrameError, match="non-printable"):
        Reply.from_bytes(bytes([2, 0x31, 0x33, 0, 0, 0, 0, 0, 0]), ReplyKind.VERSION_STRING)


@given(byte, instructions)
def test_memory_reply_legacy_layout(host: int, stored: Instruction) -> None:
    # 134: the reply's module/status/opcode bytes carry the stored opcode/type/motor
    reply = Reply(host, 1, Status.OK, Control.READ_MEMORY, stored.value, stored=stored)
    frame = reply.to_bytes()
    assert frame[1:8] == stored.to_bytes() and frame[8] == checksum(frame[:8])
    back = Reply.from_bytes(frame, ReplyKind.MEMORY, module=1)
    assert back.stored == stored and back.host == host and back.module == 1
    dec = FrameDecoder(host)
    dec.feed(frame)
    assert dec.next(memory=True) == (FRAME_PIECE, frame)  # whatever its "status" byte
    can = Reply.from_can(host, reply.to_can(), ReplyKind.MEMORY, module=1)
    assert can.stored == stored


def test_target_reached_event_replies() -> None:
    # TMCM-1311 §5.7.37: 100 right away, then 128 with the motor bit mask when reached
    first = Reply.from_bytes(Reply(2, 1, 100, 138, 1).to_bytes())
    event = Reply.from_bytes(Reply(2, 1, 128, 138, 1).to_bytes())
    assert first.ok and not first.is_event
    assert event.ok and event.is_event and event.value == 1
    assert event.status_text == "target position reached (event)"


# -- CAN framing ------------------------------------------------------------------------------

def test_can_framing_drops_address_and_checksum() -> None:
    req = Request(1, 6, 1, 2, 0)
    assert req.to_can() == req.to_bytes()[1:8]
    reply = Reply(2, 1, 100, 6, 711)
    assert reply.to_can() == reply.to_bytes()[1:8]
    assert Reply.from_can(2, reply.to_can()) == reply


# -- helpers ----------------------------------------------------------------------------------

@pytest.mark.parametrize("text", ["01 06 01 02", "$01 $06 $01 $02", "0x01,0x06,0x01,0x02",
                                  "01060102"])
def test_parse_hex(text: str) -> None:
    assert parse_hex(text) == bytes([1, 6, 1, 2])


def test_parse_hex_refuses_text() -> None:
    with pytest.raises(FrameError):
        parse_hex("GAP 1, 0")


@given(st.integers(INT32_MIN, UINT32_MAX))
def test_to_signed32(value: int) -> None:
    assert INT32_MIN <= to_signed32(value) <= INT32_MAX
    assert struct.pack(">i", to_signed32(value)) == struct.pack(">I", value & UINT32_MAX)
