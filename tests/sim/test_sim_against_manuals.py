"""The simulator reviewed against the manuals: what a client on the bench would notice.

* robustness: random frames, random bytes and random ASCII lines never raise, never kill the
  simulator thread and never wedge it (a GAP still answers afterwards); a flood of address
  bytes is handled in linear time;
* reply values: a reply carries the request's value field unless the command answers with a
  result (TMCM-1311 §5.7.16 prints ``CALC MUL, -5000`` answered with -5000), in binary and
  ASCII mode alike, errors included;
* time: WAIT TICKS and timer interrupts keep module time exactly at any ``speed``, the
  TMCM-1311 timer-interrupt example (§5.6.5) toggles at exactly its periods, a timer period
  counts from when it is set;
* GP 81: switching the disassembling protection off wipes the program (all three manuals);
* AP 2 in position mode: maximum speed while accelerating, 0 while decelerating (TMCM-1311
  chapter 6).
"""

from __future__ import annotations

import logging
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tmclsh.tmcl.asm import assemble
from tmclsh.tmcl.frames import Instruction, Reply, ReplyKind, Request, Status
from tmclsh.sim import Simulator
from manuals import listing

MODULES = ("TMCM-1311", "TMCM-351", "TMCM-1640")
ROR, MST, MVP, SAP, GAP, STAP, SGP, GGP, SIO, GIO = 1, 3, 4, 5, 6, 7, 9, 10, 14, 15


def fuzz(examples: int) -> settings:
    return settings(max_examples=examples, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])


def exchange(sim: Simulator, op: int, type_: int = 0, motor: int = 0, value: int = 0,
             timeout: float = 1.0) -> Reply:
    sim.write(Request(sim.address, op, type_, motor, value & 0xFFFFFFFF).to_bytes())
    data = b""
    deadline = time.monotonic() + timeout
    while len(data) < 9 and time.monotonic() < deadline:
        data += sim.read(max(0.0, deadline - time.monotonic()))
    assert len(data) >= 9, f"no reply to {op} ({data!r})"
    return Reply.from_bytes(data[:9], ReplyKind.NORMAL, module=sim.address, opcode=op)


def ascii_line(sim: Simulator, text: str, timeout: float = 1.0) -> bytes:
    sim.write(text.encode() + b"\r")
    data = b""
    deadline = time.monotonic() + timeout
    while not data.endswith(b"\r") and time.monotonic() < deadline:
        data += sim.read(max(0.0, deadline - time.monotonic()))
    return data


class Errors(logging.Handler):
    """Collects what the simulator logs as an error (its thread logs and survives them)."""

    def __init__(self):
        super().__init__(logging.ERROR)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@pytest.fixture
def sim_errors():
    handler = Errors()
    logger = logging.getLogger("tmclsh.sim")
    logger.addHandler(handler)
    yield handler.records
    logger.removeHandler(handler)


# -- robustness: the storm ---------------------------------------------------------------------

OPCODES = list(range(0, 42)) + list(range(64, 72)) + list(range(128, 141)) + [200, 255]
SMALL = st.one_of(st.integers(0, 15), st.integers(0, 255))
VALUES = st.one_of(st.sampled_from([0, 1, -1, 1234, 4321, 2**31 - 1, -2**31]),
                   st.integers(-300, 3000), st.integers(-2**31, 2**31 - 1))


