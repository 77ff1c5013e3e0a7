"""TMCL source text: the one line parser, the assembler and the disassembler.

The shell, scripts, the assembler and the simulator's ASCII mode all read TMCL lines through
``parse_line``/``encode``, so a command means the same everywhere and is checked the same way:
against the instruction set and the connected module's database, before any byte is sent.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from . import instructions as isa
from .errors import AsmError, ValidationError
from .modules import Module, Parameter
from .protocol import INSTRUCTION_LEN, INT32_MAX, INT32_MIN, UINT32_MAX, Control, Instruction

# -- lexing ------------------------------------------------------------------------------

_TOKEN = re.compile(r"""
    (?P<ws>\s+)
  | (?P<hex>(?:\$|0[xX])[0-9A-Fa-f]+)
  | (?P<bin>0[bB][01]+)
  | (?P<num>\d+)
  | (?P<name>[A-Za-z_][A-Za-z0-9_.]*)
  | (?P<op>[-+*/(),:=%])
""", re.VERBOSE)


@dataclass(frozen=True)
class Token:
    kind: str
    text: str
    col: int  # 1-based
    value: int | None = None


def tokenize(text: str, line: int | None = None, file: str | None = None) -> list[Token]:
    tokens: list[Token] = []
    pos = 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if not m:
            raise AsmError(f"unexpected character {text[pos]!r}", line, pos + 1, file)
        kind = m.lastgroup
        tok = m.group()
        if kind == "hex":
            tokens.append(Token("num", tok, pos + 1, int(tok.lstrip("$")[2:] if tok[:2].lower() == "0x" else tok[1:], 16)))
        elif kind == "bin":
            tokens.append(Token("num", tok, pos + 1, int(tok[2:], 2)))
        elif kind == "num":
            tokens.append(Token("num", tok, pos + 1, int(tok)))
        elif kind != "ws":
            tokens.append(Token(kind, tok, pos + 1))
        pos = m.end()
    return tokens


def strip_comment(text: str) -> tuple[str, str]:
    """Split off a ``//`` comment (the TMCL-IDE's comment syntax)."""
    idx = text.find("//")
    if idx < 0:
        return text, ""
    return text[:idx], text[idx + 2:].strip()


# -- operand expressions -----------------------------------------------------------------

@dataclass(frozen=True)
class Expr:
    """A parsed operand: a number, a name, or arithmetic on them (for constants)."""

    op: str  # "num", "name", "neg", "+", "-", "*", "/", "%"
    col: int
    value: int | None = None
    name: str | None = None
    args: tuple[Expr, ...] = ()
    text: str = ""

    @property
    def is_name(self) -> bool:
        return self.op == "name"

    def names(self) -> list[str]:
        if self.op == "name":
            return [self.name or ""]
        return [n for a in self.args for n in a.names()]


class _Parser:
    def __init__(self, tokens: list[Token], line: int | None, file: str | None, end_col: int):
        self.toks = tokens
        self.i = 0
        self.line = line
        self.file = file
        self.end_col = end_col

    def peek(self) -> Token | None:
        return self.toks[self.i] if self.i < len(self.toks) else None

    def take(self) -> Token:
        tok = self.peek()
        if tok is None:
            raise AsmError("operand missing at end of line", self.line, self.end_col, self.file)
        self.i += 1
        return tok

    def error(self, msg: str, tok: Token | None) -> AsmError:
        return AsmError(msg, self.line, tok.col if tok else self.end_col, self.file)

    def expr(self) -> Expr:
        left = self.term()
        while (tok := self.peek()) is not None and tok.text in "+-" and tok.kind == "op":
            self.i += 1
            left = Expr(tok.text, left.col, args=(left, self.term()))
        return left

    def term(self) -> Expr:
        left = self.unary()
        while (tok := self.peek()) is not None and tok.kind == "op" and tok.text in "*/%":
            self.i += 1
            left = Expr(tok.text, left.col, args=(left, self.unary()))
        return left

    def unary(self) -> Expr:
        tok = self.take()
        if tok.kind == "op" and tok.text == "-":
            inner = self.unary()
            return Expr("neg", tok.col, args=(inner,))
        if tok.kind == "op" and tok.text == "+":
            return self.unary()
        if tok.kind == "num":
            return Expr("num", tok.col, value=tok.value, text=tok.text)
        if tok.kind == "name":
            return Expr("name", tok.col, name=tok.text, text=tok.text)
        if tok.kind == "op" and tok.text == "(":
            inner = self.expr()
            close = self.take()
            if close.text != ")":
                raise self.error("expected ')'", close)
            return inner
        raise self.error(f"expected a number or a name, found {tok.text!r}", tok)


