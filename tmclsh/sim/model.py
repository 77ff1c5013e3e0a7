"""Parameter, EEPROM, coordinate and I/O state of one simulated module.

Everything here is built from the module database (``tmclsh/tmcl/modules/*.toml``): which
parameters exist, their ranges, access letters and start values. The model knows nothing of
frames or time; it answers "may this be written / stored?" with TMCL status codes so the
command layer can pass them straight into a reply.

A parameter slot has a RAM value and, when its access includes ``E``, an EEPROM copy. Values
that belong to the motion or program state (actual position, program counter ...) are not
stored here: the command layer registers them as *live* parameters with a getter and setter.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

from ..tmcl.modules import IoPort, Module, Parameter
from ..tmcl.frames import INT32_MAX, Status

log = logging.getLogger(__name__)

AXIS = "axis"
GLOBAL = "global"

OTHER = "?"  # START_VALUES: a module without an entry of its own
EEPROM_MAGIC = 0xE4  # GP 64: any other value in EEPROM means "factory defaults at next boot"
LOCK_WRITE = 1234  # GP 73: writing 1234 locks the configuration EEPROM ...
UNLOCK_WRITE = 4321  # ... and 4321 unlocks it (module notes of all three data files)

# Start values the manuals do not print but a simulated motor needs in order to move at all.
# They are simulator assumptions, keyed by parameter name (never by number) and module;
# everything not listed starts at the data file's `default`, else 0 (or the range minimum).
START_VALUES: dict[str, dict[str, int]] = {
    # the factory addresses every example telegram of the manuals uses (module 1, host 2)
    "*": {"EEPROMMagic": EEPROM_MAGIC, "SerialAddress": 1, "SerialHostAddress": 2},
    "TMCM-1311": {"MaxPositioningSpeed": 51200, "MaxAcceleration": 51200},
    "TMCM-351": {"MaxPositioningSpeed": 1000, "MaxAcceleration": 100, "PulseDivisor": 3,
                 "RampDivisor": 7},
    # MotorPoles: the QBL4208 the manual names as its example motor has 8 poles
    # EnableDriver, ActivateRamp: a module that drives its motor with the ramp it is given;
    # the manual prints no default and PyTrinamic's examples for it set neither to start
    "TMCM-1640": {"MaxPositioningSpeed": 4000, "Acceleration": 2000, "MotorPoles": 8,
                  "EnableDriver": 1, "ActivateRamp": 1},
    # any other module (a user's file, one imported from PyTrinamic, which carries no
    # defaults): a motor that moves when told to, at the TMCM-1311's start values
    OTHER: {"MaxPositioningSpeed": 51200, "MaxAcceleration": 51200, "Acceleration": 51200,
            "EnableDriver": 1, "ActivateRamp": 1},
}

# Other names the simulator's rules (written by the names of the built-in files) know a
# parameter by: PyTrinamic's names, which files imported from it carry. A rule for the name on
# the left applies to a module that has one of those on the right instead (never beside it).
ALSO_CALLED: dict[str, dict[str, tuple[str, ...]]] = {
    AXIS: {
        "MaxPositioningSpeed": ("MaxVelocity",),
        "TargetSpeed": ("TargetVelocity",),
        "ActualSpeed": ("ActualVelocity",),
        "TargetPositionReached": ("PositionReachedFlag",),
        "ReferenceSwitchStatus": ("HomeSwitch", "referenceSwitchStatus"),
        "RightLimitSwitchStatus": ("RightEndstop",),
        "LeftLimitSwitchStatus": ("LeftEndstop",),
        "RightLimitSwitchDisable": ("rightLimitSwitchDisable",),
        "LeftLimitSwitchDisable": ("leftLimitSwitchDisable",),
        "ReferenceSwitchSpeed": ("RefSwitchSpeed", "referenceSwitchSpeed"),
        "ActivateRamp": ("EnableRamp",),
    },
    GLOBAL: {
        "SerialAddress": ("serialAddress",),
        "SerialHostAddress": ("serialHostAddress",),
        "TelegramPauseTime": ("telegramPauseTime",),
        "AutoStartMode": ("autoStartMode",),
    },
}


def known_as(module: Module) -> dict[tuple[str, str], Parameter]:
    """``(kind, name) -> parameter`` for every name the simulator may ask for on ``module``:
    its own names, and those of ``ALSO_CALLED`` it has under another name only."""
    names: dict[tuple[str, str], Parameter] = {}
    for kind, params in ((AXIS, module.axis_params), (GLOBAL, module.global_params)):
        for p in params:
            names.setdefault((kind, p.name), p)
    for kind, table in ALSO_CALLED.items():
        for name, others in table.items():
            if (kind, name) in names:
                continue
            found = next((names[(kind, o)] for o in others if (kind, o) in names), None)
            if found is not None:
                names[(kind, name)] = found
    return names


Key = tuple[str, int, int]  # (kind, motor or bank, number)
Getter = Callable[[int], int]  # motor/bank -> value
Setter = Callable[[int, int], int]  # (motor/bank, value) -> status


def _start_value(module: Module, p: Parameter, names: tuple[str, ...],
                 overrides: dict[str, int]) -> tuple[int, bool]:
    """``p``'s start value, and whether it is the simulator's own (from ``START_VALUES``);
    ``names``: what the simulator knows ``p`` by (its own name first)."""
    for name in names:
        if name in overrides:
            return overrides[name], False
    if p.default is not None:
        return p.default, False
    for table in (START_VALUES.get(module.name, START_VALUES[OTHER]), START_VALUES["*"]):
        for name in names:
            if name in table:
                return table[name], True
    if p.in_range(0):
        return 0, False
    if p.choices:
        return p.choices[0], False
    return (p.min if p.min is not None else 0), False


def wire_to_param(p: Parameter, value: int) -> int:
    """A value field as received (signed 32 bit) read for ``p``: unsigned parameters
    (range above 2^31-1) travel as two's complement, so -1 means 4294967295 for them."""
    if value < 0 and p.max is not None and p.max > INT32_MAX:
        return value + 2**32
    return value


