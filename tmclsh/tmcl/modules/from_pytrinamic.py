"""Module files written from PyTrinamic's module classes: names and numbers, nothing more.

PyTrinamic, the vendor's Python package, has a class per module (``pytrinamic.modules.TMCM1260``)
whose instance lists its motors; each motor has a nested ``AP`` class naming the axis
parameters (``MaxVelocity = 4``), and the module class has ``GP``/``GP0``/``GP3`` ... classes
naming global parameters by bank (``GP`` is bank 0). That is all it carries: no ranges, units,
access or defaults, no I/O port kinds, no program memory size. A file written from it says so
in every entry; tmclsh then checks those values as 32-bit numbers only and the module decides.

PyTrinamic is optional (``pip install 'tmclsh[pytrinamic]'``) and imported here only, only
when a user asks for an import. A missing PyTrinamic, or one whose classes no longer look like
this, is one clear ``ImportFailed`` line, never a traceback.
"""

from __future__ import annotations

import inspect
import json
import re
from dataclasses import dataclass, field

from ...base.errors import TmclError, UsageError
from . import _normalise, built_in
from .schema import parse

SOURCE_TAG = "# Written by 'tmclsh modules import pytrinamic'"  # first line of every such file
PROGRAM_MEMORY = 65536  # not known: as for a module without data, addresses are not checked
COORDINATES = 256
_CLASS = re.compile(r"([A-Z]+)(\d{3,4})$")  # TMCM1260, TMCC160: letters, then the type number
# TMCM123x_0_1: one class for a family; its docstring names the modules ("TMCM-1230 and
# TMCM-1231"), each a type number of its own
_FAMILY = re.compile(r"([A-Z]+)(\d{2,3})x(?:_\w+)?$")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*$")
STATUS_WORD = "StatusFlags"  # the axis parameter PyTrinamic tests its FLAG_ values against


class ImportFailed(TmclError):
    """PyTrinamic is missing, or a class of it is not what this importer reads."""


@dataclass
class Imported:
    """One module file's text, and what it holds."""

    class_name: str
    name: str
    text: str
    motors: int
    axis: int
    globals_: int
    notes: list[str] = field(default_factory=list)


def _library():
    try:
        import pytrinamic
        import pytrinamic.modules as modules
    except ImportError as exc:
        raise ImportFailed(f"PyTrinamic is not installed ({exc}); pip install "
                           "'tmclsh[pytrinamic]' brings it") from None
    except Exception as exc:  # a broken installation: say so, in one line
        raise ImportFailed(f"PyTrinamic could not be imported: {type(exc).__name__}: "
                           f"{exc}") from None
    base = getattr(modules, "TMCLModule", None)
    if not inspect.isclass(base):
        raise ImportFailed(f"PyTrinamic {version()} has no pytrinamic.modules.TMCLModule: "
                           "tmclsh reads the module classes of PyTrinamic 0.2 (a class per "
                           "module, an AP class per motor)")
    return pytrinamic, modules, base


def version() -> str:
    try:
        from importlib.metadata import version as dist_version

        return dist_version("pytrinamic")
    except Exception:
        return "(version unknown)"


def class_names() -> list[str]:
    """PyTrinamic's module classes (its own spelling: ``TMCM1260``), sorted."""
    _, modules, base = _library()
    return sorted(name for name, cls in vars(modules).items()
                  if inspect.isclass(cls) and issubclass(cls, base) and cls is not base)


def targets() -> list[tuple[str, str]]:
    """``(class, module name)`` for every module PyTrinamic has a class for, sorted by name:
    ``("TMCM1260", "TMCM-1260")``, and one pair per module a family class names
    (``("TMCM123x_0_1", "TMCM-1230")``, ``("TMCM123x_0_1", "TMCM-1231")``). A class whose name
    holds no type number is ``(class, "")``."""
    _, modules, _base = _library()
    out = []
    for cls in class_names():
        names = modules_of(cls, getattr(modules, cls))
        out += [(cls, name) for name in names] or [(cls, "")]
    return sorted(out, key=lambda cn: (cn[1] or cn[0]).lower())


