"""The simulator at the byte level: frames in, bytes out (framing, statuses, parameters,
special replies, faults, CAN, several modules on one line)."""

from __future__ import annotations

import struct
import time
import weakref

import pytest

from tmclsh.tmcl.frames import Control, Reply, ReplyKind, Request, Status, checksum
from tmclsh.sim import Faults, SimBus, Simulator

MODULES = ("TMCM-1311", "TMCM-351", "TMCM-1640")


_pending: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def read_exact(sim, n: int, timeout: float = 1.0) -> bytes:
    """Exactly ``n`` bytes (fewer on timeout); extra bytes wait for the next call."""
    deadline = time.monotonic() + timeout
    data = _pending.pop(sim, b"")
    while len(data) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        data += sim.read(left)
    if len(data) > n:
        _pending[sim] = data[n:]
    return data[:n]


def tx(sim, op, type_=0, motor=0, value=0, address=1, kind=ReplyKind.NORMAL) -> Reply:
    sim.write(Request(address, op, type_, motor, value).to_bytes())
    data = read_exact(sim, 9)
    assert len(data) == 9, f"no complete reply to op {op}: {data!r}"
    return Reply.from_bytes(data, kind, module=address, opcode=op)


def status(sim, *args, **kw) -> int:
    return tx(sim, *args, **kw).status


@pytest.fixture
def sim():
    s = Simulator("TMCM-1311")
    yield s
    s.close()


@pytest.fixture(params=MODULES)
def any_sim(request):
    s = Simulator(request.param)
    yield s
    s.close()


# -- framing and addressing -----------------------------------------------------------------------

def test_gap_reply_bytes(sim):
    sim.write(bytes.fromhex("01 06 04 00 00 00 00 00 0b"))
    data = read_exact(sim, 9)
    assert data == Reply(2, 1, 100, 6, 51200).to_bytes()
    assert data[:4] == bytes((2, 1, 100, 6)) and data[8] == checksum(data[:8])


def test_wrong_checksum_answers_status_1(sim):
    frame = bytearray(Request(1, 6, 1).to_bytes())
    frame[8] ^= 0xFF
    sim.write(bytes(frame))
    reply = Reply.from_bytes(read_exact(sim, 9))
    assert (reply.status, reply.opcode) == (Status.WRONG_CHECKSUM, 6)


def test_frames_for_other_addresses_are_ignored(sim):
    sim.write(Request(2, 6, 1).to_bytes())
    assert sim.read(0.05) == b""
    assert tx(sim, 6, 1).ok


def test_leading_garbage_byte_resynchronises(sim):
    sim.write(b"\x55" + Request(1, 6, 4).to_bytes())
    reply = Reply.from_bytes(read_exact(sim, 9))
    assert (reply.status, reply.value) == (100, 51200)


def test_garbage_equal_to_address_recovers_within_bounded_frames(sim):
    req = Request(1, 6, 4).to_bytes()
    sim.write(b"\x01")
    for _ in range(3):
        sim.write(req)
    replies = read_exact(sim, 27, timeout=0.5)
    frames = [Reply.from_bytes(replies[i:i + 9]) for i in range(0, len(replies) - 8, 9)]
    assert frames and frames[-1].status == 100 and frames[-1].value == 51200
    assert len(frames) <= 3


def test_partial_frame_discarded_after_gap(sim):
    sim.write(Request(1, 6, 4).to_bytes()[:4])
    time.sleep(sim.FRAME_GAP + 0.03)
    assert tx(sim, 6, 4).value == 51200
    assert sim.read(0.05) == b""


def test_split_frame_without_gap_is_joined(sim):
    req = Request(1, 6, 4).to_bytes()
    sim.write(req[:3])
    sim.write(req[3:])
    assert Reply.from_bytes(read_exact(sim, 9)).value == 51200


def test_address_and_host_address_parameters(sim):
    assert tx(sim, 9, 66, 0, 5).ok
    assert tx(sim, 6, 4, address=5).module == 5
    sim.write(Request(1, 6, 4).to_bytes())
    assert sim.read(0.05) == b""
    assert tx(sim, 9, 76, 0, 7, address=5).ok
    assert tx(sim, 6, 4, address=5).host == 7


def test_constructor_addresses():
    with Simulator("TMCM-351", 3, host_address=9) as s:
        reply = tx(s, 6, 4, address=3)
        assert (reply.host, reply.module) == (9, 3)
        assert s.param("global", 66) == 3


