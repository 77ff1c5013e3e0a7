"""What every parameter of the simulated module reads, where it is not simply what was written.

The manuals relate many values to others: a read-out and the I/O port that measures the same
quantity (TMCM-1311 AP 153 and GIO 8, 1), a maximum derived from two settings (AP 15 from AP 6
and AP 179), a status bit and the mode it names (AP 18 bit 5, AP 128 = 2), a flag that follows
a state machine (AP 132/133). Each such value is computed here, once, from the model's state
(the axes, the parameter store, the I/O levels and the module clock), and every view of it
(GAP, GIO, a status bit, a stored program) reads that one computation, so they cannot drift
apart. The other direction lives here too: what the parameters allow the motion to do right
now (``limits``: speed, ramp, switches, driver on or off).

Behaviour is attached to parameters by name, never by number: a rule applies to every module
whose data file has the names it needs. Where the simulator models nothing (winding currents
under load, temperature drift, an encoder's own signals) it answers a plausible steady value
and says so: every rule carries a sentence for users, which ``help`` and ``.param --source``
show beside the manual's text (``simulated_notes``). A value that cannot be 0 on a powered
module (its supply voltage, its temperature, the current in a driven motor) never reads 0.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from ..tmcl.frames import Status
from ..tmcl.modules import Module
from .model import AXIS, IoState, Live, ParamStore
from .motion import Axis, Limits, Mode, Units

# -- the simulated hardware (what a bench module would have attached) -----------------------
# The TMCM-1311 manual's closed-loop example (§8.11.1) runs "an encoder with 40000 increments
# per rotation" on a motor with 200 full steps (AP 202's default): that is the simulated one.
ENCODER_INCREMENTS = 40000
ENCODER_INIT_TIME = 0.5  # s of module time the automatic encoder initialisation (AP 132) takes
CLOSED_LOOP_INIT_TIME = 0.2  # s until the closed loop is ready (AP 133) after AP 129 = 1
QUIESCENT_MA = 40  # mA a powered stepper module draws with its motor at rest, besides the motor
BLDC_NO_LOAD_MA = 200  # mA an unloaded BLDC motor draws turning at a steady speed
BLDC_ACCEL_MA = 1000  # mA it draws while the ramp speeds it up or slows it down
ANGLE_FULL_TURN = 65536  # TMCM-1640 AP 210-212: one electrical turn, read as -32767..32767
HALL_SECTORS = 6  # hall sensors: six commutation steps per electrical turn (3 x poles per turn)

Getter = Callable[[Axis, int], int]
Setter = Callable[[Axis, int, int], int]


@dataclass
class _Init:
    """A timed start-up of one axis (encoder initialisation, closed loop): when it is done."""

    done_at: float
    ok: bool = True
    applied: bool = False  # its result written where the module keeps it


def _wrap32(value: int) -> int:
    return (value + 2**31) % 2**32 - 2**31


def _angle(turns: float) -> int:
    """An electrical angle in turns as the module reads it: -32767..32767 a turn."""
    value = round(turns * ANGLE_FULL_TURN) % ANGLE_FULL_TURN
    value = value - ANGLE_FULL_TURN if value >= ANGLE_FULL_TURN // 2 else value
    return max(value, -(ANGLE_FULL_TURN // 2 - 1))


def _max(store: ParamStore, name: str) -> int:
    p = store.by_name(AXIS, name)
    return 0 if p is None or p.max is None else p.max


def _motor_fullsteps(store: ParamStore) -> int:
    """The simulated motor's full steps a turn: the default of the module's AP 202."""
    p = store.by_name(AXIS, "MotorResolution")
    return p.default if p is not None and p.default else 200


def simulated_notes(module: Module) -> dict[tuple[str, str], str]:
    """``(kind, name) -> sentence``: what the simulator does for each parameter it derives or
    invents on ``module`` (for ``help``/``.param``); built on a model of its own, no device."""
    key = (module.name, module.source, id(module))
    if key not in _NOTES:
        _NOTES[key] = _notes(module)
    return _NOTES[key]


_NOTES: dict[tuple[str, str, int], dict[tuple[str, str], str]] = {}


def _notes(module: Module) -> dict[tuple[str, str], str]:
    store = ParamStore(module)
    derived = Derived(module, store, IoState(module), [Axis() for _ in range(module.motors)],
                      lambda: 0.0)
    return dict(derived.notes)


class Derived:
    """The parameters of one simulated module that are read from its state (see the module
    docstring); ``register`` routes them into the store, ``limits`` feeds the motion."""

    def __init__(self, module: Module, store: ParamStore, io: IoState, axes: list[Axis],
                 clock: Callable[[], float]):
        self.module, self.store, self.io, self.axes = module, store, io, axes
        self.clock = clock
        self.units = Units(module)
        self.notes: dict[tuple[str, str], str] = {}
        self._encoder_init: dict[int, _Init] = {}
        self._closed_loop: dict[int, _Init] = {}
        self._encoder_offset = [0] * module.motors
        self._register()
        for key, value in store.assumed.items():
            self.notes.setdefault(key, f"Starts at {value} in the simulator, a start value "
                                       "of its own: the module's data names none.")

    # -- reading the store ----------------------------------------------------------------
    def has(self, *names: str) -> bool:
        return all(self.store.has(AXIS, n) for n in names)

    def get(self, name: str, motor: int, default: int = 0) -> int:
        return self.store.get(AXIS, name, motor, default)

    def _ram(self, name: str, motor: int) -> int:
        """A parameter's stored value, past its live getter (the setting behind a state)."""
        p = self.store.by_name(AXIS, name)
        return 0 if p is None else self.store.ram.get((AXIS, motor, p.number), 0)

    def _set_ram(self, name: str, motor: int, value: int) -> None:
        self.store.set_raw(AXIS, name, value, motor)

    # -- units and limits -----------------------------------------------------------------
    def _getter(self, motor: int) -> Callable[[str], int]:
        return lambda name: self.get(name, motor)

    def vscale(self, motor: int) -> float:
        return self.units.velocity(self._getter(motor))

    def ascale(self, motor: int) -> float:
        return self.units.acceleration(self._getter(motor))

    def steps_per_turn(self, motor: int) -> float:
        """Position units per mechanical turn of a BLDC motor (encoder or hall steps)."""
        return Units._steps_per_rev(self._getter(motor))

    def limits(self, motor: int) -> Limits:
        get = self._getter(motor)
        vs = self.vscale(motor)
        accel_units = get("MaxAcceleration") if self.store.has(AXIS, "MaxAcceleration") \
            else get("Acceleration")
        # TMCM-1640 AP 146 = 0: "disabled to support motor positioning with max allowed
        # speed" (§7.5), in position and velocity mode: no ramp
        ramp = not self.has("ActivateRamp") or get("ActivateRamp") != 0
        accel = accel_units * self.ascale(motor) if accel_units and ramp else math.inf
        vmax = get("MaxPositioningSpeed") * vs
        search = abs(get("ReferenceSearchSpeed")) * vs or vmax
        switch = abs(get("ReferenceSwitchSpeed")) * vs or vmax / 4
        return Limits(vmax=vmax, accel=accel, stop_left=self._stop_enabled(motor, 0),
                      stop_right=self._stop_enabled(motor, 1), search_speed=search,
                      switch_speed=switch, driver=self.driver_on(motor))

    def driver_on(self, motor: int) -> bool:
        """TMCM-1640 AP 255 "Enable or disable the driver": a disabled driver turns nothing."""
        return not self.has("EnableDriver") or self._ram("EnableDriver", motor) != 0

    def _stop_enabled(self, motor: int, bit: int) -> bool:
        name = ("LeftLimitSwitchDisable", "RightLimitSwitchDisable")[bit]
        if self.store.has(AXIS, name):
            return not self.get(name, motor)
        if self.store.has(AXIS, "StopSwitchEnable"):
            return bool(self.get("StopSwitchEnable", motor) >> bit & 1)
        return False

    def wrap_position(self, value: float) -> int:
        lo, hi = self.module.position_min, self.module.position_max
        span = hi - lo + 1
        return (int(round(value)) - lo) % span + lo

    # -- registration -----------------------------------------------------------------------
    def _axis(self, name: str, get: Getter, set_: Setter | None = None, *,
              note: str | None = None, accept: bool = False) -> bool:
        """Route axis parameter ``name`` (when the module has it) to ``get``/``set_``;
        ``accept``: a write is accepted without lasting effect. Returns whether it exists."""
        if not self.store.has(AXIS, name):
            return False
        axes = self.axes
        setter = None
        if set_ is not None:
            setter = lambda m, v: set_(axes[m], m, v)  # noqa: E731
        elif not accept:
            setter = self._keep(name)
        self.store.add_live(AXIS, name, Live(lambda m: get(axes[m], m), setter))
        if note:  # under the module's own name, which help looks it up by
            own = self.store.by_name(AXIS, name)
            self.notes[(AXIS, own.name if own is not None else name)] = note
        return True

    def _keep(self, name: str) -> Callable[[int, int], int]:
        """A write that is stored as written (the getter reads something else meanwhile)."""
        def set_(m: int, v: int) -> int:
            self._set_ram(name, m, v)
            return Status.OK
        return set_

    def _register(self) -> None:
        self._register_motion()
        self._register_modes()
        self._register_status_words()
        self._register_io_readouts()
        self._register_stepper_currents()
        self._register_stall_guard()
        self._register_encoder()
        self._register_torque()
        self._register_bldc()

    # -- the motion state, in module units ----------------------------------------------------
    def _register_motion(self) -> None:
        def move(a: Axis, m: int, v: int) -> int:
            a.move_to(v)
            return Status.OK

        def set_pos(a: Axis, m: int, v: int) -> int:
            a.set_position(v)
            return Status.OK

        def set_speed(a: Axis, m: int, v: int) -> int:
            a.rotate(v * self.vscale(m), v)
            return Status.OK

        def target_speed(a: Axis, m: int) -> int:
            """Velocity mode: as commanded. Position mode: "set by hardware: during
            acceleration to maximum speed, during deceleration and rest to zero" (TMCM-1311
            AP 2)."""
            if a.mode == Mode.VELOCITY and not a.rfs:
                return a.target_vel_units
            if a.mode == Mode.TORQUE:
                return int(round(a.target_vel / self.vscale(m)))
            if not a.moving or a.accel_now * a.vel < 0:
                return 0
            vmax_units = self.get("MaxPositioningSpeed", m)
            return vmax_units if a.target_pos >= a.pos else -vmax_units

        position = lambda a, m: self.wrap_position(a.pos)  # noqa: E731
        for name, get, set_ in (
                ("TargetPosition", lambda a, m: a.target_pos, move),
                ("ActualPosition", position, set_pos),
                ("TargetSpeed", target_speed, set_speed)):
            self._axis(name, get, set_)
        self._axis("VirtualActualPosition", position, accept=True)
        for name in ("ActualSpeed", "MeasuredSpeed", "RampGeneratorSpeed"):
            self._axis(name, self.speed_units, accept=True)
        self._axis("ActualAcceleration",
                   lambda a, m: int(round(abs(a.accel_now) / self.ascale(m)))
                   if math.isfinite(a.accel_now) else 0, accept=True)
        self._axis("TargetPositionReached", lambda a, m: int(a.reached), accept=True)
        self._axis("ReferenceSwitchStatus", lambda a, m: int(a.switch("ref")), accept=True)
        self._axis("RightLimitSwitchStatus", lambda a, m: int(a.switch("right")), accept=True)
        self._axis("LeftLimitSwitchStatus", lambda a, m: int(a.switch("left")), accept=True)
        self._axis("VelocityReached", lambda a, m: int(self.velocity_reached(a, m)),
                   accept=True)

    def speed_units(self, a: Axis, m: int) -> int:
        """The actual speed in the module's units, as AP 3 reads it."""
        return int(round(a.vel / self.vscale(m)))

    def velocity_reached(self, a: Axis, m: int) -> bool:
        """Compared in the module's units, as AP 3 reads them: when the actual speed reads
        as the target speed, the target speed is reached."""
        vs = self.vscale(m)
        actual = int(round(a.vel / vs))
        target = int(round(a.target_vel / vs)) if a.mode != Mode.POSITION else actual
        return abs(actual - target) <= self.get("VelocityReachedWindow", m)

    def position_end(self, a: Axis, m: int) -> bool:
        """At the target: exactly (TMCM-1311 AP 8), or where the module's data gives a window
        (TMCM-1640 AP 10 distance and AP 7 speed: "no target-reached while passing")."""
        if a.mode != Mode.POSITION or a.rfs:
            return False
        if not self.has("TargetReachedDistance"):
            return a.reached
        near = abs(a.target_pos - a.pos) <= self.get("TargetReachedDistance", m)
        slow = abs(self.speed_units(a, m)) <= self.get("TargetReachedVelocity", m)
        return near and slow

    # -- modes ------------------------------------------------------------------------------
    def _mode_value(self, text: str) -> int | None:
        """The RampMode value whose name contains ``text`` (the numbers differ per module:
        TMCM-1311 1 = velocity, TMCM-351 2 = velocity)."""
        p = self.store.by_name(AXIS, "RampMode")
        if p is None:
            return None
        return next((n for n, t in p.values.items() if text in t.lower()), None)

    def _register_modes(self) -> None:
        if not self.has("RampMode"):
            return
        velocity = self._mode_value("velocity")
        position = self._mode_value("position") or 0
        torque = self._mode_value("torque")

        def get(a: Axis, m: int) -> int:
            if a.mode == Mode.TORQUE and torque is not None:
                return torque
            return velocity if a.mode == Mode.VELOCITY and velocity is not None else position

        def set_(a: Axis, m: int, v: int) -> int:
            if v == velocity:
                a.rotate(a.target_vel if a.mode != Mode.TORQUE else 0.0,
                         a.target_vel_units)
            elif v == position:
                a.move_to(a.target_pos)
            elif v == torque:
                self.enter_torque(a, m, a.target_current)
            return Status.OK  # other modes (soft) are accepted and not modelled

        self._axis("RampMode", get, set_, note=(
            "Follows the motion: the mode the last motion command (or a torque target "
            "current) put the motor in." if torque is not None else None))

    # -- status words: each bit the mode or state it names ------------------------------------
    def _register_status_words(self) -> None:
        for name in ("StatusWord", "StatusFlags"):
            p = self.store.by_name(AXIS, name)
            if p is not None and p.bits:
                get, modelled = self._status_word(p.bits)
                quiet = sorted(set(p.bits) - modelled)
                self._axis(name, get, accept=True, note=(
                    "Each bit follows the state it names (target reached, modes, switches, "
                    + ("driver off, " if self.has("EnableDriver") else "")
                    + "...)" + (f"; bits {', '.join(map(str, quiet))} (errors and warnings "
                                "the simulator does not model) stay 0." if quiet else ".")))

    def _status_word(self, bits: dict[int, str]) -> tuple[Getter, set[int]]:
        """A status word getter from the bit names in the data file, and the bits it sets."""
        probes: list[tuple[int, Callable[[Axis, int], bool]]] = []
        for bit, text in bits.items():
            t = text.lower()
            probe: Callable[[Axis, int], bool] | None = None
            if t.startswith("target reached") or t.startswith("position end"):
                probe = self.position_end
            elif t.startswith("velocity reached"):
                probe = self.velocity_reached
            elif t.startswith("position mode"):
                probe = lambda a, m: a.mode == Mode.POSITION  # noqa: E731
            elif t.startswith("velocity mode"):
                probe = lambda a, m: a.mode == Mode.VELOCITY  # noqa: E731
            elif t.startswith("torque mode"):
                probe = lambda a, m: a.mode == Mode.TORQUE  # noqa: E731
            elif t.startswith("closed loop mode"):
                probe = lambda a, m: bool(self.closed_loop_ready(m))  # noqa: E731
            elif t.startswith("home switch"):
                probe = lambda a, m: a.switch("ref")  # noqa: E731
            elif t.startswith("left stop switch"):
                probe = lambda a, m: a.switch("left")  # noqa: E731
            elif t.startswith("right stop switch"):
                probe = lambda a, m: a.switch("right")  # noqa: E731
            elif t.startswith("motor halted"):
                probe = self.halted
            elif t.startswith("module initialized"):
                probe = lambda a, m: True  # noqa: E731
            if probe is not None:
                probes.append((bit, probe))

        def get(a: Axis, m: int) -> int:
            return sum(1 << bit for bit, probe in probes if probe(a, m))

        return get, {bit for bit, _ in probes}

    def halted(self, a: Axis, m: int) -> bool:
        """TMCM-1640 AP 156 bit 4 "motor halted: motor has been switched off", and AP 9: "set
        while the actual speed is below this value"."""
        if not self.driver_on(m):
            return True
        return abs(self.speed_units(a, m)) < self.get("MotorHaltedVelocity", m)

    # -- read-outs of the same quantity an input port measures --------------------------------
    def _register_io_readouts(self) -> None:
        """A parameter whose data names an analog input (``io``) reads what GIO reads there:
        the one value, live where a rule here computes it, else the port's level."""
        for p in self.module.axis_params:
            if p.io is None:
                continue
            port = next(q for q in self.module.io if q.name == p.io and q.kind == "analog_in")
            key = (port.bank, port.port)
            rule = self._io_rules().get(p.name)
            if rule is not None:
                get = rule
                self.io.live[key] = lambda get=get: get(self.axes[0], 0)
            else:
                get = lambda a, m, key=key: self.io.get(*key)  # noqa: E731
            self._axis(p.name, get, accept=True, note=(
                f"The same quantity GIO {port.port}, {port.bank} ({port.name}) reads"
                + (": " + self._io_notes()[p.name] if p.name in self._io_notes() else
                   f": a steady {self.io.get(*key)}{' ' + port.unit if port.unit else ''} "
                   "in the simulator.")))

    def _io_rules(self) -> dict[str, Getter]:
        rules: dict[str, Getter] = {}
        if self.has("PhaseACurrent", "PhaseBCurrent"):
            rules["PhaseACurrent"] = lambda a, m: self.phase_currents(a, m)[0]
            rules["PhaseBCurrent"] = lambda a, m: self.phase_currents(a, m)[1]
            rules["DCCurrent"] = self.dc_current
        return rules

    def _io_notes(self) -> dict[str, str]:
        wave = ("the simulated motor's sine-wave current: its peak is the current scale in "
                "use (AP 6 running, AP 200 while accelerating if set, AP 7 after the power "
                "down delay) at the position's microstep.")
        return {"PhaseACurrent": wave, "PhaseBCurrent": wave,
                "DCCurrent": f"simulated: {QUIESCENT_MA} mA for the module plus a quarter of "
                             "the motor's RMS current."}

    # -- a stepper's currents (TMCM-1311 AP 6/7/15/150-154/179/200/214) ------------------------
    def current_rms(self, scale: int, motor: int) -> int:
        """mA RMS for a current scale (AP 6/7/200, 0..255) at the sense range (AP 179): 32
        steps of (CS + 1)/32 of full scale (AP 15's maximum; Vsense 1 halves the range)."""
        p_scale = self.store.by_name(AXIS, "MaxCurrent")
        p_full = self.store.by_name(AXIS, "MaxPossibleCurrent")
        if p_scale is None or p_full is None or p_scale.max is None or p_full.max is None:
            return 0
        per_step = (p_scale.max + 1) // 32
        full = p_full.max >> (1 if self.get("Vsense", motor) else 0)
        return round((scale // per_step + 1) * full / 32)

    def scale_now(self, a: Axis, m: int) -> int:
        """The current scale driving the motor now: run, boost while accelerating, standby
        once it has been at rest for the power down delay (AP 214, in 10 ms)."""
        if a.moving:
            boost = self.get("BoostCurrent", m)
            return boost if boost and a.accelerating else self.get("MaxCurrent", m)
        delay = self.get("PowerDownDelay", m) / 100.0
        if a.still_since is not None and self.clock() - a.still_since < delay:
            return self.get("MaxCurrent", m)
        return self.get("StandbyCurrent", m)

    def phase_currents(self, a: Axis, m: int) -> tuple[int, int]:
        """Coil A and B peak-scaled currents (mA) at the motor's microstep position."""
        peak = self.current_rms(self.scale_now(a, m), m) * math.sqrt(2)
        microsteps = 2 ** self.get("MicrostepResolution", m)
        theta = 2 * math.pi * (a.pos % (4 * microsteps)) / (4 * microsteps)
        return round(peak * math.sin(theta)), round(peak * math.cos(theta))

    def dc_current(self, a: Axis, m: int) -> int:
        return QUIESCENT_MA + self.current_rms(self.scale_now(a, m), m) // 4

    def _register_stepper_currents(self) -> None:
        if not self.has("MaxCurrent", "MaxPossibleCurrent"):
            return
        self._axis("MaxPossibleCurrent",
                   lambda a, m: self.current_rms(self.get("MaxCurrent", m), m), accept=True,
                   note="Derived from AP 6 (current scale) and AP 179 (sense range): "
                        "(CS + 1)/32 of 3000 mA, or of 1500 mA with Vsense = 1, where CS is "
                        "AP 6 in 32 steps of 8.")
        if self.has("MotorCurrent", "PhaseACurrent", "PhaseBCurrent"):
            self._axis("MotorCurrent",
                       lambda a, m: round(math.hypot(*self.phase_currents(a, m))), accept=True,
                       note="sqrt(AP 151² + AP 152²) of the simulated phase currents: the "
                            "peak of the current scale in use.")

    # -- stallGuard2 (TMCM-1311 AP 174/181/206/208) --------------------------------------------
    def _register_stall_guard(self) -> None:
        if not self.has("ActualLoadValue", "StopOnStall"):
            return
        load = self.store.by_name(AXIS, "ActualLoadValue")
        steady = ((load.max or 0) + 1) // 2
        self._axis("ActualLoadValue", lambda a, m: steady, accept=True, note=(
            f"Simulated: an unloaded motor, {steady} (half the range) at any speed. It never "
            "reaches 0 (maximum load), so stop on stall (AP 181) never stops it."))
        flags = self.store.by_name(AXIS, "DriverErrorFlags")
        if flags is not None and flags.bits:
            standstill = [b for b, t in flags.bits.items() if t.lower().startswith("standstill")]
            self._axis("DriverErrorFlags", lambda a, m: sum(
                1 << b for b in standstill if not a.moving), accept=True, note=(
                "The standstill bit follows the motor; the error bits (overtemperature, short, "
                "open load, stallGuard2) stay 0: the simulated motor is sound and unloaded."))
        self._axis("SmartEnergyActualCurrent", lambda a, m: _max(self.store, "SmartEnergyActualCurrent"),
                   accept=True, note="coolStep is not simulated: the full current scale.")

    # -- encoder and closed loop (TMCM-1311 AP 129/132/133/202/209/210) --------------------------
    def encoder_counts(self, a: Axis, m: int) -> int:
        """The simulated encoder: ENCODER_INCREMENTS per turn of the simulated motor."""
        microsteps = 2 ** self.get("MicrostepResolution", m)
        turns = a.pos / (_motor_fullsteps(self.store) * microsteps)
        return round(turns * ENCODER_INCREMENTS)

    def encoder_state(self, m: int) -> int:
        """AP 132 read-out: 0 none, 1 in process, 2 completed, 3 incorrect (000:4708-4718)."""
        init = self._encoder_init.get(m)
        if init is None:
            return 0
        if not init.ok:
            return 3
        if self.clock() < init.done_at:
            return 1
        return 2

    def closed_loop_ready(self, m: int) -> int:
        init = self._closed_loop.get(m)
        return int(init is not None and init.ok and self.clock() >= init.done_at)

    def _register_encoder(self) -> None:
        if self.has("EncoderInitialization"):
            def start(a: Axis, m: int, v: int) -> int:
                if v == 0:
                    self._encoder_init.pop(m, None)
                elif v == 1:
                    fullsteps = self.get("MotorResolution", m)
                    self._encoder_init[m] = _Init(self.clock() + ENCODER_INIT_TIME,
                                                  ok=fullsteps > 0)
                return Status.OK  # 2 and 3 are read-outs: accepted, nothing starts

            self._axis("EncoderInitialization", lambda a, m: self.encoder_state(m), start,
                       note=(f"Simulated: writing 1 takes {ENCODER_INIT_TIME:g} s (1, in "
                             "process), then reads 2 (completed) and sets AP 210 to the "
                             f"simulated encoder's {ENCODER_INCREMENTS} increments per turn "
                             "(scaled by AP 202 against the motor's 200 full steps); 3 when "
                             "AP 202 is 0."))
        if self.has("EncoderResolution"):
            def resolution(a: Axis, m: int) -> int:
                init = self._encoder_init.get(m)
                if init is not None and init.ok and not init.applied \
                        and self.clock() >= init.done_at:
                    found = round(ENCODER_INCREMENTS * self.get("MotorResolution", m)
                                  / _motor_fullsteps(self.store))
                    self._set_ram("EncoderResolution", m, found)
                    init.applied = True
                return self._ram("EncoderResolution", m)

            self._axis("EncoderResolution", resolution)
        if self.has("ClosedLoopMode", "ClosedLoopInitFlag"):
            def switch(a: Axis, m: int, v: int) -> int:
                self._set_ram("ClosedLoopMode", m, v)
                if v:
                    ready = (self.get("EncoderResolution", m) > 0
                             and self.get("MotorResolution", m) > 0)
                    self._closed_loop[m] = _Init(self.clock() + CLOSED_LOOP_INIT_TIME, ready)
                else:
                    self._closed_loop.pop(m, None)
                    if a.mode == Mode.TORQUE:  # "cannot be used in open loop mode"
                        a.stop()
                return Status.OK

            self._axis("ClosedLoopMode", lambda a, m: self._ram("ClosedLoopMode", m), switch)
            self._axis("ClosedLoopInitFlag", lambda a, m: self.closed_loop_ready(m),
                       accept=True, note=(
                           f"Becomes 1 {CLOSED_LOOP_INIT_TIME:g} s after AP 129 = 1 when the "
                           "encoder resolution (AP 210) and motor full steps (AP 202) are "
                           "set; 0 in open loop. The position still counts microsteps in "
                           "the simulator."))
        if self.has("EncoderCounter"):
            def set_counter(a: Axis, m: int, v: int) -> int:
                self._encoder_offset[m] = v - self.encoder_counts(a, m)
                return Status.OK

            self._axis("EncoderCounter", lambda a, m: _wrap32(
                self.encoder_counts(a, m) + self._encoder_offset[m]), set_counter,
                note=f"Simulated: an encoder of {ENCODER_INCREMENTS} increments per turn on "
                     "a motor of 200 full steps, counting with the motor's position.")

    # -- torque mode (TMCM-1311 AP 14/19, TMCM-1640 AP 155) -------------------------------------
    def enter_torque(self, a: Axis, m: int, current: int) -> None:
        """Torque mode at ``current`` mA: the unloaded motor speeds up toward the speed limit
        (AP 4) in the current's direction; at 0 it slows to a stop."""
        sign = (current > 0) - (current < 0)
        a.torque(sign * self.get("MaxPositioningSpeed", m) * self.vscale(m), current)

    def _register_torque(self) -> None:
        torque_note = ("Simulated as an unloaded motor: it turns in the current's direction, "
                       "speeding up to the maximum positioning speed (AP 4).")
        if self.has("TorqueModeTargetCurrent"):
            def set_target(a: Axis, m: int, v: int) -> int:
                if self.closed_loop_ready(m):  # "In closed loop mode only" (AP 128 = 2)
                    self.enter_torque(a, m, v)
                else:
                    a.target_current = v
                return Status.OK

            self._axis("TorqueModeTargetCurrent",
                       lambda a, m: a.target_current if a.mode == Mode.TORQUE else 0,
                       set_target, note="Writing it in closed loop mode switches to torque "
                       "mode (AP 128 = 2, status word bit 5); in open loop the value is held "
                       "and nothing moves. Outside torque mode it reads the advance angle, "
                       "which the simulator does not model (0). " + torque_note)
            self._axis("TorqueModeActualCurrent",
                       lambda a, m: a.target_current if a.mode == Mode.TORQUE else 0,
                       accept=True, note="The torque mode current ramp (AP 20, 141) is not "
                       "simulated: the target current at once in torque mode, else 0.")
        if self.has("TargetCurrent"):
            def set_current(a: Axis, m: int, v: int) -> int:
                self.enter_torque(a, m, v)
                return Status.OK

            self._axis("TargetCurrent",
                       lambda a, m: a.target_current if a.mode == Mode.TORQUE
                       else self.bldc_current(a, m), set_current,
                       note="Writing it switches to torque mode (AP 156 bit 11). Outside "
                            "torque mode it reads the current the regulators ask for: the "
                            "actual motor current (AP 150). " + torque_note)

    # -- a BLDC motor (TMCM-1640 AP 150/210-212/255) --------------------------------------------
    def bldc_current(self, a: Axis, m: int) -> int:
        """Signed motor current (mA): the target in torque mode; an unloaded motor's draw
        while it turns (more while the ramp changes its speed); 0 at rest or switched off."""
        if not self.driver_on(m):
            return 0
        if a.mode == Mode.TORQUE:
            return a.target_current
        if a.accelerating:
            return BLDC_ACCEL_MA if a.accel_now * a.vel > 0 else -BLDC_ACCEL_MA
        if a.vel != 0.0:
            return BLDC_NO_LOAD_MA if a.vel > 0 else -BLDC_NO_LOAD_MA
        return 0

    def electrical_angle(self, a: Axis, m: int) -> float:
        """The rotor's electrical angle in turns (0..1): mechanical turns times pole pairs."""
        turns = a.pos / self.steps_per_turn(m)
        return (turns * max(self.get("MotorPoles", m) // 2, 1)) % 1.0

    def hall_angle(self, a: Axis, m: int) -> int:
        sector = math.floor(self.electrical_angle(a, m) * HALL_SECTORS)
        return _angle(sector / HALL_SECTORS)

    def _register_bldc(self) -> None:
        if self.has("ActualMotorCurrent"):
            self._axis("ActualMotorCurrent", self.bldc_current, accept=True, note=(
                f"Simulated: the target current in torque mode; turning at a steady speed an "
                f"unloaded motor's {BLDC_NO_LOAD_MA} mA, {BLDC_ACCEL_MA} mA while the ramp "
                "changes its speed (signed by the direction); 0 at rest or with the driver "
                "off."))
        angle_note = ("Simulated from the motor's position: one electrical turn (65536) per "
                      "AP 253 / 2 of a mechanical one")
        self._axis("ActualHallAngle", self.hall_angle, accept=True,
                   note=angle_note + ", in the hall sensors' six sectors.")
        self._axis("ActualEncoderAngle",
                   lambda a, m: _angle(self.electrical_angle(a, m)), accept=True,
                   note=angle_note + ".")
        commutation = self.store.by_name(AXIS, "CommutationMode")
        encoder_modes = {n for n, t in (commutation.values.items() if commutation else ())
                         if "encoder" in t.lower() or "controlled" in t.lower()}
        self._axis("ActualControlledAngle", lambda a, m: (
            _angle(self.electrical_angle(a, m))
            if self.get("CommutationMode", m) in encoder_modes else self.hall_angle(a, m)),
            accept=True, note=angle_note + ": the encoder angle in encoder and controlled "
            "commutation, else the hall angle.")
        if self.has("EnableDriver"):
            def enable(a: Axis, m: int, v: int) -> int:
                self._set_ram("EnableDriver", m, v)
                if not v:  # "disable the driver and switch to stop mode": it coasts to rest
                    a.stop()
                    a.vel = a.accel_now = 0.0
                return Status.OK

            self._axis("EnableDriver", lambda a, m: self._ram("EnableDriver", m), enable,
                       note="With the driver disabled the motor does not turn: motion "
                            "commands are taken, and it moves once the driver is enabled.")
