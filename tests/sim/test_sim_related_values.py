"""Values the manuals relate to others read alike, seen by a client tmclsh did not write.

Issue 27, section 1: driven through PyTrinamic's own TMCL interface over a pty (real bytes,
the vendor's framing and checks), the simulated TMCM-1311 and TMCM-1640 answer what their
manuals say: a read-out equals the GIO that measures the same quantity, a maximum follows the
settings it is derived from, a status bit follows the mode it names, a start-up flag comes up,
a disabled driver turns nothing, and nothing that cannot be 0 on a powered, driven module
reads 0. Each test names the manual lines it follows (``cite``: checked against the manual's
text when the manuals are beside the checkout; seed file numbering, ``000`` the TMCM-1311,
``003`` the TMCM-1640).
"""

from __future__ import annotations

import math
import time

import pytest

from manuals import SEEDS, manual_lines
from tmclsh.sim import Simulator
from tmclsh.sim.serve import serve_pty
from conftest import patience
from steppedsim import SteppedSimulator

pytest.importorskip("pytrinamic")

SPEED = 10  # module time runs 10x real time: start-ups and ramps take a tenth


def cite(module: str, line: int, text: str) -> None:
    """The manual line a test follows; when the manuals are here, it must say ``text``."""
    if not SEEDS.is_dir():
        return
    assert text in manual_lines(module)[line - 1], (module, line, text)


class Witness:
    """PyTrinamic's serial TMCL interface on a simulated module's pty."""

    def __init__(self, sim: Simulator, iface):
        self.sim, self.iface = sim, iface

    def gap(self, number: int) -> int:
        return self.iface.get_axis_parameter(number, 0, signed=True)

    def sap(self, number: int, value: int) -> None:
        self.iface.set_axis_parameter(number, 0, value)

    def gio(self, port: int, bank: int) -> int:
        assert bank == 1  # the analog read-outs: PyTrinamic's get_analog_input is GIO x, 1
        value = self.iface.get_analog_input(port)  # read unsigned: the 32 bits as signed
        return value - 2**32 if value >= 2**31 else value

    def until(self, pred, timeout: float = 3.0):
        """``pred()`` once true; on a stepped simulator module time moves 50 ms a try."""
        stepped = isinstance(self.sim, SteppedSimulator)
        deadline = time.monotonic() + (patience(30) if stepped else timeout)
        while True:
            value = pred()
            if value:
                return value
            assert time.monotonic() < deadline, "not within the time"
            if stepped:
                self.sim.step(0.05)
            else:
                time.sleep(0.01)


@pytest.fixture
def witness():
    from pytrinamic.connections import ConnectionManager

    opened = []

    def open_(module: str, stepped: bool = False) -> Witness:
        sim = SteppedSimulator(module) if stepped else Simulator(module, speed=SPEED)
        server = serve_pty(sim)
        server.__enter__()
        iface = ConnectionManager(
            f"--interface serial_tmcl --port {server.path} --data-rate 9600").connect()
        opened.append((sim, server, iface))
        return Witness(sim, iface)

    yield open_
    for sim, server, iface in opened:
        iface.close()
        server.__exit__(None, None, None)
        sim.close()


# -- TMCM-1311 --------------------------------------------------------------------------------

def test_1311_encoder_initialisation_completes_and_closed_loop_comes_up(witness):
    cite("TMCM-1311", 4716, "1 encoder initialization in process")
    cite("TMCM-1311", 4717, "2 encoder initialization completed")
    cite("TMCM-1311", 4729, "1: closed loop is initialized and ready for use")
    cite("TMCM-1311", 4256, "Bit 2 Closed loop mode")
    w = witness("TMCM-1311", stepped=True)  # "in process" seen however late the next read
    assert w.gap(132) == 0
    w.sap(132, 1)
    assert w.gap(132) == 1  # in process ...
    assert w.until(lambda: w.gap(132) == 2)  # ... then completed, never stuck at 1
    assert w.gap(210) == 40000  # the encoder of the manual's closed-loop example
    assert w.gap(133) == 0 and not w.gap(18) >> 2 & 1
    w.sap(129, 1)
    assert w.until(lambda: w.gap(133) == 1)
    assert w.gap(18) >> 2 & 1  # the status word says what AP 133 says
    w.sap(129, 0)
    assert w.gap(133) == 0 and not w.gap(18) >> 2 & 1