def test_telegram_pause_delays_reply(sim):
    assert tx(sim, 9, 75, 0, 60).ok
    start = time.monotonic()
    sim.write(Request(1, 6, 4).to_bytes())
    assert sim.read(0.0) == b""
    assert len(read_exact(sim, 9)) == 9
    assert time.monotonic() - start >= 0.055


# -- status codes -----------------------------------------------------------------------------------

@pytest.mark.parametrize("module, frame, expected", [
    ("TMCM-1311", (17, 0, 0, 0), Status.INVALID_COMMAND),  # no such opcode
    ("TMCM-1311", (6, 99, 0, 0), Status.WRONG_TYPE),  # no AP 99
    ("TMCM-1311", (6, 4, 1, 0), Status.INVALID_VALUE),  # motor 1 on a one-axis module
    ("TMCM-1311", (5, 5, 0, 0), Status.INVALID_VALUE),  # AP 5 minimum is 1
    ("TMCM-1311", (5, 140, 0, 9), Status.INVALID_VALUE),  # microsteps 0..8
    ("TMCM-1311", (5, 8, 0, 1), Status.WRONG_TYPE),  # target reached is read-only
    ("TMCM-1311", (6, 29, 0, 0), Status.WRONG_TYPE),  # AP 29 is write-only
    ("TMCM-1311", (7, 0, 0, 0), Status.WRONG_TYPE),  # STAP on a parameter without E
    ("TMCM-1311", (9, 66, 1, 3), Status.INVALID_VALUE),  # no bank 1
    ("TMCM-1311", (9, 128, 0, 1), Status.WRONG_TYPE),  # GP 128 is read-only
    ("TMCM-1311", (4, 3, 0, 0), Status.WRONG_TYPE),  # MVP type 3
    ("TMCM-1311", (1, 0, 0, 268435455), Status.INVALID_VALUE),  # ROR beyond the range
    ("TMCM-1311", (29, 0, 0, 0), Status.COMMAND_NOT_AVAILABLE),  # SAC is TMCM-351 only
    ("TMCM-1311", (19, 0, 0, 1), Status.COMMAND_NOT_AVAILABLE),  # CALC only in programs
    ("TMCM-1311", (22, 0, 0, 0), Status.COMMAND_NOT_AVAILABLE),  # JA only in programs
    ("TMCM-1311", (137, 0, 0, 1), Status.INVALID_VALUE),  # factory reset needs 1234
    ("TMCM-1311", (136, 2, 0, 0), Status.WRONG_TYPE),
    ("TMCM-1311", (14, 0, 0, 1), Status.WRONG_TYPE),  # SIO on an input port
    ("TMCM-1311", (15, 5, 1, 0), Status.WRONG_TYPE),  # no analog port 5
    ("TMCM-1311", (30, 21, 0, 0), Status.WRONG_TYPE),  # coordinates 0..20
    ("TMCM-1640", (13, 0, 0, 0), Status.COMMAND_NOT_AVAILABLE),  # no RFS on the 1640
    ("TMCM-1640", (139, 0, 0, 0), Status.INVALID_COMMAND),  # no ASCII interface
    ("TMCM-1640", (138, 0, 0, 0), Status.INVALID_COMMAND),
    ("TMCM-351", (25, 0, 0, 0), Status.COMMAND_NOT_AVAILABLE),  # EI is TMCM-1311 only
    ("TMCM-351", (138, 0, 0, 0), Status.INVALID_COMMAND),  # "reserved"
    ("TMCM-351", (1, 0, 3, 100), Status.INVALID_VALUE),  # motors 0..2
    ("TMCM-351", (1, 0, 0, -1), Status.INVALID_VALUE),  # ROR 0..2047
])
def test_status_codes(module, frame, expected):
    with Simulator(module) as s:
        assert status(s, *frame) == expected


def test_every_status_code_appears_on_the_wire(sim):
    seen = {status(sim, 17), status(sim, 6, 99), status(sim, 5, 5, 0, 0), status(sim, 19)}
    assert tx(sim, 9, 73, 0, 1234).ok
    seen.add(status(sim, 7, 4))
    bad = bytearray(Request(1, 6, 1).to_bytes())
    bad[8] ^= 1
    sim.write(bytes(bad))
    seen.add(Reply.from_bytes(read_exact(sim, 9)).status)
    assert tx(sim, 132, 0, 0, 0).ok
    seen.add(status(sim, 6, 1))  # stored in download mode: 101
    assert seen == {1, 2, 3, 4, 5, 6, 101}


# -- parameters -------------------------------------------------------------------------------------