@st.composite
def frames(draw) -> tuple[str, object]:
    """A frame for the module (valid checksum mostly), or raw bytes, or an ASCII line."""
    kind = draw(st.sampled_from(["frame", "frame", "frame", "bytes", "line"]))
    if kind == "bytes":
        return "bytes", draw(st.binary(min_size=1, max_size=24))
    if kind == "line":
        head = draw(st.sampled_from(["A", "A ", "B", " A", ""]))
        body = draw(st.one_of(
            st.text(max_size=30),
            st.sampled_from(["GAP 1, 0", "SAP 4, 0, -1", "MVP ABS, 0, 100", "ROR 0, 99999999",
                             "RUN", "STOP", "SIO 255, 2, 3", "GIO 255, 0", "\x08\x08\x7f",
                             "SAC 0, 0, 0", "UF3 1, 2, 3", "CALC ADD, 1", "MVP COORD, 135, 3"])))
        end = draw(st.sampled_from(["\r", "\n", "\r\n", ""]))
        return "line", (head + body + end).encode("utf-8", "replace")
    op = draw(st.sampled_from(OPCODES))
    type_, value = draw(SMALL), draw(VALUES)
    motor = draw(st.sampled_from([0, 1, 2, 3, 128, 135, 255]))
    if draw(st.integers(0, 9)) == 0:  # now and then the link parameters themselves
        op, motor = 9, 0
        type_ = draw(st.sampled_from([66, 67, 75, 76, 255]))
        value = draw(st.sampled_from([0, 1, 2, 3, 5, 48, 255]))
    return "frame", (op, type_, motor, value, draw(st.booleans()) or draw(st.booleans()))


def recover(sim: Simulator) -> Reply:
    """What a host does after a storm: leave ASCII and download mode, then ask for AP 1."""
    time.sleep(Simulator.FRAME_GAP + 0.02)  # a partial binary frame is discarded
    if sim.ascii_active:
        sim.write(b"\r" + bytes(((64 + sim.address) & 0xFF,)) + b"BIN\r")
    if sim.store.has("global", "SuppressReply"):
        sim.write(Request(sim.address, SGP, 255, 0, 0).to_bytes())
    sim.write(Request(sim.address, 133).to_bytes())  # quit download mode
    pause = sim.param("global", 75) if sim.store.has("global", "TelegramPauseTime") else 0
    time.sleep(pause / 1000 + 0.03)  # the replies to all that have gone out
    sim.read(0)
    return exchange(sim, GAP, 1, 0)


@pytest.mark.parametrize("module", MODULES)
@fuzz(20)
@given(storm=st.lists(frames(), min_size=1, max_size=40))
def test_random_frames_bytes_and_lines_never_wedge_the_simulator(module, storm, sim_errors):
    sim = Simulator(module, speed=50)
    try:
        for kind, item in storm:
            if kind == "frame":
                op, type_, motor, value, good = item  # type: ignore[misc]
                frame = bytearray(Request(sim.address, op, type_, motor, value & 0xFFFFFFFF)
                                  .to_bytes())
                if not good:
                    frame[8] ^= 0x5A
                sim.write(bytes(frame))
            else:
                sim.write(item)  # type: ignore[arg-type]
            sim.read(0)
        reply = recover(sim)
        assert reply.status == Status.OK and reply.host == sim.host_address
        assert not sim_errors, [r.getMessage() for r in sim_errors]
        assert sim._thread.is_alive()
    finally:
        sim.close()


@fuzz(15)
@given(lines=st.lists(st.binary(max_size=40), min_size=1, max_size=20))
def test_arbitrary_ascii_bytes_in_ascii_mode(lines, sim_errors):
    with Simulator("TMCM-1311", ascii_startup=True) as sim:
        for raw in lines:
            sim.write(b"A" + raw.replace(b"BIN", b"B1N") + b"\r")
            sim.read(0)
        if not sim.ascii_active:  # a line like "A\tBIN" leaves ASCII mode: fine
            sim.write(Request(1, 139).to_bytes())
            time.sleep(0.05)
        sim.read(0)
        assert ascii_line(sim, "AGAP 4, 0").endswith(b"BA 100 51200\r")
        assert not sim_errors


def test_random_programs_run_without_errors(sim_errors):
    """Whatever a program holds, the interpreter runs it without raising."""
    import random
    rng = random.Random(1311)
    for module in MODULES:
        with Simulator(module, speed=200) as sim:
            opcodes = [i.opcode for i in sim.module.instructions]
            for _ in range(15):
                program = [Instruction(rng.choice(opcodes), rng.randrange(12),
                                       rng.choice([0, 1, 3]),
                                       rng.choice([0, 1, 5, 2**32 - 1, rng.randrange(2**32)]))
                           for _ in range(rng.randrange(1, 30))]
                program = [i for i in program if not (i.opcode == SGP and i.type in (66, 76, 255))]
                sim.load_program(program)
                assert exchange(sim, 129, 1, 0, 0).ok
                time.sleep(0.02)
                assert exchange(sim, GAP, 1, 0).ok
                assert exchange(sim, 128).ok
    assert not sim_errors


