"""The TMCL instruction set, loaded from ``instructions.toml``.

One table, keyed by opcode and by mnemonic, read by the assembler, disassembler, shell,
completer and simulator alike, so that adding a command or a symbolic type is a data change.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from functools import cache

from ..base.datafiles import load_toml
from .frames import Control


@dataclass(frozen=True)
class InstructionSpec:
    opcode: int
    mnemonic: str
    summary: str
    fields: tuple[str, ...]
    type_kind: str
    motor_kind: str
    value_kind: str
    modules: frozenset[str]
    direct: bool
    ascii: bool
    reads: bool = False
    persists: bool = False
    note: str | None = None  # for users: shown by `help MNEMONIC`
    source: str | None = None  # for maintainers: how the entry was read from the manuals
    types: dict[str, int] = field(default_factory=dict)
    types_for: dict[str, dict[str, int]] = field(default_factory=dict)
    # per module: motor/bank values with a special meaning besides the motor numbers
    # (TMCM-1311 SCO/GCO bank 255: copy coordinates between RAM and EEPROM)
    motor_special: dict[str, dict[int, str]] = field(default_factory=dict)

    def type_names(self, module: str | None = None) -> dict[str, int]:
        """Symbolic types valid on ``module`` (all documented ones when None)."""
        module = None if module is None else _LIKE.get(module, module)
        if module == GENERIC:
            return self.types
        if module is not None and module in self.types_for:
            return self.types_for[module]
        if module is None and self.types_for:
            merged = dict(self.types)
            for extra in self.types_for.values():
                merged.update(extra)
            return merged
        return self.types

    def type_name(self, number: int, module: str | None = None) -> str | None:
        for name, num in self.type_names(module).items():
            if num == number:
                return name
        return None

    def on(self, module: str) -> bool:
        return _offered(self.modules, module)

    @property
    def jumps(self) -> bool:
        """The value field holds a program address (a label in source)."""
        return self.value_kind == "label"

    @property
    def syntax(self) -> str:
        slot = {
            "type": {"symbolic": "|".join(self.type_names()) or "<type>",
                     "axis_param": "<parameter>", "global_param": "<parameter>",
                     "port": "<port>", "coordinate": "<coordinate>",
                     "interrupt": "<interrupt>", "number": "<type>"}.get(self.type_kind, "<type>"),
            "motor": {"motor": "<motor>", "bank": "<bank>"}.get(self.motor_kind, "<motor>"),
            "value": {"velocity": "<velocity>", "position": "<position>", "param": "<value>",
                      "port_value": "<value>", "label": "<label>", "ticks": "<ticks>"}
            .get(self.value_kind, "<value>"),
        }
        ops = ", ".join(slot[f] for f in self.fields)
        return f"{self.mnemonic} {ops}".rstrip()


@dataclass(frozen=True)
class ControlSpec:
    opcode: int
    name: str
    modules: frozenset[str]
    note: str | None = None
    source: str | None = None

    def on(self, module: str) -> bool:
        return _offered(self.modules, module)


# A module the manuals above do not describe (a user's module file, or one known only by its
# 136 answer) borrows the command set of a documented module, or the generic one: the
# commands every documented module has, i.e. the TMCL family's common core.
GENERIC = "generic"
_LIKE: dict[str, str] = {}


def use_commands_of(module: str, like: str) -> None:
    """Let ``module`` have the commands of ``like`` (a documented module, or ``"generic"``)."""
    _LIKE[module] = like


def commands_like(module: str) -> str:
    return _LIKE.get(module, module)


def _offered(modules: frozenset[str], module: str) -> bool:
    module = _LIKE.get(module, module)
    if module == GENERIC:
        return modules >= family()
    return module in modules


@cache
def family() -> frozenset[str]:
    """The modules the instruction table documents."""
    return frozenset().union(*(s.modules for s in _tables()[0].values()))


def _load() -> dict:
    return load_toml(__package__, "instructions.toml")


@cache
def _tables() -> tuple[dict[int, InstructionSpec], dict[int, ControlSpec], dict[str, int]]:
    data = _load()
    by_opcode: dict[int, InstructionSpec] = {}
    for raw in data["instruction"]:
        spec = _spec(raw)
        by_opcode[spec.opcode] = spec
        if raw.get("user_function"):
            for n in range(1, 8):
                uf = _spec({**raw, "opcode": raw["opcode"] + n, "mnemonic": f"UF{n}",
                            "summary": raw["summary"].replace("0", str(n), 1)})
                by_opcode[uf.opcode] = uf
    controls = {c["opcode"]: ControlSpec(c["opcode"], c["name"], frozenset(c["modules"]),
                                         c.get("note"), c.get("source")) for c in data["control"]}
    return by_opcode, controls, dict(data["interrupts"])


def _spec(raw: dict) -> InstructionSpec:
    return InstructionSpec(
        opcode=raw["opcode"], mnemonic=raw["mnemonic"], summary=raw["summary"],
        fields=tuple(raw["fields"]), type_kind=raw["type"], motor_kind=raw["motor"],
        value_kind=raw["value"], modules=frozenset(raw["modules"]), direct=raw["direct"],
        ascii=raw["ascii"], reads=raw.get("reads", False), persists=raw.get("persists", False),
        note=raw.get("note"), source=raw.get("source"), types=dict(raw.get("types", {})),
        types_for={k: dict(v) for k, v in raw.get("types_for", {}).items()},
        motor_special={mod: {int(k): v for k, v in table.items()}
                       for mod, table in raw.get("motor_special", {}).items()},
    )


def all_instructions() -> list[InstructionSpec]:
    return sorted(_tables()[0].values(), key=lambda s: s.opcode)


def by_opcode(opcode: int) -> InstructionSpec | None:
    return _tables()[0].get(opcode)


def by_mnemonic(mnemonic: str) -> InstructionSpec | None:
    return _mnemonics().get(mnemonic.upper())


@cache
def _mnemonics() -> dict[str, InstructionSpec]:
    return {s.mnemonic: s for s in _tables()[0].values()}


def controls() -> dict[int, ControlSpec]:
    return dict(_tables()[1])


def control(opcode: int) -> ControlSpec | None:
    return _tables()[1].get(opcode)


def interrupts() -> dict[str, int]:
    """Interrupt numbers by their Interrupts.inc name (TI_TIMER0 ...)."""
    return dict(_tables()[2])


def interrupt_name(number: int) -> str | None:
    for name, num in _tables()[2].items():
        if num == number:
            return name
    return None


def _opcode_enum() -> type[IntEnum]:
    members = {s.mnemonic: s.opcode for s in all_instructions()}
    members.update({c.name: int(c) for c in Control})
    return IntEnum("Opcode", members)


Opcode = _opcode_enum()

# ASCII-mode-only commands (no binary opcode): leave ASCII mode, run and stop the program.
ASCII_ONLY_COMMANDS = ("BIN", "RUN", "STOP")