def test_store_restore_axis_parameter(sim):
    assert tx(sim, 5, 4, 0, 1000).ok
    assert tx(sim, 7, 4).ok
    assert tx(sim, 5, 4, 0, 2000).ok
    assert tx(sim, 6, 4).value == 2000
    assert tx(sim, 8, 4).ok
    assert tx(sim, 6, 4).value == 1000
    assert tx(sim, 5, 4, 0, 3000).ok
    sim.reset()
    assert tx(sim, 6, 4).value == 1000
    assert sim.stored_param("axis", 4) == 1000


def test_volatile_parameter_returns_to_default_on_reset(sim):
    assert tx(sim, 5, 17, 0, 500).ok
    sim.reset()
    assert tx(sim, 6, 17).value == 0
    assert tx(sim, 6, 140).value == 8  # data-file default


def test_user_variables_bank_2(sim):
    assert tx(sim, 9, 0, 2, 42).ok
    assert tx(sim, 11, 0, 2).ok
    assert tx(sim, 9, 0, 2, 7).ok
    assert tx(sim, 9, 60, 2, 99).ok
    assert status(sim, 11, 60, 2) == Status.WRONG_TYPE  # #56..#255 are RAM only
    assert tx(sim, 10, 0, 2).value == 7
    assert tx(sim, 12, 0, 2).ok
    assert tx(sim, 10, 0, 2).value == 42
    assert tx(sim, 9, 0, 2, -5).ok
    sim.reset()
    assert tx(sim, 10, 0, 2).value == 42
    assert tx(sim, 10, 60, 2).value == 0


def test_do_not_restore_user_variables(sim):
    assert tx(sim, 9, 3, 2, 11).ok and tx(sim, 11, 3, 2).ok
    assert tx(sim, 9, 85, 0, 1).ok  # bank 0 below 128: stored by SGP itself
    sim.reset()
    assert tx(sim, 10, 3, 2).value == 0


def test_unsigned_parameter_as_twos_complement(sim):
    big = 3_000_000_000
    assert tx(sim, 5, 25, 0, big - 2**32).ok
    reply = tx(sim, 6, 25)
    assert reply.value == big - 2**32
    assert sim.param("axis", 25) == big
    assert tx(sim, 9, 0, 3, -1).ok  # timer period: 32 bit unsigned
    assert sim.param("global", 0, 3) == 2**32 - 1


def test_eeprom_lock(sim):
    assert tx(sim, 9, 73, 0, 1234).ok
    assert tx(sim, 10, 73).value == 1
    assert status(sim, 7, 4) == Status.EEPROM_LOCKED
    assert status(sim, 11, 0, 2) == Status.EEPROM_LOCKED
    assert status(sim, 9, 66, 0, 4) == Status.EEPROM_LOCKED  # bank 0 config lives in EEPROM
    assert tx(sim, 5, 4, 0, 1234).ok  # RAM values still change
    assert tx(sim, 9, 73, 0, 1).ok and tx(sim, 10, 73).value == 1  # read-back values: no effect
    sim.reset()
    assert tx(sim, 10, 73).value == 1  # the lock itself is persistent
    assert tx(sim, 9, 73, 0, 4321).ok
    assert tx(sim, 10, 73).value == 0
    assert tx(sim, 7, 4).ok


def test_auto_stored_bank0_parameter(sim):
    assert tx(sim, 9, 77, 0, 1).ok
    assert sim.stored_param("global", 77) == 1


def test_factory_reset_sends_no_reply(sim):
    assert tx(sim, 5, 4, 0, 777).ok and tx(sim, 7, 4).ok
    assert tx(sim, 9, 0, 2, 5).ok and tx(sim, 11, 0, 2).ok
    sim.write(Request(1, 137, 0, 0, 1234).to_bytes())
    assert sim.read(0.1) == b""
    assert tx(sim, 6, 4).value == 51200
    assert tx(sim, 10, 0, 2).value == 0


def test_eeprom_magic_triggers_factory_defaults_at_boot(sim):
    assert tx(sim, 5, 4, 0, 777).ok and tx(sim, 7, 4).ok
    assert tx(sim, 9, 64, 0, 0).ok
    sim.reset()
    assert tx(sim, 6, 4).value == 51200
    assert tx(sim, 10, 64).value == 0xE4


def test_parameter_model_comes_from_the_database(any_sim):
    """Every parameter in the data file answers GAP/GGP (or 3 when not readable)."""
    mod = any_sim.module
    for p in mod.axis_params:
        expected = Status.OK if p.readable else Status.WRONG_TYPE
        assert status(any_sim, 6, p.number, mod.motors - 1) == expected, p.name
    for p in mod.global_params:
        expected = Status.OK if p.readable else Status.WRONG_TYPE
        assert status(any_sim, 10, p.number + p.count - 1, p.bank) == expected, p.name