# -- lines -------------------------------------------------------------------------------

@dataclass
class Line:
    """One parsed source line. At most one of instruction, constant or include is set."""

    text: str
    number: int | None = None
    file: str | None = None
    label: str | None = None
    label_col: int = 0
    mnemonic: str | None = None
    mnemonic_col: int = 0
    operands: list[Expr] = field(default_factory=list)
    constant: str | None = None
    constant_col: int = 0
    include: str | None = None
    comment: str = ""

    def error(self, msg: str, col: int | None = None) -> AsmError:
        return AsmError(msg, self.number, col, self.file)


def parse_line(text: str, number: int | None = None, file: str | None = None) -> Line:
    """Parse one line of TMCL source (or one typed command) without resolving any name.

    Accepts ``Label:``, ``Label: CMD ...``, ``Name = expr``, ``#include FILE``, ``CMD a, b, c``
    and a comma straight after the mnemonic (``EI, 255`` as the manuals print some examples).
    """
    body, comment = strip_comment(text.rstrip("\r\n"))
    line = Line(text=text, number=number, file=file, comment=comment)
    stripped = body.strip()
    if stripped.lower().startswith("#include"):
        target = stripped[len("#include"):].strip().strip('"<>')
        if not target:
            raise line.error("#include needs a file name", body.find("#") + 1)
        line.include = target
        return line
    if stripped.startswith("#"):
        raise line.error(f"unknown directive {stripped.split()[0]!r}", body.find("#") + 1)
    toks = tokenize(body, number, file)
    if not toks:
        return line
    end_col = len(body.rstrip()) + 1
    i = 0
    if len(toks) >= 2 and toks[0].kind == "name" and toks[1].text == ":":
        line.label, line.label_col = toks[0].text, toks[0].col
        i = 2
    if i < len(toks) and toks[i].kind == "name" and i + 1 < len(toks) and toks[i + 1].text == "=":
        if line.label:
            raise line.error("a constant cannot follow a label", toks[i].col)
        line.constant, line.constant_col = toks[i].text, toks[i].col
        p = _Parser(toks[i + 2:], number, file, end_col)
        line.operands = [p.expr()]
        if p.peek() is not None:
            raise p.error(f"unexpected {p.peek().text!r} after the constant's value", p.peek())
        return line
    if i >= len(toks):
        return line
    head = toks[i]
    if head.kind == "num":
        # a raw command number: `136 1` or `138 0, 0, 0`
        line.mnemonic, line.mnemonic_col = head.text, head.col
    elif head.kind == "name":
        line.mnemonic, line.mnemonic_col = head.text.upper(), head.col
    else:
        raise line.error(f"expected a command, found {head.text!r}", head.col)
    rest = toks[i + 1:]
    if rest and rest[0].text == ",":
        rest = rest[1:]  # `EI, 255`: manual erratum, accepted
    p = _Parser(rest, number, file, end_col)
    while p.peek() is not None:
        line.operands.append(p.expr())
        tok = p.peek()
        if tok is None:
            break
        if tok.text != ",":
            raise p.error(f"expected ',' between operands, found {tok.text!r}", tok)
        p.i += 1
        if p.peek() is None:
            raise p.error("operand missing after ','", None)
    if len(line.operands) > 3:
        raise line.error("a TMCL command has at most three operands", line.operands[3].col)
    return line


# -- symbols and encoding ----------------------------------------------------------------

