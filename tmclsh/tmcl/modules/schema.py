"""What a module data file must hold (SCHEMA.md in words, here as data), checked at load.

A user's own module file is read at start-up; a mistake in it must be one line naming the
file and the line, never a traceback, so every key's type is checked here before ``Module``
reads the data. tomllib gives no positions, so ``_Lines`` finds the line of a key by reading
the text the way TOML lays it out (headers, then ``key = value`` lines).
"""

from __future__ import annotations

import re
from pathlib import Path

from ...base.errors import ValidationError

ACCESS_CODES = ("R", "W", "RW", "RWE")
IO_KINDS = ("digital_in", "analog_in", "digital_out")
# what a link parameter sets: how the module is reached from now on (the client follows it)
REACHES = ("address", "host_address", "can_id", "reply_id", "baud")
# which link a write of a link parameter may cut until tmclsh reconnects (nothing to follow:
# a CAN bit rate, the interface selection, the ASCII echo); "any" is every link
BREAKS = ("can", "serial", "ascii", "any")

# key -> (type, required); "ints"/"strs" are lists of those, "names" an int-keyed text table
MODULE_KEYS: dict[str, tuple[str, bool]] = {
    "name": ("str", True), "summary": ("str", False), "motors": ("int", True),
    "program_memory": ("int", True), "firmware_id": ("int", True),
    "version_string": ("str", True), "firmware_version": ("int", False),
    "ascii_mode": ("bool", False), "interrupts": ("bool", False),
    "position_min": ("int", False), "position_max": ("int", False),
    "velocity_min": ("int", False), "velocity_max": ("int", False),
    "units": ("table", False), "notes": ("strs", False), "io_all_port": ("int", False),
    "io_all_banks": ("ints", False), "coordinates": ("int", False),
    "commands_like": ("str", False), "version_layout": ("str", False),
    "origin": ("str", False), "any_io": ("bool", False),
    "firmware_start": ("int", False), "firmware_size": ("int", False),
}
PARAMETER_KEYS: dict[str, tuple[str, bool]] = {
    "number": ("int", True), "name": ("str", True), "manual_name": ("str", False),
    "description": ("str", False), "access": ("str", True), "bank": ("int", False),
    "count": ("int", False), "min": ("int", False), "max": ("int", False),
    "choices": ("ints", False), "unit": ("str", False), "default": ("int", False),
    "values": ("names", False), "bits": ("names", False), "note": ("str", False),
    "source": ("str", False), "state": ("bool", False), "link": ("bool", False),
    "starts_motion": ("bool", False), "reaches": ("str", False), "io": ("str", False),
    "breaks": ("str", False), "aliases": ("strs", False),
}
IO_KEYS: dict[str, tuple[str, bool]] = {
    "bank": ("int", True), "port": ("int", True), "name": ("str", True), "kind": ("str", True),
    "min": ("int", True), "max": ("int", True), "description": ("str", False),
    "unit": ("str", False), "default": ("int", False), "note": ("str", False),
    "source": ("str", False),
}
TABLES = {"axis": PARAMETER_KEYS, "global": PARAMETER_KEYS, "io": IO_KEYS}
# what each key means, for the man page (SCHEMA.md says the same at more length)
MEANINGS = {
    "module": {
        "name": "the module's name, \"TMCM-1161\" (a built-in name replaces the built-in)",
        "motors": "number of axes: motors 0..motors-1",
        "program_memory": "TMCL program memory, in instructions",
        "firmware_id": "the type number 136 reports (1161 for 1161V130)",
        "version_string": "the 136 type 0 answer of the firmware described (\"1161V130\"); "
                          "an exact match wins over one by type number",
        "commands_like": "whose command set the module has: TMCM-1311, TMCM-351, TMCM-1640, "
                         "or generic (the commands all of them have; the default)",
        "version_layout": "byte order of the 136 type 1 value: type_first (type, then "
                          "version; the default) or version_first (as the TMCM-1640)",
        "origin": "where the data comes from when not from a manual (shown in the banner)",
        "any_io": "true: the I/O ports are not known; GIO/SIO take any port and bank",
        "firmware_start": "where the application memory a firmware image goes into starts, "
                          "as its bootloader answers 206 (firmware_size too: its size in "
                          "bytes); tmclsh firmware then refuses an image that does not fit "
                          "before it restarts the module",
        "position_min": "position range of MVP (position_max too; default 32 bits)",
        "velocity_min": "velocity range of ROR/ROL (velocity_max too; default 32 bits)",
    },
    "axis": {
        "number": "the parameter number (type field of SAP/GAP)",
        "name": "the name typed on the command line (GAP MaxSpeed, 0)",
        "aliases": "other names the parameter is found by, as exactly as by its name "
                   "([\"minimumSpeed\"]: another tool's spelling)",
        "access": "R, W, RW or RWE (E: may be stored with STAP/STGP)",
        "min": "inclusive range (max too); choices = [..] lists the only legal values",
        "bank": "global parameters only: the bank (0..3)",
        "values": "names of values: { \"0\" = \"off\" }; bits names bits the same way",
        "io": "the analog input ([[io]] name) that reads the same quantity in the same unit",
        "link": "true: part of the module's place on its line (address, baud rate, CAN, ASCII "
                "start-up); a clone leaves it alone unless --with-link",
    },
    "io": {
        "bank": "0 digital inputs, 1 analog inputs, 2 digital outputs (as the manual numbers)",
        "port": "the port number",
        "kind": "one of digital_in, analog_in, digital_out",
        "min": "the value range (max too)",
    },
}
# The numbers a module file may give, as (low, high, why). A file is data from the field and
# may be cut or hostile: the simulator makes a list per motor, per instruction of program
# memory and per coordinate, so a count no module has (motors = 1000000000) would grow
# tmclsh to gigabytes. The bounds are what Trinamic's TMCL modules have, or what the
# protocol's fields can carry.
BYTE = (0, 255, "one byte of a TMCL frame carries it")
INT32 = (-(2**31), 2**31 - 1, "a 32-bit signed value")
VALUE = (-(2**31), 2**32 - 1, "a 32-bit value")  # unsigned parameters reach 2**32 - 1
RANGES: dict[str, dict[str, tuple[int, int, str]]] = {
    "module": {
        # the most axes of any Trinamic TMCL module: 6 (TMCM-6110, TMCM-6212, TMCM-6214)
        "motors": (1, 6, "no TMCL module drives more than 6 motors"),
        # the manuals' modules hold 2048 instructions; tmclsh assembles to addresses
        # 0..65535 (asm --at), so no program it makes needs more
        "program_memory": (1, 65536, "tmclsh's program addresses are 0..65535"),
        # 136 type 1 carries the type number and the version in 16 bits each
        "firmware_id": (0, 65535, "136 reports it in 16 bits"),
        "firmware_version": (0, 65535, "136 reports it in 16 bits"),
        # a coordinate number is the type byte of SCO/GCO/CCO/ACO
        "coordinates": (0, 256, "SCO/GCO number coordinates in one byte"),
        # where the bootloader's application memory lies: 32-bit addresses
        "firmware_start": (0, 2**32 - 1, "a 32-bit address"),
        "firmware_size": (1, 2**32, "a 32-bit address space"),
        "io_all_port": BYTE, "io_all_banks": BYTE,
        "position_min": INT32, "position_max": INT32,
        "velocity_min": INT32, "velocity_max": INT32,
    },
    "parameter": {
        "number": BYTE, "bank": BYTE,
        # a run of user variables ends at 255, the last number the type byte carries
        "count": (1, 256, "numbers 0..255 fit the type byte"),
        "min": VALUE, "max": VALUE, "default": VALUE, "choices": VALUE,
    },
    "io": {"bank": BYTE, "port": BYTE, "min": VALUE, "max": VALUE, "default": VALUE},
}
_RANGE_TABLE = {"module": "module", "axis": "parameter", "global": "parameter", "io": "io"}
_TYPE_WORDS = {"str": "a string", "int": "an integer", "bool": "true or false",
               "table": "a table", "strs": "a list of strings", "ints": "a list of integers",
               "names": "a table of texts keyed by numbers (\"0\" = \"...\")"}