@dataclass
class Live:
    """A parameter whose value is owned by the motion or program state, not by the store."""

    get: Getter
    set: Setter | None = None


@dataclass
class Coordinates:
    """SCO/GCO/CCO/ACO storage: per motor, RAM and EEPROM arrays (coordinate 0 is RAM only)."""

    motors: int
    count: int
    ram: list[list[int]] = field(init=False)
    eeprom: list[list[int]] = field(init=False)

    def __post_init__(self) -> None:
        self.ram = [[0] * self.count for _ in range(self.motors)]
        self.eeprom = [[0] * self.count for _ in range(self.motors)]


class ParamStore:
    """RAM and EEPROM copies of every axis and global parameter of a module."""

    def __init__(self, module: Module, overrides: dict[str, int] | None = None):
        self.module = module
        self.ram: dict[Key, int] = {}
        self.eeprom: dict[Key, int] = {}
        self.factory: dict[Key, int] = {}
        self.live: dict[Key, Live] = {}
        self._params: dict[Key, Parameter] = {}
        self._names = known_as(module)
        overrides = overrides or {}
        also: dict[int, tuple[str, ...]] = {}  # id(parameter) -> its names, its own first
        for (kind, name), p in self._names.items():
            also[id(p)] = also.get(id(p), ()) + ((name,) if name != p.name else ())
        # (kind, name) -> the simulator's own start value, where the data gives none
        self.assumed: dict[tuple[str, str], int] = {}
        for p in module.axis_params:
            start, own = _start_value(module, p, (p.name, *also.get(id(p), ())), overrides)
            if own:
                self.assumed[(AXIS, p.name)] = start
            for motor in range(module.motors):
                self._params[(AXIS, motor, p.number)] = p
                self.factory[(AXIS, motor, p.number)] = start
        for p in module.global_params:
            start, own = _start_value(module, p, (p.name, *also.get(id(p), ())), overrides)
            if own:
                self.assumed[(GLOBAL, p.name)] = start
            for n in range(p.number, p.number + p.count):
                self._params[(GLOBAL, p.bank, n)] = p
                self.factory[(GLOBAL, p.bank, n)] = start
        self.factory_reset()
        self.power_up()

    # -- lookup ---------------------------------------------------------------------------
    def param(self, kind: str, number: int, index: int) -> Parameter | None:
        """The parameter behind a slot (``index``: motor for axis, bank for global)."""
        return self._params.get((kind, index, number))

    def by_name(self, kind: str, name: str) -> Parameter | None:
        return self._names.get((kind, name))

    def number_of(self, kind: str, name: str) -> int | None:
        p = self.by_name(kind, name)
        return None if p is None else p.number

    def add_live(self, kind: str, name: str, live: Live) -> None:
        """Route a parameter (looked up by name; absent on this module = no-op) to ``live``."""
        p = self.by_name(kind, name)
        if p is None:
            return
        indices = range(self.module.motors) if kind == AXIS else [p.bank]
        for idx in indices:
            self.live[(kind, idx, p.number)] = live

    # -- EEPROM life cycle ----------------------------------------------------------------
    def storable(self, key: Key) -> bool:
        p = self.param(key[0], key[2], key[1])
        return p is not None and p.storable

    def factory_reset(self) -> None:
        self.eeprom = {k: v for k, v in self.factory.items() if self.storable(k)}

    def power_up(self) -> None:
        """RAM from the EEPROM copy (and factory values where there is none)."""
        no_restore = self.by_name(GLOBAL, "DoNotRestoreUserVariables")
        skip_bank2 = (no_restore is not None
                      and self.eeprom.get((GLOBAL, no_restore.bank, no_restore.number), 0) == 1)
        for key, value in self.factory.items():
            if key in self.eeprom and not (skip_bank2 and key[0] == GLOBAL and key[1] == 2):
                self.ram[key] = self.eeprom[key]
            else:
                self.ram[key] = value

    def locked(self) -> bool:
        p = self.by_name(GLOBAL, "EEPROMLockFlag")
        return p is not None and self.ram.get((GLOBAL, p.bank, p.number), 0) == 1

    @staticmethod
    def auto_stored(p: Parameter) -> bool:
        """Bank 0 configuration parameters below 128 live in EEPROM only: SGP stores them
        (TMCM-1311 §10.1, TMCM-1640 §6.1, TMCM-351 SGP text)."""
        return p.kind == GLOBAL and p.bank == 0 and p.storable and p.number < 128

    # -- the four operations, with TMCL status codes ---------------------------------------
    def read(self, kind: str, number: int, index: int, *, check_access: bool = True
             ) -> tuple[int, int]:
        p = self.param(kind, number, index)
        if p is None or (check_access and not p.readable):
            return Status.WRONG_TYPE, 0
        key = (kind, index, number)
        live = self.live.get(key)
        if live is not None:
            return Status.OK, live.get(index)
        return Status.OK, self.ram.get(key, 0)

    def write(self, kind: str, number: int, index: int, value: int) -> int:
        p = self.param(kind, number, index)
        if p is None or not p.writable:
            return Status.WRONG_TYPE
        value = wire_to_param(p, value)
        if not p.in_range(value):
            return Status.INVALID_VALUE
        key = (kind, index, number)
        if p.name == "EEPROMLockFlag":
            return self._write_lock(key, value)
        if self.auto_stored(p) and self.locked():
            return Status.EEPROM_LOCKED
        live = self.live.get(key)
        if live is not None:
            if live.set is None:
                return Status.OK  # accepted, no lasting effect (e.g. a measured speed)
            status = live.set(index, value)
            if status != Status.OK:
                return status
        else:
            self.ram[key] = value
        if self.auto_stored(p):
            self.eeprom[key] = value
        return Status.OK

    def _write_lock(self, key: Key, value: int) -> int:
        if value in (LOCK_WRITE, UNLOCK_WRITE):
            state = 1 if value == LOCK_WRITE else 0
            self.ram[key] = state
            self.eeprom[key] = state
        # 0 and 1 are the read-back values: accepted, no effect (only 1234/4321 act).
        return Status.OK

    def store(self, kind: str, number: int, index: int) -> int:
        p = self.param(kind, number, index)
        if p is None or not p.storable:
            return Status.WRONG_TYPE
        if self.locked():
            return Status.EEPROM_LOCKED
        key = (kind, index, number)
        self.eeprom[key] = self.read(kind, number, index, check_access=False)[1]
        return Status.OK

    def restore(self, kind: str, number: int, index: int) -> int:
        p = self.param(kind, number, index)
        if p is None or not p.storable:
            return Status.WRONG_TYPE
        key = (kind, index, number)
        value = self.eeprom.get(key, self.factory.get(key, 0))
        live = self.live.get(key)
        if live is not None and live.set is not None:
            live.set(index, value)
        else:
            self.ram[key] = value
        return Status.OK

    # -- direct access for the command layer ----------------------------------------------
    def get(self, kind: str, name: str, index: int = 0, default: int = 0) -> int:
        """Current value of a parameter by name (``default`` when the module lacks it)."""
        # (``read`` without its access check, inlined: the module's own settings are read
        # this way several times for every request it answers)
        p = self._names.get((kind, name))
        if p is None:
            return default
        idx = p.bank if kind == GLOBAL else index
        key = (kind, idx, p.number)
        if key not in self._params:
            return 0
        live = self.live.get(key)
        if live is not None:
            return live.get(idx)
        return self.ram.get(key, 0)

    def has(self, kind: str, name: str) -> bool:
        return self.by_name(kind, name) is not None

    def set_raw(self, kind: str, name: str, value: int, index: int = 0) -> None:
        p = self.by_name(kind, name)
        if p is not None:
            self.ram[(kind, p.bank if kind == GLOBAL else index, p.number)] = value


