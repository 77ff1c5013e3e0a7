"""The module database: consistent in itself, and complete against the manuals' tables.

The parameter numbers are extracted from the manual text here (not copied), so a parameter the
database lacks, or one it invents, fails a test. The manuals are read from ``shared/seeds``
beside the checkout; without them those tests skip and the consistency tests still run.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import pytest

from tmclsh.tmcl import asm, modules
from tmclsh.tmcl import instructions as isa
from tmclsh.base.errors import ValidationError
from tmclsh.tmcl.modules import ACCESS_CODES, Parameter
from manuals import MODULES, manual_lines




# -- reading parameter tables out of the manual text --------------------------------------------
#
# The PDF extraction flattened each table row into several lines; a row starts with its number
# and the parameter's name ("140 Microstep", "0… 55 general purpose variable", on the TMCM-351
# also "20..55" and the font-garbled "34Ğ 033" = "56…255"). Inside a table the row numbers
# increase, which tells rows from the value lists in their description cells ("0 full step").

_SECTION = re.compile(r"^\d+(\.\d+)+\s+[A-Z]")  # "6.1 Velocity Calculation", "10.3 Bank 2"
_ACCESS = re.compile(r"(?:^|\s)(RWE|RW|R|W)\s*$")


def _ungarble(text: str) -> str:
    """The TMCM-351's shifted font: each character printed two code points low, Ğ for '…'."""
    return "".join("…" if c == "Ğ" else c if c.isspace() else chr(ord(c) + 2) for c in text)


@dataclass
class Row:
    number: int
    last: int  # last number of a range row ("0… 55"), else == number
    lines: list[str]
    table: str = ""  # what the table is for: "SAP" list, bank number, ...

    @property
    def name(self) -> str:
        return self.lines[0]

    @property
    def access(self) -> set[str]:
        """Access codes printed in the row (some rows print two: 'RW torque mode, R ...')."""
        return {m.group(1) for line in self.lines if (m := _ACCESS.search(line))}


@dataclass
class TableSpec:
    header: re.Pattern[str]
    name: str  # regex: how a parameter name starts in this manual
    context: re.Pattern[str] | None = None  # a line naming what the following tables are for


def read_tables(lines: list[str], spec: TableSpec) -> list[Row]:
    row_re = re.compile(r"^\s*(\d{1,3})(?:\s*(?:…|\.\.)\s*(\d{1,3}))?\s+(" + spec.name + r".*)$")
    garbled_re = re.compile(r"^\s*[./0-7]+Ğ\s*[./0-7]+\s")  # "34Ğ 033 eclcp_j" = "56… 255 general"
    rows: list[Row] = []
    context, last, in_table = "", -1, False
    for line in lines:
        if spec.context is not None and (m := spec.context.search(line)):
            context = m.group(1)
        if spec.header.search(line):
            in_table, last = True, -1
            continue
        if not in_table:
            continue
        if _SECTION.match(line):
            in_table = False
            continue
        m = row_re.match(line)
        if m is None and garbled_re.match(line):
            m = row_re.match(_ungarble(line))
        if m and int(m.group(1)) > last:
            number = int(m.group(1))
            last = int(m.group(2)) if m.group(2) else number
            rows.append(Row(number, last, [m.group(3)], context))
        elif rows and rows[-1].table == context:
            rows[-1].lines.append(line)
    return rows


AXIS_TABLES = {
    "TMCM-1311": TableSpec(re.compile(r"^Number Axis [Pp]arameter Description"),
                           r"(?:[A-Z]|smartEnergy|stallGuard)"),
    "TMCM-351": TableSpec(re.compile(r"^Number Axis Parameter Description"), r"[a-z]",
                          re.compile(r"which can be used for (SAP|GAP|STAP|RSAP)")),
    "TMCM-1640": TableSpec(re.compile(r"^Number Axis Parameter Description"), r"[A-Za-z]"),
}
GLOBAL_TABLES = {
    "TMCM-1311": TableSpec(re.compile(r"^\s*Number Global parameter"), r"[A-Za-z]",
                           re.compile(r"^10\.\d Bank (\d)")),
    "TMCM-351": TableSpec(re.compile(r"^\s*Number Global parameter"), r"[A-Za-z]",
                          re.compile(r"o ?f bank (\d), which can be used for (?:SGP|GGP|STGP|RSGP)")),
    "TMCM-1640": TableSpec(re.compile(r"^\s*Number Global parameter"), r"[A-Za-z]",
                           re.compile(r"^6\.\d Bank (\d)")),
}
# The 351's global tables are per command; which command a table belongs to:
_351_GLOBAL_LIST = re.compile(r"which can be used for (SGP|GGP|STGP|RSGP)")

