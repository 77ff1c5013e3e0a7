"""The instruction set: consistent in itself, and as the manuals print it.

The command numbers and symbolic types are read out of the manual text (``shared/seeds``
beside the checkout); without the manuals those tests skip.
"""

from __future__ import annotations

import re

import pytest

from tmclsh.tmcl import instructions as isa
from tmclsh.tmcl import modules
from tmclsh.tmcl.frames import Control
from manuals import MODULES, manual_lines




# -- the table in itself ------------------------------------------------------------------------

KINDS = {
    "type": {"none", "symbolic", "axis_param", "global_param", "port", "coordinate", "interrupt",
             "number"},
    "motor": {"none", "motor", "bank", "number"},
    "value": {"none", "velocity", "position", "param", "port_value", "label", "ticks", "number"},
}


@pytest.mark.parametrize("spec", isa.all_instructions(), ids=lambda s: s.mnemonic)
def test_spec_is_consistent(spec: isa.InstructionSpec) -> None:
    assert isa.by_opcode(spec.opcode) is spec and isa.by_mnemonic(spec.mnemonic) is spec
    assert isa.by_mnemonic(spec.mnemonic.lower()) is spec
    assert spec.type_kind in KINDS["type"]
    assert spec.motor_kind in KINDS["motor"]
    assert spec.value_kind in KINDS["value"]
    assert len(set(spec.fields)) == len(spec.fields)
    assert set(spec.fields) <= {"type", "motor", "value"}
    # a field is an operand exactly when it holds something
    for f, kind in (("type", spec.type_kind), ("motor", spec.motor_kind),
                    ("value", spec.value_kind)):
        assert (f in spec.fields) == (kind != "none"), f
    assert spec.modules and spec.modules <= set(modules.available())
    assert bool(spec.types or spec.types_for) == (spec.type_kind == "symbolic")
    for module in spec.types_for:
        assert module in spec.modules
    for module in modules.available():
        names = spec.type_names(module)
        assert len(set(names.values())) == len(names), "two names for one type number"
        assert all(0 <= v <= 255 and n.isupper() for n, v in names.items())
    assert set(spec.motor_special) <= spec.modules
    assert spec.syntax.startswith(spec.mnemonic)
    assert spec.jumps == (spec.mnemonic in ("JC", "JA", "CSUB", "VECT"))


def test_opcodes_and_mnemonics() -> None:
    specs = isa.all_instructions()
    assert len({s.opcode for s in specs}) == len(specs)
    assert [s.opcode for s in specs if s.mnemonic.startswith("UF")] == list(range(64, 72))
    assert [s.mnemonic for s in specs if 64 <= s.opcode <= 71] == [f"UF{n}" for n in range(8)]
    assert isa.by_mnemonic("NOPE") is None and isa.by_opcode(99) is None
    assert isa.Opcode.MVP == 4 and isa.Opcode.GET_VERSION == 136
    application = {op for op, c in isa.controls().items() if c.boot is None}
    assert application == set(range(128, 140)) == {int(c) for c in Control}
    # the bootloader's (PyTrinamic's tmcl.py: BOOT_ERASE_ALL = 200 ... BOOT = 242)
    assert {op: c.boot for op, c in isa.controls().items() if c.boot} == {
        200: "erase", 201: "write_word", 202: "write_page", 203: "checksum", 204: "read",
        205: "start", 206: "info", 208: "length", 242: "enter"}


def test_per_module_command_sets() -> None:
    """The commands that exist on one module only (NOTES.md §2)."""
    only = {m: {s.mnemonic for s in isa.all_instructions() if s.modules == {m}} for m in MODULES}
    assert only["TMCM-1311"] == {"EI", "DI", "VECT", "RETI"}
    assert only["TMCM-351"] == {"SAC"}
    assert only["TMCM-1640"] == set()
    missing_1640 = {s.mnemonic for s in isa.all_instructions() if not s.on("TMCM-1640")}
    assert missing_1640 == {"RFS", "EI", "DI", "VECT", "RETI", "SAC", "SCO", "GCO", "CCO",
                            "CLE", "ACO"}
    # the modules' own view of it
    assert modules.load("TMCM-1640").has_instruction(4)
    assert not modules.load("TMCM-1640").has_instruction(13)
    assert modules.load("TMCM-1311").has_control(138)
    assert not modules.load("TMCM-1640").has_control(139)


