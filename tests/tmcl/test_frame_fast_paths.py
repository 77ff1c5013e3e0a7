"""The hot paths that build frames and requests without the dataclasses' checks (the
simulator's receive and reply, issue 33's replay rate) give what the checked constructors
give, for every field value a frame can carry."""

from __future__ import annotations

import struct

from hypothesis import given
from hypothesis import strategies as st

from tmclsh.tmcl.frames import Instruction, Reply, Request, reply_frame

BYTE = st.integers(0, 255)
INT32 = st.integers(-2**31, 2**31 - 1)


@given(BYTE, BYTE, BYTE, BYTE, st.integers(-2**31, 2**32 - 1))
def test_reply_frame_is_the_reply_s_bytes(host, module, status, opcode, value):
    assert reply_frame(host, module, status, opcode, value) == Reply(
        host, module, status, opcode, value).to_bytes()


@given(BYTE, BYTE, BYTE, BYTE, INT32)
def test_a_request_read_from_its_bytes_is_the_request(address, opcode, type_, motor, value):
    req = Request(address, opcode, type_, motor, value)
    raw = req.to_bytes()
    for data in (raw, bytearray(raw)):
        got = Request.from_bytes(data)
        assert got == req and got.value == req.value
        assert got.to_bytes() == raw
        assert got.instruction == Instruction(opcode, type_, motor, value)
        assert got.instruction.to_bytes() == raw[1:8]


def test_a_bad_sum_is_still_refused():
    import pytest

    from tmclsh.base.errors import ChecksumError

    body = struct.pack(">BBBBi", 1, 6, 4, 0, 0)
    with pytest.raises(ChecksumError):
        Request.from_bytes(body + bytes([(sum(body) + 1) & 0xFF]))