@dataclass
class Symbols:
    """Names a line may use besides the built-in ones: constants and labels."""

    constants: dict[str, int] = field(default_factory=dict)
    labels: dict[str, int] = field(default_factory=dict)
    allow_forward: bool = False  # first assembler pass: unknown labels resolve to 0

    def lookup(self, name: str) -> int | None:
        for table in (self.constants, self.labels):
            for key, val in table.items():
                if key.lower() == name.lower():
                    return val
        return None


@dataclass(frozen=True)
class Encoded:
    """An instruction with what the checks learned about it (for rendering replies)."""

    instruction: Instruction
    spec: isa.InstructionSpec | None
    parameter: Parameter | None = None
    label: str | None = None  # jump target name, if given by name


def _eval(expr: Expr, line: Line, resolve) -> int:
    if expr.op == "num":
        return expr.value  # type: ignore[return-value]
    if expr.op == "name":
        value = resolve(expr)
        if value is None:
            raise line.error(f"unknown name {expr.name!r}", expr.col)
        return value
    if expr.op == "neg":
        return -_eval(expr.args[0], line, resolve)
    a, b = (_eval(x, line, resolve) for x in expr.args)
    if expr.op == "+":
        return a + b
    if expr.op == "-":
        return a - b
    if expr.op == "*":
        return a * b
    if b == 0:
        raise line.error("division by zero", expr.args[1].col)
    q = abs(a) // abs(b) * (1 if (a >= 0) == (b >= 0) else -1)  # truncate like C
    return q if expr.op == "/" else a - q * b


def eval_constant(line: Line, symbols: Symbols) -> int:
    value = _eval(line.operands[0], line, lambda e: symbols.lookup(e.name or ""))
    _check_int32(value, line, line.operands[0].col)
    return value


def _check_int32(value: int, line: Line, col: int) -> None:
    if not INT32_MIN <= value <= UINT32_MAX:
        raise line.error(f"{value} does not fit in 32 bits", col)


def _suggest(word: str, choices) -> str:
    import difflib

    close = difflib.get_close_matches(word.upper(), [c.upper() for c in choices], n=3, cutoff=0.5)
    return f"; did you mean {', '.join(close)}?" if close else ""


def encode(line: Line, module: Module, symbols: Symbols | None = None, *,
           direct: bool = False, ascii: bool = False) -> Encoded:
    """Turn a parsed command line into an instruction, checked against ``module``.

    ``direct``: the line is typed at a prompt (control-flow commands refused, labels unknown);
    ``ascii``: it will go through the module's ASCII mode (only the commands it accepts).
    Every refusal is an AsmError naming what is wrong and what is allowed.
    """
    symbols = symbols or Symbols()
    if line.mnemonic is None:
        raise line.error("no command on this line")
    if line.mnemonic[0].isdigit():
        return _encode_raw(line, module, symbols, direct=direct)
    spec = isa.by_mnemonic(line.mnemonic)
    if spec is None:
        known = [s.mnemonic for s in isa.all_instructions()]
        raise line.error(f"unknown command {line.mnemonic!r}{_suggest(line.mnemonic, known)}",
                         line.mnemonic_col)
    if not spec.on(module.name):
        raise line.error(f"{spec.mnemonic} is not available on the {module.name}", line.mnemonic_col)
    if direct and not spec.direct:
        raise line.error(f"{spec.mnemonic} only works inside a stored program, not as a direct "
                         "command (upload a program with .upload)", line.mnemonic_col)
    if ascii and not spec.ascii:
        raise line.error(f"{spec.mnemonic} is not accepted in ASCII mode; switch to binary "
                         "mode (.mode binary) to send it", line.mnemonic_col)
    return _Encoder(line, spec, module, symbols, direct).run()