# Entries per manual (NOTES.md counts; a bank-2 range row is one entry).
AXIS_COUNTS = {"TMCM-1311": 107, "TMCM-351": 36, "TMCM-1640": 56}
GLOBAL_COUNTS = {"TMCM-1311": 38, "TMCM-351": 22, "TMCM-1640": 16}


def axis_rows(module: str) -> dict[int, list[Row]]:
    out: dict[int, list[Row]] = {}
    for row in read_tables(manual_lines(module), AXIS_TABLES[module]):
        out.setdefault(row.number, []).append(row)
    return out


def global_rows(module: str) -> dict[tuple[int, int], list[Row]]:
    """(bank, number) -> rows; a range row is filed under its first number."""
    lines = manual_lines(module)
    rows = read_tables(lines, GLOBAL_TABLES[module])
    out: dict[tuple[int, int], list[Row]] = {}
    for row in rows:
        out.setdefault((int(row.table), row.number), []).append(row)
    return out


def _351_global_lists() -> dict[tuple[int, int], set[str]]:
    """TMCM-351: in which command lists (SGP, GGP, STGP, RSGP) each global parameter is."""
    lines = manual_lines("TMCM-351")
    found: dict[tuple[int, int], set[str]] = {}
    for command in ("SGP", "GGP", "STGP", "RSGP"):
        for row in read_tables(_section(lines, command), GLOBAL_TABLES["TMCM-351"]):
            for number in range(row.number, row.last + 1):
                found.setdefault((int(row.table), number), set()).add(command)
    return found


def _section(lines: list[str], command: str) -> list[str]:
    """The lines of a 351 command section: from 'for <command>:' lists to the next command."""
    out, inside = [], False
    for line in lines:
        if (m := _351_GLOBAL_LIST.search(line)) is not None:
            inside = m.group(1) == command
        elif re.match(r"^5\.7\.\d+ ", line):
            inside = False
        if inside:
            out.append(line)
    return out


# -- the database against the manuals ------------------------------------------------------------

def _has_range(p: Parameter) -> bool:
    return p.choices is not None or (p.min is not None and p.max is not None)


def _explained(p: Parameter, printed: set[str]) -> bool:
    """The database's access code is the printed one, or its source says why not."""
    note = p.source or ""
    if p.access in printed:
        return True
    if not printed:
        return "access" in note.lower()
    mentions = [code for code in (p.access, *printed) if re.search(rf"\b{code}\b", note)]
    return len(mentions) >= 2


def _norm(text: str) -> str:
    return re.sub(r"[^a-z0-9]", "", text.replace("™", "TM").lower())


def _same_name(printed: str, manual_name: str) -> bool:
    """The row's first word is in the recorded manual name ("Target pos." / "Target pos. reached")."""
    return _norm(re.split(r"[\s(]", printed.strip(), maxsplit=1)[0]) in _norm(manual_name)


@pytest.mark.parametrize("module", MODULES)
def test_every_axis_parameter_of_the_manual_is_in_the_database(module: str) -> None:
    mod = modules.load(module)
    rows = axis_rows(module)
    assert len(rows) == AXIS_COUNTS[module]
    for number, printed in rows.items():
        p = mod.axis(number)
        assert p is not None, f"{module} AP {number} ({printed[0].name!r}) is not in the database"
        assert p.name and p.manual_name
        # the number is the manual's: the printed name starts like the recorded manual name
        assert any(_same_name(r.name, p.manual_name) for r in printed), (
            f"{module} AP {number}: manual prints {printed[0].name!r}, database says "
            f"{p.manual_name!r}")
        assert _has_range(p) or p.source, f"{module} AP {number}: no range and no source why"
        assert p.access in ACCESS_CODES


@pytest.mark.parametrize("module", MODULES)
def test_database_has_no_axis_parameter_the_manual_lacks(module: str) -> None:
    printed = set(axis_rows(module))
    extra = [p.label for p in modules.load(module).axis_params if p.number not in printed]
    assert extra == []