def test_interrupt_numbers() -> None:
    # TMCM-1311 §5.6.3
    ints = isa.interrupts()
    assert sorted(ints.values()) == [0, 1, 2, 3, 15, 21, 27, 28, *range(39, 47), 255]
    assert isa.interrupt_name(255) == "TI_GLOBAL" and isa.interrupt_name(3) == "TI_TARGET"
    assert isa.interrupt_name(4) is None
    # the interrupts that need configuring are the 1311's bank-3 global parameters
    bank3 = {p.number for p in modules.load("TMCM-1311").global_params if p.bank == 3}
    assert bank3 == set(ints.values()) - {3, 15, 21, 255}


# -- against the manuals ------------------------------------------------------------------------

# the command overview tables ("Mnemonic Command number Meaning") and the 351's command list
_OVERVIEW = {
    "TMCM-1311": (r"^5 TMCL Commands", r"^5\.7 Commands"),
    "TMCM-351": (r"^5\.4 ", r"^5\.6 The ASCII interface"),
    "TMCM-1640": (r"^4\.4 TMCL Command Overview", r"^4\.5\.1 "),
}
_OVERVIEW_ROW = re.compile(r"^([A-Z][A-Z0-9]{1,4})\s+(\d{1,3})\s+(?:[A-Z<]|$)")


def overview(module: str) -> dict[str, int]:
    start, end = (re.compile(x) for x in _OVERVIEW[module])
    found: dict[str, int] = {}
    inside = False
    for line in manual_lines(module):
        if start.search(line):
            inside = True
        elif end.search(line):
            inside = False
        elif inside and (m := _OVERVIEW_ROW.match(line)):
            assert found.setdefault(m.group(1), int(m.group(2))) == int(m.group(2)), line
    return found


@pytest.mark.parametrize("module", MODULES)
def test_command_numbers_as_printed(module: str) -> None:
    printed = overview(module)
    assert len(printed) >= 25
    for mnemonic, opcode in printed.items():
        spec = isa.by_mnemonic(mnemonic)
        assert spec is not None, f"{module} prints {mnemonic} {opcode}"
        assert spec.opcode == opcode and spec.on(module), mnemonic


@pytest.mark.parametrize("module", MODULES)
def test_every_command_of_a_module_is_in_its_manual(module: str) -> None:
    text = "\n".join(manual_lines(module))
    printed = overview(module)
    for spec in isa.all_instructions():
        if not spec.on(module):
            assert spec.mnemonic not in printed
            continue
        # printed in an overview table, or at least named in the manual (UF0…UF7, and the
        # TMCM-1311's CLE, which its §5.3 overview leaves out: 1311 #12)
        named = re.search(rf"\b{spec.mnemonic}\b", text) or (
            spec.mnemonic.startswith("UF") and "UF0" in text)
        assert spec.mnemonic in printed or named, f"{spec.mnemonic} not in the {module} manual"


_SECTION = re.compile(r"^(?:5\.7|4\.5)\.\d+(?:\.\d+)?\s+([A-Z]+)\b")  # "5.7.4 MVP (move...)"
_OTHER_HEADING = re.compile(r"^\d+(?:\.\d+)*\s+[A-Z][a-z]")  # "5.7.39 Control", "6 Axis"
# "0 ABS – absolute", "19 0 ADD – add", "0 – (ALL) all flags", "0 ADD add X register" (ē: 351)
# (type numbers are 0…10; parameter rows such as "64 EEPROM magic" are not types)
_TYPE = re.compile(r"(?:^|\s)(10|\d)\s+(?:[–ē-]\s+\()?([A-Z]{2,6})\)?(?=\s*(?:[–ē-]|\s[a-z]|\*|$))")


def symbolic_types(module: str) -> dict[str, dict[str, int]]:
    """Command -> {type name: number}, from each command section of the manual."""
    sections: dict[str, dict[str, int]] = {}
    current = None
    for line in manual_lines(module):
        if m := _SECTION.match(line):
            current = sections.setdefault(m.group(1), {})
            continue
        if _OTHER_HEADING.match(line):
            current = None
        if current is not None:
            for t in _TYPE.finditer(line):
                current.setdefault(t.group(2), int(t.group(1)))
    return {cmd: types for cmd, types in sections.items() if types}