class ModuleFileError(ValidationError):
    """A module data file that cannot be used: ``FILE:LINE: what is wrong``."""


class _Lines:
    """Line numbers of tables and keys in a TOML text, by (table, entry index, key)."""

    _HEADER = re.compile(r"\s*(\[\[?)\s*([A-Za-z0-9_.\"-]+)\s*\]\]?")
    _KEY = re.compile(r"\s*(\"[^\"]*\"|[A-Za-z0-9_-]+)\s*=")

    def __init__(self, text: str):
        self.headers: dict[tuple[str, int], int] = {}
        self.keys: dict[tuple[str, int, str], int] = {}
        counts: dict[str, int] = {}
        where: tuple[str, int] = ("", 0)
        for no, raw in enumerate(text.splitlines(), 1):
            header = self._HEADER.match(raw)
            if header:
                name = header.group(2)
                if header.group(1) == "[[":
                    counts[name] = counts.get(name, -1) + 1
                where = (name, counts.get(name, 0))
                self.headers.setdefault(where, no)
                continue
            key = self._KEY.match(raw)
            if key:
                self.keys.setdefault((*where, key.group(1).strip('"')), no)

    def line(self, table: str, index: int, key: str | None = None) -> int:
        if key is not None and (table, index, key) in self.keys:
            return self.keys[(table, index, key)]
        return self.headers.get((table, index), 1)