def test_address_byte_flood_is_linear():
    """Every 9 bytes of 0x01 are a bad-checksum frame for address 1: one status-1 reply each,
    and no quadratic search for a frame further on."""
    with Simulator("TMCM-1311") as sim:
        start = time.monotonic()
        sim.write(b"\x01" * 90_000)
        assert time.monotonic() - start < 3.0
        data = b""
        while True:
            chunk = sim.read(0.2)
            if not chunk:
                break
            data += chunk
        assert len(data) == 10_000 * 9
        assert Reply.from_bytes(data[:9]).status == Status.WRONG_CHECKSUM
        assert exchange(sim, GAP, 4, 0).value == 51200


def test_garbage_before_a_frame_still_resynchronises():
    with Simulator("TMCM-1311") as sim:
        for garbage in (b"\x01", b"\x01\x01\x55", b"\x01" * 8):
            sim.write(garbage + Request(1, GAP, 4).to_bytes())
            reply = Reply.from_bytes(sim.read(0.5)[-9:])
            assert (reply.status, reply.value) == (Status.OK, 51200)


# -- reply values ------------------------------------------------------------------------------

@pytest.mark.parametrize("request_, expected", [
    ((ROR, 0, 0, 10000), (100, 10000)),
    ((2, 0, 0, -300), (100, -300)),  # ROL
    ((MST, 0, 0, 77), (100, 77)),
    ((MVP, 0, 0, 90000), (100, 90000)),
    ((MVP, 1, 0, -1000), (100, -1000)),
    ((SAP, 4, 0, 1000), (100, 1000)),
    ((STAP, 4, 0, 5), (100, 5)),
    ((8, 4, 0, 6), (100, 6)),  # RSAP
    ((SGP, 0, 2, -42), (100, -42)),
    ((11, 0, 2, 9), (100, 9)),  # STGP
    ((SIO, 7, 2, 1), (100, 1)),
    ((30, 1, 0, 1000), (100, 1000)),  # SCO
    ((32, 3, 0, 12), (100, 12)),  # CCO
    ((13, 1, 0, 4), (100, 4)),  # RFS STOP
    ((64, 1, 2, 3), (100, 3)),  # UF0
    ((GAP, 4, 0, 99), (100, 51200)),  # reads answer their result
    ((GGP, 66, 0, 99), (100, 1)),
    ((GIO, 8, 1, 99), (100, 240)),
    ((13, 2, 0, 99), (100, 0)),  # RFS STATUS
    ((GAP, 250, 0, 7), (3, 7)),  # errors keep the request's value
    ((SAP, 4, 0, -5), (4, -5)),
    ((ROR, 0, 3, 100), (4, 100)),
    ((19, 2, 0, -5000), (6, -5000)),  # CALC MUL, -5000 (§5.7.16's bytes; status 6 in direct mode)
    ((29, 0, 0, 8), (6, 8)),  # SAC: another module's command
    ((16, 0, 0, 8), (2, 8)),  # no such command
    ((128, 0, 0, 8), (100, 8)),  # stop application
    ((131, 0, 0, 8), (100, 8)),  # reset application
    ((135, 0, 0, 8), (100, 3)),  # application status: the result
    ((129, 5, 0, 8), (3, 8)),
])
def test_reply_value_is_the_request_value_unless_a_result(request_, expected):
    with Simulator("TMCM-1311") as sim:
        if request_[0] == 135:
            exchange(sim, 131)
        reply = exchange(sim, *request_)
        assert (reply.status, reply.value) == expected


