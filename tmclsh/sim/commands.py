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
from collections.abc import Callable

from ..tmcl import instructions as isa
from ..tmcl.modules import Module
from ..tmcl.frames import Instruction, Status
from .derived import Derived
from .model import AXIS, GLOBAL, Coordinates, IoState, ParamStore
from .motion import Axis, Limits

log = logging.getLogger(__name__)

ALL_COORDS_BANK = 255  # SCO/GCO <n>, 255: copy between RAM and EEPROM (TMCM-1311 §5.7.24/25)
MULTI_MOTOR = 0x80  # TMCM-351 MVP COORD motor field: bit 7 = several motors, bits 0-2 = mask

Result = tuple[int, int]  # (status, value)


class Commands:
    def __init__(self, module: Module, store: ParamStore, io: IoState, coords: Coordinates,
                 axes: list[Axis], clock: Callable[[], float] = lambda: 0.0):
        self.module = module
        self.store = store
        self.io = io
        self.coords = coords
        self.axes = axes
        # every parameter read from the state, and the limits the parameters set, in one place
        self.derived = Derived(module, store, io, axes, clock)
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

    # -- units and limits (derived.py: what the parameters allow and what they read) ---------
    def vscale(self, motor: int) -> float:
        return self.derived.vscale(motor)

    def limits(self, motor: int) -> Limits:
        return self.derived.limits(motor)

    def wrap_position(self, value: float) -> int:
        return self.derived.wrap_position(value)

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
        # "unknown": a port of a module whose data lists none (any_io): taken, read back
        if port is None or port.kind not in ("digital_out", "unknown"):
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