class _Encoder:
    def __init__(self, line: Line, spec: isa.InstructionSpec, module: Module, symbols: Symbols,
                 direct: bool):
        self.line, self.spec, self.module, self.symbols, self.direct = line, spec, module, symbols, direct
        self.param: Parameter | None = None
        self.label: str | None = None

    def fail(self, msg: str, expr: Expr | None = None) -> AsmError:
        col = expr.col if expr is not None else self.line.mnemonic_col
        return self.line.error(msg, col)

    def number(self, expr: Expr, extra: dict[str, int] | None = None) -> int:
        def resolve(e: Expr) -> int | None:
            name = e.name or ""
            if extra:
                for key, val in extra.items():
                    if key.upper() == name.upper():
                        return val
            return self.symbols.lookup(name)
        value = _eval(expr, self.line, resolve)
        _check_int32(value, self.line, expr.col)
        return value

    def run(self) -> Encoded:
        spec, ops = self.spec, list(self.line.operands)
        slots = list(spec.fields)
        for f in ("type", "motor", "value"):
            if len(slots) >= len(ops):
                break
            if f not in slots:
                slots.append(f)  # don't-care operands such as `GAP 1, 0, 0`
        if len(ops) > len(slots):
            raise self.fail(f"too many operands: {spec.syntax}", ops[len(slots)])
        given = dict(zip(slots, ops))
        missing = [f for f in spec.fields if f not in given]
        fields = {"type": 0, "motor": 0, "value": 0}
        # motor/bank first: a global parameter's number depends on its bank
        if "motor" in given:
            fields["motor"] = self.motor(given["motor"])
        if "type" in given:
            fields["type"] = self.type_(given["type"], fields["motor"], "motor" in given)
        if "motor" not in given and "motor" in spec.fields:
            fields["motor"] = self.default_motor()
        if "type" in given and spec.type_kind == "global_param" and self.param is not None:
            if "motor" not in given:
                fields["motor"] = self.param.bank
        if "value" in given:
            fields["value"] = self.value(given["value"], fields)
        elif "value" in missing:
            raise self.fail(f"{spec.mnemonic} needs a value: {spec.syntax}")
        if "type" in missing:
            raise self.fail(f"{spec.mnemonic} needs its first operand: {spec.syntax}")
        if spec.type_kind == "global_param" and self.param is None and "type" in given:
            pass
        self.check_access(fields)
        value = fields["value"]
        ins = Instruction(spec.opcode, fields["type"], fields["motor"],
                          value & 0xFFFFFFFF if value < 0 else value)
        return Encoded(ins, spec, self.param, self.label)

    def default_motor(self) -> int:
        return 0

    def motor(self, expr: Expr) -> int:
        kind = self.spec.motor_kind
        value = self.number(expr)
        if kind == "motor":
            is_coord = self.spec.mnemonic == "MVP" and self.module.motors > 1
            if is_coord and value > self.module.motors - 1 and value & 0xC0:
                # TMCM-351 MVP COORD: bit 7 multi-motor, bit 6 interpolation, bits 0-2 mask
                if value > 0xFF or value & 0x38:
                    raise self.fail(f"motor field {value} is not a valid MVP COORD motor mask", expr)
                return value
            try:
                self.module.check_motor(value)
            except ValidationError as exc:
                raise self.fail(str(exc), expr) from None
        elif kind == "bank":
            banks = (self.module.io_banks() if self.spec.type_kind == "port" else self.module.banks())
            if value not in banks:
                what = "I/O bank" if self.spec.type_kind == "port" else "parameter bank"
                raise self.fail(f"{self.module.name} has no {what} {value}: banks "
                                f"{', '.join(map(str, banks))}", expr)
        elif not 0 <= value <= 255:
            raise self.fail(f"{value} does not fit the motor/bank byte (0..255)", expr)
        return value

    def type_(self, expr: Expr, motor: int, motor_given: bool) -> int:
        spec, mod = self.spec, self.module
        kind = spec.type_kind
        if kind == "symbolic":
            names = spec.type_names(mod.name)
            if expr.is_name and (expr.name or "").upper() in names:
                return names[(expr.name or "").upper()]
            if expr.is_name and self.symbols.lookup(expr.name or "") is None:
                raise self.fail(f"{spec.mnemonic} has no type {expr.name!r}: "
                                f"{'|'.join(names)}", expr)
            value = self.number(expr)
            if value not in names.values():
                raise self.fail(f"{spec.mnemonic} has no type {value}: "
                                + ", ".join(f"{n}={v}" for n, v in names.items()), expr)
            return value
        if kind in ("axis_param", "global_param"):
            pkind = "axis" if kind == "axis_param" else "global"
            bank = motor if (pkind == "global" and motor_given) else None
            try:
                if expr.is_name and self.symbols.lookup(expr.name or "") is None:
                    self.param = mod.lookup(pkind, expr.name or "", bank)
                    if bank is not None and self.param.bank != bank:
                        raise ValidationError(f"{self.param.name} is in bank {self.param.bank}, "
                                              f"not bank {bank}")
                    number = self.param.number
                else:
                    number = self.number(expr)
                    self.param = mod.lookup(pkind, number, bank)
            except ValidationError as exc:
                raise self.fail(str(exc), expr) from None
            if pkind == "global" and self.param.count > 1:
                return number
            return self.param.number if pkind == "axis" else number
        if kind == "interrupt":
            value = self.number(expr, isa.interrupts())
            if value not in isa.interrupts().values():
                raise self.fail(f"{value} is not an interrupt number: "
                                + ", ".join(str(v) for v in sorted(isa.interrupts().values())), expr)
            return value
        value = self.number(expr)
        if kind == "port":
            bank = motor if motor_given else 0
            if not (mod.io_all_port is not None and value == mod.io_all_port
                    and bank in mod.io_all_banks) and mod.port(bank, value) is None:
                ports = [str(p.port) for p in mod.io if p.bank == bank]
                raise self.fail(f"{mod.name} has no port {value} in I/O bank {bank}: ports "
                                f"{', '.join(ports) or 'none'}", expr)
            return value
        if kind == "coordinate":
            if not 0 <= value < mod.coordinates:
                raise self.fail(f"coordinate {value} out of range: 0..{mod.coordinates - 1}", expr)
            return value
        if not 0 <= value <= 255:
            raise self.fail(f"{value} does not fit the type byte (0..255)", expr)
        return value

    def value(self, expr: Expr, fields: dict[str, int]) -> int:
        spec, mod = self.spec, self.module
        kind = spec.value_kind
        if kind == "label":
            if expr.is_name:
                self.label = expr.name
                addr = self.symbols.lookup(expr.name or "")
                if addr is None:
                    if self.symbols.allow_forward:
                        return 0
                    if self.direct:
                        raise self.fail(f"unknown label {expr.name!r} (labels exist only in "
                                        "programs)", expr)
                    raise self.fail(f"undefined label {expr.name!r}", expr)
                return addr
            value = self.number(expr)
            if not 0 <= value < mod.program_memory:
                raise self.fail(f"address {value} is outside program memory "
                                f"0..{mod.program_memory - 1}", expr)
            return value
        value = self.number(expr)
        if kind == "velocity":
            lo, hi = mod.velocity_min, mod.velocity_max
            if not lo <= value <= hi:
                raise self.fail(f"velocity {value} out of range {lo}..{hi}", expr)
        elif kind == "position":
            if spec.mnemonic == "MVP" and fields["type"] == spec.type_names(mod.name).get("COORD"):
                if not 0 <= value < mod.coordinates:
                    raise self.fail(f"coordinate {value} out of range: 0..{mod.coordinates - 1}", expr)
            elif not mod.position_min <= value <= mod.position_max:
                raise self.fail(f"position {value} out of range "
                                f"{mod.position_min}..{mod.position_max}", expr)
        elif kind == "param" and self.param is not None:
            try:
                self.param.check(value)
            except ValidationError as exc:
                raise self.fail(str(exc), expr) from None
        elif kind == "port_value":
            port = fields["type"]
            if mod.io_all_port is not None and port == mod.io_all_port:
                lo, hi = (-1 if not self.direct else 0), 255
            else:
                p = mod.port(fields["motor"], port)
                lo, hi = (p.min, p.max) if p else (0, 1)
                if not self.direct and value == -1:
                    lo = -1  # -1: copy from the accumulator (in programs)
            if p_kind_out := (port != mod.io_all_port):
                p = mod.port(fields["motor"], port)
                if p is not None and p.kind != "digital_out":
                    raise self.fail(f"{p.name} (bank {p.bank} port {p.port}) is an input; "
                                    "SIO sets outputs", expr)
            del p_kind_out
            if not lo <= value <= hi:
                raise self.fail(f"value {value} out of range {lo}..{hi} for this port", expr)
        elif kind == "ticks":
            if value < 0:
                raise self.fail("ticks must not be negative", expr)
        return value

    def check_access(self, fields: dict[str, int]) -> None:
        p, spec = self.param, self.spec
        if p is None:
            return
        if spec.mnemonic in ("SAP", "SGP", "AAP", "AGP") and not p.writable:
            raise self.fail(f"{p.label} {p.name} is read-only")
        if spec.reads and not p.readable:
            raise self.fail(f"{p.label} {p.name} is write-only")
        if spec.mnemonic in ("STAP", "STGP", "RSAP", "RSGP") and not p.storable:
            raise self.fail(f"{p.label} {p.name} cannot be stored in EEPROM (access {p.access})")


