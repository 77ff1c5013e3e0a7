"""Simulated motion (ramps, positioning, switches, reference search), coordinates and I/O,
driven through real request frames."""

from __future__ import annotations

import time

import pytest

from tmclsh.tmcl.frames import Reply, Request, Status
from tmclsh.sim import Simulator
from tmclsh.sim.motion import Axis, Limits


class Host:
    """A minimal host on the simulator's byte stream (one request, one reply)."""

    def __init__(self, sim: Simulator, address: int = 1):
        self.sim, self.address = sim, address

    def tx(self, op, type_=0, motor=0, value=0) -> Reply:
        self.sim.write(Request(self.address, op, type_, motor, value).to_bytes())
        data = b""
        deadline = time.monotonic() + 1
        while len(data) < 9 and time.monotonic() < deadline:
            data += self.sim.read(deadline - time.monotonic())
        return Reply.from_bytes(data[:9])

    def ok(self, *args) -> int:
        reply = self.tx(*args)
        assert reply.status == Status.OK, reply
        return reply.value

    def gap(self, number, motor=0) -> int:
        return self.ok(6, number, motor)

    def wait(self, pred, timeout=3.0) -> None:
        deadline = time.monotonic() + timeout
        while not pred():
            assert time.monotonic() < deadline, "condition not met in time"
            time.sleep(0.005)


@pytest.fixture
def host():
    sim = Simulator("TMCM-1311", speed=20)
    yield Host(sim)
    sim.close()


def timed(sim: Simulator, fn):
    """fn() and the module-time window it was evaluated in."""
    before = sim.now()
    value = fn()
    return value, before, sim.now()


def test_ror_ramps_by_the_acceleration():
    with Simulator("TMCM-1311") as sim:
        h = Host(sim)
        h.ok(5, 5, 0, 2000)  # 2000 pps/s
        h.ok(1, 0, 0, 1000)
        time.sleep(0.1)
        v1, a1, b1 = timed(sim, lambda: h.gap(3))
        time.sleep(0.1)
        v2, a2, b2 = timed(sim, lambda: h.gap(3))
        assert 0 < v1 < v2 <= 1000
        if v2 < 1000:  # still ramping: the speed grew by acceleration x elapsed time
            assert 2000 * (a2 - b1) - 2 <= v2 - v1 <= 2000 * (b2 - a1) + 2
        assert h.gap(2) == 1000 and h.gap(8) == 0
        h.wait(lambda: h.gap(3) == 1000)
        assert h.gap(16) == 1  # velocity reached
        h.ok(2, 0, 0, 500)
        assert h.gap(2) == -500
        h.ok(3, 0, 0, 0)
        h.wait(lambda: h.gap(3) == 0)
        assert h.gap(1) > 0


def test_mvp_reaches_target_and_sets_ap8(host):
    host.ok(5, 4, 0, 20000)
    host.ok(5, 5, 0, 50000)
    host.ok(4, 0, 0, 90000)
    assert host.gap(8) == 0 and host.gap(0) == 90000
    host.wait(lambda: host.gap(8) == 1)
    assert host.gap(1) == 90000 and host.gap(3) == 0
    host.ok(4, 1, 0, -1000)  # REL
    host.wait(lambda: host.gap(8) == 1)
    assert host.gap(1) == 89000
    assert host.sim.param("axis", 18) & 1  # status word: target reached


def test_mvp_never_exceeds_max_speed(host):
    host.ok(5, 4, 0, 5000)
    host.ok(5, 5, 0, 100000)
    host.ok(4, 0, 0, -40000)
    speeds = []
    while host.gap(8) == 0:
        speeds.append(host.gap(3))
    assert min(speeds) >= -5000 and min(speeds) < -4000
    assert host.gap(1) == -40000


def test_mvp_coord_and_coordinates(host):
    host.ok(30, 3, 0, 1234)
    assert host.ok(31, 3, 0) == 1234
    host.ok(4, 2, 0, 3)
    host.wait(lambda: host.gap(8) == 1)
    assert host.gap(1) == 1234
    host.ok(32, 4, 0)  # capture
    assert host.ok(31, 4, 0) == 1234
    assert host.tx(4, 2, 0, 21).status == Status.INVALID_VALUE


