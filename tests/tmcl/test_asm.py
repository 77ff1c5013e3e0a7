"""The line parser, the encoder's checks, the assembler and the disassembler, by example.

Every refusal is an AsmError that names the file, line and column and says what is allowed.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tmclsh.tmcl import asm, modules
from tmclsh.base.errors import AsmError
from tmclsh.tmcl.frames import Instruction

M1311 = modules.load("TMCM-1311")
M351 = modules.load("TMCM-351")
M1640 = modules.load("TMCM-1640")


def enc(text: str, module=M1311, **kw) -> Instruction:
    return asm.encode(asm.parse_line(text), module, **kw).instruction


def error(text: str, module=M1311) -> AsmError:
    """The AsmError that assembling ``text`` as a program raises."""
    with pytest.raises(AsmError) as info:
        asm.assemble(text, module, file="prog.tmc")
    return info.value


# -- the line parser --------------------------------------------------------------------------

def test_parse_line_forms() -> None:
    line = asm.parse_line("Loop:   MVP ABS, 0, 100000   //Move to Position")
    assert (line.label, line.mnemonic, len(line.operands), line.comment) == (
        "Loop", "MVP", 3, "Move to Position")
    assert asm.parse_line("Out0Off:").label == "Out0Off"
    assert asm.parse_line("Out0Off:").mnemonic is None
    const = asm.parse_line("MaxSpeed = 500")
    assert (const.constant, const.constant_col) == ("MaxSpeed", 1)
    assert asm.parse_line("#include Interrupts.inc").include == "Interrupts.inc"
    quoted = asm.parse_line('  #include "My File.inc"  // x')
    assert (quoted.include, quoted.include_col) == ("My File.inc", 13)
    assert asm.parse_line("   // only a comment").mnemonic is None
    assert asm.parse_line("").mnemonic is None
    assert asm.parse_line("rol 0, 500").mnemonic == "ROL"  # case-insensitive


def test_numbers_and_expressions() -> None:
    symbols = asm.Symbols(constants={"Base": 100})
    for text, value in [("$1F", 31), ("0x1f", 31), ("0b101", 5), ("-(2+3)*4", -20),
                        ("Base/3", 33), ("-7/2", -3), ("-7%2", -1), ("7%-2", 1),
                        ("base * 2 - 1", 199), ("- 10000", -10000)]:
        line = asm.parse_line(f"COMP {text}")
        assert asm.encode(line, M1311, symbols).instruction.value == value, text


def test_comma_after_mnemonic_is_accepted() -> None:
    # the manuals print `EI, 255` and `SGP, 0, 2, 100`
    assert enc("EI, 255") == enc("EI 255") == Instruction(25, 255, 0, 0)
    assert enc("SGP, 0, 2, 100", M1640) == Instruction(9, 0, 2, 100)


def test_raw_command_numbers() -> None:
    assert enc("138 0, 0, 0") == Instruction(138, 0, 0, 0)
    assert enc("$8A 0, 0, 1") == enc("0x8A 0, 0, 1") == Instruction(138, 0, 0, 1)
    assert enc("136 1") == Instruction(136, 1, 0, 0)
    assert enc("6 1, 0, 5") == Instruction(6, 1, 0, 5)
    assert enc("137 0, 0, 1234", direct=True) == Instruction(137, 0, 0, 1234)
    with pytest.raises(AsmError, match="needs the value 1234"):
        enc("137", direct=True)
    with pytest.raises(AsmError, match="out of range 0..255"):
        enc("256 0, 0, 0")
    with pytest.raises(AsmError, match="out of range 0..255"):
        enc("6 1, 256, 0")


def test_all_three_fields_may_be_written() -> None:
    # the manual writes `GAP 1, 0, 0` (don't-care value) and `GCO 0, 255, 0`
    assert enc("GAP 1, 0, 0") == enc("GAP 1, 0") == Instruction(6, 1, 0, 0)
    assert enc("ROR 0, 0, 500") == enc("ROR 0, 500")
    # a value in a field the command does not use is refused (issue 23: it went unseen), the
    # instruction data saying which fields each command uses; the raw form sends it
    for line, col, field in (("GAP 1, 0, 5", 11, "value"), ("MST 0, 0, 5", 11, "value"),
                             ("MST 2, 0, 0", 5, "type"), ("GGP 66, 0, 5", 12, "value")):
        with pytest.raises(AsmError, match=rf"too many operands: .*does not use its {field} "
                           r"field; the raw form \d+ <type>, <motor>, <value> sends") as info:
            enc(line)
        assert info.value.col == col
    assert enc("6 1, 0, 5") == Instruction(6, 1, 0, 5)
    assert enc("GAP 1, 0, 2 - 2") == Instruction(6, 1, 0, 0)  # (an expression that is 0)
    with pytest.raises(AsmError, match=r"too many operands: MST <motor>") as info:
        enc("MST 0, 0")
    assert info.value.col == 8


def test_parameter_names_in_the_type_slot() -> None:
    assert enc("GAP ActualPosition, 0") == Instruction(6, 1, 0, 0)
    assert enc("GAP actualposition") == Instruction(6, 1, 0, 0)  # motor 0 by default
    assert enc("SAP MaxPositioningSpeed, 0, 1000") == Instruction(5, 4, 0, 1000)
    assert enc("SGP SerialAddress, 0, 5") == Instruction(9, 66, 0, 5)
    assert enc("GGP SerialAddress") == Instruction(10, 66, 0, 0)  # its bank
    assert enc("SGP Timer0Period, 3, 1000") == Instruction(9, 0, 3, 1000)
    with pytest.raises(AsmError, match="in bank 0, not bank 2"):
        enc("GGP SerialAddress, 2")
    with pytest.raises(AsmError, match="unknown axis parameter 'Nonsense'.*did you mean Vsense"):
        enc("SAP Nonsense, 0, 1")  # a misspelling is never guessed into another parameter


def test_direct_and_ascii_mode_refusals() -> None:
    with pytest.raises(AsmError, match="only works inside a stored program"):
        enc("CALC ADD, 1", direct=True)
    with pytest.raises(AsmError, match="only works inside a stored program"):
        enc("JA Somewhere", direct=True)
    with pytest.raises(AsmError, match="RSUB is not accepted in ASCII mode"):
        enc("RSUB", ascii=True)
    assert enc("GAP 1, 0", direct=True, ascii=True) == Instruction(6, 1, 0, 0)
    assert enc("UF3 1, 2, 3", direct=True, ascii=True) == Instruction(67, 1, 2, 3)


def test_module_specific_commands_and_types() -> None:
    with pytest.raises(AsmError, match="EI is not available on the TMCM-351"):
        enc("EI 255", M351)
    with pytest.raises(AsmError, match="RFS is not available on the TMCM-1640"):
        enc("RFS START, 0", M1640)
    with pytest.raises(AsmError, match="MVP has no type 'COORD': ABS|REL"):
        enc("MVP COORD, 0, 1", M1640)
    assert enc("JC EAL, 0", M1640) == Instruction(21, 9, 0, 0)
    with pytest.raises(AsmError, match="JC has no type 'EAL'"):
        enc("JC EAL, 0")
    assert enc("SAC 1, 2, 3", M351) == Instruction(29, 1, 2, 3)


# -- the checks: each refusal names what is allowed -----------------------------------------------

@pytest.mark.parametrize("text, module, message, col", [
    ("SAP 140, 0, 9", M1311, r"9 is out of range for AP 140 MicrostepResolution: allowed 0..8", 13),
    ("SAP 4, 0, 4294967296", M1311, r"out of range for a TMCL operand: allowed -2147483648..4294967295", 11),
    ("ROR 0, 300000000", M1311, r"velocity 300000000 out of range -268435455..268435454", 8),
    ("ROL 0, -1", M351, r"velocity -1 out of range 0..2047", 8),
    ("MVP ABS, 0, 8388608", M351, r"position 8388608 out of range -8388608..8388607", 13),
    ("MVP COORD, 0, 21", M1311, r"coordinate 21 out of range: 0..20", 15),
    ("MVP COORD, $08, 2", M351, r"not a valid MVP COORD motor mask", 12),
    ("MVP ABS, $47, 2", M351, r"TMCM-351 has no motor 71: motors 0..2", 10),
    ("SCO 21, 0, 0", M1311, r"coordinate 21 out of range", 5),
    ("SIO 0, 2, 2", M1311, r"value 2 out of range 0..1 for this port", 11),
    ("SIO 0, 0, 1", M1311, r"AIN_0 \(bank 0 port 0\) is an input; SIO sets outputs", 11),
    ("SIO 1, 2, 1", M1640, r"TMCM-1640 has no port 1 in I/O bank 2: ports 0", 5),
    ("GIO 0, 5", M1311, r"no I/O bank 5: banks 0, 1, 2", 8),
    ("SGP 64, 1, 0", M1311, r"no parameter bank 1: banks 0, 2, 3", 9),
    ("SGP 70, 0, 0", M1640, r"TMCM-1640 has no global parameter 70", 5),
    ("SAP 8, 0, 1", M1311, r"AP 8 TargetPositionReached is read-only", 1),
    ("GAP 29, 0", M1311, r"AP 29 ClearI2tExceededFlag is write-only", 1),
    ("STAP 1, 0", M1311, r"AP 1 ActualPosition cannot be stored in EEPROM \(access RW\)", 1),
    ("WAIT TICKS, 0, -1", M1311, r"ticks must not be negative", 16),
    ("WAIT FOREVER, 0, 0", M1311, r"WAIT has no type 'FOREVER': TICKS\|POS\|REFSW\|LIMSW\|RFS", 6),
    ("CALC 11, 1", M1311, r"CALC has no type 11: ADD=0", 6),
    ("EI 4", M1311, r"4 is not an interrupt number: 0, 1, 2, 3, 15", 4),
    ("JA 2048", M1311, r"address 2048 is outside program memory 0..2047", 4),
    ("GAP 1, 3", M351, r"TMCM-351 has no motor 3: motors 0..2", 8),
    ("SAP 4, 0", M1311, r"SAP needs a value: SAP <parameter>, <motor>, <value>", 1),
    ("CALC", M1311, r"CALC needs its first operand", 1),
    # three operands fill type, motor, value: where that moves one, the refusal says so
    ("ROR 0, 1000, 5", M1311, r"no motor 1000: only motor 0 \(ROR takes ROR <motor>, "
     r"<velocity>; three operands are read as <type>, <motor>, <value>\)$", 8),
    ("GAP 1, 3, 5", M1311, r"no motor 3: only motor 0$", 8),
])
def test_out_of_range_and_wrong_operands(text: str, module, message: str, col: int) -> None:
    err = error(f"// a program\n{text}\n", module)
    assert (err.file, err.line, err.col) == ("prog.tmc", 2, col)
    assert re.search(message, err.message), err.message
    assert str(err).startswith(f"prog.tmc:2:{col}: ")


@pytest.mark.parametrize("text, message, col", [
    ("SAP 4, , 5", r"expected a number or a name, found ','", 8),
    ("SAP 4 0 5", r"expected ',' between operands, found '0'", 7),
    ("MVP ABS, 0, (5", r"operand missing at end of line", 15),
    ("MVP ABS, 0, (5 6)", r"expected '\)', found '6'", 16),
    ("SAP 4, 0,", r"operand missing after ','", 10),
    ("SAP 1, 0, 2, 3", r"at most three operands", 14),
    ("ROR 0, 500 ?", r"unexpected character '\?'", 12),
    ("ROR 0, 5.5", r"unexpected character '\.'", 9),
    ("#define X 1", r"unknown directive '#define' \(only #include is known\)", 1),
    ("#include", r"#include needs a file name", 1),
    ("Loop: X = 1", r"a constant cannot follow a label", 7),
    ("X = 1 2", r"unexpected '2' after the constant's value", 7),
    (", 5", r"expected a command, found ','", 1),
    ("COMP 1/0", r"division by zero", 8),
    ("COMP Undefined", r"unknown name 'Undefined'", 6),
    ("COMP 99999999999999999999999999999999999999999", r"is too long", 6),
    ("COMP " + "-" * 200 + "1", r"nested too deeply", 70),
    ("COMP " + "(" * 100 + "1" + ")" * 100, r"nested too deeply", 70),
    ("COMP 65536*65536*65536*65536*65536", r"value too large", 6),
])
def test_malformed_source(text: str, message: str, col: int) -> None:
    err = error(text)
    assert (err.file, err.line) == ("prog.tmc", 1)
    assert re.search(message, err.message), err.message
    assert err.col == col


def test_unknown_mnemonic_with_suggestion() -> None:
    err = error("Start:\n    MPV ABS, 0, 5000\n")
    assert (err.line, err.col) == (2, 5)
    assert err.message.startswith("unknown command 'MPV'; did you mean MVP")
    assert error("ROTATE 0, 5").message == "unknown command 'ROTATE'"
    # suggestions come from the module's own commands (SAC is the TMCM-351's)
    message = error("CALXC ADD").message
    assert message.startswith("unknown command 'CALXC'; did you mean CALC, CALCX")
    assert "SAC" not in message


def test_undefined_and_duplicate_labels() -> None:
    err = error("    JA Nowhere\n")
    assert (err.line, err.col, err.message) == (1, 8, "undefined label 'Nowhere'")
    err = error("Loop: STOP\n\nloop: STOP\n")  # names are case-insensitive
    assert (err.line, err.col, err.message) == (3, 1, "'loop' is already defined (line 1)")
    err = error("Speed = 5\nSpeed: STOP\n")
    assert (err.line, err.message) == (2, "'Speed' is already defined (line 1)")
    err = error("STOP: JA STOP\n")
    assert err.message == "'STOP' is a command name"


def test_program_larger_than_memory() -> None:
    assert len(asm.assemble("STOP\n" * 2048, M1311)) == 2048
    err = error("STOP\n" * 2049)
    assert (err.line, err.col) == (2049, 1)
    assert "program needs 2049 instructions from address 0; the TMCM-1311 holds 2048" in str(err)
    with pytest.raises(AsmError, match="needs 49 instructions from address 2000") as info:
        asm.assemble("STOP\n" * 49, M1640, origin=2000)
    assert info.value.line == 49


# -- includes ---------------------------------------------------------------------------------

def test_includes_beside_the_file(tmp_path: Path) -> None:
    (tmp_path / "speeds.inc").write_text("MaxSpeed = 1000 // from an include\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "inner.inc").write_text("Inner = 3\n")
    (tmp_path / "outer.inc").write_text("#include sub/inner.inc\nOuter = Inner + 1\n")
    main = tmp_path / "main.tmc"
    main.write_text("#include speeds.inc\n#include outer.inc\nSAP 4, 0, MaxSpeed\nCOMP Outer\n")
    program = asm.assemble_file(main, M1311)
    assert program.instructions == [Instruction(5, 4, 0, 1000), Instruction(20, 0, 0, 4)]
    assert program.loc(0).file == str(main) and program.loc(0).line == 3


def test_generated_include_files() -> None:
    text = ("#include Interrupts.inc\n#include TMCLParam.tmc\n"
            "EI TI_TIMER1\nGAP APActualPosition, Motor0\nGGP GPSerialAddress, 0\n")
    program = asm.assemble(text, M1311)
    assert program.instructions == [Instruction(25, 1, 0, 0), Instruction(6, 1, 0, 0),
                                    Instruction(10, 66, 0, 0)]
    generated = asm.generated_includes(M351)
    assert set(generated) == {"interrupts.inc", "tmclparam.tmc", "tmclparam.inc", "tmcm-351.inc"}
    assert "Motor2 = 2" in generated["tmclparam.tmc"]
    assert "APMicrostepResolution = 140" in generated["tmclparam.tmc"]
    assert set(asm.generated_includes(None)) == {"interrupts.inc"}
    # every generated file assembles on its own and defines no name twice
    for module in (M1311, M351, M1640):
        for name in asm.generated_includes(module):
            asm.assemble(f"#include {name}\n", module)


def test_real_include_file_wins_over_generated(tmp_path: Path) -> None:
    (tmp_path / "Interrupts.inc").write_text("TI_TIMER0 = 2\n")
    main = tmp_path / "main.tmc"
    main.write_text("#include Interrupts.inc\nEI TI_TIMER0\n")
    # a constant shadows the built-in interrupt name
    assert asm.assemble_file(main, M1311).instructions == [Instruction(25, 2, 0, 0)]


def test_recursive_include(tmp_path: Path) -> None:
    (tmp_path / "a.inc").write_text("X = 1\n#include b.inc\n")
    (tmp_path / "b.inc").write_text("\n\n#include a.inc\n")
    main = tmp_path / "main.tmc"
    main.write_text("#include a.inc\nSTOP\n")
    with pytest.raises(AsmError, match="recursive #include of a.inc") as info:
        asm.assemble_file(main, M1311)
    assert (info.value.file, info.value.line, info.value.col) == (str(tmp_path / "b.inc"), 3, 10)
    (tmp_path / "self.tmc").write_text("#include self.tmc\n")
    with pytest.raises(AsmError, match="recursive #include of self.tmc"):
        asm.assemble_file(tmp_path / "self.tmc", M1311)


def test_missing_include(tmp_path: Path) -> None:
    main = tmp_path / "main.tmc"
    main.write_text("STOP\n#include nothere.inc\n")
    with pytest.raises(AsmError) as info:
        asm.assemble_file(main, M1311)
    err = info.value
    assert (err.file, err.line, err.col) == (str(main), 2, 10)
    assert "cannot find include file 'nothere.inc'" in err.message
    assert "built-in: interrupts.inc" in err.message


def test_missing_or_binary_source_file(tmp_path: Path) -> None:
    with pytest.raises(AsmError, match="cannot read") as info:
        asm.assemble_file(tmp_path / "none.tmc", M1311)
    assert info.value.file == str(tmp_path / "none.tmc")
    (tmp_path / "bin.tmc").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(AsmError, match="not a text file"):
        asm.assemble_file(tmp_path / "bin.tmc", M1311)


def test_include_names_that_cannot_be_files() -> None:
    for name in ("a\x00b", "x" * 5000):
        with pytest.raises(AsmError, match="include file"):
            asm.assemble(f"#include {name}\n", M1311)


# -- programs, images, disassembly ------------------------------------------------------------

SOURCE = """\
// demo
Speed = 2 * 500
        SAP 4, 0, Speed