def _encode_raw(line: Line, module: Module, symbols: Symbols, direct: bool) -> Encoded:
    """A bare command number with up to three numeric operands: sent as typed."""
    opcode = int(line.mnemonic or "0")
    if not 0 <= opcode <= 255:
        raise line.error(f"command number {opcode} out of range 0..255", line.mnemonic_col)
    vals = []
    for i, expr in enumerate(line.operands):
        v = _eval(expr, line, lambda e: symbols.lookup(e.name or ""))
        limit = (0, 255) if i < 2 else (INT32_MIN, UINT32_MAX)
        if not limit[0] <= v <= limit[1]:
            raise line.error(f"{v} out of range {limit[0]}..{limit[1]}", expr.col)
        vals.append(v)
    vals += [0] * (3 - len(vals))
    if opcode == Control.FACTORY_DEFAULT and vals[2] != 1234:
        raise line.error("137 (restore factory defaults) needs the value 1234", line.mnemonic_col)
    spec = isa.by_opcode(opcode)
    ins = Instruction(opcode, vals[0], vals[1], vals[2] & 0xFFFFFFFF if vals[2] < 0 else vals[2])
    return Encoded(ins, spec)


# -- the assembler -----------------------------------------------------------------------

@dataclass(frozen=True)
class SourceLoc:
    file: str
    line: int
    text: str