def test_coordinates_eeprom_copies_bank_255(host):
    host.ok(30, 1, 0, 500)
    host.ok(30, 2, 0, 600)
    host.ok(30, 0, 255, 0)  # all but coordinate 0 to EEPROM
    host.ok(30, 1, 0, 0)
    host.ok(31, 1, 255)  # coordinate 1 back from EEPROM
    assert host.ok(31, 1, 0) == 500
    host.sim.reset()  # GP 84 = 0: RAM coordinates start at 0
    assert host.ok(31, 2, 0) == 0
    host.ok(31, 0, 255)
    assert host.ok(31, 2, 0) == 600
    host.ok(9, 84, 0, 1)  # always EEPROM
    host.ok(30, 5, 0, 77)
    host.sim.reset()
    assert host.ok(31, 5, 0) == 77


def test_right_limit_switch_stops_motion(host):
    host.sim.set_switch_position(0, "right", 1000)
    host.ok(5, 4, 0, 10000)
    host.ok(4, 0, 0, 5000)
    host.wait(lambda: host.gap(10) == 1 and host.gap(3) == 0)
    assert host.gap(1) == 1000 and host.gap(8) == 0
    host.ok(4, 0, 0, 0)  # away from the switch is allowed
    host.wait(lambda: host.gap(8) == 1)
    host.ok(5, 12, 0, 1)  # disable the right stop function
    host.ok(4, 0, 0, 5000)
    host.wait(lambda: host.gap(8) == 1)
    assert host.gap(1) == 5000 and host.gap(10) == 1


def test_forced_left_switch_stops_rol(host):
    host.ok(2, 0, 0, 2000)
    time.sleep(0.02)
    host.sim.set_switch(0, "left", True)
    host.wait(lambda: host.gap(3) == 0)
    assert host.gap(11) == 1
    stopped = host.gap(1)
    time.sleep(0.02)
    assert host.gap(1) == stopped
    host.sim.set_switch(0, "left", None)
    host.wait(lambda: host.gap(3) != 0)


def test_reference_search(host):
    sim = host.sim
    sim.set_switch_position(0, "ref", -3000)
    host.ok(5, 4, 0, 20000)
    host.ok(1, 0, 0, 0)
    host.ok(13, 0, 0)  # RFS START
    assert host.ok(13, 2, 0) != 0  # STATUS: searching
    host.wait(lambda: host.ok(13, 2, 0) == 0)
    assert host.gap(1) == 0 and host.gap(3) == 0 and host.gap(8) == 1
    assert host.gap(9) == 0  # just released
    host.ok(4, 0, 0, -10)
    host.wait(lambda: host.gap(8) == 1)
    assert host.gap(9) == 1  # the switch is where position 0 was found


def test_reference_search_with_forced_switch_and_stop(host):
    sim = host.sim
    host.ok(5, 194, 0, 1000)
    host.ok(13, 0, 0)
    host.wait(lambda: host.gap(3) < 0)
    host.ok(13, 1, 0)  # RFS STOP
    host.wait(lambda: host.gap(3) == 0)
    assert host.ok(13, 2, 0) == 0
    host.ok(13, 0, 0)
    sim.set_switch(0, "ref", True)
    host.wait(lambda: host.gap(3) > 0)
    sim.set_switch(0, "ref", False)
    host.wait(lambda: host.ok(13, 2, 0) == 0)
    assert host.gap(1) == 0


def test_351_three_motors():
    with Simulator("TMCM-351", speed=20) as sim:
        h = Host(sim)
        h.ok(1, 0, 2, 500)
        h.ok(4, 0, 1, 20000)
        h.wait(lambda: h.gap(3, 2) == 500)
        h.wait(lambda: h.gap(8, 1) == 1)
        assert h.gap(1, 1) == 20000
        assert h.gap(1, 0) == 0 and h.gap(3, 0) == 0
        assert h.gap(138, 2) == 2 and h.gap(138, 1) == 0  # ramp mode: velocity / position
        h.ok(3, 0, 2)
        for m, pos in ((0, 100), (1, 200), (2, 300)):
            h.ok(30, 7, m, pos)
        h.ok(4, 2, 0x80 | 0b101, 7)  # MVP COORD 7 for motors 0 and 2
        h.wait(lambda: h.gap(8, 0) == 1 and h.gap(8, 2) == 1)
        assert (h.gap(1, 0), h.gap(1, 1), h.gap(1, 2)) == (100, 20000, 300)


