"""What each TMCL instruction does to the simulated module, with the status it answers.

One code path for direct mode (binary and ASCII) and for stored programs: ``execute(ins,
accu)``. ``accu`` is None in direct mode, which never touches the accumulator; inside a
program it is the accumulator, used where the manual says so (``SIO ..., -1``).

Status codes follow the TMCL firmware convention: an unknown or unusable type field
(parameter number, access not allowed, coordinate, port) answers 3 "wrong type"; a
motor/bank, value or address out of range answers 4 "invalid value".
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

from ..tmcl import instructions as isa
from ..tmcl.modules import Module
from ..tmcl.frames import Instruction, Status
from .model import AXIS, GLOBAL, Coordinates, IoState, Live, ParamStore
from .motion import Axis, Limits, Mode, Units

log = logging.getLogger(__name__)

ALL_COORDS_BANK = 255  # SCO/GCO <n>, 255: copy between RAM and EEPROM (TMCM-1311 §5.7.24/25)
MULTI_MOTOR = 0x80  # TMCM-351 MVP COORD motor field: bit 7 = several motors, bits 0-2 = mask

Result = tuple[int, int]  # (status, value)


class Commands:
    def __init__(self, module: Module, store: ParamStore, io: IoState, coords: Coordinates,
                 axes: list[Axis]):
        self.module = module
        self.store = store
        self.io = io
        self.coords = coords
        self.axes = axes
        self.units = Units(module)
        self.handlers: dict[int, Callable[[Instruction, int | None], Result]] = {}
        for name, fn in (
                ("ROR", self._ror), ("ROL", self._rol), ("MST", self._mst), ("MVP", self._mvp),
                ("SAP", self._sap), ("GAP", self._gap), ("STAP", self._stap),
                ("RSAP", self._rsap), ("SGP", self._sgp), ("GGP", self._ggp),
                ("STGP", self._stgp), ("RSGP", self._rsgp), ("RFS", self._rfs),
                ("SIO", self._sio), ("GIO", self._gio), ("SCO", self._sco), ("GCO", self._gco),
                ("CCO", self._cco), ("SAC", self._nothing)):
            spec = isa.by_mnemonic(name)
            if spec is not None:
                self.handlers[spec.opcode] = fn
        for spec in isa.all_instructions():
            if spec.mnemonic.startswith("UF"):
                self.handlers[spec.opcode] = self._nothing
        self._register_live()

    # -- unit conversion and limits -------------------------------------------------------------
    def _get(self, motor: int) -> Callable[[str], int]:
        return lambda name: self.store.get(AXIS, name, motor)

    def vscale(self, motor: int) -> float:
        return self.units.velocity(self._get(motor))

    def ascale(self, motor: int) -> float:
        return self.units.acceleration(self._get(motor))

    def limits(self, motor: int) -> Limits:
        get = self._get(motor)
        vs = self.vscale(motor)
        accel_units = get("MaxAcceleration") if self.store.has(AXIS, "MaxAcceleration") \
            else get("Acceleration")
        accel = accel_units * self.ascale(motor) if accel_units else math.inf
        vmax = get("MaxPositioningSpeed") * vs
        search = abs(get("ReferenceSearchSpeed")) * vs or vmax
        switch = abs(get("ReferenceSwitchSpeed")) * vs or vmax / 4
        return Limits(vmax=vmax, accel=accel, stop_left=self._stop_enabled(motor, 0),
                      stop_right=self._stop_enabled(motor, 1), search_speed=search,
                      switch_speed=switch)

    def _stop_enabled(self, motor: int, bit: int) -> bool:
        name = ("LeftLimitSwitchDisable", "RightLimitSwitchDisable")[bit]
        if self.store.has(AXIS, name):
            return not self.store.get(AXIS, name, motor)
        if self.store.has(AXIS, "StopSwitchEnable"):
            return bool(self.store.get(AXIS, "StopSwitchEnable", motor) >> bit & 1)
        return False

    def wrap_position(self, value: float) -> int:
        lo, hi = self.module.position_min, self.module.position_max
        span = hi - lo + 1
        return (int(round(value)) - lo) % span + lo

    # -- dispatch -------------------------------------------------------------------------------
    def execute(self, ins: Instruction, accu: int | None = None) -> Result:
        spec = isa.by_opcode(ins.opcode)
        if spec is None:
            return Status.INVALID_COMMAND, 0
        if not spec.on(self.module):
            return Status.COMMAND_NOT_AVAILABLE, 0
        handler = self.handlers.get(ins.opcode)
        if handler is None:
            return Status.COMMAND_NOT_AVAILABLE, 0
        return handler(ins, accu)

    def _motor_ok(self, motor: int) -> bool:
        return 0 <= motor < self.module.motors

    # -- motion ---------------------------------------------------------------------------------
    def _rotate(self, ins: Instruction, sign: int) -> Result:
        if not self._motor_ok(ins.motor):
            return Status.INVALID_VALUE, 0
        v = ins.signed_value
        if not self.module.velocity_min <= v <= self.module.velocity_max:
            return Status.INVALID_VALUE, 0
        self.axes[ins.motor].rotate(sign * v * self.vscale(ins.motor), sign * v)
        return Status.OK, 0

    def _ror(self, ins: Instruction, accu: int | None) -> Result:
        return self._rotate(ins, 1)

    def _rol(self, ins: Instruction, accu: int | None) -> Result:
        return self._rotate(ins, -1)

    def _mst(self, ins: Instruction, accu: int | None) -> Result:
        if not self._motor_ok(ins.motor):
            return Status.INVALID_VALUE, 0
        self.axes[ins.motor].stop()
        return Status.OK, 0

    def _mvp(self, ins: Instruction, accu: int | None) -> Result:
        types = isa.by_mnemonic("MVP").type_names(self.module)  # type: ignore[union-attr]
        value = ins.signed_value
        if ins.type == types.get("COORD"):
            motors = [ins.motor]
            if self.module.motors > 1 and ins.motor & MULTI_MOTOR:
                motors = [m for m in range(self.module.motors) if ins.motor >> m & 1]
            if not motors or not all(self._motor_ok(m) for m in motors):
                return Status.INVALID_VALUE, 0
            if not 0 <= value < self.coords.count:
                return Status.INVALID_VALUE, 0
            for m in motors:
                self.axes[m].move_to(self.coords.ram[m][value])
            return Status.OK, 0
        if ins.type not in (types.get("ABS"), types.get("REL")):
            return Status.WRONG_TYPE, 0
        if not self._motor_ok(ins.motor):
            return Status.INVALID_VALUE, 0
        axis = self.axes[ins.motor]
        target = value if ins.type == types["ABS"] else self.wrap_position(axis.pos) + value
        if not self.module.position_min <= target <= self.module.position_max:
            return Status.INVALID_VALUE, 0
        axis.move_to(target)
        return Status.OK, 0

    def _rfs(self, ins: Instruction, accu: int | None) -> Result:
        types = isa.by_mnemonic("RFS").type_names(self.module)  # type: ignore[union-attr]
        if ins.type not in types.values():
            return Status.WRONG_TYPE, 0
        if not self._motor_ok(ins.motor):
            return Status.INVALID_VALUE, 0
        axis = self.axes[ins.motor]
        if ins.type == types["START"]:
            axis.start_rfs()
        elif ins.type == types["STOP"]:
            axis.stop_rfs()
        else:
            return Status.OK, 1 if axis.rfs else 0
        return Status.OK, 0

    # -- parameters -----------------------------------------------------------------------------
    def _sap(self, ins: Instruction, accu: int | None) -> Result:
        if not self._motor_ok(ins.motor):
            return Status.INVALID_VALUE, 0
        return self._echo(self.store.write(AXIS, ins.type, ins.motor, ins.signed_value), ins)

    def _gap(self, ins: Instruction, accu: int | None) -> Result:
        if not self._motor_ok(ins.motor):
            return Status.INVALID_VALUE, 0
        return self.store.read(AXIS, ins.type, ins.motor)

    def _stap(self, ins: Instruction, accu: int | None) -> Result:
        if not self._motor_ok(ins.motor):
            return Status.INVALID_VALUE, 0
        return self.store.store(AXIS, ins.type, ins.motor), 0

    def _rsap(self, ins: Instruction, accu: int | None) -> Result:
        if not self._motor_ok(ins.motor):
            return Status.INVALID_VALUE, 0
        return self.store.restore(AXIS, ins.type, ins.motor), 0

    def _bank_ok(self, bank: int) -> bool:
        return bank in self.module.banks()

    def _sgp(self, ins: Instruction, accu: int | None) -> Result:
        if not self._bank_ok(ins.motor):
            return Status.INVALID_VALUE, 0
        return self._echo(self.store.write(GLOBAL, ins.type, ins.motor, ins.signed_value), ins)

    @staticmethod
    def _echo(status: int, ins: Instruction) -> Result:
        """SAP/SGP answer with the value written (the manuals say "don't care"; Trinamic
        firmware echoes it, and tmclsh's --json contract in DESIGN.md shows it)."""
        return status, ins.signed_value if status == Status.OK else 0

    def _ggp(self, ins: Instruction, accu: int | None) -> Result:
        if not self._bank_ok(ins.motor):
            return Status.INVALID_VALUE, 0
        return self.store.read(GLOBAL, ins.type, ins.motor)

    def _stgp(self, ins: Instruction, accu: int | None) -> Result:
        if not self._bank_ok(ins.motor):
            return Status.INVALID_VALUE, 0
        return self.store.store(GLOBAL, ins.type, ins.motor), 0

    def _rsgp(self, ins: Instruction, accu: int | None) -> Result:
        if not self._bank_ok(ins.motor):
            return Status.INVALID_VALUE, 0
        return self.store.restore(GLOBAL, ins.type, ins.motor), 0

    # -- I/O ------------------------------------------------------------------------------------
    def _all_port(self, ins: Instruction) -> bool:
        return (self.module.io_all_port is not None and ins.type == self.module.io_all_port
                and ins.motor in self.module.io_all_banks)

    def _sio(self, ins: Instruction, accu: int | None) -> Result:
        bank, value = ins.motor, ins.signed_value
        if bank not in self.module.io_banks():
            return Status.INVALID_VALUE, 0
        if self._all_port(ins):
            if value == -1 and accu is not None:
                value = accu & 0xFF  # "the lower 8 bits of the accumulator" (§5.7.14)
            outs = self.io.ports(bank, ("digital_out",))
            if not outs:
                return Status.WRONG_TYPE, 0
            if not 0 <= value <= 255:
                return Status.INVALID_VALUE, 0
            for p in outs:
                self.io.values[(p.bank, p.port)] = value >> p.port & 1
            return Status.OK, 0
        port = self.module.port(bank, ins.type)
        if port is None or port.kind != "digital_out":
            return Status.WRONG_TYPE, 0
        if not port.min <= value <= port.max:
            return Status.INVALID_VALUE, 0
        self.io.values[(bank, ins.type)] = value
        return Status.OK, 0

    def _gio(self, ins: Instruction, accu: int | None) -> Result:
        bank = ins.motor
        if bank not in self.module.io_banks():
            return Status.INVALID_VALUE, 0
        if self._all_port(ins):
            mask = 0
            for p in self.io.ports(bank, ("digital_in", "digital_out")):
                if p.port < 32 and self.io.get(p.bank, p.port):
                    mask |= 1 << p.port
            return Status.OK, mask
        if self.module.port(bank, ins.type) is None:
            return Status.WRONG_TYPE, 0
        return Status.OK, self.io.get(bank, ins.type)

    # -- coordinates ----------------------------------------------------------------------------
    def _coord_args(self, ins: Instruction) -> int | None:
        """Status for a bad coordinate/motor, None when fine."""
        if not 0 <= ins.type < self.coords.count:
            return Status.WRONG_TYPE
        if not self._motor_ok(ins.motor):
            return Status.INVALID_VALUE
        return None

    def _eeprom_copy_bank(self, ins: Instruction) -> bool:
        """SCO/GCO <n>, 255: the data file marks the modules that have the EEPROM copy."""
        if ins.motor != ALL_COORDS_BANK:
            return False
        spec = isa.by_opcode(ins.opcode)
        special = getattr(spec, "motor_special", {}).get(self.module.name, {})
        return ALL_COORDS_BANK in special

    def _copy_coords(self, ins: Instruction, to_eeprom: bool) -> Result:
        if not 0 <= ins.type < self.coords.count:
            return Status.WRONG_TYPE, 0
        if to_eeprom and self.store.locked():
            return Status.EEPROM_LOCKED, 0
        numbers = range(1, self.coords.count) if ins.type == 0 else [ins.type]
        for m in range(self.module.motors):
            for n in numbers:
                if to_eeprom:
                    self.coords.eeprom[m][n] = self.coords.ram[m][n]
                else:
                    self.coords.ram[m][n] = self.coords.eeprom[m][n]
        return Status.OK, 0

    def set_coordinate(self, motor: int, number: int, value: int) -> None:
        self.coords.ram[motor][number] = value
        if number and self.store.get(GLOBAL, "CoordinateStorage") == 1:
            self.coords.eeprom[motor][number] = value

    def _sco(self, ins: Instruction, accu: int | None) -> Result:
        if self._eeprom_copy_bank(ins):
            return self._copy_coords(ins, to_eeprom=True)
        bad = self._coord_args(ins)
        if bad is not None:
            return bad, 0
        value = ins.signed_value
        if not self.module.position_min <= value <= self.module.position_max:
            return Status.INVALID_VALUE, 0
        self.set_coordinate(ins.motor, ins.type, value)
        return Status.OK, 0

    def _gco(self, ins: Instruction, accu: int | None) -> Result:
        if self._eeprom_copy_bank(ins):
            return self._copy_coords(ins, to_eeprom=False)
        bad = self._coord_args(ins)
        if bad is not None:
            return bad, 0
        return Status.OK, self.coords.ram[ins.motor][ins.type]

    def _cco(self, ins: Instruction, accu: int | None) -> Result:
        bad = self._coord_args(ins)
        if bad is not None:
            return bad, 0
        self.set_coordinate(ins.motor, ins.type, self.wrap_position(self.axes[ins.motor].pos))
        return Status.OK, 0

    def _nothing(self, ins: Instruction, accu: int | None) -> Result:
        return Status.OK, 0  # SAC (no SPI devices) and UF0-7 (no customer functions)

    # -- parameters owned by the motion state --------------------------------------------------
    def _register_live(self) -> None:
        st, axes = self.store, self.axes

        def axis_live(name: str, get: Callable[[Axis, int], int],
                      set_: Callable[[Axis, int, int], int] | None = None) -> None:
            st.add_live(AXIS, name, Live(
                lambda m: get(axes[m], m),
                None if set_ is None else (lambda m, v: set_(axes[m], m, v))))

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
            if not a.moving or a.accel_now * a.vel < 0:
                return 0
            vmax_units = self.store.get(AXIS, "MaxPositioningSpeed", m)
            return vmax_units if a.target_pos >= a.pos else -vmax_units

        position = lambda a, m: self.wrap_position(a.pos)  # noqa: E731
        speed = lambda a, m: int(round(a.vel / self.vscale(m)))  # noqa: E731
        axis_live("TargetPosition", lambda a, m: a.target_pos, move)
        axis_live("ActualPosition", position, set_pos)
        axis_live("VirtualActualPosition", position)
        axis_live("TargetSpeed", target_speed, set_speed)
        axis_live("ActualSpeed", speed)
        axis_live("MeasuredSpeed", speed)
        axis_live("RampGeneratorSpeed", speed)
        axis_live("ActualAcceleration",
                  lambda a, m: int(round(abs(a.accel_now) / self.ascale(m)))
                  if math.isfinite(a.accel_now) else 0)
        axis_live("TargetPositionReached", lambda a, m: int(a.reached))
        axis_live("ReferenceSwitchStatus", lambda a, m: int(a.switch("ref")))
        axis_live("RightLimitSwitchStatus", lambda a, m: int(a.switch("right")))
        axis_live("LeftLimitSwitchStatus", lambda a, m: int(a.switch("left")))
        axis_live("VelocityReached", lambda a, m: int(self._velocity_reached(a, m)))
        self._register_ramp_mode(axis_live)
        for name in ("StatusWord", "StatusFlags"):
            p = st.by_name(AXIS, name)
            if p is not None and p.bits:
                axis_live(name, self._status_word(p.bits))

    def _velocity_reached(self, a: Axis, m: int) -> bool:
        """Compared in the module's units, as AP 3 reads them: when the actual speed reads
        as the target speed, the target speed is reached."""
        vs = self.vscale(m)
        actual = int(round(a.vel / vs))
        target = int(round(a.target_vel / vs)) if a.mode == Mode.VELOCITY else actual
        return abs(actual - target) <= self.store.get(AXIS, "VelocityReachedWindow", m)

    def _register_ramp_mode(self, axis_live) -> None:
        """RampMode numbers differ per module (1311: 1 = velocity, 351: 2 = velocity); read
        them from the value names in the data file."""
        p = self.store.by_name(AXIS, "RampMode")
        if p is None:
            return
        velocity = next((n for n, t in p.values.items() if "velocity" in t.lower()), None)
        position = next((n for n, t in p.values.items() if "position" in t.lower()), 0)

        def get(a: Axis, m: int) -> int:
            return velocity if a.mode == Mode.VELOCITY and velocity is not None else position

        def set_(a: Axis, m: int, v: int) -> int:
            if v == velocity:
                a.rotate(a.target_vel, a.target_vel_units)
            elif v == position:
                a.move_to(a.target_pos)
            return Status.OK  # other modes (torque, soft) are accepted and not modelled

        axis_live("RampMode", get, set_)

    def _status_word(self, bits: dict[int, str]) -> Callable[[Axis, int], int]:
        """Build a status word getter from the bit names in the data file."""
        probes: list[tuple[int, Callable[[Axis, int], bool]]] = []
        for bit, text in bits.items():
            t = text.lower()
            probe: Callable[[Axis, int], bool] | None = None
            if t.startswith("target reached") or t.startswith("position end"):
                probe = lambda a, m: a.reached  # noqa: E731
            elif t.startswith("velocity reached"):
                probe = self._velocity_reached
            elif t.startswith("position mode"):
                probe = lambda a, m: a.mode == Mode.POSITION  # noqa: E731
            elif t.startswith("velocity mode"):
                probe = lambda a, m: a.mode == Mode.VELOCITY  # noqa: E731
            elif t.startswith("home switch"):
                probe = lambda a, m: a.switch("ref")  # noqa: E731
            elif t.startswith("left stop switch"):
                probe = lambda a, m: a.switch("left")  # noqa: E731
            elif t.startswith("right stop switch"):
                probe = lambda a, m: a.switch("right")  # noqa: E731
            elif t.startswith("module initialized"):
                probe = lambda a, m: True  # noqa: E731
            if probe is not None:
                probes.append((bit, probe))

        def get(a: Axis, m: int) -> int:
            return sum(1 << bit for bit, probe in probes if probe(a, m))

        return get