def modules_of(class_name: str, cls: type | None = None) -> list[str]:
    """The module names a class stands for: ``TMCM1260`` -> ``["TMCM-1260"]``; a family class
    (``TMCM123x_0_1``) -> the modules its docstring names; ``[]`` when none can be told."""
    name = tmclsh_name(class_name)
    if name is not None:
        return [name]
    m = _FAMILY.match(class_name)
    if m is None or cls is None:
        return []
    letters, stem = m.groups()
    doc = inspect.getdoc(cls) or ""
    found = re.findall(rf"\b{letters}-?({stem}\d)\b", doc)
    return sorted({f"{letters}-{digits}" for digits in found})


def find(query: str) -> tuple[str, str]:
    """``(class, module name)`` a user's name means (``TMCM1260``, ``TMCM-1260``,
    ``tmcm1260``, ``1260``; ``TMCM1230`` is one of the family class ``TMCM123x_0_1``)."""
    pairs = targets()
    want = _normalise(query)
    for cls, name in pairs:
        if name and want in (_normalise(name), _normalise(name).removeprefix("tmcm")):
            return cls, name
    for cls in dict.fromkeys(cls for cls, _ in pairs):
        if want == _normalise(cls):
            names = [name for c, name in pairs if c == cls and name]
            if len(names) > 1:
                raise UsageError(f"PyTrinamic's {cls} stands for {' and '.join(names)}: name "
                                 f"one of them ({names[0].replace('-', '')})")
            return cls, (names[0] if names else "")
    known = ", ".join(name.replace("-", "") or cls for cls, name in pairs)
    raise UsageError(f"PyTrinamic {version()} has no module class {query!r}; it has {known}")


def tmclsh_name(class_name: str) -> str | None:
    """``TMCM1260`` -> ``TMCM-1260``; None when the class name holds no type number."""
    m = _CLASS.match(class_name)
    return f"{m.group(1)}-{m.group(2)}" if m else None


def convert(class_name: str, name: str | None = None) -> Imported:
    """A module file for PyTrinamic's ``class_name``, as module ``name`` (default: the one
    the class stands for; one of a family class's); ImportFailed when it cannot be read."""
    _, modules, _base = _library()
    cls = getattr(modules, class_name, None)
    if cls is None:
        raise UsageError(f"PyTrinamic {version()} has no module class {class_name!r}")
    names = modules_of(class_name, cls)
    if name is None and len(names) == 1:
        name = names[0]
    if name is None or name not in names:
        raise ImportFailed(f"{class_name}: the class name holds no type number (such as 1260) "
                           "and its description names no module, so the module could not be "
                           "recognised by its 136 answer")
    try:
        instance = cls(None)  # the classes keep the connection and never use it to build
        motors = list(instance.motors)
    except Exception as exc:
        raise ImportFailed(f"PyTrinamic {version()}'s {class_name} could not be read: "
                           f"{type(exc).__name__}: {exc}") from None
    if not motors:
        raise ImportFailed(f"PyTrinamic {version()}'s {class_name} lists no motors")
    tables = [getattr(m, "AP", None) for m in motors]
    if any(t is None for t in tables):
        raise ImportFailed(f"PyTrinamic {version()}'s {class_name} has a motor without an AP "
                           "class of parameter numbers")
    notes: list[str] = []
    if len(names) > 1:
        notes.append(f"PyTrinamic's {class_name} stands for {' and '.join(names)}: the same "
                     "names and numbers for each.")
    axis = _entries([_numbers(t) for t in tables], notes, "axis")
    if len({id(t) for t in tables}) > 1 and any(_numbers(t) != _numbers(tables[0])
                                                 for t in tables):
        notes.append("The motors' AP classes differ; every number any of them names is here.")
    globals_: list[tuple[int, int, str, list[str], str]] = []
    for bank, table in _gp_tables(cls):
        for number, first, others, own in _entries([_numbers(table)], notes, f"bank {bank}"):
            globals_.append((bank, number, first, others, own))
    flags = _flags(motors) if any(n == STATUS_WORD for _, n, _o, _w in axis) else {}
    text = _render(class_name, name, cls, len(motors), axis, globals_, notes, flags)
    parse(text, f"{name} (from PyTrinamic)")  # what is written is a file tmclsh can use
    return Imported(class_name, name, text, len(motors), len(axis), len(globals_), notes)


