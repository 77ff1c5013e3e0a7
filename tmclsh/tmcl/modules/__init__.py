"""The module database: one TOML file per module (see SCHEMA.md), one generic ``Module``.

Adding a module means adding a data file. Lookups accept numbers and names
(case-insensitive, prefix and fuzzy), because a technician types ``GAP maxpos`` or
``.param microstep`` long before they remember ``AP 140``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from functools import cache, cached_property
from pathlib import Path

from ...base.datafiles import load_toml, package_files
from ...base.errors import RangeError, ValidationError
from ..instructions import GENERIC, InstructionSpec, all_instructions, controls, family
from ..version import TYPE_FIRST, decode_type1, parse_string
from .schema import ACCESS_CODES, ModuleFileError  # noqa: F401
from .schema import check_text
from .schema import read as read_data

BUILT_IN = "built in"
INT32_MIN, INT32_MAX, UINT32_MAX = -(2**31), 2**31 - 1, 2**32 - 1

# How well a name matches a query (Module.search / Module.lookup), best first.
_RANK_EXACT, _RANK_PREFIX, _RANK_SUBSTRING, _RANK_SUBSEQUENCE, _RANK_FUZZY = range(5)


@dataclass(frozen=True)
class Parameter:
    """One axis or global parameter (or a run of user variables when ``count`` > 1)."""

    kind: str  # "axis" or "global"
    number: int
    name: str
    manual_name: str
    description: str
    access: str
    bank: int = 0
    count: int = 1
    min: int | None = None
    max: int | None = None
    choices: tuple[int, ...] | None = None
    unit: str = ""
    default: int | None = None
    values: dict[int, str] = field(default_factory=dict)
    bits: dict[int, str] = field(default_factory=dict)
    note: str | None = None  # for users: shown by help and .param
    source: str | None = None  # for maintainers: how the entry was read from the manual
    # motion or module state (positions, speeds, counters) or a write that acts rather than
    # configures: a configuration backup (.save) keeps it as a comment, .restore never writes it
    state: bool = False
    # part of the module's place on its line (address, baud rate, host address, CAN ids and
    # bit rate, ASCII start-up, telegram pause, ...): its link identity, which belongs to the
    # module, not to a backup: a clone leaves it alone unless asked (--with-link)
    link: bool = False
    # which link a write of it may cut until tmclsh reconnects ("can", "serial", "ascii",
    # "any"): nothing to follow, so a restore writes it last and does not read it back there
    breaks: str | None = None
    # writing it can start the motor (AP 2 TargetSpeed: in velocity mode the motor follows it)
    starts_motion: bool = False
    # writing it changes where the module answers (address, host_address, can_id, reply_id,
    # baud): the client follows it (client/reach.py)
    reaches: str | None = None
    # the analog input that reads the same quantity (TMCM-1311 AP 153 and GIO 8, 1)
    io: str | None = None
    # other names it is found by as exactly as by ``name`` (another tool's spelling: an
    # imported file keeps PyTrinamic's ``minimumSpeed`` beside ``MinimumSpeed``)
    aliases: tuple[str, ...] = ()

    @property
    def readable(self) -> bool:
        return "R" in self.access

    @property
    def unsigned(self) -> bool:
        """Its data says it is an unsigned 32-bit quantity (a range beyond 2**31 - 1)."""
        return self.max is not None and self.max > INT32_MAX

    def reading(self, value: int) -> int:
        """A reply's value as this parameter reads (the one rule, for every reader): what
        the reply carries, 32 signed bits, unless the data says the parameter is an unsigned
        32-bit quantity. A -5 on a parameter the manual calls 0..2047 is shown as -5 (the
        module holds it; the manual is not the witness), not as 4294967291."""
        if value < 0 and self.unsigned:
            return value & 0xFFFFFFFF
        return value

    def outside(self, value: int) -> str | None:
        """The manual's range when ``value`` (as read) lies outside it, else None: said
        beside the value, never in its place."""
        return None if self.in_range(value) else self.range_text

    @property
    def writable(self) -> bool:
        return "W" in self.access

    @property
    def storable(self) -> bool:
        return "E" in self.access

    def covers(self, number: int) -> bool:
        return self.number <= number < self.number + self.count

    @property
    def label(self) -> str:
        """``AP 140`` / ``GP 66`` / ``GP 0..55 (bank 2)``."""
        if self.kind == "axis":
            return f"AP {self.number}"
        span = f"{self.number}..{self.number + self.count - 1}" if self.count > 1 else str(self.number)
        return f"GP {span}" + (f" (bank {self.bank})" if self.bank else "")

    @property
    def range_text(self) -> str:
        if self.choices:
            return ", ".join(str(c) for c in self.choices)
        if self.min is None and self.max is None:
            return "any"
        if self.min == 0 and self.max == 1:
            return "0/1"
        return f"{self.min}..{self.max}"

    def in_range(self, value: int) -> bool:
        if self.choices:
            return value in self.choices
        if self.min is not None and value < self.min:
            return False
        if self.max is not None and value > self.max:
            return False
        return True

    def check(self, value: int) -> None:
        """Raise a ValidationError naming the parameter and its range if ``value`` is illegal."""
        if not self.in_range(value):
            raise RangeError(
                f"{value} is out of range for {self.label} {self.name}: "
                f"allowed {self.range_text}{' ' + self.unit if self.unit else ''}")

    def describe_value(self, value: int) -> str:
        """A value in words: its named meaning or its set bits (empty when neither applies)."""
        if value in self.values:
            return self.values[value]
        if self.bits:
            on = [text for bit, text in sorted(self.bits.items()) if value >> bit & 1]
            return "; ".join(on) if on else "no bits set"
        return ""


@dataclass(frozen=True)
class IoPort:
    bank: int
    port: int
    name: str
    kind: str  # digital_in | analog_in | digital_out
    min: int
    max: int
    description: str = ""
    unit: str = ""
    default: int | None = None
    note: str | None = None
    source: str | None = None


def _int_keys(table: dict | None) -> dict[int, str]:
    return {int(k): v for k, v in (table or {}).items()}


def _parameter(kind: str, raw: dict) -> Parameter:
    return Parameter(
        kind=kind, number=raw["number"], name=raw["name"], manual_name=raw.get("manual_name", raw["name"]),
        description=raw.get("description", ""), access=raw["access"], bank=raw.get("bank", 0),
        count=raw.get("count", 1), min=raw.get("min"), max=raw.get("max"),
        choices=tuple(raw["choices"]) if raw.get("choices") else None, unit=raw.get("unit", ""),
        default=raw.get("default"), values=_int_keys(raw.get("values")),
        bits=_int_keys(raw.get("bits")), note=raw.get("note"), source=raw.get("source"),
        state=bool(raw.get("state", False)), link=bool(raw.get("link", False)),
        starts_motion=bool(raw.get("starts_motion", False)), reaches=raw.get("reaches"),
        breaks=raw.get("breaks"),
        io=raw.get("io"), aliases=tuple(raw.get("aliases", ())))


def _normalise(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", name.lower())


class Module:
    """Everything tmclsh knows about one module type, read from its data file."""

    generic = False  # a module known by number only (GenericModule)

    def __init__(self, data: dict, source: str = BUILT_IN):
        info = data["module"]
        self.data = data
        self.source = source  # BUILT_IN or the path of the user's file
        self.name: str = info["name"]
        self.summary: str = info.get("summary", "")
        self.motors: int = info["motors"]
        self.program_memory: int = info["program_memory"]
        self.firmware_id: int = info["firmware_id"]
        self.version_string: str = info["version_string"]
        self.firmware_version: int = info.get("firmware_version", 0)
        self.ascii_mode: bool = info.get("ascii_mode", False)
        self.interrupts: bool = info.get("interrupts", False)
        self.position_min: int = info.get("position_min", -(2**31))
        self.position_max: int = info.get("position_max", 2**31 - 1)
        self.velocity_min: int = info.get("velocity_min", -(2**31))
        self.velocity_max: int = info.get("velocity_max", 2**31 - 1)
        self.units: dict[str, str] = dict(info.get("units", {}))
        self.notes: list[str] = list(info.get("notes", []))
        self.io_all_port: int | None = info.get("io_all_port")
        self.io_all_banks: tuple[int, ...] = tuple(info.get("io_all_banks", ()))
        self.coordinates: int = info.get("coordinates", 21)
        # where the data comes from when not from a manual (a PyTrinamic import)
        self.origin: str | None = info.get("origin")
        # the file does not know the I/O ports: any port and bank, the module answers
        self.any_io: bool = info.get("any_io", False)
        # the application memory its bootloader writes a firmware image into, where the data
        # says (the manuals here do not): an image is measured before the module restarts
        self.firmware_start: int | None = info.get("firmware_start")
        self.firmware_size: int | None = info.get("firmware_size")
        # the byte order of its 136 type 1 answer (tmcl/version.py)
        self.version_layout: str = info.get("version_layout", TYPE_FIRST)
        # whose command set it has: its own (a documented module), the one its file names
        # (commands_like), or the generic one (the commands every documented module has)
        self.commands_like: str = info.get("commands_like") or (
            self.name if self.name in family() else GENERIC)
        self.axis_params: list[Parameter] = [_parameter("axis", p) for p in data.get("axis", [])]
        self.global_params: list[Parameter] = [_parameter("global", p) for p in data.get("global", [])]
        self.io: list[IoPort] = [IoPort(**{k: v for k, v in p.items()}) for p in data.get("io", [])]

    def __repr__(self) -> str:
        return f"Module({self.name!r})"

    # -- instructions -------------------------------------------------------------------
    @cached_property
    def instructions(self) -> list[InstructionSpec]:
        return [s for s in all_instructions() if s.on(self)]

    def has_instruction(self, opcode: int) -> bool:
        return any(s.opcode == opcode for s in self.instructions)

    def has_control(self, opcode: int) -> bool:
        spec = controls().get(opcode)
        return spec is not None and spec.on(self)

    @property
    def label(self) -> str:
        """The name as banner and toolbar show it (and where its data comes from, when that
        is not a manual)."""
        return f"{self.name} (data from {self.origin})" if self.origin else self.name

    def check_motor(self, motor: int) -> None:
        if not 0 <= motor < self.motors:
            allowed = "only motor 0" if self.motors == 1 else f"motors 0..{self.motors - 1}"
            raise ValidationError(f"{self.name} has no motor {motor}: {allowed}")

    # -- parameters ---------------------------------------------------------------------
    def axis(self, number: int) -> Parameter | None:
        return next((p for p in self.axis_params if p.number == number), None)

    def glob(self, number: int, bank: int = 0) -> Parameter | None:
        return next((p for p in self.global_params if p.bank == bank and p.covers(number)), None)

    def banks(self) -> list[int]:
        return sorted({p.bank for p in self.global_params})

    def reads_setting(self, spec: InstructionSpec | None, type_: int, motor: int) -> bool:
        """Does this command read a setting: a writable parameter the data does not mark
        ``state``, whose value holds still between two reads, so that two reads of it must
        agree? (Motion state, read-only measurements and flags, inputs and counters change
        by themselves.)"""
        if spec is None or not spec.reads_with(type_, self):
            return False
        if spec.type_kind == "axis_param":
            param = self.axis(type_)
        elif spec.type_kind == "global_param":
            param = self.glob(type_, motor)
        else:
            return False
        return param is not None and param.writable and not param.state

    def _pool(self, kind: str) -> list[Parameter]:
        return self.axis_params if kind == "axis" else self.global_params

    def lookup(self, kind: str, key: int | str, bank: int | None = None) -> Parameter:
        """Resolve a parameter by number or name; unknown keys raise with suggestions.

        A name resolves when it is a parameter's name (case and ``_`` ignored), or the only
        one it starts (``microstep``) or is part of. Misspellings only make suggestions: a
        fuzzy match never picks a parameter, since the result may be written to the module.
        """
        if isinstance(key, int):
            found = self.axis(key) if kind == "axis" else self.glob(key, bank or 0)
            if found is None:
                where = f" in bank {bank}" if kind == "global" and bank else ""
                raise ValidationError(f"{self.name} has no {kind} parameter {key}{where}")
            return found
        ranked = self._ranked(key, kind)
        best = min((r for r, _ in ranked), default=None)
        top = [p for r, p in ranked if r == best]
        if best is not None and best <= _RANK_SUBSTRING and len(top) == 1:
            return top[0]
        near = ", ".join(p.name for p in self.search(key, kind)[:5])
        what = f"unknown {kind} parameter {key!r} on {self.name}"
        raise ValidationError(f"{what}; did you mean {near}?" if near else what)

    def search(self, query: str, kind: str | None = None) -> list[Parameter]:
        """Parameters matching ``query``: number, name prefix, word in name/manual name, fuzzy."""
        pool = self.axis_params + self.global_params if kind is None else self._pool(kind)
        q = query.strip()
        if re.fullmatch(r"\d{1,40}", q):  # longer: no number (nor one Python converts)
            n = int(q)
            return [p for p in pool if p.covers(n)]
        ranked = self._ranked(q, kind)
        if not _normalise(q):
            return list(pool)
        best = min((r for r, _ in ranked), default=None)
        if best == _RANK_EXACT:
            return [p for r, p in ranked if r == _RANK_EXACT]
        return [p for _, p in sorted(ranked, key=lambda rp: (rp[0], rp[1].kind, rp[1].number))]

    def _ranked(self, query: str, kind: str | None) -> list[tuple[int, Parameter]]:
        pool = self.axis_params + self.global_params if kind is None else self._pool(kind)
        nq = _normalise(query)
        if not nq:
            return []
        ranked: list[tuple[int, Parameter]] = []
        for p in pool:
            name, manual = _normalise(p.name), _normalise(p.manual_name)
            if name == nq or any(_normalise(a) == nq for a in p.aliases):
                ranked.append((_RANK_EXACT, p))
            elif name.startswith(nq):
                ranked.append((_RANK_PREFIX, p))
            elif nq in name or nq in manual:
                ranked.append((_RANK_SUBSTRING, p))
            elif _subsequence(nq, name):
                ranked.append((_RANK_SUBSEQUENCE, p))
        if not ranked:
            names = {_normalise(p.name): p for p in pool}
            import difflib  # only when nothing closer matched

            for close in difflib.get_close_matches(nq, list(names), n=5, cutoff=0.6):
                ranked.append((_RANK_FUZZY, names[close]))
        return ranked

    # -- I/O ----------------------------------------------------------------------------
    def port(self, bank: int, port: int) -> IoPort | None:
        found = next((p for p in self.io if p.bank == bank and p.port == port), None)
        if found is None and self.any_io and 0 <= bank <= 255 and 0 <= port <= 255:
            return IoPort(bank, port, f"port {port}", "unknown", INT32_MIN, UINT32_MAX)
        return found

    def io_banks(self) -> list[int]:
        if self.any_io:
            return list(range(256))
        return sorted({p.bank for p in self.io})


def _subsequence(needle: str, hay: str) -> bool:
    it = iter(hay)
    return all(ch in it for ch in needle)


class GenericModule(Module):
    """A TMCL module tmclsh has no data for: commands by number, the family's common commands.

    Types and motors are checked as the bytes they are, values as 32 bits; what needs the
    module's data (ranges, read-only parameters, which motors exist) is not checked.
    """

    generic = True

    def __init__(self, type_name: str | None = None, version: str = ""):
        firmware_id = int(type_name.split("-")[-1]) if type_name and type_name[-1:].isdigit() else 0
        name = type_name or "TMCL module"
        if name in family():  # `-m generic` on a documented module: keep its own command set
            name += " (generic)"
        super().__init__({"module": {
            "name": name, "summary": "no parameter data: numbers only", "motors": 1,
            "program_memory": 65536, "firmware_id": firmware_id, "version_string": version,
            "coordinates": 256}})
        self.type_name = type_name or "TMCL module"
        self.commands_like = GENERIC

    @property
    def forced(self) -> bool:
        """``-m generic`` on a module tmclsh has data for: the data is there, just not used."""
        return self.name.endswith(" (generic)")

    @property
    def label(self) -> str:
        if self.forced:
            return f"{self.type_name} (generic mode: numbers only)"
        return f"{self.type_name} (no parameter data: numbers only)"

    @property
    def NOTICE(self) -> str:  # noqa: N802  (read once at the start of a session)
        why = ("generic mode (-m generic), its parameter data not used" if self.forced
               else "no parameter data for this module")
        return (f"{why}: commands go by number; ranges, read-only parameters and motor numbers "
                "are not checked")

    def check_motor(self, motor: int) -> None:
        if not 0 <= motor <= 255:
            raise ValidationError(f"{motor} does not fit the motor byte (0..255)")

    def banks(self) -> list[int]:
        return list(range(256))

    def io_banks(self) -> list[int]:
        return list(range(256))

    def port(self, bank: int, port: int) -> IoPort | None:
        if not (0 <= bank <= 255 and 0 <= port <= 255):
            return None
        return IoPort(bank, port, f"port {port}", "unknown", INT32_MIN, UINT32_MAX)

    def lookup(self, kind: str, key: int | str, bank: int | None = None) -> Parameter:
        if isinstance(key, int):
            if not 0 <= key <= 255:
                raise ValidationError(f"{key} does not fit the type byte (0..255)")
            return Parameter(kind, key, f"{'AP' if kind == 'axis' else 'GP'} {key}",
                             "", "", "RWE", bank=bank or 0)
        example = 'GAP 1, 0' if kind == 'axis' else 'GGP 66, 0'
        if self.forced:
            raise ValidationError(
                f"generic mode (-m generic) knows no parameter names, so {key!r} means nothing "
                f"here: give the {kind} parameter by number (e.g. {example}), or leave "
                f"-m generic out to use the {self.type_name}'s parameter data")
        raise ValidationError(
            f"{self.type_name} has no parameter data, so {key!r} means nothing here: give the "
            f"{kind} parameter by number (e.g. {example}),"
            " or describe the module in a module file (--module-file)")


def _file_name(name: str) -> str:
    return _normalise(name if _normalise(name).startswith("tmcm") else "tmcm" + name) + ".toml"


# -- the user's module files ------------------------------------------------------------------

_extra_files: list[Path] = []
_user_scan: tuple[list[Module], list[str]] | None = None


def user_dir() -> Path:
    """Where the user's own module files are found: the config directory's ``modules/``."""
    from ...base.config import config_dir

    return config_dir() / "modules"


def add_file(path: str | Path) -> None:
    """Use one more module file (``--module-file``); read with the others on first lookup."""
    global _user_scan
    _extra_files.append(Path(path))
    _user_scan = None


def forget_user_files() -> None:
    """Read the user's files again on the next lookup (tests, a changed config dir)."""
    global _user_scan
    _extra_files.clear()
    _user_scan = None