@dataclass
class Program:
    """An assembled program: instructions from ``origin`` on, and where each came from."""

    module: Module
    instructions: list[Instruction]
    source: list[SourceLoc]
    labels: dict[str, int]
    origin: int = 0

    def __len__(self) -> int:
        return len(self.instructions)

    def to_binary(self) -> bytes:
        return b"".join(i.to_bytes() for i in self.instructions)

    def to_hex(self) -> str:
        return "".join(i.to_bytes().hex(" ") + "\n" for i in self.instructions)

    def loc(self, address: int) -> SourceLoc | None:
        idx = address - self.origin
        return self.source[idx] if 0 <= idx < len(self.source) else None

    def address_of_line(self, line: int, file: str | None = None) -> int | None:
        for idx, loc in enumerate(self.source):
            if loc.line >= line and (file is None or loc.file == file):
                return self.origin + idx
        return None

    def label_at(self, address: int) -> str | None:
        return next((n for n, a in self.labels.items() if a == address), None)


def generated_includes(module: Module | None) -> dict[str, str]:
    """Include files the TMCL-IDE ships, generated from the database (never typed twice)."""
    out = {"interrupts.inc": "// Interrupt numbers (generated by tmclsh)\n" + "".join(
        f"{name} = {num}\n" for name, num in isa.interrupts().items())}
    if module is not None:
        lines = [f"// {module.name} parameters (generated by tmclsh from its database)\n"]
        lines += [f"AP_{p.name} = {p.number}\n" for p in module.axis_params]
        lines += [f"GP_{p.name} = {p.number}\n" for p in module.global_params]
        text = "".join(lines)
        out[f"{module.name.lower()}.inc"] = text
        out["tmclparam.inc"] = text
    return out


