"""Property tests of the assembler and disassembler.

* For every instruction of every module that the module accepts, the disassembler writes the
  mnemonic form and ``assemble(disassemble(image)) == image``.
* Any seven bytes at all disassemble to a line that assembles back to them (the raw form where
  no mnemonic fits).
* The assembler never crashes: any text gives a Program or an AsmError.
"""

from __future__ import annotations

import string

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tmclsh.tmcl import asm, modules
from tmclsh.tmcl import instructions as isa
from tmclsh.base.errors import AsmError
from tmclsh.tmcl.modules import Module, Parameter
from tmclsh.tmcl.frames import INT32_MAX, INT32_MIN, UINT32_MAX, Instruction

MODULES = [modules.load(name) for name in ("TMCM-1311", "TMCM-351", "TMCM-1640")]
FAST = settings(max_examples=150, deadline=None,
                suppress_health_check=[HealthCheck.too_slow])

int32 = st.integers(INT32_MIN, INT32_MAX)


# -- valid instructions, built from the instruction set and the module database --------------

def _allowed(spec: isa.InstructionSpec, p: Parameter) -> bool:
    if spec.mnemonic in ("SAP", "SGP", "AAP", "AGP") and not p.writable:
        return False
    if spec.reads and not p.readable:
        return False
    if spec.mnemonic in ("STAP", "STGP", "RSAP", "RSGP") and not p.storable:
        return False
    return True


def _param_values(p: Parameter) -> st.SearchStrategy[int]:
    if p.choices:
        return st.sampled_from(p.choices)
    lo = INT32_MIN if p.min is None else p.min
    hi = INT32_MAX if p.max is None else p.max
    return st.integers(lo, hi)


@st.composite
def valid_instruction(draw: st.DrawFn, module: Module) -> Instruction:
    specs = [s for s in module.instructions]
    spec = draw(st.sampled_from(specs))
    f = {"type": 0, "motor": 0, "value": 0}
    tk, mk, vk = spec.type_kind, spec.motor_kind, spec.value_kind
    if tk == "symbolic":
        f["type"] = draw(st.sampled_from(sorted(spec.type_names(module.name).values())))
    elif tk == "axis_param":
        param = draw(st.sampled_from([p for p in module.axis_params if _allowed(spec, p)]))
        f["type"] = param.number
    elif tk == "global_param":
        param = draw(st.sampled_from([p for p in module.global_params if _allowed(spec, p)]))
        f["type"] = param.number + draw(st.integers(0, param.count - 1))
        f["motor"] = param.bank
    elif tk == "port":
        ports = [p for p in module.io if spec.mnemonic != "SIO" or p.kind == "digital_out"]
        port = draw(st.sampled_from(ports))
        f["type"], f["motor"] = port.port, port.bank
    elif tk == "coordinate":
        f["type"] = draw(st.integers(0, module.coordinates - 1))
    elif tk == "interrupt":
        f["type"] = draw(st.sampled_from(sorted(isa.interrupts().values())))
    elif tk == "number":
        f["type"] = draw(st.integers(0, 255))
    if mk == "motor":
        motors = list(range(module.motors)) + sorted(spec.motor_special.get(module.name, {}))
        f["motor"] = draw(st.sampled_from(motors))
        coord = spec.type_names(module.name).get("COORD")
        if spec.mnemonic == "MVP" and module.motors > 1 and f["type"] == coord:
            mask = draw(st.integers(1, 2 ** module.motors - 1))
            f["motor"] = draw(st.sampled_from([f["motor"], 0x40 | mask, 0x80 | mask]))
    elif mk == "number":
        f["motor"] = draw(st.integers(0, 255))
    if vk == "velocity":
        f["value"] = draw(st.integers(module.velocity_min, module.velocity_max))
    elif vk == "position":
        if spec.mnemonic == "MVP" and f["type"] == spec.type_names(module.name).get("COORD"):
            f["value"] = draw(st.integers(0, module.coordinates - 1))
        else:
            f["value"] = draw(st.integers(module.position_min, module.position_max))
    elif vk == "param":
        f["value"] = draw(_param_values(param))
    elif vk == "port_value":
        f["value"] = draw(st.integers(port.min, port.max))
    elif vk == "label":
        f["value"] = draw(st.integers(0, module.program_memory - 1))
    elif vk == "ticks":
        f["value"] = draw(st.integers(0, INT32_MAX))
    elif vk == "number":
        f["value"] = draw(int32)
    return Instruction(spec.opcode, f["type"], f["motor"], f["value"])


def _check_mnemonic_round_trip(module: Module, ins: Instruction) -> None:
    text, _ = asm.disassemble_instruction(ins, module)
    assert not text[0].isdigit(), f"{ins} disassembled to the raw form {text!r}"
    assert asm.encode(asm.parse_line(text), module).instruction == ins, text


@FAST
@given(st.data())
def test_every_valid_instruction_round_trips_1311(data: st.DataObject) -> None:
    module = MODULES[0]
    _check_mnemonic_round_trip(module, data.draw(valid_instruction(module)))


@FAST
@given(st.data())
def test_every_valid_instruction_round_trips_351(data: st.DataObject) -> None:
    module = MODULES[1]
    _check_mnemonic_round_trip(module, data.draw(valid_instruction(module)))


@FAST
@given(st.data())
def test_every_valid_instruction_round_trips_1640(data: st.DataObject) -> None:
    module = MODULES[2]
    _check_mnemonic_round_trip(module, data.draw(valid_instruction(module)))