def read_file(path: str | Path) -> Module:
    """A module from a user's data file, checked (ModuleFileError: one line, file and line)."""
    return Module(read_data(Path(path)), source=str(path))


def commands_of(mod: Module) -> str:
    """Whose command set ``mod`` uses: its own (a documented module), another's, or generic."""
    return mod.commands_like


def _user() -> tuple[list[Module], list[str]]:
    global _user_scan
    if _user_scan is None:
        folder = user_dir()
        try:
            files = sorted(folder.glob("*.toml")) if folder.is_dir() else []
        except OSError:
            files = []
        files += [p for p in _extra_files if p not in files]
        mods: list[Module] = []
        problems: list[str] = []
        for path in files:
            try:
                mods.append(read_file(path))
            except ModuleFileError as exc:
                problems.append(str(exc))
        _user_scan = (mods, problems)
    return _user_scan


def user_modules() -> list[Module]:
    """The user's modules that loaded (a later file with the same name wins)."""
    return list(_user()[0])


def problems() -> list[str]:
    """One line per user module file that could not be used (file:line: what)."""
    return list(_user()[1])


def _find_user(name: str) -> Module | None:
    want = _file_name(name)
    return next((m for m in reversed(_user()[0]) if _file_name(m.name) == want), None)


@cache
def _built_in_ids() -> dict[str, int]:
    """Each built-in module's name and firmware id, from its data without its tables built:
    a module told by its 136 answer builds only the one it names."""
    ids = {}
    for entry in package_files(__package__).iterdir():
        if entry.name.endswith(".toml"):
            info = load_toml(__package__, entry.name)["module"]
            ids[info["name"]] = info["firmware_id"]
    return ids