Loop:   MVP ABS, 0, 10000
        WAIT POS, 0, 0
        JC GE, Loop
        CSUB Sub
        JA Loop
Sub:    RSUB
"""


def test_program_object() -> None:
    program = asm.assemble(SOURCE, M1311, file="demo.tmc")
    assert len(program) == 7 and program.labels == {"Loop": 1, "Sub": 6}
    assert program.instructions[0] == Instruction(5, 4, 0, 1000)
    assert program.instructions[3] == Instruction(21, 5, 0, 1)
    assert program.loc(1).line == 4 and program.loc(1).text.startswith("Loop:")
    assert program.loc(7) is None
    assert program.address_of_line(5) == 2 and program.label_at(6) == "Sub"
    assert asm.read_image(program.to_binary()) == program.instructions
    assert asm.read_image(program.to_hex().encode()) == program.instructions


def test_origin_shifts_labels() -> None:
    program = asm.assemble(SOURCE, M1311, origin=100)
    assert program.labels == {"Loop": 101, "Sub": 106}
    assert program.instructions[-2] == Instruction(22, 0, 0, 101)


def test_read_image_errors() -> None:
    with pytest.raises(AsmError, match="8-byte records; this one has 7 bytes"):
        asm.read_image(bytes(7))
    with pytest.raises(AsmError, match="record 2 .* expected 0x0b"):
        asm.read_image(bytes(8) + bytes((5, 4, 0, 0, 0, 0, 2, 0)))
    with pytest.raises(AsmError, match="expected 7 hex bytes, found 3") as info:
        asm.read_image(b"05 04 00 00 00 03 e8\n05 04 00\n")
    assert info.value.line == 2
    assert asm.read_image(b"") == []


@pytest.mark.parametrize("text", [b"SAP 4, 0, 1000\n", b"MVP ABS, 0, 100\n",  # 15 and 16 bytes
                                  "// Geschwindigkeit \u00e4ndern\nSTOP\n".encode()])
def test_text_given_as_an_image_is_called_text(text) -> None:
    """Was "a binary image is 8-byte records; this one has 15 bytes" (or, for 16 bytes, a
    checksum error about a "damaged" image)."""
    with pytest.raises(AsmError, match=r"this is text \(line 1: .*\), not a program image: a "
                                       r"TMCL-IDE binary image \(8-byte records\) or the --hex "
                                       r"text form .* `tmclsh asm FILE` makes an image of it"):
        asm.read_image(text)


def test_disassemble_generates_labels() -> None:
    program = asm.assemble(SOURCE, M1311)
    text = asm.disassemble(program.instructions, M1311)
    assert text.splitlines()[1:3] == ["L0001:", "    MVP ABS, 0, 10000"]
    assert "    JC GE, L0001" in text and "    CSUB L0006" in text
    assert "// MaxPositioningSpeed" in text.splitlines()[0]
    assert asm.assemble(text, M1311).instructions == program.instructions
    assert "// @3" in asm.disassemble(program.instructions, M1311, addresses=True)


def test_disassemble_jump_outside_the_image() -> None:
    image = [Instruction(22, 0, 0, 500), Instruction(22, 0, 0, 0)]
    text = asm.disassemble(image, M1311)
    assert "JA 500" in text and "L0000:" in text
    assert asm.assemble(text, M1311).instructions == image


@pytest.mark.parametrize("ins, text", [
    (Instruction(38, 0, 0, 256), "38 0, 0, 256"),  # RETI with a don't-care value (1311 #7)
    (Instruction(6, 6, 1, 0), "6 6, 1, 0"),  # GAP on a motor the module lacks (1311 #4)
    (Instruction(22, 0, 0, -1), "22 0, 0, -1"),  # a jump outside program memory
    (Instruction(25, 4, 0, 0), "25 4, 0, 0"),  # EI of an interrupt that does not exist
    (Instruction(29, 1, 2, 3), "29 1, 2, 3"),  # SAC: TMCM-351 only
    (Instruction(200, 1, 2, -3), "200 1, 2, -3"),  # no such command
    (Instruction(5, 140, 0, 9), "5 140, 0, 9"),  # microstep resolution out of range
])
def test_disassembler_falls_back_to_the_raw_form(ins: Instruction, text: str) -> None:
    got, comment = asm.disassemble_instruction(ins, M1311)
    assert got == text and comment
    assert enc(got) == ins


def test_disassembler_mnemonic_forms() -> None:
    cases = [
        (Instruction(4, 2, 0x47, 2), M351, "MVP COORD, $47, 2"),
        (Instruction(9, 132, 0, -1), M1640, "SGP 132, 0, 4294967295"),  # unsigned GP 132
        (Instruction(37, 0, 0, 12), M1311, "VECT TI_TIMER0, 12"),
        (Instruction(27, 0, 0, 50), M1311, "WAIT TICKS, 0, 50"),
        (Instruction(31, 0, 255, 0), M1311, "GCO 0, 255"),
        (Instruction(24, 0, 0, 0), M1311, "RSUB"),
    ]
    for ins, module, text in cases:
        assert asm.disassemble_instruction(ins, module)[0] == text
        assert enc(text, module) == ins
    # without a module the mnemonic is written unchecked; don't-care fields still go raw
    assert asm.disassemble_instruction(Instruction(6, 6, 1, 0))[0] == "GAP 6, 1"
    assert asm.disassemble_instruction(Instruction(6, 6, 1, 7))[0] == "6 6, 1, 7"


def test_symbols_are_case_insensitive() -> None:
    symbols = asm.Symbols(constants={"MaxSpeed": 5}, labels={"Loop": 3})
    assert symbols.lookup("MaxSpeed") == symbols.lookup("MAXSPEED") == 5
    assert symbols.lookup("loop") == 3 and symbols.lookup("nope") is None


@pytest.mark.parametrize("module", [M1311, M351, M1640], ids=lambda m: m.name)
def test_no_command_takes_a_value_in_a_field_it_does_not_use(module) -> None:
    """For every command the instruction data gives fewer than three fields: written with all
    three, a 0 in the unused field is the manuals' form; anything else is refused, naming the
    field (`GAP 4, 0, 5` used to send, or drop, the 5 without a word)."""
    from tmclsh.tmcl import instructions as isa

    checked = 0
    for spec in isa.all_instructions():
        if not spec.on(module.name) or len(spec.fields) == 3:
            continue
        for t, m, v in ((t, m, v) for t in (0, 1, 4, 255) for m in (0, 1, 2)
                        for v in (0, 1, 1234)):
            fields = {"type": t, "motor": m, "value": v}
            used = {f: (fields[f] if f in spec.fields else 0) for f in asm.FIELDS}
            line = f"{spec.mnemonic} {used['type']}, {used['motor']}, {used['value']}"
            direct = spec.direct  # (a program-only command: as the assembler reads it)
            try:
                enc(line, module, direct=direct)
            except AsmError:
                continue  # not valid on this module: try other field values
            break
        else:
            continue  # nothing simple is valid for it here (checked elsewhere by example)
        for unused in (f for f in asm.FIELDS if f not in spec.fields):
            bad = dict(used, **{unused: 7})
            with pytest.raises(AsmError, match=rf"does not use its {unused} field"):
                enc(f"{spec.mnemonic} {bad['type']}, {bad['motor']}, {bad['value']}", module,
                    direct=direct)
        checked += 1
    assert checked >= 20  # the commands of the module, not a handful


# -- the plain line's fast path (issue 34) -----------------------------------------------------

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_SPACE = st.sampled_from(["", " ", "  ", "\t", " \t "])
_NUMBER = st.one_of(st.integers(0, 2**40).map(str), st.sampled_from(["0", "007", "9" * 40,
                                                                      "9" * 41]))


@st.composite
def _plain_ish(draw) -> str:
    """Lines the fast path takes, and their near misses (a sign, hex, a missing comma, a
    label, a comment, a comma after the command, digits glued to a name)."""
    word = draw(st.sampled_from(["SGP", "sap", "MVP", "STOP", "x_1.y", "WAIT", "GAP1"]))
    numbers = draw(st.lists(_NUMBER, max_size=4))
    seps = [draw(st.sampled_from([", ", ",", " , ", " ", ",,"])) for _ in numbers]
    text = draw(_SPACE) + word
    if numbers:
        text += draw(st.sampled_from([" ", "\t", ", ", ""])) + numbers[0]
        for sep, n in zip(seps[1:], numbers[1:]):
            text += sep + draw(st.sampled_from(["", "-", "$", "0x", "+"])) + n
    text += draw(st.sampled_from(["", " ", "\n", "\r\n", " // note", ":", " = 1"]))
    return draw(_SPACE) + text


@settings(max_examples=400, deadline=None)
@given(_plain_ish())
def test_the_plain_lines_fast_path_reads_what_the_general_way_reads(text) -> None:
    try:
        want = asm._parse_line(text, 3, "x.tmc")
    except AsmError as exc:
        with pytest.raises(AsmError) as got:
            asm.parse_line(text, 3, "x.tmc")
        assert str(got.value) == str(exc)
        return
    assert asm.parse_line(text, 3, "x.tmc") == want


def test_the_fast_path_takes_the_plain_lines() -> None:
    for text in ("SGP 3, 2, 100", "  mvp 0,0, 51200\n", "STOP", "ROR 0 , 500"):
        assert asm._PLAIN.fullmatch(text.rstrip("\r\n")) is not None, text
