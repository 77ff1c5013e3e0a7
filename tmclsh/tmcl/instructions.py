"""The TMCL instruction set, loaded from ``instructions.toml``.

One table, keyed by opcode and by mnemonic, read by the assembler, disassembler, shell,
completer and simulator alike, so that adding a command or a symbolic type is a data change.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from functools import cache
from typing import Protocol, Union

from ..base.datafiles import load_toml
from .frames import Control, ReplyKind
from .frames import reply_kind as frame_reply_kind


class HasCommands(Protocol):
    """A module as the instruction set sees it: its name and whose command set it has (its
    own for a documented module; another's, or ``GENERIC``, for one the manuals do not
    describe). ``tmcl.modules.Module`` is one."""

    name: str
    commands_like: str


# a module, by name or as a ``HasCommands``; None: any documented module
ModuleRef = Union[str, HasCommands, None]


def _family_key(module: ModuleRef) -> str | None:
    """Whose command set ``module`` has: a documented module's name or ``GENERIC``."""
    if module is None or isinstance(module, str):
        return module
    return module.commands_like


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
    access: str | None = None  # read | write | store (of the parameter the type names)
    read_types: tuple[str, ...] = ()  # symbolic types whose reply value is a reading
    idempotent: bool = False  # sending it twice has the outcome of sending it once
    once_types: tuple[str, ...] = ()  # ... except with these symbolic types
    starts_motion: bool = False
    stops: bool = False  # it stops the motor (its target speed becomes 0)
    confirm: str | None = None  # store | storable | factory: asked before it is sent
    done: str | dict[str, str] | None = None  # what the shell says when it was accepted
    turns: str | None = None  # ROR/ROL: the way a positive speed turns the motor
    waits: bool = False  # WAIT: holds the program counter until its condition is met
    note: str | None = None  # for users: shown by `help MNEMONIC`
    source: str | None = None  # for maintainers: how the entry was read from the manuals
    # per module: what it means on that module, shown instead of ``note`` when connected to it
    notes_for: dict[str, str] = field(default_factory=dict)
    types: dict[str, int] = field(default_factory=dict)
    types_for: dict[str, dict[str, int]] = field(default_factory=dict)
    # per module: motor/bank values with a special meaning besides the motor numbers
    # (TMCM-1311 SCO/GCO bank 255: copy coordinates between RAM and EEPROM)
    motor_special: dict[str, dict[int, str]] = field(default_factory=dict)

    @property
    def reads(self) -> bool:
        """Its reply value is a reading of what its type names (GAP, GGP, GIO, GCO)."""
        return self.access == "read"

    @property
    def sets_parameter(self) -> bool:
        """It writes a value to the parameter its type names (SAP, SGP; not AAP/AGP, which
        copy the accumulator): what a configuration backup is made of."""
        return (self.access == "write" and "value" in self.fields
                and self.type_kind in ("axis_param", "global_param"))

    @property
    def persists(self) -> bool:
        """It writes the module's EEPROM (STAP, STGP)."""
        return self.confirm == "store"

    def reads_with(self, type_: int, module: ModuleRef = None) -> bool:
        """Is the reply value to this command with type ``type_`` a reading (GAP; RFS
        STATUS)?"""
        if self.reads:
            return True
        names = self.type_names(module)
        return any(names.get(t) == type_ for t in self.read_types)

    def repeatable(self, type_: int) -> bool:
        """May a request with type ``type_`` be sent again when its reply was lost?"""
        return self.idempotent and not any(self.types.get(t) == type_ for t in self.once_types)

    def done_text(self, type_: int, module: ModuleRef = None) -> str | None:
        """The template of what the shell says once the module accepted the command."""
        if isinstance(self.done, dict):
            name = self.type_name(type_, module)
            return self.done.get(name) if name is not None else None
        return self.done

    def note_for(self, module: ModuleRef = None) -> str | None:
        """What users should know about it on ``module`` (its own note, else the common)."""
        return self.notes_for.get(_family_key(module) or "", self.note)

    def type_names(self, module: ModuleRef = None) -> dict[str, int]:
        """Symbolic types valid on ``module`` (all documented ones when None)."""
        module = _family_key(module)
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

    def type_name(self, number: int, module: ModuleRef = None) -> str | None:
        for name, num in self.type_names(module).items():
            if num == number:
                return name
        return None

    def on(self, module: ModuleRef) -> bool:
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
    idempotent: bool = False
    starts_motion: bool = False
    confirm: str | None = None
    not_a_line: str | None = None  # never sent as a typed line: why
    ascii_word: str | None = None  # the module's ASCII mode calls it this (RUN, STOP)
    download: str | None = None  # enter | leave: it starts or ends download mode
    reply: str | None = None  # "none": no reply comes (137, 205, 242)
    boot: str | None = None  # its role in a firmware update (bootloader.toml)
    access: str | None = None  # read: it only reads (134, 135, 136)
    ascii_types: tuple[int, ...] | None = None  # the types ascii_word does (None: all)
    ascii_line: str | None = None  # in ASCII mode, this line asks the same (135: GGP 128)

    def on(self, module: ModuleRef) -> bool:
        return _offered(self.modules, module)

    def repeatable(self, type_: int) -> bool:
        return self.idempotent


# A module the manuals above do not describe (a user's module file, or one known only by its
# 136 answer) borrows the command set of a documented module, or the generic one: the
# commands every documented module has, i.e. the TMCL family's common core.
GENERIC = "generic"