@dataclass
class _Item:
    line: Line
    address: int


class Assembler:
    def __init__(self, module: Module, origin: int = 0, include_dirs: list[Path] | None = None):
        self.module = module
        self.origin = origin
        self.include_dirs = include_dirs or []
        self.generated = generated_includes(module)

    def _read(self, name: str, base: Path | None, stack: list[str], line: Line | None
              ) -> tuple[str, str]:
        candidates = [(base / name) if base else Path(name)] + [d / name for d in self.include_dirs]
        for path in candidates:
            if path.is_file():
                key = str(path.resolve())
                if key in stack:
                    raise (line.error if line else AsmError)(f"recursive #include of {name}")
                return key, path.read_text(encoding="utf-8", errors="replace")
        gen = self.generated.get(Path(name).name.lower())
        if gen is not None:
            key = "<" + Path(name).name + ">"
            if key in stack:
                raise (line.error if line else AsmError)(f"recursive #include of {name}")
            return key, gen
        if line is None:
            raise AsmError(f"cannot read {name}")
        raise line.error(f"cannot find include file {name!r}")

    def _lines(self, text: str, file: str, base: Path | None, stack: list[str]):
        for no, raw in enumerate(text.splitlines(), 1):
            line = parse_line(raw, no, file)
            if line.include:
                key, sub = self._read(line.include, base, stack, line)
                sub_base = Path(key).parent if not key.startswith("<") else base
                if len(stack) > 32:
                    raise line.error("#include nested too deeply")
                yield from self._lines(sub, line.include if key.startswith("<") else key,
                                       sub_base, stack + [key])
            else:
                yield line

    def assemble(self, text: str, file: str = "<input>", base: Path | None = None) -> Program:
        stack = [str(Path(file).resolve())] if base is not None else []
        lines = list(self._lines(text, file, base, stack))
        symbols = Symbols()
        items: list[_Item] = []
        addr = self.origin
        # pass 1: constants in order, labels at their addresses
        for line in lines:
            if line.label:
                if symbols.lookup(line.label) is not None:
                    raise line.error(f"duplicate label or name {line.label!r}", line.label_col)
                symbols.labels[line.label] = addr
            if line.constant:
                if symbols.lookup(line.constant) is not None:
                    raise line.error(f"{line.constant!r} is already defined", line.constant_col)
                if isa.by_mnemonic(line.constant):
                    raise line.error(f"{line.constant!r} is a command name", line.constant_col)
                symbols.constants[line.constant] = eval_constant(line, symbols)
            elif line.mnemonic:
                items.append(_Item(line, addr))
                addr += 1
        limit = self.module.program_memory
        if addr > limit:
            over = items[limit - self.origin] if limit - self.origin < len(items) else items[-1]
            raise over.line.error(
                f"program needs {addr - self.origin} instructions from address {self.origin}; "
                f"the {self.module.name} holds {limit}", over.line.mnemonic_col)
        # pass 2: encode with every label known
        out, source = [], []
        for item in items:
            enc = encode(item.line, self.module, symbols)
            out.append(enc.instruction)
            source.append(SourceLoc(item.line.file or file, item.line.number or 0,
                                    item.line.text.strip()))
        return Program(self.module, out, source, dict(symbols.labels), self.origin)


def assemble(text: str, module: Module, file: str = "<input>", origin: int = 0,
             base: Path | None = None) -> Program:
    return Assembler(module, origin).assemble(text, file, base)


def assemble_file(path: str | Path, module: Module, origin: int = 0) -> Program:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise AsmError(f"cannot read {p}: {exc.strerror}", file=str(p)) from None
    except UnicodeDecodeError:
        raise AsmError(f"{p} is not a text file", file=str(p)) from None
    return Assembler(module, origin).assemble(text, str(p), p.parent)