def _built_in_names() -> tuple[str, ...]:
    return tuple(sorted(_built_in_ids()))


def built_in() -> list[str]:
    """The names of the modules shipped with tmclsh."""
    return list(_built_in_names())


def available() -> list[str]:
    """Module names with data, built in and the user's, e.g. ``["TMCM-1311", ...]``."""
    return sorted(set(_built_in_names()) | {m.name for m in _user()[0]})


def catalogue() -> list[Module]:
    """Every known module as it is used (a user's file replaces a built-in of that name)."""
    return [load(n) for n in available()]


def load(name: str) -> Module:
    """Load a module by name: ``TMCM-1311``, ``tmcm1311`` and ``1311`` all give the same object;
    ``generic`` gives the numbers-only module."""
    if _normalise(name) == GENERIC:
        return GenericModule()
    module = _find_user(name) or _load(_file_name(name))
    if module is None:
        raise ValidationError(f"unknown module {name!r}; known: {', '.join(available())}, "
                              "or generic (numbers only); for a module PyTrinamic knows, "
                              "make its file first: tmclsh modules import pytrinamic NAME")
    return module


@cache
def _load(file_name: str) -> Module | None:
    """A built-in module: read as a user's file is, through the same schema check (run when
    the file is parsed, not on every start: the parsed data is cached by content)."""
    entry = package_files(__package__).joinpath(file_name)
    if not entry.is_file():
        return None
    return Module(load_toml(__package__, file_name, check=lambda text: check_text(
        text, f"tmclsh/tmcl/modules/{file_name}")))