def test_1311_encoder_initialisation_without_motor_steps_is_incorrect(witness):
    cite("TMCM-1311", 4709, "automatically by writing 1. Attention: the")
    cite("TMCM-1311", 4710, "fullstep resolution of the encoder has to be set")
    cite("TMCM-1311", 4718, "3 encoder initialization incorrect")
    w = witness("TMCM-1311")
    w.sap(202, 0)
    w.sap(132, 1)
    assert w.gap(132) == 3


def test_1311_supply_voltage_and_temperature_are_what_gio_reads(witness):
    cite("TMCM-1311", 2378, "Supply voltage [1/10V] GIO 8, 1")
    cite("TMCM-1311", 2379, "Temperature [˚C] GIO 9, 1")
    cite("TMCM-1311", 4878, "153 Supply Voltage Actual value of supply voltage  [1/10 V] R")
    cite("TMCM-1311", 4887, "Actual temperature of the module [°C] R")
    w = witness("TMCM-1311")
    assert w.gap(153) == w.gio(8, 1) > 0  # a powered module has a supply voltage
    assert w.gap(155) == w.gio(9, 1) != 0
    w.sim.set_input(1, 8, 123)  # the supply sags: both views see it
    w.sim.set_input(1, 9, 55)
    assert w.gap(153) == w.gio(8, 1) == 123
    assert w.gap(155) == w.gio(9, 1) == 55


def test_1311_maximum_possible_current_follows_ap6_and_ap179(witness):
    cite("TMCM-1311", 4218, "parameter returns the maximum possible RMS")
    w = witness("TMCM-1311")
    w.sap(6, 128)
    full_range = w.gap(15)
    assert full_range == round(17 / 32 * 3000)  # CS = 128 // 8 = 16: 17/32 of 3 A RMS
    w.sap(179, 1)  # Vsense: the 1.5 A range
    assert w.gap(15) == round(17 / 32 * 1500)
    w.sap(179, 0)
    w.sap(6, 255)
    assert w.gap(15) == 3000