@pytest.mark.parametrize("module", MODULES)
def test_symbolic_types_as_printed(module: str) -> None:
    printed = symbolic_types(module)
    expected_commands = {"TMCM-1311": {"MVP", "RFS", "CALC", "JC", "WAIT", "CALCX", "CLE"},
                         "TMCM-351": {"MVP", "RFS"},  # the rest of its chapter 5.7 is missing
                         "TMCM-1640": {"MVP", "CALC", "JC", "WAIT", "CALCX"}}[module]
    assert set(printed) == expected_commands
    for command, types in printed.items():
        assert isa.by_mnemonic(command).type_names(module) == types, command


def test_351_types_for_its_unprinted_commands() -> None:
    """The 351 manual ends before CALC…CLE; their types are the other manuals' (NOTES §2)."""
    for command in ("CALC", "JC", "WAIT", "CALCX", "CLE"):
        spec = isa.by_mnemonic(command)
        assert spec.type_names("TMCM-351") == spec.type_names("TMCM-1311")


# -- what users read ------------------------------------------------------------------------------

# The modules' vocabulary of transcribing a manual, plus the words the instruction notes used
# for it ("the TMCM-1311 manual says", "copied from ROR", "follows the TMCM-351 wording").
from test_modules import _TRANSCRIPTION  # noqa: E402

_WORDS = re.compile(_TRANSCRIPTION.pattern + r"|wording|copied from|\bsays?\b|\bfollows\b",
                    _TRANSCRIPTION.flags)


def _user_texts() -> list[tuple[str, str]]:
    """Every text `help`, the completer and the disassembler show about the instruction set."""
    out: list[tuple[str, str]] = []
    for spec in isa.all_instructions():
        out += [(f"{spec.mnemonic} summary", spec.summary), (f"{spec.mnemonic} note",
                                                               spec.note or "")]
        out += [(f"{spec.mnemonic} note on the {mod}", text)
                for mod, text in spec.notes_for.items()]
        out += [(f"{spec.mnemonic} type {name}", name) for name in spec.type_names()]
        out += [(f"{spec.mnemonic} {mod} motor {n}", text)
                for mod, table in spec.motor_special.items() for n, text in table.items()]
    for ctl in isa.controls().values():
        out += [(f"control {ctl.opcode} name", ctl.name),
                (f"control {ctl.opcode} note", ctl.note or "")]
    out += [(f"interrupt {name}", name) for name in isa.interrupts()]
    return [(where, text) for where, text in out if text]


@pytest.mark.parametrize("where, text", _user_texts(), ids=[w for w, _ in _user_texts()])
def test_user_text_has_no_transcription_notes(where: str, text: str) -> None:
    found = _WORDS.search(text)
    assert found is None, f"{where} says {found.group()!r}: move it to source"


def test_the_old_notes_are_sources_now() -> None:
    """The maintainers' record survives word for word, and the check above would have refused
    the notes that cited the manuals (CLE's only named the manual's syntax)."""
    old = {"ROL": "TMCM-1311 manual §5.7.2 says 'positive direction' (copied from ROR)",
           "RFS": "tmclsh follows the TMCM-351 wording",
           "CALC": "'nine different arithmetic functions' and list ten",
           "CLE": "The TMCM-1311 syntax names EPO but gives it no number"}
    for mnemonic, text in old.items():
        spec = isa.by_mnemonic(mnemonic)
        assert spec.source and text in spec.source, mnemonic
        assert _WORDS.search(spec.source) or mnemonic == "CLE", mnemonic
        assert spec.note is None or not _WORDS.search(spec.note)
    ctl = isa.control(128)
    assert ctl.source and "§11.6 'run command with address'" in ctl.source
    assert _WORDS.search(ctl.source) and ctl.note is None


def test_what_only_reads_is_the_instruction_sets_fact():
    """A replay sends these without --yes: reading instructions, RFS STATUS, and the
    controls marked ``access = "read"`` (134, 135, 136); anything else, and anything
    unknown, may write, store or move."""
    from tmclsh.tmcl import instructions as isa

    reads = [(6, 4), (10, 66), (15, 0), (13, isa.by_mnemonic("RFS").types["STATUS"]),
             (134, 0), (135, 0), (136, 0), (136, 1)]
    assert all(isa.only_reads(op, t) for op, t in reads)
    others = [(5, 4), (7, 4), (1, 0), (4, 0), (13, 0), (128, 0), (129, 0), (137, 0),
              (139, 0), (242, 0x81), (99, 0)]
    assert not any(isa.only_reads(op, t) for op, t in others)