def by_firmware_id(firmware_id: int) -> Module | None:
    built_in = _built_in_ids()
    for name in available():
        if built_in.get(name, firmware_id) != firmware_id and _find_user(name) is None:
            continue  # (another type: its tables are not built for nothing)
        mod = load(name)
        if mod.firmware_id == firmware_id:
            return mod
    return None


def from_version_string(text: str) -> Module | None:
    """Identify a module from its 136 string (``1311V111`` -> TMCM-1311): a module whose
    version_string is exactly this first (a user's file for one firmware), else by type number."""
    exact = [m for m in _user()[0] if m.version_string == text.strip()]
    if exact:
        return exact[-1]
    parsed = parse_string(text)
    return by_firmware_id(parsed.type_number) if parsed is not None and \
        not parsed.bootloader else None


def generic_for(text: str) -> GenericModule | None:
    """The numbers-only module for a 136 string naming a type with no data (``1161V130``)."""
    parsed = parse_string(text)
    if parsed is None or parsed.bootloader:
        return None
    return GenericModule(f"TMCM-{parsed.type_number}", text.strip())


def by_type1(value: int) -> Module | None:
    """The module a 136 type 1 value names, each known module's value read in its own byte
    order (tmcl/version.py): a TMCM-1640 answers version first, a TMCM-1311 type first."""
    for name in available():
        mod = load(name)
        if decode_type1(value, mod.version_layout)[0] == mod.firmware_id:
            return mod
    return None