def _is(kind: str, value: object) -> bool:
    if kind == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "str":
        return isinstance(value, str)
    if kind == "bool":
        return isinstance(value, bool)
    if kind == "table":
        return isinstance(value, dict)
    if kind == "strs":
        return isinstance(value, list) and all(isinstance(v, str) for v in value)
    if kind == "ints":
        return isinstance(value, list) and all(_is("int", v) for v in value)
    if kind == "names":
        return isinstance(value, dict) and all(
            re.fullmatch(r"-?\d{1,10}", k) and isinstance(v, str) for k, v in value.items())
    raise AssertionError(kind)


def check_text(text: str, path: str) -> None:
    """Check a module file's text already parsed elsewhere (a built-in file, whose parsed
    data is cached): ModuleFileError as for a user's file."""
    parse(text, path)


def parse(text: str, path: str) -> dict:
    """A module file's text as data, checked against the schema; ModuleFileError if not."""
    import tomllib  # only when a file is parsed: a cached built-in table is not

    from ...base.files import toml_limits

    beyond = toml_limits(text)
    if beyond is not None:
        raise ModuleFileError(f"{path}:{beyond[0]}: {beyond[1]}")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"\(at line (\d+), column \d+\)", str(exc))
        msg = re.sub(r"\s*\(at (line \d+, column \d+|end of document)\)", "", str(exc))
        no = m.group(1) if m else max(1, len(text.splitlines()))  # at the end: a cut file
        raise ModuleFileError(f"{path}:{no}: not valid TOML: {msg}") from None
    check(data, _Lines(text), path)
    return data


def check(data: dict, lines: _Lines, path: str) -> None:
    def fail(table: str, index: int, key: str | None, msg: str) -> ModuleFileError:
        return ModuleFileError(f"{path}:{lines.line(table, index, key)}: {msg}")

    unknown = sorted(set(data) - {"module", *TABLES})
    if unknown:
        first = unknown[0]
        what = f"unknown table [{first}]" if isinstance(data[first], (dict, list)) \
            else f"{first} = ... outside any table (module keys go under [module])"
        raise fail(first, 0, None, f"{what}; a module file has "
                   "[module], [[axis]], [[global]] and [[io]]")
    if not isinstance(data.get("module"), dict):
        raise fail("", 0, None, "no [module] table (name, motors, program_memory, "
                   "firmware_id, version_string)")
    _entry(data["module"], MODULE_KEYS, "module", 0, "[module]", fail)
    info = data["module"]
    if len(info["version_string"]) != 8 or not info["version_string"].isascii():
        raise fail("module", 0, "version_string", "[module] version_string must be the 8 "
                   f"characters 136 answers (\"1161V130\"), got {_shown(info['version_string'])}")
    memory = [k for k in ("firmware_start", "firmware_size") if k in info]
    if len(memory) == 1:
        other = "firmware_size" if memory[0] == "firmware_start" else "firmware_start"
        raise fail("module", 0, memory[0], f"[module] {memory[0]} needs {other} beside it "
                   "(the application memory is where it starts and how large it is)")
    if memory and (info["firmware_start"] < 0 or info["firmware_size"] < 1):
        raise fail("module", 0, "firmware_size", "[module] firmware_start must be 0 or more "
                   "and firmware_size at least 1")
    layout = info.get("version_layout")
    if layout is not None:
        from ..version import LAYOUTS

        if layout not in LAYOUTS:
            raise fail("module", 0, "version_layout", f"[module] version_layout must be one "
                       f"of {', '.join(LAYOUTS)}, got {_shown(layout)}")
    like = info.get("commands_like")
    if like is not None:
        from ..instructions import GENERIC, family

        allowed = sorted(family()) + [GENERIC]
        if like not in allowed:
            raise fail("module", 0, "commands_like", f"[module] commands_like must be one of "
                       f"{', '.join(allowed)}, got {_shown(like)}")
    for table, keys in TABLES.items():
        entries = data.get(table, [])
        if not isinstance(entries, list):
            raise fail(table, 0, None, f"{table} must be written [[{table}]] (one per entry)")
        seen: dict[tuple, int] = {}
        for i, entry in enumerate(entries):
            what = f"[[{table}]] entry {i + 1}"
            if isinstance(entry, dict) and _is("int", entry.get("number")):
                what += f" ({'AP' if table == 'axis' else 'GP'} {entry['number']})"
            _entry(entry, keys, table, i, what, fail)
            if table == "io":
                if entry["kind"] not in IO_KINDS:
                    raise fail(table, i, "kind", f"{what}: kind must be one of "
                               f"{', '.join(IO_KINDS)}, got {_shown(entry['kind'])}")
                ident: tuple = (entry["bank"], entry["port"])
            else:
                if entry.get("reaches") not in (None, *REACHES):
                    raise fail(table, i, "reaches", f"{what}: reaches must be one of "
                               f"{', '.join(REACHES)}, got {_shown(entry['reaches'])}")
                if entry.get("breaks") not in (None, *BREAKS):
                    raise fail(table, i, "breaks", f"{what}: breaks must be one of "
                               f"{', '.join(BREAKS)}, got {_shown(entry['breaks'])}")
                if entry["access"] not in ACCESS_CODES:
                    raise fail(table, i, "access", f"{what}: access must be one of "
                               f"{', '.join(ACCESS_CODES)}, got {_shown(entry['access'])}")
                ident = (entry.get("bank", 0), entry["number"])
                if entry["number"] + entry.get("count", 1) > 256:
                    raise fail(table, i, "count", f"{what}: numbers {entry['number']}.."
                               f"{entry['number'] + entry.get('count', 1) - 1} go past 255, "
                               "the last the type byte carries")
            if ident in seen:
                raise fail(table, i, None, f"{what} repeats entry {seen[ident] + 1}")
            seen[ident] = i
    _check_io_links(data, fail)