def test_1640_acceleration_is_ap11_and_speeds_are_rpm():
    with Simulator("TMCM-1640") as sim:
        h = Host(sim)
        h.ok(5, 11, 0, 1000)  # rpm/s
        start = sim.now()
        h.ok(1, 0, 0, 600)
        time.sleep(0.2)
        v, _, end = timed(sim, lambda: h.gap(3))
        assert 100 <= v <= min(600, 1000 * (end - start) + 1)
        assert h.tx(5, 5, 0, 10).status == Status.WRONG_TYPE  # no AP 5 on the 1640
        h.ok(3, 0, 0)
        sim.speed = 20
        h.ok(5, 4, 0, 3000)
        h.ok(4, 0, 0, 500)
        h.wait(lambda: h.gap(1) == 500 and h.gap(3) == 0)
        assert sim.param("axis", 156) >> 14 & 1  # status flags: position end


def test_position_counter_wraps_on_the_351():
    with Simulator("TMCM-351") as sim:
        h = Host(sim)
        h.ok(5, 1, 0, 8388607)
        assert h.gap(1) == 8388607
        assert h.tx(4, 1, 0, 1).status == Status.INVALID_VALUE  # would leave ±2^23


def test_set_actual_position_keeps_a_resting_motor_still(host):
    host.ok(5, 1, 0, 5000)
    assert host.gap(0) == 5000 and host.gap(8) == 1
    time.sleep(0.02)
    assert host.gap(1) == 5000


def test_physics_exact_with_huge_steps():
    axis = Axis()
    axis.move_to(123457)
    lim = Limits(vmax=1000.0, accel=300.0)
    axis.advance(10_000.0, lim)
    assert axis.pos == 123457 and axis.vel == 0 and axis.reached


# -- I/O --------------------------------------------------------------------------------------------

def test_gio_sio_every_port(host):
    sim, mod = host.sim, host.sim.module
    for port in mod.io:
        value = host.ok(15, port.port, port.bank)
        assert port.min <= value <= port.max
        if port.kind == "digital_out":
            host.ok(14, port.port, port.bank, 1)
            assert host.ok(15, port.port, port.bank) == 1
            assert host.tx(14, port.port, port.bank, 2).status == Status.INVALID_VALUE
        else:
            try:
                sim.set_input(port.bank, port.port, port.max)
            except ValueError as exc:  # a coil current: it follows the motor (derived.py)
                assert "follows the simulated motor" in str(exc)
                continue
            assert host.ok(15, port.port, port.bank) == port.max


def test_all_ports_at_once_on_the_1311(host):
    sim = host.sim
    for port in (1, 3, 7):
        sim.set_input(0, port, 1)
    assert host.ok(15, 255, 0) == 0b10001010
    host.ok(14, 255, 2, 0b01010101)
    assert host.ok(15, 255, 2) == 0b01010101
    assert host.ok(15, 2, 2) == 1 and host.ok(15, 1, 2) == 0
    assert host.tx(14, 255, 2, -1).status == Status.INVALID_VALUE  # accu copy only in programs
    assert host.tx(14, 255, 2, 256).status == Status.INVALID_VALUE


def test_analog_and_digital_views_of_one_pin(host):
    host.sim.set_input(1, 0, 4000)
    assert host.ok(15, 0, 0) == 1
    host.sim.set_input(0, 0, 0)
    assert host.ok(15, 0, 1) == 0
    assert host.ok(15, 8, 1) == 240  # supply voltage start value from the data file


def test_set_input_rejects_outputs_and_ranges(host):
    with pytest.raises(ValueError):
        host.sim.set_input(2, 0, 1)
    with pytest.raises(ValueError):
        host.sim.set_input(0, 0, 2)
    with pytest.raises(ValueError):
        host.sim.set_input(0, 42, 1)


def test_1640_io():
    with Simulator("TMCM-1640") as sim:
        h = Host(sim)
        h.ok(14, 0, 2, 1)
        assert h.ok(15, 0, 2) == 1
        assert h.tx(14, 7, 2, 1).status == Status.WRONG_TYPE
        assert h.tx(15, 255, 0).status == Status.WRONG_TYPE  # no all-ports number
        assert h.ok(15, 4, 1) == 2730