def test_write_every_writable_parameter_at_its_limits(any_sim):
    mod = any_sim.module
    for p in mod.axis_params:
        if not p.writable or p.min is None or p.name in ("EEPROMLockFlag",):
            continue
        for value in (p.min, p.max):
            if p.choices and value not in p.choices:
                continue
            assert status(any_sim, 5, p.number, 0, value) == Status.OK, (p.name, value)
        if p.max < 2**31 - 1:
            assert status(any_sim, 5, p.number, 0, p.max + 1) == Status.INVALID_VALUE, p.name


# -- special replies --------------------------------------------------------------------------------

@pytest.mark.parametrize("module, expected", [
    ("TMCM-1311", bytes((0x05, 0x1F, 111, 0))),
    ("TMCM-351", bytes((0x01, 0x5F, 103, 0))),
    ("TMCM-1640", bytes((210, 0, 0x68, 0x06))),
])
def test_version_replies(module, expected):
    with Simulator(module) as s:
        s.write(Request(1, 136, 0).to_bytes())
        raw = read_exact(s, 9)
        assert raw == b"\x02" + s.module.version_string.encode()
        value = tx(s, 136, 1).value
        assert struct.pack(">i", value) == expected


def test_read_memory_legacy_layout(sim):
    assert tx(sim, 132, 0, 0, 10).ok
    assert status(sim, 4, 1, 0, -1000) == Status.LOADED
    assert status(sim, 27, 1, 0, 0) == Status.LOADED
    assert tx(sim, 133).ok
    sim.write(Request(1, 134, 0, 0, 10).to_bytes())
    raw = read_exact(sim, 9)
    assert raw[:8] == bytes((2, 4, 1, 0)) + struct.pack(">i", -1000)
    reply = Reply.from_bytes(raw, ReplyKind.MEMORY)
    assert reply.stored is not None and reply.stored.signed_value == -1000
    assert tx(sim, 134, 0, 0, 11, kind=ReplyKind.MEMORY).stored.opcode == 27
    unwritten = tx(sim, 134, 0, 0, 12, kind=ReplyKind.MEMORY).stored
    assert (unwritten.opcode, unwritten.type, unwritten.motor, unwritten.value) == (0, 0, 0, 0)
    assert status(sim, 134, 0, 0, 5000) == Status.INVALID_VALUE


def test_target_reached_event(sim):
    assert tx(sim, 4, 0, 0, 2000).ok
    first = tx(sim, 138, 0, 0, 0)
    assert (first.status, first.value) == (100, 1)
    event = Reply.from_bytes(read_exact(sim, 9, timeout=3))
    assert (event.status, event.opcode, event.value) == (Status.EVENT, 138, 1)
    assert tx(sim, 6, 1).value == 2000


def test_target_reached_event_interleaves_with_replies():
    with Simulator("TMCM-1311", speed=4) as s:
        assert tx(s, 4, 0, 0, 3000).ok
        assert tx(s, 138).ok
        frames = []
        deadline = time.monotonic() + 3
        while time.monotonic() < deadline and not any(f.status == 128 for f in frames):
            s.write(Request(1, 6, 1).to_bytes())
            data = read_exact(s, 9)
            frames.append(Reply.from_bytes(data))
            time.sleep(0.002)
        extra = read_exact(s, 9, timeout=0.05)
        frames += [Reply.from_bytes(extra[i:i + 9]) for i in range(0, len(extra), 9)]
        assert [f.opcode for f in frames if f.status == 128] == [138]
        assert all(f.opcode == 6 for f in frames if f.status == 100)


def test_138_when_already_reached_fires_at_once(sim):
    assert tx(sim, 138).ok
    event = Reply.from_bytes(read_exact(sim, 9))
    assert event.status == Status.EVENT


# -- faults -----------------------------------------------------------------------------------------

def test_fault_corrupt(sim):
    sim.faults.corrupt_next = 2
    good = Reply(2, 1, 100, 6, 51200).to_bytes()
    for _ in range(2):
        sim.write(Request(1, 6, 4).to_bytes())
        bad = read_exact(sim, 9)
        assert bad != good and checksum(bad[:8]) != bad[8]
    assert tx(sim, 6, 4).value == 51200


def test_fault_drop_and_lose(sim):
    sim.faults.drop_next = 1
    sim.write(Request(1, 5, 4, 0, 1111).to_bytes())
    assert sim.read(0.05) == b""
    assert tx(sim, 6, 4).value == 1111  # executed, reply dropped
    sim.faults.lose_next = 1
    sim.write(Request(1, 5, 4, 0, 2222).to_bytes())
    assert sim.read(0.05) == b""
    assert tx(sim, 6, 4).value == 1111  # never arrived