def test_download_mode_replies_echo_the_value():
    with Simulator("TMCM-1311") as sim:
        assert exchange(sim, 132, 0, 0, 0).value == 0
        reply = exchange(sim, MVP, 0, 0, 123456)
        assert (reply.status, reply.value) == (Status.LOADED, 123456)
        reply = exchange(sim, 19, 2, 0, -5000)
        assert (reply.status, reply.value) == (Status.LOADED, -5000)
        assert exchange(sim, 133, 0, 0, 3).value == 3


def test_ascii_replies_carry_the_same_values_as_binary():
    with Simulator("TMCM-1311") as sim:
        sim.write(Request(1, 139).to_bytes())
        assert len(sim.read(0.5)) == 9
        assert exchange_ascii(sim, "AROR 0, 500") == b"BA 100 500\r"
        assert exchange_ascii(sim, "AMVP ABS, 0, -7") == b"BA 100 -7\r"
        assert exchange_ascii(sim, "ASAP 140, 0, 99") == b"BA 4 99\r"  # refused: value echoed
        assert exchange_ascii(sim, "AGAP 4, 0") == b"BA 100 51200\r"


def exchange_ascii(sim: Simulator, text: str) -> bytes:
    data = ascii_line(sim, text)
    while data.count(b"\r") < 2:  # echo line, then the reply
        more = sim.read(0.5)
        if not more:
            break
        data += more
    return data.split(b"\r")[1] + b"\r"


# -- time --------------------------------------------------------------------------------------

@pytest.mark.parametrize("speed", [1, 20, 200])
def test_wait_ticks_keep_module_time_at_any_speed(speed):
    """50 x WAIT TICKS 1 take 500 ms on the tick timer (GP 132), however fast the clock runs."""
    with Simulator("TMCM-1311", speed=speed) as sim:
        program = assemble("SGP 132, 0, 0\n" + "WAIT TICKS, 0, 1\n" * 50
                           + "GGP 132, 0\nAGP 0, 2\nSTOP\n", sim.module)
        sim.load_program(program.instructions)
        assert exchange(sim, 129, 1, 0, 0).ok
        deadline = time.monotonic() + 5
        while sim.program_state != 0:
            assert time.monotonic() < deadline
            time.sleep(0.005)
        assert exchange(sim, GGP, 0, 2).value == 500


class Recorder(dict):
    """The simulator's I/O levels, recording each change with its module time."""

    def __init__(self, sim: Simulator):
        super().__init__(sim.io.values)
        self.sim = sim
        self.changes: list[tuple[float, tuple[int, int], int]] = []

    def __setitem__(self, key, value) -> None:
        if self.get(key) != value:
            self.changes.append((self.sim.clock(), key, value))
        super().__setitem__(key, value)

    def periods(self, bank: int, port: int) -> list[float]:
        times = [t for t, k, _ in self.changes if k == (bank, port)]
        return [b - a for a, b in zip(times, times[1:])]


@pytest.mark.parametrize("speed", [4, 40])
def test_manual_timer_interrupt_example_keeps_its_periods(speed):
    """TMCM-1311 §5.6.5: the timer-0 routine toggles OUT_0 every 1000 ms while the main loop
    toggles OUT_3 every 500 ms with WAIT TICKS; both exactly, in module time."""
    with Simulator("TMCM-1311", speed=speed) as sim:
        rec = sim.io.values = Recorder(sim)
        sim.load_program(assemble(listing("tmcm1311-timer-interrupt"), sim.module).instructions)
        assert exchange(sim, 129, 1, 0, 0).ok
        time.sleep(4.2 / speed)
        assert exchange(sim, 128).ok
        out0, out3 = rec.periods(2, 0), rec.periods(2, 3)
        assert len(out0) >= 2 and len(out3) >= 6
        assert all(abs(p - 1.0) < 1e-3 for p in out0), out0
        assert all(abs(p - 0.5) < 1e-3 for p in out3), out3