def identify(version: str | None = None, type1: int | None = None
             ) -> Module | GenericModule | None:
    """The one reading of "what module is this" from its 136 answers: the string names a
    module with data, else the type 1 value does (its checksum makes it the surer of the two
    when the string is garbled), else the string names a type without data (numbers only).
    None when neither names anything."""
    if version is not None:
        mod = from_version_string(version)
        if mod is not None:
            return mod
    if type1 is not None:
        mod = by_type1(type1)
        if mod is not None:
            return mod
    return generic_for(version) if version is not None else None


def type1_of(value: int, module: Module | None) -> tuple[int, int] | None:
    """``(type number, version)`` from a 136 type 1 value, read in ``module``'s byte order;
    None when the type read so is not ``module``'s (another layout or another module)."""
    layout = module.version_layout if module is not None else TYPE_FIRST
    kind, ver = decode_type1(value, layout)
    if module is not None and not module.generic and kind != module.firmware_id:
        return None
    return kind, ver


def baud_rates(module: Module | None = None) -> list[int]:
    """The baud rates GP 65 can select, from the module database (``module``'s, or those of
    every known module), in the order of their codes."""
    mods = [module] if module is not None else [load(n) for n in available()]
    rates: dict[int, int] = {}
    for mod in mods:
        p = mod.glob(65)
        for code, text in (p.values.items() if p is not None else ()):
            word = text.split()[0] if text.split() else ""
            if word.isdigit():
                rates.setdefault(int(word), code)
    return sorted(rates, key=lambda r: (rates[r], r))
