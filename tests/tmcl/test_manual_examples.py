"""Every binary example and every program listing printed in the three manuals.

The tables below are transcribed from the manuals' "Example" / "Binary:" / "Value (hex)" blocks
(TMCM-1311 and TMCM-1640 print eight bytes: address and instruction, no checksum; TMCM-351
prints nine, with the checksum). Where the manual contradicts itself, the row says how in
``erratum`` and the flags say which part is wrong; the bytes are taken as the better witness.
When the manuals are available (``shared/seeds`` beside the checkout), the transcription itself
is checked against them: every row's bytes are printed there, and every all-hex "Value (hex)"
line of a manual has a row here.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from tmclsh.tmcl import asm, modules
from tmclsh.tmcl import instructions as isa
from tmclsh.base.errors import AsmError
from tmclsh.tmcl.frames import Instruction, Reply, Request, checksum
from manuals import manual_lines

PROGRAMS = Path(__file__).resolve().parents[2] / "scripts" / "programs"



def hexbytes(printed: str) -> bytes:
    return bytes(int(tok, 16) for tok in printed.replace("$", " ").split())


def squeeze(text: str) -> str:
    """Compare source text ignoring spacing and case (`AAP 0,0` is `AAP 0, 0`)."""
    return re.sub(r"\s+", "", text).upper()


# -- the binary examples ---------------------------------------------------------------------

@dataclass(frozen=True)
class Example:
    module: str
    where: str
    mnemonic: str | None  # as printed (None: the manual prints bytes only)
    printed: str  # "Value (hex)" as printed: address, instruction (and checksum on the 351)
    disasm: str | None = None  # what the printed bytes disassemble to, if not `mnemonic`
    labels: dict[str, int] = field(default_factory=dict)  # addresses the caption assumes
    erratum: str | None = None
    mnemonic_differs: bool = False  # the printed mnemonic does not encode the printed bytes
    bad_checksum: bool = False  # the printed checksum byte is wrong
    bad_address: bool = False  # the target-address byte is not the module address 1

    @property
    def id(self) -> str:
        return f"{self.module}-{self.where}-{self.mnemonic or self.disasm}"


M1311, M351, M1640 = "TMCM-1311", "TMCM-351", "TMCM-1640"

EXAMPLES = [
    # TMCM-1311 TMCL firmware V1.11 manual rev. 1.17, chapter 5.7 ----------------------------
    Example(M1311, "5.7.1", "ROR 0, 10000", "$01 $01 $00 $00 $00 $00 $27 $10"),
    Example(M1311, "5.7.2", "ROL 0, 10000", "$01 $02 $00 $00 $00 $00 $27 $10"),
    Example(M1311, "5.7.3", "MST 0", "$01 $03 $00 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.4", "MVP ABS, 0, 9000", "$01 $04 $00 $00 $00 $01 $5f $90",
            disasm="MVP ABS, 0, 90000", mnemonic_differs=True,
            erratum="1311 #3: caption says 90000 and the bytes $00 $01 $5f $90 are 90000, "
                    "the mnemonic says MVP ABS, 0, 9000"),
    Example(M1311, "5.7.4", "MVP REL, 0, -1000", "$01 $04 $01 $00 $ff $ff $fc $18"),
    Example(M1311, "5.7.4", "MVP COORD, 0, 8", "$01 $04 $02 $00 $00 $00 $00 $08"),
    Example(M1311, "5.7.5", "SAP 6, 0, 200", "$01 $05 $06 $00 $00 $00 $00 $c8"),
    Example(M1311, "5.7.6", "GAP 6, 0", "$01 $06 $06 $01 $00 $00 $00 $00",
            disasm="6 6, 1, 0", mnemonic_differs=True,
            erratum="1311 #4: mnemonic GAP 6, 0 but the motor/bank byte is $01; the TMCM-1311 "
                    "has motor 0 only, so the bytes disassemble to the raw form"),
    Example(M1311, "5.7.7", "STAP 4, 0", "$01 $07 $04 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.8", "RSAP 6, 0", "$01 $08 $06 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.9", "SGP 66, 0, 3", "$01 $09 $42 $00 $00 $00 $00 $03"),
    Example(M1311, "5.7.10", "GGP 66, 0", "$01 $0a $42 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.11", "STGP 42, 2", "$01 $0b $2a $02 $00 $00 $00 $00"),
    Example(M1311, "5.7.12", "RSGP 42, 2", "$01 $0c $2a $02 $00 $00 $00 $00"),
    Example(M1311, "5.7.13", "RFS START, 0", "$01 $0d $00 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.14", "SIO 7, 2, 1", "$01 $0e $07 $02 $00 $00 $00 $01"),
    Example(M1311, "5.7.15", "GIO 0, 1", "$01 $0f $00 $01 $00 $00 $00 $00"),
    Example(M1311, "5.7.16", "CALC MUL, -5000", "$01 $13 $02 $00 $FF $FF $EC $78"),
    Example(M1311, "5.7.17", "COMP 1000", "$01 $14 $00 $00 $00 $00 $03 $e8"),
    Example(M1311, "5.7.18", "JC GE, Label", "$01 $15 $05 $00 $00 $00 $00 $0a",
            labels={"Label": 10}),
    Example(M1311, "5.7.19", "JA Loop", "$01 $16 $00 $00 $00 $00 $00 $14", labels={"Loop": 20}),
    Example(M1311, "5.7.20", "CSUB SubW", "$01 $17 $00 $00 $00 $00 $00 $64",
            labels={"SubW": 100}),
    Example(M1311, "5.7.21", "RSUB", "$01 $18 $00 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.22", "WAIT POS, 0, 0", "$01 $1b $01 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.23", "STOP", "$01 $1c $00 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.24", "SCO 1, 0, 1000", "$01 $1e $01 $00 $00 $00 $03 $e8"),
    Example(M1311, "5.7.25", "GCO 1, 0", "$01 $1f $01 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.26", "CCO 3, 0", "$01 $20 $03 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.27", "ACO 1, 0", "$01 $27 $01 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.28", "CALCX MUL", "$01 $21 $02 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.29", "AAP 0,0", "$01 $22 $00 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.30", "AGP 3, 2", "$01 $23 $03 $02 $00 $00 $00 $00"),
    Example(M1311, "5.7.31", "CLE ETO", "$01 $24 $01 $00 $00 $00 $00 $00"),
    Example(M1311, "5.7.32", "VECT 3, 500", "$01 $25 $03 $00 $00 $00 $01 $F4",
            disasm="VECT TI_TARGET, 500",
            erratum="1311 #14: caption 'Define interrupt vector at target position 500': it is "
                    "interrupt 3 (target position reached) with vector address 500"),
    Example(M1311, "5.7.33", "EI, 255", "$01 $19 $FF $00 $00 $00 $00 $00",
            disasm="EI TI_GLOBAL", erratum="1311 #15: comma after the mnemonic (accepted)"),
    Example(M1311, "5.7.33", "EI, 3", "$01 $19 $03 $00 $00 $00 $00 $00",
            disasm="EI TI_TARGET", erratum="1311 #15: comma after the mnemonic (accepted)"),
    Example(M1311, "5.7.34", "DI, 255", "$01 $1A $FF $00 $00 $00 $00 $00",
            disasm="DI TI_GLOBAL", erratum="1311 #15: comma after the mnemonic (accepted)"),
    Example(M1311, "5.7.34", "DI, 3", "$01 $1A $03 $00 $00 $00 $00 $00",
            disasm="DI TI_TARGET", erratum="1311 #15: comma after the mnemonic (accepted)"),
    Example(M1311, "5.7.35", "RETI", "$01 $26 $00 $00 $00 $00 $01 $00",
            disasm="38 0, 0, 256", mnemonic_differs=True,
            erratum="1311 #7: value bytes $00 $00 $01 $00 (256) in RETI's don't-care value; "
                    "only the raw form reproduces them"),
    # TMCM-351 TMCL firmware manual V1.03, chapter 5.7 (nine bytes: with checksum) -----------
    Example(M351, "5.7.1", "ROR 2, 350", "$01 $01 $00 $02 $00 $00 $01 $5e $62",
            bad_checksum=True, erratum="351 #4: checksum printed $62, the sum is $63"),
    Example(M351, "5.7.2", "ROL 1, 1200", "$01 $02 $00 $01 $00 $00 $04 $b0 $b8"),
    Example(M351, "5.7.3", "MST 1", "$01 $03 $00 $01 $00 $00 $00 $00 $05"),
    Example(M351, "5.7.4", "MVP ABS, 1, 9000", "$01 $04 $00 $01 $00 $01 $5f $90 $f6",
            disasm="MVP ABS, 1, 90000", mnemonic_differs=True,
            erratum="351 #5: caption 90000, bytes (and checksum $f6) 90000, mnemonic 9000"),
    Example(M351, "5.7.4", "MVP REL, 0, -1000", "$01 $04 $01 $00 $ff $ff $fc $18 $18"),
    Example(M351, "5.7.4", "MVP COORD, $47, 2", "$01 $04 $02 $47 $00 $00 $00 $02 $50"),
    Example(M351, "5.7.4", "MVP COORD, $87, 5", "$01 $04 $02 $87 $00 $00 $00 $05 $93"),
    Example(M351, "5.7.5", "SAP 6, 1, 200", "$01 $05 $06 $01 $00 $00 $00 $c8 $d5",
            erratum="351 #8: caption says '200mA'; AP 6 is a 0..255 scale (bytes are right)"),
    Example(M351, "5.7.6", "GAP 2, 1", "$01 $06 $01 $02 $00 $00 $00 $00 $0a",
            disasm="GAP 1, 2", mnemonic_differs=True,
            erratum="351 #6: mnemonic GAP 2, 1 but the bytes are GAP 1, 2 (actual position of "
                    "motor 2, as the caption says)"),
    Example(M351, "5.7.7", "STAP 4, 1", "$01 $07 $04 $01 $00 $00 $00 $00 $0d"),
    Example(M351, "5.7.8", "RSAP 6, 1", "$01 $08 $06 $01 $00 $00 $00 $00 $10"),
    Example(M351, "5.7.9", "SGP 66, 0, 3", "$01 $09 $42 $00 $00 $00 $00 $03 $4f"),
    Example(M351, "5.7.10", "GGP 66, 0", "$01 $0a $42 $00 $00 $00 $00 $00 $4d"),
    Example(M351, "5.7.11", "STGP 42, 2", "$01 $0b $2a $02 $00 $00 $00 $00 $38"),
    Example(M351, "5.7.12", "RSGP 66, 0", "$01 $08 $06 $00 $00 $00 $00 $00 $10",
            disasm="RSAP 6, 0", mnemonic_differs=True, bad_checksum=True,
            erratum="351 #7: RSGP example bytes are RSAP 6, 0 (instruction 8, not 12) and the "
                    "checksum is printed $10 where the sum is $0f"),
    Example(M351, "5.7.13", "RFS START, 1", "$01 $0d $00 $01 $00 $00 $00 $00 $0f"),
    Example(M351, "5.7.14", "SIO 7, 2, 1", "$01 $0e $07 $02 $00 $00 $00 $01 $19"),
    # TMCM-1640 TMCL firmware V2.10 manual rev. 2.06, chapter 4.5 ------------------------------
    Example(M1640, "4.5.1", "ROR 0, 350", "$01 $01 $00 $00 $00 $00 $01 $5e"),
    Example(M1640, "4.5.2", "ROL 0, 1200", "$01 $02 $00 $00 $00 $00 $04 $b0"),
    Example(M1640, "4.5.3", "MST 0", "$01 $03 $00 $00 $00 $00 $00 $00"),
    Example(M1640, "4.5.4", "MVP ABS, 0, 9000", "$01 $04 $00 $00 $00 $00 $23 $28"),
    Example(M1640, "4.5.4", "MVP REL, 0, -1000", "$00 $04 $01 $00 $ff $ff $fc $18",
            bad_address=True, erratum="1640 #1: target-address byte $00 (all other examples $01)"),
    Example(M1640, "4.5.5", "SAP 6, 0, 2000", "$01 $05 $06 $00 $00 $00 $07 $D0"),
    Example(M1640, "4.5.6", "GAP 1, 0", "$01 $06 $01 $00 $00 $00 $00 $00"),
    Example(M1640, "4.5.7", "STAP 4, 0", "$01 $07 $04 $00 $00 $00 $00 $00"),
    Example(M1640, "4.5.8", "RSAP 6, 0", "$01 $08 $06 $00 $00 $00 $00 $00"),
    Example(M1640, "4.5.9", "SGP, 0, 2, 100", "$01 $09 $00 $02 $00 $00 $00 $64",
            disasm="SGP 0, 2, 100", erratum="1640 #5: comma after the mnemonic (accepted)"),
    Example(M1640, "4.5.10", "GGP, 0, 2", "$01 $0a $00 $02 $00 $00 $00 $00",
            disasm="GGP 0, 2", erratum="1640 #5: comma after the mnemonic (accepted)"),
    Example(M1640, "4.5.11", "STGP, 0, 2", "$01 $0b $00 $02 $00 $00 $00 $00",
            disasm="STGP 0, 2", erratum="1640 #5: comma after the mnemonic (accepted)"),
    Example(M1640, "4.5.12", "RSGP, 0, 2", "$01 $0c $00 $02 $00 $00 $00 $00",
            disasm="RSGP 0, 2", erratum="1640 #5: comma after the mnemonic (accepted)"),
    Example(M1640, "4.5.13.1", None, "$01 $0e $07 $02 $00 $00 $00 $01",
            disasm="14 7, 2, 1",
            erratum="1640 #4: SIO example without mnemonic; its bytes are SIO 7, 2, 1 but the "
                    "TMCM-1640 has output port 0 only, so they disassemble to the raw form"),
    Example(M1640, "4.5.13.2", None, "$01 $0f $00 $01 $00 $00 $00 $00", disasm="GIO 0, 1",
            erratum="1640 #4: GIO example without mnemonic (bytes: GIO 0, 1)"),
    Example(M1640, "4.5.14", "CALC MUL, -5000", "$01 $13 $02 $00 $FF $FF $EC $78"),
    Example(M1640, "4.5.15", "COMP 1000", "$01 $14 $00 $00 $00 $00 $03 $e8"),
    Example(M1640, "4.5.16", "JC GE, Label", "$01 $15 $05 $00 $00 $00 $00 $0a",
            labels={"Label": 10}),
    Example(M1640, "4.5.17", "JA Loop", "$01 $16 $00 $00 $00 $00 $00 $14", labels={"Loop": 20}),
    Example(M1640, "4.5.18.1", "CSUB SubW", "$01 $17 $00 $00 $00 $00 $00 $64",
            labels={"SubW": 100}),
    Example(M1640, "4.5.18.2", "RSUB", "$01 $18 $00 $00 $00 $00 $00 $00"),
    Example(M1640, "4.5.19", "WAIT POS, 0, 0", "$01 $1b $01 $01 $00 $00 $00 $00",
            disasm="27 1, 1, 0", mnemonic_differs=True,
            erratum="1640 #3: WAIT POS, 0, 0 with motor/bank byte $01; the TMCM-1640 has "
                    "motor 0 only, so the bytes disassemble to the raw form"),
    Example(M1640, "4.5.20", "STOP", "$01 $1c $00 $00 $00 $00 $00 $00"),
    Example(M1640, "4.5.21", "CALCX MUL", "$01 $21 $02 $00 $00 $00 $00 $00"),
    Example(M1640, "4.5.22", "AAP 0, 0", "$01 $22 $00 $00 $00 $00 $00 $00"),
    Example(M1640, "4.5.23", "AGP 3, 2", "$01 $23 $03 $02 $00 $00 $00 $00"),
]


@dataclass(frozen=True)
class ReplyExample:
    module: str
    where: str
    printed: str  # host address, module address, status, opcode, value (and checksum: 351)
    host: int
    address: int
    status: int
    opcode: int
    value: int
    erratum: str | None = None


REPLIES = [
    ReplyExample(M1311, "5.7.6 GAP", "$02 $01 $64 $06 $00 $00 $02 $80", 2, 1, 100, 6, 640,
                 erratum="1311 #4: value 640 is outside AP 6's range 0..255"),
    ReplyExample(M1311, "5.7.10 GGP", "$02 $01 $64 $0a $00 $00 $00 $01", 2, 1, 100, 10, 1),
    ReplyExample(M1311, "5.7.15 GIO", "$02 $01 $64 $0f $00 $00 $01 $2e", 2, 1, 100, 15, 302),
    ReplyExample(M1311, "5.7.16 CALC", "$02 $01 $64 $13 $ff $ff $ec $78", 2, 1, 100, 19, -5000),
    ReplyExample(M1311, "5.7.25 GCO", "$02 $01 $64 $0a $00 $00 $00 $00", 2, 1, 100, 10, 0,
                 erratum="1311 #6: the GCO reply shows instruction $0a (GGP) instead of $1f"),
    ReplyExample(M351, "5.7.6 GAP", "$02 $01 $64 $06 $00 $00 $02 $c7 $36", 2, 1, 100, 6, 711),
    ReplyExample(M351, "5.7.10 GGP", "$02 $01 $64 $0a $00 $00 $00 $01 $72", 2, 1, 100, 10, 1),
    ReplyExample(M1640, "4.5.6 GAP", "$00 $01 $64 $06 $00 $00 $02 $c7", 0, 1, 100, 6, 711,
                 erratum="1640 #2: reply host-address byte $00 (the other replies $02)"),
    ReplyExample(M1640, "4.5.13.2 GIO", "$02 $01 $64 $0f $00 $00 $01 $2e", 2, 1, 100, 15, 302),
]


def _instruction(ex: Example) -> Instruction:
    return Instruction.from_bytes(hexbytes(ex.printed)[1:8])


@pytest.mark.parametrize("ex", EXAMPLES, ids=lambda e: e.id)
def test_printed_frame_and_checksum(ex: Example) -> None:
    raw = hexbytes(ex.printed)
    assert len(raw) == (9 if ex.module == M351 else 8)
    assert (raw[0] != 1) == ex.bad_address
    request = Request(raw[0], *raw[1:4], int.from_bytes(raw[4:8], "big"))
    frame = request.to_bytes()
    assert frame[:8] == raw[:8]
    assert frame[8] == checksum(raw[:8])
    assert Request.from_bytes(frame) == request
    if len(raw) == 9:
        assert (raw[8] != checksum(raw[:8])) == ex.bad_checksum
    else:
        assert not ex.bad_checksum


@pytest.mark.parametrize("ex", [e for e in EXAMPLES if e.mnemonic is not None], ids=lambda e: e.id)
def test_mnemonic_assembles_to_printed_bytes(ex: Example) -> None:
    module = modules.load(ex.module)
    symbols = asm.Symbols(labels=dict(ex.labels))
    encoded = asm.encode(asm.parse_line(ex.mnemonic), module, symbols).instruction
    if ex.mnemonic_differs:
        assert encoded != _instruction(ex), f"erratum no longer applies: {ex.erratum}"
    else:
        assert encoded == _instruction(ex)


@pytest.mark.parametrize("ex", EXAMPLES, ids=lambda e: e.id)
def test_bytes_disassemble_to_mnemonic(ex: Example) -> None:
    module = modules.load(ex.module)
    ins = _instruction(ex)
    names = {addr: name for name, addr in ex.labels.items()}
    text, _ = asm.disassemble_instruction(ins, module, names)
    assert squeeze(text) == squeeze(ex.disasm or ex.mnemonic or "")
    # and the disassembly is a line the assembler turns back into the same bytes
    symbols = asm.Symbols(labels=dict(ex.labels))
    assert asm.encode(asm.parse_line(text), module, symbols).instruction == ins


def test_every_erratum_row_says_what_is_wrong() -> None:
    for ex in EXAMPLES:
        flagged = ex.mnemonic_differs or ex.bad_checksum or ex.bad_address
        if flagged or ex.mnemonic is None:
            assert ex.erratum, ex.id
        if ex.mnemonic_differs:
            assert ex.disasm and squeeze(ex.disasm) != squeeze(ex.mnemonic or ""), ex.id


@pytest.mark.parametrize("rx", REPLIES, ids=lambda r: f"{r.module}-{r.where}")
def test_reply_examples_decode(rx: ReplyExample) -> None:
    raw = hexbytes(rx.printed)
    frame = raw if len(raw) == 9 else raw + bytes([checksum(raw)])
    assert len(raw) == (9 if rx.module == M351 else 8)
    reply = Reply.from_bytes(frame)  # raises ChecksumError if a printed checksum is wrong
    assert (reply.host, reply.module, reply.status, reply.opcode, reply.value) == (
        rx.host, rx.address, rx.status, rx.opcode, rx.value)
    assert reply.ok and reply.status_text == "ok"
    assert reply.to_bytes() == frame


def test_reply_errata() -> None:
    mod1311 = modules.load(M1311)
    gap = REPLIES[0]
    assert not mod1311.axis(6).in_range(gap.value)  # 1311 #4
    gco = next(r for r in REPLIES if r.where == "5.7.25 GCO")
    assert gco.opcode == isa.by_mnemonic("GGP").opcode != isa.by_mnemonic("GCO").opcode  # #6
    host = next(r for r in REPLIES if r.module == M1640 and r.where.endswith("GAP"))
    default_host = modules.load(M1640).glob(76).default
    assert host.host == 0 and default_host in (None, 2)  # 1640 #2: every other reply says $02


_HEX_LINE = re.compile(r"^Value \(hex\)((?:\s+\$[0-9A-Fa-f]{2})+)\s*$")


@pytest.mark.parametrize("module", [M1311, M351, M1640])
def test_table_holds_every_binary_example_of_the_manual(module: str) -> None:
    printed = Counter(" ".join(m.group(1).split()).lower()
                      for line in manual_lines(module) if (m := _HEX_LINE.match(line)))
    table = Counter(" ".join(x.printed.split()).lower()
                    for x in [*EXAMPLES, *REPLIES] if x.module == module)
    assert printed == table


# -- mnemonic-only examples -------------------------------------------------------------------

def _encode(module: str, text: str, direct: bool = False) -> Instruction:
    return asm.encode(asm.parse_line(text), modules.load(module), direct=direct).instruction


def test_1311_comp_example_uses_motor_2() -> None:
    # 1311 #5: §5.7.17 "GAP 1, 2, 0 //... motor: 0": the comment and §5.7.18 mean motor 0.
    with pytest.raises(AsmError, match="no motor 2"):
        _encode(M1311, "GAP 1, 2, 0")
    assert _encode(M1311, "GAP 1, 0, 0") == Instruction(6, 1, 0, 0)


def test_1311_sio_all_outputs_examples() -> None:
    # 1311 #8: "Set all output pins high: SIO 255, 2, 3" sets only OUT_0 and OUT_1.
    assert _encode(M1311, "SIO 255, 2, 3") == Instruction(14, 255, 2, 3)
    assert _encode(M1311, "SIO 255, 2, 255") == Instruction(14, 255, 2, 255)
    # "SIO 255, 2,-1" copies the accumulator: a program instruction, refused in direct mode
    assert _encode(M1311, "SIO 255, 2,-1").signed_value == -1
    with pytest.raises(AsmError, match=r"out of range 0\.\.255"):
        _encode(M1311, "SIO 255, 2,-1", direct=True)


def test_1311_sgp_88_example_lacks_its_value() -> None:
    # 1311 #9: §3.1 "SGP 88, 0" to switch to RS485 has no value operand.
    with pytest.raises(AsmError, match="needs a value"):
        _encode(M1311, "SGP 88, 0", direct=True)
    assert _encode(M1311, "SGP 88, 0, 0", direct=True) == Instruction(9, 88, 0, 0)


def test_1311_coordinate_eeprom_copy_forms() -> None:
    # §5.7.24/5.7.25: SCO/GCO <n>, 255, 0 copy coordinates between RAM and EEPROM
    assert _encode(M1311, "SCO 0, 255, 0") == Instruction(30, 0, 255, 0)
    assert _encode(M1311, "GCO 0, 255, 0") == Instruction(31, 0, 255, 0)
    assert _encode(M1311, "GCO 20, 255, 0") == Instruction(31, 20, 255, 0)
    with pytest.raises(AsmError, match="no motor 255"):
        _encode(M351, "SCO 0, 255, 0")  # the TMCM-351 manual does not document the forms


@pytest.mark.parametrize("module, text, ok", [
    # §4.4.1 / §5.6.1 "examples for valid command lines" (after the address character A),
    # printed identically in the 1311 and 351 manuals: motors 1 and 2 exist on the 351 only.
    (M351, "MVP ABS, 1, 50000", True), (M351, "ROL 2, 500", True), (M351, "MST 1", True),
    (M1311, "MVP ABS, 1, 50000", False), (M1311, "ROL 2, 500", False), (M1311, "MST 1", False),
    # §4.4.2 "AGAP 0, 1 ... actual position of axis 1": AP 0 is the *target* position (1311 #36)
    (M351, "GAP 0, 1", True), (M1311, "GAP 0, 1", False),
])
def test_ascii_examples_name_motors_of_the_351(module: str, text: str, ok: bool) -> None:
    if ok:
        _encode(module, text, direct=True)
    else:
        with pytest.raises(AsmError, match="has no motor"):
            _encode(module, text, direct=True)


# -- program listings ---------------------------------------------------------------------------

PROGRAM_FILES = sorted(PROGRAMS.glob("*.tmc"))

# Listings that do not assemble as printed: file -> (line, what the error says)
EXPECTED_ERRORS = {
    "tmcm1311-user-variables.tmc": (21, r"no motor 2.*use AGP"),  # 1311 #33
}


def _module_of(path: Path) -> modules.Module:
    return modules.load(path.name.split("-", 1)[0])


def test_program_listings_present() -> None:
    names = {p.name for p in PROGRAM_FILES}
    # chapter 3, 5, 8 and 11 listings of the TMCM-1311, the 351's two chapter 4 programs,
    # and the 1640's command examples
    for expected in ("tmcm1311-first-program.tmc", "tmcm1311-timer-interrupt.tmc",
                     "tmcm1311-timer-interrupt-symbolic.tmc", "tmcm1311-closed-loop-1.tmc",
                     "tmcm1311-closed-loop-2.tmc", "tmcm1311-main-loop.tmc",
                     "tmcm1311-symbolic-constants.tmc", "tmcm1311-user-variables.tmc",
                     "tmcm1311-routine-table.tmc", "tmcm351-first-program.tmc",
                     "tmcm351-encoder-demo.tmc", "tmcm1640-subroutine.tmc"):
        assert expected in names
    assert len(PROGRAM_FILES) == 20


@pytest.mark.parametrize("path", PROGRAM_FILES, ids=lambda p: p.name)
def test_program_listing_assembles(path: Path) -> None:
    module = _module_of(path)
    if path.name in EXPECTED_ERRORS:
        line, message = EXPECTED_ERRORS[path.name]
        with pytest.raises(AsmError, match=message) as err:
            asm.assemble_file(path, module)
        assert (err.value.file, err.value.line) == (str(path), line)
        assert err.value.col is not None
        return
    program = asm.assemble_file(path, module)
    assert len(program) > 0
    # and the listing survives a trip through the disassembler, labels and all
    text = asm.disassemble(program.instructions, module)
    assert asm.assemble(text, module).instructions == program.instructions


@pytest.mark.parametrize("path", PROGRAM_FILES, ids=lambda p: p.name)
def test_program_listing_is_printed_in_its_manual(path: Path) -> None:
    """Every code line of the file appears, as a line, in the module's manual."""
    module = _module_of(path).name
    printed = {squeeze(asm.strip_comment(line)[0]) for line in manual_lines(module)}
    for no, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        code = squeeze(asm.strip_comment(line)[0])
        if code:
            assert code in printed, f"{path.name}:{no}: {line.strip()!r} is not in the manual"