@pytest.mark.parametrize("module", ["TMCM-1311", "TMCM-1640"])
def test_axis_access_as_printed(module: str) -> None:
    mod = modules.load(module)
    for number, printed in axis_rows(module).items():
        p = mod.axis(number)
        codes = set().union(*(r.access for r in printed))
        # a deviation from the printed code, a choice between two codes, or a code chosen
        # where the manual prints none (AP 149: chapter 9 table only) is explained in the note
        assert _explained(p, codes), (
            f"{module} AP {number}: database {p.access}, manual {sorted(codes)}")


def test_351_axis_access_follows_the_command_lists() -> None:
    """TMCM-351 prints no access column: R = in the GAP list, W = SAP, E = STAP and RSAP."""
    mod = modules.load("TMCM-351")
    for number, printed in axis_rows("TMCM-351").items():
        lists = {r.table for r in printed}
        derived = ("R" if "GAP" in lists else "") + ("W" if "SAP" in lists else "") + (
            "E" if lists & {"STAP", "RSAP"} else "")
        assert _explained(mod.axis(number), {derived}), f"AP {number} is in the lists {lists}"


@pytest.mark.parametrize("module", MODULES)
def test_every_global_parameter_of_the_manual_is_in_the_database(module: str) -> None:
    mod = modules.load(module)
    rows = global_rows(module)
    entries: set[str] = set()
    for (bank, number), printed in rows.items():
        row = printed[0]
        p = mod.glob(number, bank)
        assert p is not None, f"{module} GP {number} bank {bank} ({row.name!r}) missing"
        # a range row ("0… 55") lies inside one entry
        assert p.covers(row.last), f"{p.label} does not cover {row.number}..{row.last}"
        entries.add(p.label)
        assert p.name and p.manual_name
        assert any(_same_name(r.name, p.manual_name) for r in printed), (
            f"{module} GP {number}: manual prints {row.name!r}, database {p.manual_name!r}")
        assert _has_range(p) or p.source, f"{module} {p.label}: no range and no source why"
        if module != "TMCM-351":  # the 351 prints no access column (see the list test)
            codes = set().union(*(r.access for r in printed))
            assert _explained(p, codes), (
                f"{module} {p.label}: database {p.access}, manual {sorted(codes)}")
    assert len(entries) == GLOBAL_COUNTS[module]


@pytest.mark.parametrize("module", MODULES)
def test_database_has_no_global_parameter_the_manual_lacks(module: str) -> None:
    printed = {(bank, n) for (bank, first), rows in global_rows(module).items()
               for n in range(first, rows[0].last + 1)}
    extra = [f"{p.label} #{n}" for p in modules.load(module).global_params
             for n in range(p.number, p.number + p.count) if (p.bank, n) not in printed]
    assert extra == []


def test_351_global_access_follows_the_command_lists() -> None:
    """R = in the GGP list, W = SGP, E = bank 0 (stored by SGP itself) or the STGP list."""
    mod = modules.load("TMCM-351")
    lists = _351_global_lists()
    assert lists, "no TMCM-351 global parameter lists found"
    for (bank, number), commands in lists.items():
        p = mod.glob(number, bank)
        assert p is not None, f"GP {number} bank {bank}"
        derived = ("R" if "GGP" in commands else "") + ("W" if "SGP" in commands else "") + (
            "E" if bank == 0 and "SGP" in commands or commands & {"STGP", "RSGP"} else "")
        assert _explained(p, {derived}), f"{p.label}: lists {sorted(commands)}"


# -- the database in itself ------------------------------------------------------------------------

ALL_PARAMS = [(m, p) for m in MODULES for p in modules.load(m).axis_params
              + modules.load(m).global_params]


@pytest.mark.parametrize("module", MODULES)
def test_names_unique_and_usable(module: str) -> None:
    mod = modules.load(module)
    for pool in (mod.axis_params, mod.global_params):
        folded = [p.name.lower() for p in pool]
        assert len(folded) == len(set(folded)), "names differ only in case or repeat"
    keywords = {s.mnemonic for s in isa.all_instructions()}
    for p in mod.axis_params + mod.global_params:
        assert p.name.isidentifier() and p.name.isascii(), p.name
        assert p.name.upper() not in keywords
        # the name is a single token the line parser reads as a name
        assert [t.kind for t in asm.tokenize(p.name)] == ["name"]