def _numbers(table: type) -> list[tuple[str, int]]:
    """``(name, number)`` in the order the class names them (ints, or objects with an index)."""
    out = []
    for key, value in vars(table).items():
        if key.startswith("_"):
            continue
        if isinstance(value, int) and not isinstance(value, bool):
            out.append((key, value))
        elif isinstance(getattr(value, "index", None), int):  # PyTrinamic's Parameter objects
            out.append((key, value.index))
    return out


def _flags(motors: list) -> dict[int, str]:
    """The status word's bits, from the ``FLAG_*`` values of the motors' ``ENUM`` classes
    (``FLAG_POSITION_END = 0x4000``: bit 14, "position end"), which PyTrinamic tests AP
    StatusFlags against; single bits only."""
    bits: dict[int, str] = {}
    for motor in motors:
        for key, value in vars(getattr(motor, "ENUM", object)).items():
            if key.startswith("FLAG_") and isinstance(value, int) and value > 0 \
                    and value & (value - 1) == 0 and value < 2**32:
                bits.setdefault(value.bit_length() - 1,
                                key.removeprefix("FLAG_").replace("_", " ").lower())
    return dict(sorted(bits.items()))


def _gp_tables(cls: type) -> list[tuple[int, type]]:
    out = []
    for key, value in vars(cls).items():
        m = re.fullmatch(r"GP(\d?)", key)
        if m and inspect.isclass(value):
            out.append((int(m.group(1) or 0), value))
    return sorted(out, key=lambda bt: bt[0])


def _entries(tables: list[list[tuple[str, int]]], notes: list[str],
             where: str) -> list[tuple[int, str, list[str], str]]:
    """``(number, name, other names, PyTrinamic's name)`` per number: PyTrinamic's first name
    for it in the built-in modules' style (usable on a command line, unique in the table),
    the others it gives the same number, and its own spelling of the first."""
    by_number: dict[int, list[str]] = {}
    beyond: set[int] = set()
    for table in tables:
        for key, number in table:
            if not 0 <= number <= 255:
                beyond.add(number)
            elif key not in by_number.setdefault(number, []):
                by_number[number].append(key)
    if beyond:
        notes.append(f"{where}: numbers above 255 ({', '.join(map(str, sorted(beyond)))}) "
                     "are left out: the type byte of a TMCL command holds 0..255.")
    out = []
    taken: set[str] = set()
    for number in sorted(by_number):
        names = by_number[number]
        own = names[0] if _NAME.match(names[0]) else f"P{number}"
        first = house_style(own)
        if _normalise(first) in taken:
            notes.append(f"{where}: {first} names two numbers in PyTrinamic; "
                         f"number {number} is {first}_{number} here.")
            first = f"{first}_{number}"
        taken.add(_normalise(first))
        out.append((number, first, names[1:], own))
    return out


def house_style(name: str) -> str:
    """PyTrinamic's name in the built-in modules' style, the manuals' (``minimumSpeed`` ->
    ``MinimumSpeed``, ``max_EncoderDeviation`` -> ``MaxEncoderDeviation``): one module's
    names read alike whichever source they come from. PyTrinamic's own stays an alias."""
    parts = [p for p in name.split("_") if p]
    if len(parts) > 1:
        parts = [p.capitalize() if p.isalpha() and p.isupper() and len(p) > 3 else p
                 for p in parts]
    return "".join(p[0].upper() + p[1:] for p in parts) or name


def _q(text: str) -> str:
    return json.dumps(text, ensure_ascii=False)  # a TOML basic string


