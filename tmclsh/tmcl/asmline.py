"""One TMCL line read and encoded: the tokens, operand expressions, ``parse_line`` (one
line of source or one typed command, nothing resolved) and ``encode`` (a line against the
instruction set and a module's data, names resolved through ``Symbols``).

Everything that reads a TMCL line goes through these (the shell, scripts, the assembler, the
simulator's ASCII mode); ``tmcl/asm.py`` builds programs of them and offers them under its
own name too, as it always has. The source syntax is asm.py's docstring's.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Callable

from . import instructions as isa
from ..base.errors import AsmError, AsmRangeError, RangeError, ValidationError
from .modules import Module, Parameter
from .frames import INT32_MIN, UINT32_MAX, Control, Instruction

FIELDS = ("type", "motor", "value")

# -- lexing ------------------------------------------------------------------------------

_TOKEN = re.compile(r"""
    (?P<ws>\s+)
  | (?P<hex>(?:\$|0[xX])[0-9A-Fa-f]+)
  | (?P<bin>0[bB][01]+)
  | (?P<num>[0-9]+)
  | (?P<name>[A-Za-z_][A-Za-z0-9_.]*)
  | (?P<op>[-+*/(),:=%])
""", re.VERBOSE | re.ASCII)

# Longest number literal accepted: anything longer cannot fit 32 bits anyway (and Python
# refuses to convert decimal strings of more than 4300 digits).
_MAX_LITERAL = 40
# Deepest nesting of parentheses and unary signs in one operand.
_MAX_DEPTH = 64
# Most binary operators in one operand: the tree of ``1+1+...`` is as deep as it is long.
_MAX_OPERATORS = 128
# Intermediate results of constant arithmetic are kept within this magnitude.
_MAX_MAGNITUDE = 2**64
# Longest source line (characters) and largest source file (bytes).
MAX_LINE_LENGTH = 4096


@dataclass(frozen=True)
class Token:
    kind: str
    text: str
    col: int  # 1-based
    value: int | None = None


def tokenize(text: str, line: int | None = None, file: str | None = None) -> list[Token]:
    if len(text) > MAX_LINE_LENGTH:
        raise AsmError(f"line longer than {MAX_LINE_LENGTH} characters", line,
                       MAX_LINE_LENGTH + 1, file)
    tokens: list[Token] = []
    pos = 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if not m:
            raise AsmError(f"unexpected character {text[pos]!r}", line, pos + 1, file)
        kind, tok = m.lastgroup, m.group()
        if kind in ("hex", "bin", "num"):
            if len(tok) > _MAX_LITERAL:
                raise AsmError(f"number {tok[:12]}... is too long", line, pos + 1, file)
            digits, base = {"hex": (tok[1:] if tok[0] == "$" else tok[2:], 16),
                            "bin": (tok[2:], 2), "num": (tok, 10)}[kind]
            tokens.append(Token("num", tok, pos + 1, int(digits, base)))
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
        self.depth = 0
        self.operators = 0

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

    def _is_op(self, chars: str) -> Token | None:
        tok = self.peek()
        return tok if tok is not None and tok.kind == "op" and tok.text in chars else None

    def _operator(self, tok: Token) -> None:
        self.operators += 1
        if self.operators > _MAX_OPERATORS:
            where = f" (column {tok.col})" if self.line is None else ""
            raise self.error(f"expression has more than {_MAX_OPERATORS} operators{where}", tok)

    def expr(self) -> Expr:
        left = self.term()
        while (tok := self._is_op("+-")) is not None:
            self._operator(tok)
            self.i += 1
            left = Expr(tok.text, left.col, args=(left, self.term()))
        return left

    def term(self) -> Expr:
        left = self.unary()
        while (tok := self._is_op("*/%")) is not None:
            self._operator(tok)
            self.i += 1
            left = Expr(tok.text, left.col, args=(left, self.unary()))
        return left

    def unary(self) -> Expr:
        tok = self.take()
        if tok.kind == "op" and tok.text in "-+(":
            self.depth += 1
            if self.depth > _MAX_DEPTH:
                raise self.error("expression nested too deeply", tok)
            try:
                if tok.text == "-":
                    return Expr("neg", tok.col, args=(self.unary(),))
                if tok.text == "+":
                    return self.unary()
                inner = self.expr()
                close = self.take()
                if close.text != ")":
                    raise self.error(f"expected ')', found {close.text!r}", close)
                return inner
            finally:
                self.depth -= 1
        if tok.kind == "num":
            return Expr("num", tok.col, value=tok.value, text=tok.text)
        if tok.kind == "name":
            return Expr("name", tok.col, name=tok.text, text=tok.text)
        raise self.error(f"expected a number or a name, found {tok.text!r}", tok)


# -- lines -------------------------------------------------------------------------------

@dataclass
class Line:
    """One parsed source line. At most one of instruction, constant or include is set.

    ``mnemonic`` is upper case, or the decimal command number for a raw command.
    """

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
    include_col: int = 0
    comment: str = ""

    def error(self, msg: str, col: int | None = None, kind: str = "syntax") -> AsmError:
        cls = AsmRangeError if kind == "range" else AsmError
        return cls(msg, self.number, col, self.file, kind)

    @property
    def is_raw(self) -> bool:
        return self.mnemonic is not None and self.mnemonic.isdigit()


# The common line, a command and up to three decimal numbers (``SGP 3, 2, 100``): read by
# one pattern into what the tokens and the parser make of it (a program is mostly these).
# Anything else (a label, a name, a sign, a comment, hex) goes the general way.
_PLAIN = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_.]*)(?:\s+([0-9]{1,%d})(?:\s*,\s*([0-9]{1,%d})"
                    r"(?:\s*,\s*([0-9]{1,%d}))?)?)?\s*" % ((_MAX_LITERAL,) * 3), re.ASCII)


def _plain_line(text: str, number: int | None, file: str | None, m: re.Match) -> Line:
    line = Line(text=text, number=number, file=file, mnemonic=m.group(1).upper(),
                mnemonic_col=m.start(1) + 1)
    operands = line.operands
    for g in (2, 3, 4):
        digits = m.group(g)
        if digits is None:
            break
        operands.append(Expr("num", m.start(g) + 1, value=int(digits), text=digits))
    return line


def parse_line(text: str, number: int | None = None, file: str | None = None) -> Line:
    """Parse one line of TMCL source (or one typed command) without resolving any name.

    Accepts ``Label:``, ``Label: CMD ...``, ``Name = expr``, ``#include FILE``, ``CMD a, b, c``
    and a comma straight after the mnemonic (``EI, 255`` as the manuals print some examples).
    """
    if "//" not in text and len(text) <= MAX_LINE_LENGTH:
        plain = _PLAIN.fullmatch(text.rstrip("\r\n"))
        if plain is not None:
            return _plain_line(text, number, file, plain)
    return _parse_line(text, number, file)


def _parse_line(text: str, number: int | None, file: str | None) -> Line:
    """Any line, token by token (``parse_line``'s general way)."""
    body, comment = strip_comment(text.rstrip("\r\n"))
    line = Line(text=text, number=number, file=file, comment=comment)
    stripped = body.strip()
    if stripped.startswith("#"):
        col = body.find("#") + 1
        directive = stripped.split()[0]
        if directive.lower() != "#include":
            raise line.error(f"unknown directive {directive!r} (only #include is known)", col)
        target = stripped[len("#include"):].strip().strip('"<>').strip()
        if not target:
            raise line.error("#include needs a file name", col)
        line.include, line.include_col = target, body.find(target, col) + 1
        return line
    toks = tokenize(body, number, file)
    if not toks:
        return line
    end_col = len(body.rstrip()) + 1
    i = 0
    if len(toks) >= 2 and toks[0].kind == "name" and toks[1].text == ":":
        line.label, line.label_col = toks[0].text, toks[0].col
        i = 2
    if i + 1 < len(toks) and toks[i].kind == "name" and toks[i + 1].text == "=":
        if line.label:
            raise line.error("a constant cannot follow a label", toks[i].col)
        line.constant, line.constant_col = toks[i].text, toks[i].col
        p = _Parser(toks[i + 2:], number, file, end_col)
        line.operands = [p.expr()]
        if (extra := p.peek()) is not None:
            raise p.error(f"unexpected {extra.text!r} after the constant's value", extra)
        return line
    if i >= len(toks):
        return line
    head = toks[i]
    if head.kind == "num":
        # a raw command number: `136 1` or `138 0, 0, 0` (also written `$8A 0, 0, 0`)
        line.mnemonic, line.mnemonic_col = str(head.value), head.col
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
    """Names a line may use besides the built-in ones: constants and labels.

    Names are case-insensitive, like mnemonics.
    """

    constants: dict[str, int] = field(default_factory=dict)
    labels: dict[str, int] = field(default_factory=dict)
    allow_forward: bool = False  # unknown labels resolve to 0 (a first pass over a program)

    def lookup(self, name: str) -> int | None:
        for table in (self.constants, self.labels):
            if name in table:
                return table[name]
        folded = name.lower()
        for table in (self.constants, self.labels):
            for key, val in table.items():
                if key.lower() == folded:
                    return val
        return None


@dataclass(frozen=True)
class Encoded:
    """An instruction with what the checks learned about it (for rendering replies)."""

    instruction: Instruction
    spec: isa.InstructionSpec | None
    parameter: Parameter | None = None
    label: str | None = None  # jump target name, if given by name


def _eval(expr: Expr, line: Line, resolve: Callable[[Expr], int | None]) -> int:
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
        result = a + b
    elif expr.op == "-":
        result = a - b
    elif expr.op == "*":
        result = a * b
    else:
        if b == 0:
            raise line.error("division by zero", expr.args[1].col)
        q = abs(a) // abs(b) * (1 if (a >= 0) == (b >= 0) else -1)  # truncate like C
        result = q if expr.op == "/" else a - q * b
    if abs(result) > _MAX_MAGNITUDE:
        raise line.error("value too large", expr.col, "range")
    return result


def _kind(exc: ValidationError) -> str:
    return "range" if isinstance(exc, RangeError) else "check"


def eval_constant(line: Line, symbols: Symbols) -> int:
    value = _eval(line.operands[0], line, lambda e: symbols.lookup(e.name or ""))
    _check_int32(value, line, line.operands[0].col)
    return value


def _check_int32(value: int, line: Line, col: int) -> None:
    if not INT32_MIN <= value <= UINT32_MAX:
        raise line.error(f"{value} is out of range for a TMCL operand: allowed "
                         f"{INT32_MIN}..{UINT32_MAX} (32 bits)", col, "range")


def _suggest(word: str, choices) -> str:
    import difflib  # only for a word that is wrong: not at start-up

    close = difflib.get_close_matches(word.upper(), [c.upper() for c in choices], n=3, cutoff=0.5)
    return f"; did you mean {', '.join(close)}?" if close else ""


def encode(line: Line, module: Module, symbols: Symbols | None = None, *,
           direct: bool = False, ascii: bool = False, as_typed: bool = False) -> Encoded:
    """Turn a parsed command line into an instruction, checked against ``module``.

    ``direct``: the line is typed at a prompt (control-flow commands refused, labels unknown);
    ``ascii``: it will go through the module's ASCII mode (only the commands it accepts);
    ``as_typed``: the value is sent as typed whatever the data says of its range (the
    override, ``!SAP ...``: the module's answer decides; it must still fit 32 bits).
    Every refusal is an AsmError naming what is wrong and what is allowed.
    """
    symbols = symbols or Symbols()
    if line.mnemonic is None:
        raise line.error("no command on this line")
    if line.is_raw:  # (the ASCII link refuses these itself: they have no ASCII form)
        return _encode_raw(line, symbols, direct=direct)
    spec = isa.by_mnemonic(line.mnemonic)
    if spec is None:
        known = [s.mnemonic for s in module.instructions]
        hint = _suggest(line.mnemonic, known)
        if module.generic and not hint:
            hint = "; any command can be sent by number: <command> <type>, <motor>, <value>"
        raise line.error(f"unknown command {line.mnemonic!r}{hint}", line.mnemonic_col)
    if not spec.on(module):
        hint = (f" (no data on this module's commands: send it by number, {spec.opcode} "
                "<type>, <motor>, <value>)") if module.generic else ""
        raise line.error(f"{spec.mnemonic} is not available on the {module.name}{hint}",
                         line.mnemonic_col)
    if direct and not spec.direct:
        raise line.error(f"{spec.mnemonic} only works inside a stored program, not as a direct "
                         "command (upload a program with .upload)", line.mnemonic_col)
    if ascii and not spec.ascii:
        raise line.error(f"{spec.mnemonic} is not accepted in ASCII mode; switch to binary "
                         "mode (.mode binary) to send it", line.mnemonic_col)
    return _Encoder(line, spec, module, symbols, direct, as_typed).run()


class _Encoder:
    def __init__(self, line: Line, spec: isa.InstructionSpec, module: Module, symbols: Symbols,
                 direct: bool, as_typed: bool = False):
        self.line, self.spec, self.module, self.symbols, self.direct = line, spec, module, symbols, direct
        self.as_typed = as_typed
        self.param: Parameter | None = None
        self.label: str | None = None
        self.all_fields = False  # three operands for a command that names fewer
        self.unused: dict[str, Expr] = {}  # those operands in fields the command does not use

    def fail(self, msg: str, expr: Expr | None = None, kind: str = "check") -> AsmError:
        """A well-formed line this module refuses; ``kind="range"`` for a value out of range."""
        col = expr.col if expr is not None else self.line.mnemonic_col
        if self.all_fields:  # `ROR 0, 1000, 5` refused for "motor 1000": say how it was read
            msg += (f" ({self.spec.mnemonic} takes {self.spec.syntax}; three operands are "
                    "read as <type>, <motor>, <value>)")
        return self.line.error(msg, col, kind)

    def number(self, expr: Expr, extra: dict[str, int] | None = None) -> int:
        def resolve(e: Expr) -> int | None:
            value = self.symbols.lookup(e.name or "")  # the program's names shadow built-ins
            if value is None and extra:
                value = extra.get((e.name or "").upper())
            return value
        value = _eval(expr, self.line, resolve)
        _check_int32(value, self.line, expr.col)
        return value

    def operands(self) -> dict[str, Expr]:
        """Which field each operand fills: the spec's operands, or all three fields."""
        spec, ops = self.spec, self.line.operands
        if len(ops) <= len(spec.fields):
            given = dict(zip(spec.fields, ops))
        elif len(ops) == len(FIELDS):
            given = dict(zip(FIELDS, ops))  # `GAP 1, 0, 0`: don't-care fields written out
            # (where that moves an operand to another field, a refusal says how it was read)
            self.all_fields = tuple(spec.fields) != FIELDS[:len(spec.fields)]
            self.unused = {name: given.pop(name) for name in FIELDS if name not in spec.fields}
        else:
            raise self.fail(f"too many operands: {spec.syntax} (or all three fields: "
                            f"{spec.mnemonic} <type>, <motor>, <value>)", ops[len(spec.fields)],
                            "syntax")
        if "type" in spec.fields and "type" not in given:
            raise self.fail(f"{spec.mnemonic} needs its first operand: {spec.syntax}",
                            kind="syntax")
        if "value" in spec.fields and "value" not in given:
            raise self.fail(f"{spec.mnemonic} needs a value: {spec.syntax}", kind="syntax")
        return given

    def _unused(self, name: str, expr: Expr) -> None:
        """An operand written into a field the instruction does not use: 0 is the manuals'
        way of writing all three fields; anything else would be sent and ignored, or
        silently dropped, so it is refused (the command number sends fields as written)."""
        if self.number(expr) == 0:
            return
        spec = self.spec
        self.all_fields = False
        raise self.fail(f"too many operands: {spec.syntax} ({spec.mnemonic} does not use its "
                        f"{name} field; the raw form {spec.opcode} <type>, <motor>, <value> "
                        "sends every field as written)", expr, "syntax")

    def run(self) -> Encoded:
        spec = self.spec
        given = self.operands()
        fields = {"type": 0, "motor": 0, "value": 0}
        # A parameter's or port's number depends on its bank (the motor field), so the motor
        # field comes first there; MVP's motor field depends on its type (COORD masks).
        if spec.type_kind == "symbolic":
            if "type" in given:
                fields["type"] = self.type_(given["type"], 0, False)
            if "motor" in given:
                fields["motor"] = self.motor(given["motor"], fields["type"])
        else:
            if "motor" in given:
                fields["motor"] = self.motor(given["motor"], None)
            if "type" in given:
                fields["type"] = self.type_(given["type"], fields["motor"], "motor" in given)
        if ("motor" not in given and spec.type_kind == "global_param"
                and self.param is not None):
            fields["motor"] = self.param.bank  # `GGP SerialAddress`: the parameter's bank
        if "value" in given:
            fields["value"] = self.value(given["value"], fields)
        for name, expr in self.unused.items():  # don't-care fields written out
            self._unused(name, expr)
        self.check_access()
        ins = Instruction(spec.opcode, fields["type"], fields["motor"], fields["value"])
        return Encoded(ins, spec, self.param, self.label)

    def motor(self, expr: Expr, type_: int | None) -> int:
        spec, mod = self.spec, self.module
        kind = spec.motor_kind
        value = self.number(expr)
        if value in spec.motor_special.get(mod.name, {}):
            return value  # SCO/GCO bank 255: copy coordinates between RAM and EEPROM
        if kind == "motor":
            if (spec.mnemonic == "MVP" and mod.motors > 1 and value >= mod.motors
                    and type_ == spec.type_names(mod).get("COORD")):
                # TMCM-351 MVP COORD: bit 7 multi-motor, bit 6 interpolation, bits 0-2 mask
                if not 0 <= value <= 0xFF or value & 0x38 or not value & 0xC0 or not value & 0x07:
                    raise self.fail(f"motor field {value} is not a valid MVP COORD motor mask "
                                    "($40 interpolation or $80 multi-motor, plus motor bits "
                                    f"0..{mod.motors - 1})", expr)
                return value
            try:
                mod.check_motor(value)
            except ValidationError as exc:
                hint = ""
                if spec.mnemonic == "AAP" and mod.glob(0, value) is not None:
                    hint = (f" (AAP writes an axis parameter; to store the accumulator in "
                            f"global parameter bank {value} use AGP)")
                raise self.fail(f"{exc}{hint}", expr) from None
        elif kind == "bank":
            port = spec.type_kind == "port"
            banks = mod.io_banks() if port else mod.banks()
            if value not in banks:
                what = "I/O bank" if port else "parameter bank"
                raise self.fail(f"{mod.name} has no {what} {value}: banks "
                                f"{', '.join(map(str, banks))}", expr)
        elif not 0 <= value <= 255:
            raise self.fail(f"{value} does not fit the motor/bank byte (0..255)", expr, "range")
        return value

    def type_(self, expr: Expr, motor: int, motor_given: bool) -> int:
        spec, mod = self.spec, self.module
        kind = spec.type_kind
        if kind == "symbolic":
            names = spec.type_names(mod)
            name = (expr.name or "").upper()
            if expr.is_name and name in names:
                return names[name]
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
            except AsmError:  # the number's own error, located already
                raise
            except ValidationError as exc:
                raise self.fail(str(exc), expr) from None
            if mod.generic:
                self.param = None  # a number without data: nothing to check or name it by
            return number
        if kind == "interrupt":
            value = self.number(expr, isa.interrupts())
            if value not in isa.interrupts().values():
                raise self.fail(f"{value} is not an interrupt number: "
                                + ", ".join(str(v) for v in sorted(isa.interrupts().values())), expr)
            return value
        value = self.number(expr)
        if kind == "port":
            bank = motor if motor_given else 0
            if not self.all_ports(value, bank) and mod.port(bank, value) is None:
                ports = [str(p.port) for p in mod.io if p.bank == bank]
                raise self.fail(f"{mod.name} has no port {value} in I/O bank {bank}: ports "
                                f"{', '.join(ports) or 'none'}", expr)
            return value
        if kind == "coordinate":
            if not 0 <= value < mod.coordinates:
                raise self.fail(f"coordinate {value} out of range: 0..{mod.coordinates - 1}", expr,
                                "range")
            return value
        if not 0 <= value <= 255:
            raise self.fail(f"{value} does not fit the type byte (0..255)", expr, "range")
        return value

    def all_ports(self, port: int, bank: int) -> bool:
        mod = self.module
        return mod.io_all_port is not None and port == mod.io_all_port and bank in mod.io_all_banks

    def value(self, expr: Expr, fields: dict[str, int]) -> int:
        spec, mod = self.spec, self.module
        kind = spec.value_kind
        if kind == "label":
            return self.address(expr)
        value = self.number(expr)
        if self.as_typed:
            return value  # the module decides (the override)
        if kind == "velocity":
            lo, hi = mod.velocity_min, mod.velocity_max
            if not lo <= value <= hi:
                raise self.fail(f"velocity {value} out of range {lo}..{hi}", expr, "range")
        elif kind == "position":
            if spec.mnemonic == "MVP" and fields["type"] == spec.type_names(mod).get("COORD"):
                if not 0 <= value < mod.coordinates:
                    raise self.fail(f"coordinate {value} out of range: 0..{mod.coordinates - 1}", expr,
                                "range")
            elif not mod.position_min <= value <= mod.position_max:
                raise self.fail(f"position {value} out of range "
                                f"{mod.position_min}..{mod.position_max}", expr, "range")
        elif kind == "param" and self.param is not None:
            try:
                self.param.check(value)
            except ValidationError as exc:
                raise self.fail(str(exc), expr, _kind(exc)) from None
        elif kind == "port_value":
            self.check_port_value(value, fields, expr)
        elif kind == "ticks":
            if value < 0:
                raise self.fail("ticks must not be negative", expr)
        return value

    def address(self, expr: Expr) -> int:
        """A jump target: a label, or a number inside program memory."""
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
        else:
            addr = self.number(expr)
        memory = self.module.program_memory
        if not 0 <= addr < memory:
            raise self.fail(f"address {addr} is outside program memory 0..{memory - 1}", expr)
        return addr

    def check_port_value(self, value: int, fields: dict[str, int], expr: Expr) -> None:
        """SIO: the port must be an output; 0/1 (or its range), or a bit mask for all ports."""
        port, bank = fields["type"], fields["motor"]
        if self.all_ports(port, bank):
            if not any(p.bank == bank and p.kind == "digital_out" for p in self.module.io):
                raise self.fail(f"I/O bank {bank} has no outputs; SIO {port} sets all outputs "
                                "of an output bank", expr)
            # all outputs at once: a bit mask; -1 copies the accumulator (programs only)
            lo, hi = (0 if self.direct else -1), 255
        else:
            p = self.module.port(bank, port)
            if p is None:  # type_() refused unknown ports already
                raise self.fail(f"no port {port} in I/O bank {bank}", expr)
            if p.kind not in ("digital_out", "unknown"):  # unknown: a generic module's port
                raise self.fail(f"{p.name} (bank {p.bank} port {p.port}) is an input; "
                                "SIO sets outputs", expr)
            lo, hi = p.min, p.max
        if not lo <= value <= hi:
            raise self.fail(f"value {value} out of range {lo}..{hi} for this port", expr, "range")

    def check_access(self) -> None:
        p, spec = self.param, self.spec
        if p is None:
            return
        if spec.access == "write" and not p.writable:
            raise self.fail(f"{p.label} {p.name} is read-only")
        if spec.access == "read" and not p.readable:
            raise self.fail(f"{p.label} {p.name} is write-only")
        if spec.access in ("store", "restore") and not p.storable:
            raise self.fail(f"{p.label} {p.name} cannot be stored in EEPROM (access {p.access})")


def _encode_raw(line: Line, symbols: Symbols, direct: bool) -> Encoded:
    """A bare command number with up to three numeric operands: sent as typed."""
    opcode = int(line.mnemonic or "0")
    if not 0 <= opcode <= 255:
        raise line.error(f"command number {opcode} out of range 0..255", line.mnemonic_col,
                         "range")
    vals = []
    for i, expr in enumerate(line.operands):
        v = _eval(expr, line, lambda e: symbols.lookup(e.name or ""))
        limit = (0, 255) if i < 2 else (INT32_MIN, UINT32_MAX)
        if not limit[0] <= v <= limit[1]:
            raise line.error(f"{v} out of range {limit[0]}..{limit[1]}", expr.col, "range")
        vals.append(v)
    vals += [0] * (3 - len(vals))
    if direct and opcode == Control.FACTORY_DEFAULT and vals[2] != 1234:
        raise line.error("137 (restore factory defaults) needs the value 1234", line.mnemonic_col)
    ins = Instruction(opcode, vals[0], vals[1], vals[2])
    return Encoded(ins, isa.by_opcode(opcode))