@pytest.mark.parametrize("module, p", ALL_PARAMS, ids=lambda x: getattr(x, "label", x))
def test_parameter_entry_consistent(module: str, p: Parameter) -> None:
    assert p.access in ACCESS_CODES
    assert (p.min is None) == (p.max is None), "a range has both ends or none"
    if p.min is not None:
        assert p.min <= p.max
        assert -(2**31) <= p.min and p.max <= 2**32 - 1, "fits the 32-bit value field"
    else:
        assert p.choices or p.source, "no range: the source must say why"
    if p.choices:
        assert len(set(p.choices)) == len(p.choices)
        if p.min is not None:
            assert all(p.min <= c <= p.max for c in p.choices)
    if p.default is not None:
        assert p.in_range(p.default), f"default {p.default} outside {p.range_text}"
    for value in p.values:
        assert p.in_range(value), f"named value {value} outside {p.range_text}"
    for bit in p.bits:
        assert 0 <= bit < 32
        if p.max is not None:
            assert p.max >= 1 << bit, f"bit {bit} cannot be set within {p.range_text}"
    if p.kind == "global":
        assert p.count >= 1 and p.number + p.count - 1 <= 255
    else:
        assert p.count == 1 and p.bank == 0 and 0 <= p.number <= 255


@pytest.mark.parametrize("module", MODULES)
def test_global_entries_do_not_overlap(module: str) -> None:
    seen: dict[tuple[int, int], str] = {}
    for p in modules.load(module).global_params:
        for n in range(p.number, p.number + p.count):
            assert (p.bank, n) not in seen, f"{p.label} overlaps {seen[(p.bank, n)]}"
            seen[(p.bank, n)] = p.label


@pytest.mark.parametrize("module", MODULES)
def test_a_136_answer_builds_only_the_module_it_names(module: str, monkeypatch) -> None:
    """Telling a module by its version string (every bring-up) reads the others' names and
    ids, not their whole tables: a start-up builds one module's."""
    version = modules.load(module).version_string
    built = []
    real = modules._load

    def counted(file_name: str):
        built.append(file_name)
        return real(file_name)

    monkeypatch.setattr(modules, "_load", counted)
    assert modules.from_version_string(version).name == module
    assert built == [modules._file_name(module)]


@pytest.mark.parametrize("module", MODULES)
def test_module_header(module: str) -> None:
    mod = modules.load(module)
    assert mod.name == module and mod.motors >= 1 and mod.program_memory > 0
    assert modules.from_version_string(mod.version_string) is mod
    assert modules.by_firmware_id(mod.firmware_id) is mod
    assert len(mod.version_string) == 8
    assert mod.position_min < 0 < mod.position_max
    assert mod.velocity_min <= mod.velocity_max
    for port in mod.io:
        assert port.kind in ("digital_in", "analog_in", "digital_out")
        assert port.min <= port.max
        if port.default is not None:
            assert port.min <= port.default <= port.max
    ports = [(p.bank, p.port) for p in mod.io]
    assert len(ports) == len(set(ports))


def test_module_facts_from_the_manuals() -> None:
    m1311, m351, m1640 = (modules.load(m) for m in MODULES)
    assert (m1311.motors, m351.motors, m1640.motors) == (1, 3, 1)
    assert m351.position_min == -(2**23) and m351.position_max == 2**23 - 1
    assert (m351.velocity_min, m351.velocity_max) == (0, 2047)
    assert (m1640.velocity_min, m1640.velocity_max) == (-200000, 200000)
    assert m1311.interrupts and not m351.interrupts and not m1640.interrupts
    assert m1311.ascii_mode and m351.ascii_mode and not m1640.ascii_mode
    assert m1311.banks() == [0, 2, 3] and m351.banks() == [0, 2] and m1640.banks() == [0, 2]
    assert [p.name for p in m1640.io if p.bank == 2] == ["OUT_0"]  # 1640: one output
    assert m351.coordinates == 57 and m1311.coordinates == 21


# -- lookups ------------------------------------------------------------------------------------