def _check_io_links(data: dict, fail) -> None:
    """``io`` names the analog input that measures the same quantity as the parameter."""
    inputs = {p["name"] for p in data.get("io", []) if p["kind"] == "analog_in"}
    for table in ("axis", "global"):
        for i, entry in enumerate(data.get(table, [])):
            name = entry.get("io")
            if name is not None and name not in inputs:
                raise fail(table, i, "io", f"[[{table}]] entry {i + 1} ({entry['name']}): io "
                           f"must name an analog input of [[io]] ({', '.join(sorted(inputs)) or 'none'}), "
                           f"got {_shown(name)}")


def _entry(entry: object, keys: dict[str, tuple[str, bool]], table: str, index: int,
           what: str, fail) -> None:
    if not isinstance(entry, dict):
        raise fail(table, index, None, f"{what} must be a table")
    for key, value in entry.items():
        if key not in keys:
            raise fail(table, index, key, f"{what}: unknown key {key!r}; known: "
                       f"{', '.join(keys)}")
        kind = keys[key][0]
        if not _is(kind, value):
            raise fail(table, index, key, f"{what}: {key} must be {_TYPE_WORDS[kind]}, "
                       f"got {_shown(value)}")
        bounds = RANGES[_RANGE_TABLE[table]].get(key)
        if bounds is not None:
            low, high, why = bounds
            for number in value if isinstance(value, list) else (value,):
                if not low <= number <= high:
                    raise fail(table, index, key, f"{what}: {key} must be from {low} to "
                               f"{high} ({why}), got {_shown(number)}")
    missing = [k for k, (_, required) in keys.items() if required and k not in entry]
    if missing:
        raise fail(table, index, None, f"{what} lacks {', '.join(missing)}")


def _shown(value: object) -> str:
    """A value as a message quotes it: cut short, so one line stays one line."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def read(path: Path) -> dict:
    """Read and check one module file (ModuleFileError for any problem, with file and line).

    A file is parsed and checked once per content and checking code: the result is kept in
    the data cache (a user with forty imported files would otherwise parse them all on every
    start)."""
    from ...base.datafiles import parsed
    from ...base.files import FileError, bounded_read, read_bytes

    try:
        raw = read_bytes(path, what="module file")  # bounded: /dev/zero
        raw.decode("utf-8")
    except FileError as exc:
        raise ModuleFileError(str(exc)) from None
    except UnicodeDecodeError:
        raise ModuleFileError(f"{path}:1: not a text file (UTF-8)") from None
    try:
        with bounded_read(str(path), "module file"):
            return parsed(raw, "user-module", lambda text: parse(text, str(path)),
                          salt=_rules())
    except FileError as exc:
        raise ModuleFileError(str(exc)) from None


_RULES: list[bytes] = []


def _rules() -> bytes:
    """This checking code, as bytes: a file that passed another version's check is checked
    again."""
    if not _RULES:
        try:
            _RULES.append(Path(__file__).read_bytes())
        except OSError:
            _RULES.append(repr((MODULE_KEYS, TABLES, ACCESS_CODES, IO_KINDS, REACHES, BREAKS)).encode())
    return _RULES[0]