def _program(name: str) -> asm.Program:
    path = PROGRAMS / name
    return asm.assemble_file(path, _module_of(path))


def test_symbolic_interrupt_listing_equals_numeric_one() -> None:
    # §5.6.5: "#include Interrupts.inc" and TI_* names give the same program
    numeric = _program("tmcm1311-timer-interrupt.tmc")
    symbolic = _program("tmcm1311-timer-interrupt-symbolic.tmc")
    assert symbolic.instructions == numeric.instructions
    assert numeric.instructions[0] == Instruction(37, 0, 0, numeric.labels["Timer0Irq"])


def test_symbolic_constants_listing_equals_main_loop() -> None:
    # §11.3 is §11.2 written with TMCLParam.tmc names and constants
    assert (_program("tmcm1311-symbolic-constants.tmc").instructions
            == _program("tmcm1311-main-loop.tmc").instructions)


def test_user_variables_listing_with_agp() -> None:
    # 1311 #33: with the AGP the text describes, §11.4 assembles to what it says
    path = PROGRAMS / "tmcm1311-user-variables.tmc"
    text = path.read_text(encoding="utf-8").replace("AAP MyVariable, 2", "AGP MyVariable, 2")
    program = asm.assemble(text, _module_of(path))
    assert program.instructions == [Instruction(9, 42, 2, 1234), Instruction(10, 42, 2, 0),
                                    Instruction(19, 2, 0, 2), Instruction(35, 42, 2, 0)]


def test_jump_examples_hit_their_labels() -> None:
    for name in ("tmcm1311-jc.tmc", "tmcm1640-jc.tmc"):
        program = _program(name)
        assert program.instructions[2] == Instruction(21, 5, 0, program.labels["Label"])
    routines = _program("tmcm1311-routine-table.tmc")
    # §11.6: the host runs the routines at addresses 0, 1 and 2
    assert [routines.labels[f"Func{n}"] for n in (1, 2, 3)] == [0, 1, 2]
    assert [routines.instructions[n].value for n in range(3)] == [
        routines.labels[f"Func{n}Start"] for n in (1, 2, 3)]