class IoState:
    """Levels of every port in the database; inputs set by tests, outputs by SIO."""

    def __init__(self, module: Module):
        self.module = module
        self.values: dict[tuple[int, int], int] = {}
        # ports that measure what the model computes (coil currents): read, never set
        self.live: dict[tuple[int, int], Callable[[], int]] = {}
        for port in module.io:
            self.values[(port.bank, port.port)] = port.default if port.default is not None else port.min
        self._sync_from_analog()

    def _sync_from_analog(self) -> None:
        for port in self.module.io:
            if port.kind == "analog_in":
                self._link(port)

    def twins(self, port: IoPort) -> list[IoPort]:
        """The other views of the same pin (AIN_0 is bank 0 port 0 and bank 1 port 0)."""
        return [p for p in self.module.io if p.name == port.name and p is not port
                and p.kind != "digital_out"]

    def _link(self, port: IoPort) -> None:
        value = self.values[(port.bank, port.port)]
        for twin in self.twins(port):
            if twin.kind == "digital_in" and port.kind == "analog_in":
                self.values[(twin.bank, twin.port)] = 1 if value * 2 > port.max else 0
            elif twin.kind == "analog_in" and port.kind == "digital_in":
                self.values[(twin.bank, twin.port)] = twin.max if value else twin.min

    def set_input(self, bank: int, port: int, value: int) -> None:
        p = self.module.port(bank, port)
        if p is None:
            raise ValueError(f"{self.module.name} has no I/O port {port} in bank {bank}")
        if p.kind == "digital_out":
            raise ValueError(f"{p.name} is an output; outputs are set with SIO")
        if (bank, port) in self.live:
            raise ValueError(f"{p.name} follows the simulated motor; it cannot be set")
        if not p.min <= value <= p.max:
            raise ValueError(f"{value} out of range {p.min}..{p.max} for {p.name}")
        self.values[(bank, port)] = value
        self._link(p)

    def get(self, bank: int, port: int) -> int:
        live = self.live.get((bank, port))
        if live is not None:
            return live()
        return self.values.get((bank, port), 0)

    def ports(self, bank: int, kinds: tuple[str, ...]) -> list[IoPort]:
        return [p for p in self.module.io if p.bank == bank and p.kind in kinds]