def _render(class_name: str, name: str, cls: type, motors: int,
            axis: list[tuple[int, str, list[str], str]],
            globals_: list[tuple[int, int, str, list[str], str]], notes: list[str],
            flags: dict[int, str]) -> str:
    ver = version()
    doc = " ".join((inspect.getdoc(cls) or "").split())
    summary = doc.split(". ")[0].rstrip(".") if doc else f"{name} (PyTrinamic's {class_name})"
    number = int(_CLASS.match(name.replace("-", "")).group(2))  # type: ignore[union-attr]
    origin = f"PyTrinamic {ver}, names and numbers only"
    note = ("From PyTrinamic's tables: its range, unit and access are not known, so tmclsh "
            "checks the value as a 32-bit number and the module decides.")
    lines = [
        SOURCE_TAG + f" from PyTrinamic {ver}'s {class_name} class.",
        "# Names and numbers only: PyTrinamic carries no ranges, units, access or I/O ports.",
        "# Edit it freely (add ranges, units, access); a new import will not overwrite an",
        "# edited copy unless this first line is still here.",
        "",
        "[module]",
        f"name = {_q(name)}",
        f"summary = {_q(summary[:200])}",
        f"origin = {_q(origin)}",
        f"motors = {motors}",
        f"program_memory = {PROGRAM_MEMORY}",
        f"firmware_id = {number}",
        f"version_string = {_q(f'{number:04d}V000')}",
        f"coordinates = {COORDINATES}",
        'commands_like = "generic"',
        "any_io = true",
        "notes = [",
        *[f"  {_q(n)}," for n in _module_notes(ver, class_name)],
        *[f"  {_q(n)}," for n in notes],
        "]",
        "",
    ]
    for num, pname, others, own in axis:
        lines += _param("axis", num, pname, others, f"{class_name}.AP", note, own=own,
                        bits=flags if pname == STATUS_WORD else None, enum=f"{class_name}.ENUM")
    for bank, num, pname, others, own in globals_:
        table = f"{class_name}.GP{bank}" if hasattr(cls, f"GP{bank}") else f"{class_name}.GP"
        lines += _param("global", num, pname, others, table, note, bank=bank, own=own)
    return "\n".join(lines)


def _module_notes(ver: str, class_name: str) -> list[str]:
    return [
        f"Written from PyTrinamic {ver} (pytrinamic.modules.{class_name}): the motors, the axis "
        "parameter names and numbers of its AP class, the global parameters of its GP classes "
        "by bank. Nothing else is known from it.",
        "Every parameter has access RWE and no range (the module decides what it takes) and "
        "is marked state, so .restore writes none of them: which are settings is not known.",
        "version_string V000: the firmware version is not known; the module is recognised by "
        "its type number. Program memory, coordinates and I/O ports are not checked. Bank 2 "
        "(user variables) is not in PyTrinamic's tables, so it is not here.",
    ]


def _param(kind: str, number: int, name: str, others: list[str], table: str, note: str,
           bank: int | None = None, bits: dict[int, str] | None = None,
           enum: str = "", own: str = "") -> list[str]:
    own = own or name
    also = f" (also {', '.join(others)})" if others else ""
    if bits:
        also += f"; bits from {enum}.FLAG_*"
    out = [f"[[{kind}]]", f"number = {number}"]
    if bank is not None:
        out.append(f"bank = {bank}")
    out.append(f"name = {_q(name)}")
    if own != name and house_style(own) == name:  # (PyTrinamic's spelling finds it too)
        out.append(f"aliases = [{_q(own)}]")
    out += ['access = "RWE"', "state = true", f"note = {_q(note)}",
            f"source = {_q(f'PyTrinamic {version()}: {table}.{own} = {number}{also}')}"]
    if bits:
        out.append("bits = { " + ", ".join(f'"{b}" = {_q(t)}' for b, t in bits.items()) + " }")
    return out + [""]


def refuse_built_in(name: str) -> str | None:
    """Why a module tmclsh has from its manual is not imported (None: it is not built in)."""
    if name in built_in():
        return (f"{name} is built in, from its manual (ranges, units, access); PyTrinamic's "
                "names would replace it with less (to write one anyway: modules import pytrinamic "
                f"{name.replace('-', '')} -o FILE)")
    return None


def file_name(name: str) -> str:
    """The file a module of this name is written to in the config directory (tmcm1260.toml,
    tmcc160.toml): tmclsh reads every file there and goes by the name inside."""
    return _normalise(name) + ".toml"