# -- images ------------------------------------------------------------------------------

def read_image(data: bytes) -> list[Instruction]:
    """Instructions from a binary image (7 bytes each) or the ``--hex`` text form."""
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        text = None
    if text is not None and re.fullmatch(r"[0-9A-Fa-f\s]*", text) and text.strip():
        out = []
        for no, raw in enumerate(text.splitlines(), 1):
            parts = raw.split()
            if not parts:
                continue
            if len(parts) != INSTRUCTION_LEN:
                raise AsmError(f"expected {INSTRUCTION_LEN} hex bytes, found {len(parts)}", no, 1)
            out.append(Instruction.from_bytes(bytes(int(x, 16) for x in parts)))
        return out
    if len(data) % INSTRUCTION_LEN:
        raise AsmError(f"a binary image is a multiple of {INSTRUCTION_LEN} bytes; "
                       f"this one has {len(data)}")
    return [Instruction.from_bytes(data[i:i + INSTRUCTION_LEN])
            for i in range(0, len(data), INSTRUCTION_LEN)]


# -- the disassembler --------------------------------------------------------------------

def label_name(address: int) -> str:
    return f"L{address:04d}"


def jump_targets(program: list[Instruction]) -> set[int]:
    targets = set()
    for ins in program:
        spec = isa.by_opcode(ins.opcode)
        if spec is not None and spec.jumps:
            targets.add(ins.signed_value)
    return targets


def disassemble_instruction(ins: Instruction, module: Module | None = None,
                            labels: dict[int, str] | None = None) -> tuple[str, str]:
    """One instruction as source text, plus a comment naming its parameter (may be empty)."""
    spec = isa.by_opcode(ins.opcode)
    modname = module.name if module else None
    if spec is None:
        return f"{ins.opcode} {ins.type}, {ins.motor}, {ins.signed_value}", "raw command"
    value = ins.signed_value
    comment = ""
    parts: dict[str, str] = {"type": str(ins.type), "motor": str(ins.motor), "value": str(value)}
    if spec.type_kind == "symbolic":
        parts["type"] = spec.type_name(ins.type, modname) or str(ins.type)
    elif spec.type_kind == "interrupt":
        parts["type"] = isa.interrupt_name(ins.type) or str(ins.type)
    elif spec.type_kind in ("axis_param", "global_param") and module is not None:
        p = (module.axis(ins.type) if spec.type_kind == "axis_param"
             else module.glob(ins.type, ins.motor))
        if p is not None:
            comment = p.name
    if spec.jumps and labels and value in labels:
        parts["value"] = labels[value]
    ops = [parts[f] for f in spec.fields]
    # keep non-zero don't-care fields so the image round-trips
    for f in ("type", "motor", "value"):
        if f not in spec.fields and getattr(ins, f) != 0:
            idx = ("type", "motor", "value").index(f)
            if all(x in spec.fields or x == f for x in ("type", "motor", "value")[:idx + 1]) or True:
                ops = None
                break
    if ops is None:
        return f"{ins.opcode} {ins.type}, {ins.motor}, {value}", f"{spec.mnemonic} with don't-care fields set"
    text = spec.mnemonic + (" " + ", ".join(ops) if ops else "")
    return text, comment


def disassemble(program: list[Instruction], module: Module | None = None, origin: int = 0,
                addresses: bool = False) -> str:
    """Source text that assembles back to the same image, with generated labels."""
    targets = {t for t in jump_targets(program) if origin <= t < origin + len(program)}
    labels = {t: label_name(t) for t in sorted(targets)}
    out = []
    for idx, ins in enumerate(program):
        addr = origin + idx
        if addr in labels:
            out.append(f"{labels[addr]}:")
        text, comment = disassemble_instruction(ins, module, labels)
        line = f"    {text}"
        notes = [c for c in (f"@{addr}" if addresses else "", comment) if c]
        if notes:
            line = f"{line:<36}// {' '.join(notes)}"
        out.append(line)
    return "\n".join(out) + "\n"