def test_every_instruction_of_every_module_is_covered() -> None:
    """Each spec's smallest valid instruction takes the mnemonic form (no spec is left out)."""
    for module in MODULES:
        for spec in module.instructions:
            _check_mnemonic_round_trip(module, _first(module, spec))


def _first(module: Module, spec: isa.InstructionSpec) -> Instruction:
    """A deterministic valid instruction of ``spec``: the first choice of every field."""
    f = {"type": 0, "motor": 0, "value": 0}
    if spec.type_kind == "symbolic":
        f["type"] = min(spec.type_names(module.name).values())
    elif spec.type_kind == "axis_param":
        f["type"] = next(p.number for p in module.axis_params if _allowed(spec, p))
    elif spec.type_kind == "global_param":
        p = next(p for p in module.global_params if _allowed(spec, p))
        f["type"], f["motor"] = p.number, p.bank
    elif spec.type_kind == "port":
        port = next(p for p in module.io if spec.mnemonic != "SIO" or p.kind == "digital_out")
        f["type"], f["motor"] = port.port, port.bank
    elif spec.type_kind == "interrupt":
        f["type"] = min(isa.interrupts().values())
    return Instruction(spec.opcode, f["type"], f["motor"], f["value"])


@FAST
@given(st.data(), st.integers(0, 3))
def test_programs_round_trip_with_generated_labels(data: st.DataObject, which: int) -> None:
    module = MODULES[which % len(MODULES)]
    size = data.draw(st.integers(1, 12))
    program = data.draw(st.lists(valid_instruction(module), min_size=size, max_size=size))
    # make some jumps land inside the program, where they get labels
    for i, ins in enumerate(program):
        spec = isa.by_opcode(ins.opcode)
        if spec.jumps and data.draw(st.booleans()):
            target = data.draw(st.integers(0, size - 1))
            program[i] = Instruction(ins.opcode, ins.type, ins.motor, target)
    text = asm.disassemble(program, module)
    assert asm.assemble(text, module).instructions == program
    inside = {ins.value for ins in program if isa.by_opcode(ins.opcode).jumps
              and 0 <= ins.value < size}
    for target in inside:
        assert f"{asm.label_name(target)}:" in text.splitlines()


@FAST
@given(st.data(), st.integers(0, 2000))
def test_disassembly_with_an_origin(data: st.DataObject, origin: int) -> None:
    module = MODULES[0]
    program = data.draw(st.lists(valid_instruction(module), min_size=1, max_size=6))
    program.append(Instruction(isa.by_mnemonic("JA").opcode, 0, 0, origin))  # jump to the start
    text = asm.disassemble(program, module, origin=origin)
    assert f"{asm.label_name(origin)}:" in text
    assert asm.assemble(text, module, origin=origin).instructions == program


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255),
       st.integers(INT32_MIN, UINT32_MAX), st.integers(0, 3))
def test_any_seven_bytes_round_trip(op: int, type_: int, motor: int, value: int,
                                    which: int) -> None:
    ins = Instruction(op, type_, motor, value)
    module = MODULES[which] if which < len(MODULES) else None
    text, _ = asm.disassemble_instruction(ins, module)
    target = module or MODULES[0]
    try:
        back = asm.encode(asm.parse_line(text), target).instruction
    except AsmError:
        # without a module the mnemonic form is not checked against one; the raw form is
        assert module is None
        back = asm.encode(asm.parse_line(asm._raw_text(ins)), target).instruction
    assert back == ins


# -- the assembler never crashes -----------------------------------------------------------------

_WORDS = ([s.mnemonic for s in isa.all_instructions()]
          + ["ABS", "REL", "COORD", "TICKS", "POS", "GE", "NZ", "MUL", "ALL", "TI_GLOBAL",
             "Loop", "Loop:", "X", "=", ",", ", ", "(", ")", "-", "+", "*", "/", "%", ":",
             "$FF", "0x10", "0b101", "255", "2048", "-1", "4294967296", "//", "#include",
             "Interrupts.inc", "TMCLParam.tmc", "nope.inc", "ActualPosition", "\t", " ", "\n",
             '"', "138", "9999999999999999999999999999999999999999999"])

source_text = st.one_of(
    st.text(max_size=200),
    st.text(alphabet=string.printable, max_size=200),
    st.lists(st.sampled_from(_WORDS), max_size=40).map(" ".join),
    st.lists(st.sampled_from(_WORDS), max_size=40).map("".join),
)


@settings(max_examples=400, deadline=None)
@given(source_text, st.sampled_from(MODULES))
def test_assembler_gives_a_program_or_an_asm_error(text: str, module: Module) -> None:
    try:
        program = asm.assemble(text, module)
    except AsmError as exc:
        assert exc.message
        assert exc.line is None or exc.line >= 1
        assert exc.col is None or exc.col >= 1
    else:
        assert len(program) <= module.program_memory
        assert asm.assemble(asm.disassemble(program.instructions, module), module
                            ).instructions == program.instructions


@settings(max_examples=300, deadline=None)
@given(source_text, st.sampled_from(MODULES), st.booleans(), st.booleans())
def test_line_encoder_gives_an_instruction_or_an_asm_error(text: str, module: Module,
                                                           direct: bool, ascii: bool) -> None:
    try:
        line = asm.parse_line(text)
        if line.mnemonic is not None:
            asm.encode(line, module, direct=direct, ascii=ascii)
    except AsmError:
        pass


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=64))
def test_read_image_gives_instructions_or_an_asm_error(data: bytes) -> None:
    try:
        image = asm.read_image(data)
    except AsmError:
        return
    assert all(isinstance(i, Instruction) for i in image)