def test_fault_delay_garbage_truncate(sim):
    sim.faults.delay = 0.05
    start = time.monotonic()
    assert tx(sim, 6, 4).ok
    assert time.monotonic() - start >= 0.045
    sim.faults.delay = 0.0
    sim.faults.garbage = b"\xAA\xBB"
    sim.write(Request(1, 6, 4).to_bytes())
    data = read_exact(sim, 11)
    assert data[:2] == b"\xAA\xBB" and Reply.from_bytes(data[2:]).value == 51200
    sim.faults.truncate_next = 1
    sim.write(Request(1, 6, 4).to_bytes())
    assert len(read_exact(sim, 9, timeout=0.1)) == 4
    assert tx(sim, 6, 4).ok


def test_faults_is_a_plain_value():
    f = Faults()
    assert (f.corrupt_next, f.drop_next, f.delay, f.garbage, f.truncate_next) == (0, 0, 0.0, b"", 0)


# -- CAN and several modules ------------------------------------------------------------------------

def test_can_framing(sim):
    sim.can_write(1, Request(1, 6, 4).to_can())
    can_id, data = sim.can_read(1.0)
    assert can_id == 2
    assert Reply.from_can(can_id, data).value == 51200
    sim.can_write(5, Request(1, 6, 4).to_can())  # not our CAN ID
    assert sim.can_read(0.05) is None
    assert tx(sim, 9, 71, 0, 5).ok and tx(sim, 9, 70, 0, 9).ok
    sim.can_write(5, Request(1, 136, 0).to_can())
    can_id, data = sim.can_read(1.0)
    assert (can_id, data) == (9, b"1311V111")
    sim.can_write(5, Request(1, 137, 0, 0, 1234).to_can())
    assert sim.can_read(0.05) is None


def test_can_has_no_ascii_mode(sim):
    sim.can_write(1, Request(1, 139).to_can())
    _, data = sim.can_read(1.0)
    assert Reply.from_can(2, data).status == Status.COMMAND_NOT_AVAILABLE
    assert not sim.ascii_active


def test_simbus_each_module_answers_its_address():
    sims = [Simulator("TMCM-1311", 1), Simulator("TMCM-351", 2), Simulator("TMCM-1640", 3)]
    with SimBus(sims) as bus:
        for address, name in ((1, "1311V111"), (2, "0351V103"), (3, "1640V210")):
            bus.write(Request(address, 136, 0).to_bytes())
            data = read_exact(bus, 9)
            assert data[1:] == name.encode()
            assert bus.read(0.02) == b""
        bus.write(Request(7, 6, 1).to_bytes())
        assert bus.read(0.05) == b""


def test_reset_returns_to_binary_and_stops(sim):
    assert tx(sim, 1, 0, 0, 1000).ok
    sim.reset()
    assert tx(sim, 6, 1).value == 0 and tx(sim, 6, 3).value == 0
    assert sim.program_state == 0


def test_control_state_parameters_mirror_the_vm(sim):
    assert tx(sim, 132, 0, 0, 5).ok
    assert sim.param("global", 129) == 1  # (a GGP now would be stored, not executed)
    assert status(sim, Control.RUN_APPLICATION) == Status.COMMAND_NOT_AVAILABLE
    assert tx(sim, 133).ok
    assert tx(sim, 10, 129).value == 0


def test_serial_heartbeat_stops_motors():
    with Simulator("TMCM-1311") as s:
        assert tx(s, 9, 68, 0, 80).ok  # 80 ms
        assert tx(s, 1, 0, 0, 5000).ok
        time.sleep(0.3)
        assert s.axes[0].target_vel == 0.0  # MST by the heartbeat


def test_suppress_reply_on_the_1640():
    with Simulator("TMCM-1640") as s:
        s.write(Request(1, 9, 255, 0, 1).to_bytes())
        assert s.read(0.05) == b""
        s.write(Request(1, 5, 4, 0, 1234).to_bytes())
        assert s.read(0.05) == b""
        assert s.param("axis", 4) == 1234


def test_speed_knob():
    with Simulator("TMCM-1311", speed=1) as s:
        s.speed = 50
        t0 = s.now()
        time.sleep(0.02)
        assert s.now() - t0 >= 0.9
        with pytest.raises(ValueError):
            s.speed = 0
    with pytest.raises(ValueError):
        Simulator("TMCM-1311", address=256)
