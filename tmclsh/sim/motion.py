"""Axis physics: trapezoidal ramps, switches and the reference search, integrated exactly.

Time is advanced in segments of constant acceleration that end at the next event (target
speed reached, braking point, target reached, a switch crossed), so a move lands exactly on
its target and stops exactly at a switch however large the time step is. That is what lets
the simulator run its clock many times faster than real time (``Simulator(speed=...)``)
without losing accuracy.

Everything here is in position units (µsteps, encoder or hall steps) and seconds; the
conversion from a module's velocity and acceleration units is ``Units`` (a swappable hook, as
pymodbus keeps device behaviour in an ``action`` callback).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import IntEnum

from ..tmcl.modules import Module

EPS_T = 1e-12  # seconds: shorter segments count as zero
MAX_SEGMENTS = 64  # per advance() call; a safety net against zero-length loops
SWITCHES = ("left", "right", "ref")

TMC428_CLOCK = 16e6  # Hz; the TMCM-351's TMC428 velocity/acceleration unit formulas


class Mode(IntEnum):
    POSITION = 0
    VELOCITY = 1
    TORQUE = 2  # a target current: the unloaded motor speeds up to the speed limit (derived.py)


class RfsPhase(IntEnum):
    IDLE = 0
    LEAVE = 1  # ref switch active at start: move off it first
    SEARCH = 2  # move toward the switch at the search speed
    BACKOFF = 3  # move off it slowly; the release point becomes position 0


def _sign(x: float) -> int:
    return (x > 0) - (x < 0)


class Units:
    """Module velocity/acceleration units -> position units per second (per second).

    Chosen from the data file's ``units.velocity`` text: ``pps`` is 1:1; ``rpm`` uses the
    steps per rotation (encoder steps in encoder commutation, else 3 × motor poles hall
    steps); ``TMC428`` uses the TMC428 formulas with the pulse and ramp divisors.
    """

    def __init__(self, module: Module):
        text = module.units.get("velocity", "").lower()
        self.kind = "rpm" if "rpm" in text else "tmc428" if "tmc428" in text else "pps"

    def velocity(self, get: Callable[[str], int]) -> float:
        if self.kind == "rpm":
            return self._steps_per_rev(get) / 60.0
        if self.kind == "tmc428":
            return TMC428_CLOCK / (2 ** get("PulseDivisor") * 2048 * 32)
        return 1.0

    def acceleration(self, get: Callable[[str], int]) -> float:
        if self.kind == "rpm":
            return self._steps_per_rev(get) / 60.0
        if self.kind == "tmc428":
            return TMC428_CLOCK ** 2 / 2 ** (get("PulseDivisor") + get("RampDivisor") + 29)
        return 1.0

    @staticmethod
    def _steps_per_rev(get: Callable[[str], int]) -> float:
        if get("CommutationMode") == 7 and get("EncoderSteps") > 0:
            return float(get("EncoderSteps"))
        return 3.0 * max(get("MotorPoles"), 2)


@dataclass
class Limits:
    """What the parameters allow right now (position units)."""

    vmax: float
    accel: float  # math.inf: no ramp
    stop_left: bool = True
    stop_right: bool = True
    search_speed: float = 0.0
    switch_speed: float = 0.0
    driver: bool = True  # False: the driver is off (TMCM-1640 AP 255 = 0), the motor holds still


@dataclass
class Switch:
    """A switch input: forced to a level by a test, or derived from a placed position.

    A placed left or reference switch is active at and below its position, a right switch
    at and above it (the switch sits at the end of travel on that side).
    """

    side: str
    forced: bool | None = None
    position: float | None = None

    def active(self, pos: float) -> bool:
        if self.forced is not None:
            return self.forced
        if self.position is None:
            return False
        return pos >= self.position if self.side == "right" else pos <= self.position


@dataclass
class Axis:
    pos: float = 0.0
    vel: float = 0.0
    accel_now: float = 0.0
    mode: Mode = Mode.POSITION
    target_pos: int = 0
    target_vel: float = 0.0  # position units/s (velocity mode)
    target_vel_units: int = 0  # as commanded, for GAP TargetSpeed
    rfs: RfsPhase = RfsPhase.IDLE
    target_current: int = 0  # mA, torque mode
    still_since: float | None = None  # module time the motor came to rest (None: long ago)
    switches: dict[str, Switch] = field(default_factory=lambda: {s: Switch(s) for s in SWITCHES})

    # -- commands ---------------------------------------------------------------------------
    def rotate(self, vel: float, units: int) -> None:
        self.rfs = RfsPhase.IDLE
        self.mode = Mode.VELOCITY
        self.target_vel = vel
        self.target_vel_units = units

    def stop(self) -> None:
        self.rotate(0.0, 0)

    def torque(self, vel: float, current: int) -> None:
        """Torque mode: ``current`` mA; the motor follows ``vel`` (what it reaches unloaded)."""
        self.rfs = RfsPhase.IDLE
        self.mode = Mode.TORQUE
        self.target_vel = vel
        self.target_vel_units = 0
        self.target_current = current

    def move_to(self, target: int) -> None:
        self.rfs = RfsPhase.IDLE
        self.mode = Mode.POSITION
        self.target_pos = target

    def set_position(self, new: float) -> None:
        """Overwrite the position counter; placed switches stay where they physically are."""
        delta = new - self.pos
        was_reached = self.reached
        self.pos = float(new)
        for sw in self.switches.values():
            if sw.position is not None:
                sw.position += delta
        if self.mode == Mode.POSITION and was_reached:
            self.target_pos = int(round(new))

    def start_rfs(self) -> None:
        self.mode = Mode.VELOCITY
        self.target_vel = 0.0
        self.target_vel_units = 0
        self.rfs = RfsPhase.LEAVE if self.switches["ref"].active(self.pos) else RfsPhase.SEARCH

    def stop_rfs(self) -> None:
        if self.rfs:
            self.stop()

    def power_cycle(self) -> None:
        self.set_position(0.0)
        self.vel = 0.0
        self.accel_now = 0.0
        self.rfs = RfsPhase.IDLE
        self.mode = Mode.POSITION
        self.target_pos = 0
        self.target_vel = 0.0
        self.target_vel_units = 0
        self.target_current = 0
        self.still_since = None

    # -- state --------------------------------------------------------------------------------
    @property
    def reached(self) -> bool:
        return self.mode == Mode.POSITION and self.vel == 0.0 and self.pos == self.target_pos

    @property
    def moving(self) -> bool:
        if self.rfs or self.vel != 0.0:
            return True
        if self.mode == Mode.POSITION:
            return self.pos != self.target_pos
        return self.target_vel != 0.0

    @property
    def accelerating(self) -> bool:
        """Speeding up or slowing down (the boost current's time on a stepper)."""
        return self.accel_now != 0.0 and self.vel != 0.0

    def switch(self, which: str) -> bool:
        return self.switches[which].active(self.pos)

    # -- integration --------------------------------------------------------------------------
    def advance(self, dt: float, lim: Limits, now: float | None = None) -> None:
        """Move on by ``dt`` seconds; ``now`` (module time at the end) marks when it stopped."""
        left = dt
        for _ in range(MAX_SEGMENTS):
            if left <= EPS_T:
                break
            left -= self._segment(left, lim)
        else:
            self.accel_now = 0.0  # gave up on a degenerate case: hold still for the rest
        if self.rfs:
            self._rfs_update()
        if self.vel != 0.0 or self.accel_now != 0.0:
            self.still_since = None
        elif self.still_since is None and now is not None:
            self.still_since = now

    def _blocked(self, direction: int, lim: Limits) -> bool:
        if self.rfs or direction == 0:
            return False
        if direction > 0:
            return lim.stop_right and self.switch("right")
        return lim.stop_left and self.switch("left")

    def _segment(self, budget: float, lim: Limits) -> float:
        if not lim.driver:
            return self._hold(budget)
        if self.rfs:
            self._rfs_update()
        if self.mode != Mode.POSITION:
            vt = self._rfs_velocity(lim) if self.rfs else self.target_vel
            return self._velocity_segment(budget, vt, lim)
        return self._position_segment(budget, lim)

    def _hold(self, budget: float) -> float:
        self.vel = 0.0
        self.accel_now = 0.0
        return budget

    def _velocity_segment(self, budget: float, vt: float, lim: Limits) -> float:
        v0 = self.vel
        if self._blocked(_sign(v0), lim):
            v0 = self.vel = 0.0
        if v0 == 0.0 and (vt == 0.0 or self._blocked(_sign(vt), lim)):
            return self._hold(budget)
        if v0 == vt:
            return self._apply(budget, 0.0)
        if math.isinf(lim.accel):
            self.vel = vt
            return 0.0
        if lim.accel <= 0.0:
            return self._apply(budget, 0.0)
        t_reach = abs(vt - v0) / lim.accel
        dur = min(budget, t_reach)
        used = self._apply(dur, math.copysign(lim.accel, vt - v0))
        if used == t_reach:
            self.vel = vt
        return used

    def _position_segment(self, budget: float, lim: Limits) -> float:
        d = self.target_pos - self.pos
        v = self.vel
        if d == 0.0 and v == 0.0:
            return self._hold(budget)
        direction = _sign(d) if d != 0.0 else -_sign(v)
        if self._blocked(_sign(v), lim):
            v = self.vel = 0.0
        if v == 0.0 and self._blocked(direction, lim):
            return self._hold(budget)
        A, vmax = lim.accel, lim.vmax
        if math.isinf(A):
            if vmax <= 0.0:
                return self._hold(budget)
            self.vel = direction * vmax
            t_arrive = abs(d) / vmax
            used = self._apply(min(budget, t_arrive), 0.0)
            if used == t_arrive:
                self._arrive()
            return used
        if A <= 0.0:
            return self._apply(budget, 0.0) if v else self._hold(budget)
        s, dd = abs(v), abs(d)
        if v != 0.0 and _sign(v) != direction:
            t = s / A  # wrong way (or overshoot): stop first
            used = self._apply(min(budget, t), -_sign(v) * A)
            if used == t:
                self.vel = 0.0
            return used
        brake = s * s / (2 * A)
        if s > 0.0 and brake >= dd * (1 - 1e-12) - 1e-9:
            if dd <= 1e-9:
                self._arrive()
                return 0.0
            t = 2 * dd / s  # decelerate exactly onto the target
            used = self._apply(min(budget, t), -direction * s * s / (2 * dd))
            if used == t:
                self._arrive()
            return used
        if s < vmax:
            t1 = (vmax - s) / A
            t2 = (-s + math.sqrt(s * s / 2 + A * dd)) / A
            t = min(t1, t2)
            used = self._apply(min(budget, t), direction * A)
            if used == t1 and t1 <= t2:
                self.vel = direction * vmax
            return used
        if s > vmax:
            t = (s - vmax) / A
            used = self._apply(min(budget, t), -direction * A)
            if used == t:
                self.vel = direction * vmax
            return used
        if vmax <= 0.0:
            return self._hold(budget)
        t = max((dd - brake) / vmax, 0.0)
        return self._apply(min(budget, t), 0.0)

    def _arrive(self) -> None:
        self.pos = float(self.target_pos)
        self.vel = 0.0
        self.accel_now = 0.0

    def _apply(self, dur: float, a: float) -> float:
        """Move for ``dur`` at acceleration ``a``, cut short at the first switch crossing."""
        v0, x0 = self.vel, self.pos
        cut = None
        for sw in self.switches.values():
            if sw.position is None or sw.forced is not None:
                continue
            t = _crossing(x0 - sw.position, v0, a, dur)
            if t is not None and (cut is None or t < cut[0]):
                cut = (t, sw.position)
        if cut is not None:
            dur = cut[0]
        self.pos = x0 + v0 * dur + 0.5 * a * dur * dur
        self.vel = v0 + a * dur
        self.accel_now = a
        if cut is not None:
            self.pos = cut[1]
        return dur

    # -- reference search ---------------------------------------------------------------------
    def _rfs_velocity(self, lim: Limits) -> float:
        if self.rfs == RfsPhase.LEAVE:
            return lim.search_speed
        if self.rfs == RfsPhase.SEARCH:
            return -lim.search_speed
        return lim.switch_speed

    def _rfs_update(self) -> None:
        ref = self.switch("ref")
        if self.rfs == RfsPhase.LEAVE and not ref:
            self.rfs = RfsPhase.SEARCH
            self.vel = 0.0
        elif self.rfs == RfsPhase.SEARCH and ref:
            self.rfs = RfsPhase.BACKOFF
            self.vel = 0.0
        elif self.rfs == RfsPhase.BACKOFF and not ref:
            self.rfs = RfsPhase.IDLE
            self.vel = 0.0
            self.accel_now = 0.0
            self.mode = Mode.POSITION
            self.target_vel = 0.0
            self.target_vel_units = 0
            self.set_position(0.0)
            self.target_pos = 0

    def settle(self) -> None:
        """Apply switch-level changes made from outside (tests) to a running search."""
        if self.rfs:
            self._rfs_update()


def _crossing(x0: float, v: float, a: float, horizon: float) -> float | None:
    """First t in (0, horizon] with x0 + v t + a t²/2 = 0, or None."""
    roots: list[float] = []
    if a == 0.0:
        if v != 0.0:
            roots.append(-x0 / v)
    else:
        disc = v * v - 2 * a * x0
        if disc >= 0.0:
            r = math.sqrt(disc)
            roots += [(-v - r) / a, (-v + r) / a]
    hits = [t for t in roots if EPS_T < t <= horizon]
    return min(hits) if hits else None