def _offered(modules: frozenset[str], module: ModuleRef) -> bool:
    module = _family_key(module)
    if module is None:
        return True
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
                                         c.get("note"), c.get("source"),
                                         c.get("idempotent", False),
                                         c.get("starts_motion", False), c.get("confirm"),
                                         c.get("not_a_line"), c.get("ascii_word"),
                                         c.get("download"), c.get("reply"), c.get("boot"),
                                         c.get("access"), _types(c.get("ascii_types")),
                                         c.get("ascii_line"))
                for c in data["control"]}
    return by_opcode, controls, dict(data["interrupts"])


def _types(raw: list[int] | None) -> tuple[int, ...] | None:
    return tuple(raw) if raw is not None else None


def _spec(raw: dict) -> InstructionSpec:
    return InstructionSpec(
        opcode=raw["opcode"], mnemonic=raw["mnemonic"], summary=raw["summary"],
        fields=tuple(raw["fields"]), type_kind=raw["type"], motor_kind=raw["motor"],
        value_kind=raw["value"], modules=frozenset(raw["modules"]), direct=raw["direct"],
        ascii=raw["ascii"], access=raw.get("access"), read_types=tuple(raw.get("read_types", ())),
        idempotent=raw.get("idempotent", False), once_types=tuple(raw.get("once_types", ())),
        starts_motion=raw.get("starts_motion", False), stops=raw.get("stops", False),
        confirm=raw.get("confirm"), done=raw.get("done"), turns=raw.get("turns"), waits=raw.get("waits", False),
        note=raw.get("note"), source=raw.get("source"),
        notes_for=dict(raw.get("notes_for", {})), types=dict(raw.get("types", {})),
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


def spec_of(opcode: int) -> InstructionSpec | ControlSpec | None:
    """The entry of a command number: an instruction or a control command."""
    return _tables()[0].get(opcode) or _tables()[1].get(opcode)


@cache
def repeatable(opcode: int, type_: int) -> bool:
    """May a request be sent again when its reply was lost (a retry)? Only a command whose
    entry says so: a retried ``MVP REL`` would move twice as far; anything unknown (a raw
    number, CALC, the user functions) is sent at most once."""
    spec = spec_of(opcode)
    return spec is not None and spec.repeatable(type_)


@cache
def reading(opcode: int, type_: int) -> bool:
    """Is the reply to this request a reading of what its type names (GAP, GGP, GIO, RFS
    STATUS)? Asking again then changes nothing on the module: an answer in doubt is read
    again."""
    spec = _tables()[0].get(opcode)
    return spec is not None and spec.reads_with(type_)


@cache
def only_reads(opcode: int, type_: int) -> bool:
    """Does this request only read (a replay sends it without asking)? A reading
    instruction, or a control command whose entry says ``access = "read"``; anything else
    may write, store or move, and anything unknown is taken to."""
    if reading(opcode, type_):
        return True
    ctl = _tables()[1].get(opcode)
    return ctl is not None and ctl.access == "read"


@cache
def starting_opcodes() -> frozenset[int]:
    """The commands that can start a motor or the stored program (``starts_motion``)."""
    return frozenset(op for op in (*_tables()[0], *_tables()[1]) if spec_of(op).starts_motion)


def is_control(opcode: int) -> bool:
    """A control command (128 and up): no mnemonic, other reply layouts, not for programs."""
    return opcode >= Control.STOP_APPLICATION


# Unwritten program memory reads as an instruction with this opcode (no command has it):
# the end of a stored program.
END_MARKER = 0


@cache
def parameter_command(kind: str, access: str) -> InstructionSpec:
    """The command that does ``access`` (read, write, store, restore) to an ``axis`` or
    ``global`` parameter with its value: GAP/SAP/STAP/RSAP, GGP/SGP/STGP/RSGP."""
    want = "axis_param" if kind == "axis" else "global_param"
    for spec in all_instructions():
        if spec.type_kind == want and spec.access == access and (
                access != "write" or spec.sets_parameter):
            return spec
    raise LookupError(f"no {access} command for {kind} parameters")


@cache
@cache
@cache
def reply_kind(opcode: int, type_: int) -> ReplyKind:
    """How the answer to a request is laid out: the frame layer's reading (136 type 0, 134),
    or none at all where the instruction set says none comes (137, 205, 242). (Kept per
    command and type: the client asks it of every control command it sends, an upload's
    verify thousands of 134s.)"""
    ctl = _tables()[1].get(opcode)
    if ctl is not None and ctl.reply == "none":
        return ReplyKind.NONE
    return frame_reply_kind(opcode, type_)


@cache
def boot_command(role: str) -> int:
    """The command that plays ``role`` in a firmware update (``enter``: 242, ``erase``:
    200, ... as ``boot`` in instructions.toml says)."""
    for op, c in _tables()[1].items():
        if c.boot == role:
            return op
    raise LookupError(f"no bootloader command for {role!r}")


@cache
def download_command(which: str) -> int:
    """The control command that enters or leaves download mode (132, 133)."""
    return next(op for op, c in _tables()[1].items() if c.download == which)


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

# ASCII-mode-only commands (no binary opcode): leave ASCII mode, run and stop the program,
# and what the ASCII terminal's completion says of them.
ASCII_ONLY = {"BIN": "leave ASCII mode (binary mode again)",
              "RUN": "start the stored TMCL program", "STOP": "stop the running TMCL program"}
ASCII_ONLY_COMMANDS = tuple(ASCII_ONLY)
# the shell command that sends each (typed at the prompt they are no TMCL lines)
ASCII_ONLY_SENT_BY = {"BIN": ".mode binary", "RUN": ".run", "STOP": ".stop"}
ASCII_BIN = "BIN"