def test_lookup_by_number_name_and_prefix() -> None:
    mod = modules.load("1311")
    assert mod.lookup("axis", 140).name == "MicrostepResolution"
    assert mod.lookup("axis", "microstepresolution").number == 140
    assert mod.lookup("axis", "Microstep_Resolution").number == 140
    assert mod.lookup("global", "SerialAddress").number == 66
    assert mod.lookup("global", 42, 2).count == 56
    with pytest.raises(ValidationError, match="no axis parameter 250"):
        mod.lookup("axis", 250)
    with pytest.raises(ValidationError, match="no global parameter 47 in bank 3"):
        mod.lookup("global", 47, 3)
    with pytest.raises(ValidationError, match="unknown axis parameter"):
        mod.lookup("axis", "NoSuchThing")
    # a unique prefix or part of a name resolves; an ambiguous one or a misspelling only
    # suggests (the result may be written to the module)
    assert mod.lookup("axis", "microstep").number == 140
    with pytest.raises(ValidationError, match="did you mean MaxPositioningSpeed, MaxPossibleCurrent"):
        mod.lookup("axis", "maxpos")
    with pytest.raises(ValidationError, match="did you mean Vsense"):
        mod.lookup("axis", "Nonsense")
    assert [p.name for p in mod.search("Nonsense", "axis")] == ["Vsense"]


def test_load_accepts_spellings_and_refuses_unknown() -> None:
    assert modules.load("TMCM-1311") is modules.load("tmcm1311") is modules.load("1311")
    assert modules.available() == sorted(MODULES)
    with pytest.raises(ValidationError, match="unknown module"):
        modules.load("TMCM-9999")
    assert modules.from_version_string("1311V111").name == "TMCM-1311"
    assert modules.from_version_string("garbage") is None


def test_parameter_check_messages() -> None:
    p = modules.load("1311").axis(140)
    p.check(8)
    with pytest.raises(ValidationError, match=r"9 is out of range for AP 140 MicrostepResolution"):
        p.check(9)
    assert p.describe_value(8).startswith("256")


# -- what users read ------------------------------------------------------------------------------

# Words of transcribing a manual: they belong in `source`, never in what `help` shows a user.
_TRANSCRIPTION = re.compile(
    r"decod|misprint|decided|decision|printed|garbled|superscript|typo|§|chapter|taken as|"
    r"\bkept\b|chosen|-era\b|dropped digit|\bread as\b|the table|revision|"
    r"(?-i:[\u0100-\u017f])",  # the TMCM-351 manual's shifted font (`.Ğ4`, `ē`)
    re.IGNORECASE)

_USER_TEXTS = [(m, p.label, field, text) for m in MODULES for p in modules.load(m).axis_params
               + modules.load(m).global_params
               for field, text in (("note", p.note), ("description", p.description),
                                   ("manual_name", p.manual_name)) if text] + [
    (m, f"{port.name} (bank {port.bank})", field, text) for m in MODULES
    for port in modules.load(m).io for field, text in (("note", port.note),
                                                        ("description", port.description)) if text]


@pytest.mark.parametrize("module, label, field, text", _USER_TEXTS,
                         ids=[f"{m}-{label}-{f}" for m, label, f, _ in _USER_TEXTS])
def test_user_text_has_no_transcription_notes(module: str, label: str, field: str,
                                              text: str) -> None:
    found = _TRANSCRIPTION.search(text)
    assert found is None, f"{module} {label} {field} says {found.group()!r}: move it to source"


def test_vocabulary_check_catches_the_old_notes() -> None:
    """The check above would have refused what `help 140` showed on the TMCM-351."""
    assert _TRANSCRIPTION.search("Range printed garbled '.\u011e4', decoded 0…6.")
    assert _TRANSCRIPTION.search("decided RWE like all neighbouring configuration parameters")
    assert _TRANSCRIPTION.search("'5535' is likely a misprint")
    assert not _TRANSCRIPTION.search("Should always be 1; do not change it.")


def test_a_source_is_kept_where_the_note_was_split() -> None:
    """The maintainers' record survives: every decision text is still in the data."""
    mod = modules.load("TMCM-351")
    p = mod.axis(140)
    assert p.note and "\u011e4" not in p.note
    assert p.source and "decoded 0…6" in p.source


@pytest.mark.parametrize("module, p", ALL_PARAMS, ids=lambda x: getattr(x, "label", x))
def test_no_default_where_the_source_says_none_was_printed(module: str, p: Parameter) -> None:
    source = (p.source or "").lower()
    if re.search(r"no default printed|default not printed", source):
        assert p.default is None, f"{module} {p.label}: the manual gives no default"