def test_1311_a_driven_motor_has_winding_currents(witness):
    cite("TMCM-1311", 6465, "150 Motor current Actual motor current")
    cite("TMCM-1311", 4876, "151 Current Phase A Actual peak current Phase A [mA] R")
    cite("TMCM-1311", 2380, "Coil current A [mA] GIO 10, 1")
    cite("TMCM-1311", 2382, "Input current [mA] GIO 12, 1")
    # module time moved by the test: "at rest one instant holds" is one instant however long a
    # busy machine takes between the reads (the power-down delay had passed between them)
    w = witness("TMCM-1311", stepped=True)
    w.sap(6, 128)
    w.sap(7, 16)
    w.iface.rotate(0, 20000)
    w.until(lambda: w.gap(3) == 20000)
    peak = round(w.gap(15) * math.sqrt(2))  # the run current's peak
    seen = set()
    for _ in range(5):
        assert abs(w.gap(150) - peak) <= 1  # sqrt(AP 151² + AP 152²) of whole mA
        a, b = w.gap(151), w.gap(152)
        assert abs(a) <= peak and abs(b) <= peak
        seen.add(a)
        w.sim.step(0.013 * SPEED)
    assert len(seen) > 1  # a sine wave along the microsteps, not a constant
    assert w.gap(154) > 0 and w.gio(12, 1) > 0
    # at rest one instant holds: AP 150 = sqrt(AP 151² + AP 152²), GIO 10/11/12 = AP 151/152/154
    w.iface.stop(0)
    w.until(lambda: w.gap(3) == 0)
    a, b = w.gap(151), w.gap(152)
    assert (a, b, w.gap(154)) == (w.gio(10, 1), w.gio(11, 1), w.gio(12, 1))
    assert abs(w.gap(150) - math.hypot(a, b)) <= 1 and (a, b) != (0, 0)
    # at rest for the power down delay (AP 214, 10 ms units) the standby current flows
    w.sap(214, 10)
    w.sim.step(0.02 * SPEED)
    standby = round((16 // 8 + 1) / 32 * 3000 * math.sqrt(2))
    assert w.until(lambda: abs(w.gap(150) - standby) <= 1)


def test_1311_a_free_running_motor_has_load_and_is_not_stopped_by_stall_guard(witness):
    cite("TMCM-1311", 5124, "181 Stop on stall Below this speed motor will not be stopped.")
    cite("TMCM-1311", 5125, "Above this speed motor will stop in case")
    cite("TMCM-1311", 5126, "stallGuard2 load value reaches zero.")
    cite("TMCM-1311", 5294, "206 Actual load value Readout of the actual load value used for stall")
    w = witness("TMCM-1311")
    w.sap(181, 1000)  # stop on stall above 1000 pps
    w.iface.rotate(0, 20000)
    w.until(lambda: w.gap(3) == 20000)
    time.sleep(0.05)  # half a second of module time at full speed
    assert w.gap(206) > 0  # not stalled ...
    assert w.gap(3) == 20000  # ... so still turning: the two agree


def test_1311_target_current_enters_torque_mode_in_closed_loop(witness):
    cite("TMCM-1311", 4186, "automatically switches to torque mode.")
    cite("TMCM-1311", 4259, "Bit 5 Torque mode")
    cite("TMCM-1311", 4651, "2: Torque mode. In closed loop mode only, the")
    w = witness("TMCM-1311")
    w.sap(14, 500)  # open loop: no torque mode, nothing moves
    assert w.gap(128) == 0 and not w.gap(18) >> 5 & 1
    assert w.gap(3) == 0
    w.sap(210, 40000)
    w.sap(129, 1)
    w.until(lambda: w.gap(133) == 1)
    w.sap(14, -500)
    assert w.gap(128) == 2  # ramp mode: torque
    status = w.gap(18)
    assert status >> 5 & 1 and not status >> 3 & 1 and not status >> 4 & 1
    assert w.gap(14) == -500
    assert w.until(lambda: w.gap(3) < 0)  # the sign of the current is the direction
    w.iface.rotate(0, 0)  # a motion command leaves torque mode
    assert w.gap(128) == 1 and not w.gap(18) >> 5 & 1


# -- TMCM-1640 --------------------------------------------------------------------------------

def test_1640_a_disabled_driver_turns_nothing(witness):
    cite("TMCM-1640", 2719, "255 Enable driver Enable or disable the driver and switch to stop mode.")
    cite("TMCM-1640", 2720, "0: Disable driver")
    cite("TMCM-1640", 2489, "Bit 4: Motor halted flag. This flag is set if motor has been")
    w = witness("TMCM-1640")
    assert w.gap(255) == 1  # a module drives its motor from the start
    w.iface.rotate(0, 1000)
    w.until(lambda: w.gap(3) == 1000)
    w.sap(255, 0)  # stop mode: the motor comes to rest at once and stays there
    assert w.gap(3) == 0 and w.gap(156) >> 4 & 1
    position = w.gap(1)
    w.iface.rotate(0, 2000)
    time.sleep(0.05)
    assert (w.gap(3), w.gap(1)) == (0, position)
    w.sap(255, 1)
    assert w.until(lambda: w.gap(3) == 2000)
    assert not w.gap(156) >> 4 & 1


def test_1640_target_current_enters_torque_mode(witness):
    cite("TMCM-1640", 2472, "155 Target current Get desired target current or set target current to activate")
    cite("TMCM-1640", 2473, "current regulation mode.  (+= turn motor in right direction; -=")
    cite("TMCM-1640", 2497, "Bit 11: Torque mode active flag.")
    w = witness("TMCM-1640")
    w.sap(155, -800)
    flags = w.gap(156)
    assert flags >> 11 & 1 and not flags >> 9 & 1 and not flags >> 10 & 1
    assert w.gap(155) == -800 and w.gap(150) == -800
    assert w.until(lambda: w.gap(3) < 0)  # "-: turn motor in left direction"
    w.iface.move_to(0, 0)
    flags = w.gap(156)
    assert flags >> 10 & 1 and not flags >> 11 & 1


def test_1640_supply_and_driver_temperature_are_what_gio_reads(witness):
    cite("TMCM-1640", 1491, "GIO 4, 1   (VSupply)")
    cite("TMCM-1640", 1493, "GIO 5, 1      (Temp)")
    cite("TMCM-1640", 2465, "151 Actual voltage Actual supply voltage.")
    cite("TMCM-1640", 3737, "Axis parameter 152 delivers the actual ADC value of the motor driver.")
    w = witness("TMCM-1640")
    assert w.gap(151) == w.gio(4, 1) > 0
    assert w.gap(152) == w.gio(5, 1) > 0
    w.sim.set_input(1, 4, 2000)
    w.sim.set_input(1, 5, 1000)
    assert (w.gap(151), w.gap(152)) == (w.gio(4, 1), w.gio(5, 1)) == (2000, 1000)


def test_1640_ramp_switched_off_reaches_the_speed_at_once(witness):
    cite("TMCM-1640", 3599, "activated/deactivated by axis parameter 146")
    cite("TMCM-1640", 3605, "disabled to support motor positioning with max allowed speed.")
    w = witness("TMCM-1640")
    w.sap(11, 100)  # 100 rpm/s: a ramp to 3000 rpm would take 30 s of module time
    w.iface.rotate(0, 3000)
    assert 0 <= w.gap(3) < 3000
    w.iface.stop(0)
    w.sap(146, 0)
    w.iface.rotate(0, 3000)
    assert w.gap(3) == 3000
    w.iface.move_to(0, w.gap(1) + 100000)
    assert w.gap(3) == w.gap(4)  # positioning at the maximum speed, no ramp up


def test_1640_hall_angle_and_current_while_turning(witness):
    cite("TMCM-1640", 2624, "210 Actual hall angle Actual hall angle value -32767… +32767 R")
    cite("TMCM-1640", 2459, "Get actual motor current.")
    w = witness("TMCM-1640")
    w.sap(4, 50)
    w.iface.rotate(0, 50)
    angles, currents = set(), set()
    for _ in range(40):
        angles.add(w.gap(210))
        currents.add(w.gap(150))
        time.sleep(0.005)
    assert len(angles) > 1 and all(-32767 <= a <= 32767 for a in angles)
    assert 0 not in currents  # a turning motor draws current
    w.iface.stop(0)
    w.until(lambda: w.gap(3) == 0)
    assert w.gap(150) == 0


# -- what help says ------------------------------------------------------------------------------

def test_help_says_which_values_are_simulated_and_what_rfs_status_means(run_tmclsh):
    cite("TMCM-1311", 2001, "100 – OK 0 ref. search active")
    r = run_tmclsh("--sim", "-c", "help 206\nhelp 153\nhelp RFS")
    assert r.returncode == 0, r.stderr
    out = " ".join(r.stdout.split())
    assert "simulator Simulated: an unloaded motor" in out
    assert "same as GIO 8, 1 (SupplyVoltage)" in out
    assert ("On the TMCM-1311, RFS STATUS answers 0 when no reference search is running and "
            "another value while one runs") in out
    r = run_tmclsh("--sim", "TMCM-351", "-c", "help RFS")
    assert "On the TMCM-1311" not in r.stdout  # other modules keep the common note