def test_timer_period_counts_from_when_it_is_set():
    with Simulator("TMCM-1311", speed=10) as sim:
        rec = sim.io.values = Recorder(sim)
        program = assemble("""
            VECT 0, Tick
            SGP 0, 3, 1000
            EI 0
            EI 255
            WAIT TICKS, 0, 30      // 300 ms into the 1000 ms period ...
            SGP 0, 3, 200          // ... a new period starts now
            SIO 2, 2, 1            // (marks the time)
        Loop: JA Loop
        Tick: GIO 1, 2
            JC NZ, Off
            SIO 1, 2, 1
            RETI
        Off: SIO 1, 2, 0
            RETI
        """, sim.module)
        sim.load_program(program.instructions)
        assert exchange(sim, 129, 1, 0, 0).ok
        time.sleep(0.15)
        assert exchange(sim, 128).ok
        times = [t for t, k, _ in rec.changes if k == (2, 1)]
        mark = next(t for t, k, _ in rec.changes if k == (2, 2))
        assert len(times) >= 3
        assert abs(times[0] - mark - 0.2) < 1e-3, (mark, times)  # not 700 ms later
        assert all(abs(b - a - 0.2) < 1e-3 for a, b in zip(times, times[1:])), times


# -- GP 81 and AP 2 ----------------------------------------------------------------------------

@pytest.mark.parametrize("module", MODULES)
def test_switching_off_disassembling_protection_wipes_the_program(module):
    with Simulator(module) as sim:
        sim.load_program([Instruction(ROR, 0, 0, 5), Instruction(28)])

        def stored_opcode() -> int:
            sim.write(Request(sim.address, 134, 0, 0, 0).to_bytes())
            data = sim.read(0.5)
            stored = Reply.from_bytes(data, ReplyKind.MEMORY).stored
            assert stored is not None
            return stored.opcode

        assert exchange(sim, SGP, 81, 0, 2).ok  # overwriting protection only: no wipe
        assert exchange(sim, SGP, 81, 0, 0).ok
        assert stored_opcode() == ROR
        assert exchange(sim, SGP, 81, 0, 3).ok
        assert exchange(sim, SGP, 81, 0, 1).ok  # still protected against disassembling
        assert stored_opcode() == ROR
        assert exchange(sim, SGP, 81, 0, 2).ok  # 1 -> 2: the program is wiped off
        assert stored_opcode() == 0
        assert exchange(sim, GGP, 81, 0).value == 2
        sim.reset()
        assert exchange(sim, GGP, 81, 0).value == 2  # stored by SGP itself


def test_target_speed_in_position_mode_is_zero_while_decelerating():
    with Simulator("TMCM-1311", speed=4) as sim:
        assert exchange(sim, SAP, 4, 0, 20000).ok
        assert exchange(sim, SAP, 5, 0, 20000).ok
        assert exchange(sim, MVP, 0, 0, 30000).ok  # 1 s up, 0.5 s at 20000, 1 s down
        seen = []
        deadline = time.monotonic() + 1.5
        while time.monotonic() < deadline and not exchange(sim, GAP, 8, 0).value:
            seen.append((exchange(sim, GAP, 3, 0).value, exchange(sim, GAP, 2, 0).value))
            time.sleep(0.01)
        accelerating = [target for speed, target in seen if 0 < speed < 19000][:3]
        assert accelerating and all(t == 20000 for t in accelerating)
        assert any(t == 0 and 0 < v < 19000 for v, t in seen[len(seen) // 2:]), seen
        assert exchange(sim, GAP, 2, 0).value == 0


def test_velocity_reached_agrees_with_the_actual_speed_read():
    """When AP 3 reads as the target speed, AP 16 (and the status word) say "reached"; the
    ramp's fractional speed (999.6 pps reads as 1000) must not tell them apart."""
    with Simulator("TMCM-1311", speed=1e-6) as sim:  # module time stands still
        assert exchange(sim, ROR, 0, 0, 1000).ok
        sim.axes[0].vel = 999.6
        assert exchange(sim, GAP, 3, 0).value == 1000
        assert exchange(sim, GAP, 16, 0).value == 1
        assert exchange(sim, GAP, 18, 0).value >> 1 & 1  # status word bit 1: velocity reached
        sim.axes[0].vel = 998.4
        assert exchange(sim, GAP, 16, 0).value == 0
