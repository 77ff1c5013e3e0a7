"""The shell's expression language, parsed: a small, safe evaluator (never Python's
``eval``). Pure code: a read is evaluated through a ``Context`` (``ops/expr.py`` sends it
on a client; the shell gives it the session's variables, ``shell/lang/expr.py``).

Used by ``.let``, ``.expect``, ``.wait``, ``.if``, ``.repeat``, ``.watch`` and ``${...}`` in
any line. Grammar (keywords and read mnemonics are case-insensitive)::

    expr        := or
    or          := and ( "or" and )*
    and         := not ( "and" not )*
    not         := "not" not | comparison
    comparison  := sum [ ("==" | "!=" | "<" | "<=" | ">" | ">=") sum ]    (no chaining)
    sum         := product ( ("+" | "-") product )*
    product     := unary ( ("*" | "/" | "%") unary )*
    unary       := ("-" | "+") unary | primary
    primary     := NUMBER | NAME | FUNC "(" expr ("," expr)* ")" | "(" expr ")" | read
    read        := READ operand [ "," operand ]         (at most the command's operand count)
    operand     := ["-"] NUMBER | NAME | "(" expr ")"
    READ        := GAP | GGP | GIO | GCO | RFS            (RFS only as "RFS STATUS, motor")
    FUNC        := abs | min | max | round | int | bit
    NUMBER      := 123 | 1.5 | .5 | 1e3 | 0x1F | $1F | 0b101

* A NAME is a shell variable (``.let``) or, inside ``.watch --until``, a watched name.
* A read is sent to the module when the expression is evaluated; its operands are TMCL text
  (``GAP ActualPosition, 0``), so a NAME there is a parameter or symbolic name, never a
  variable: write ``(n)`` or ``${n}`` for a computed operand. Operands are single atoms, so
  ``GAP 1, 0 / 51200`` divides the read value.
* Results are int or float; ``/`` always gives a float (``int()``/``round()`` convert back),
  ``%`` follows the sign of the divisor like Python's. Comparisons and ``and``/``or``/``not``
  give 1 or 0; ``and``/``or`` short-circuit (a read on the right may not be sent).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Protocol

from ..base.errors import ValidationError
from . import instructions as isa

Number = int | float

MAX_LENGTH = 2000  # characters in one expression
MAX_DEPTH = 64  # nesting of parentheses and unary operators
MAX_OPERATORS = 128  # binary operators in one expression (``1+1+...`` nests as deep)
MAX_LITERAL = 40  # digits in one number literal


class ExprError(ValidationError):
    """An expression that cannot be parsed or evaluated; ``col`` is 1-based."""

    def __init__(self, message: str, col: int | None = None, text: str = ""):
        self.message = message
        self.col = col
        self.text = text
        where = f" (column {col})" if col is not None and text else ""
        super().__init__(f"{message}{where}")


# -- lexing ------------------------------------------------------------------------------

_TOKEN = re.compile(r"""
    (?P<ws>\s+)
  | (?P<hex>(?:\$|0[xX])[0-9A-Fa-f]+)
  | (?P<bin>0[bB][01]+)
  | (?P<num>(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?)
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<op>==|!=|<=|>=|[-+*/%(),<>=])
""", re.VERBOSE | re.ASCII)


@dataclass(frozen=True)
class Token:
    kind: str  # num, name, op, end
    text: str
    col: int
    value: Number | None = None


def tokenize(text: str) -> list[Token]:
    if len(text) > MAX_LENGTH:
        raise ExprError(f"expression longer than {MAX_LENGTH} characters", MAX_LENGTH + 1, text)
    out: list[Token] = []
    pos = 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if not m:
            raise ExprError(f"unexpected character {text[pos]!r}", pos + 1, text)
        kind, tok = m.lastgroup, m.group()
        if kind in ("hex", "bin", "num"):
            if len(tok) > MAX_LITERAL:
                raise ExprError(f"number {tok[:12]}... is too long", pos + 1, text)
            if kind == "hex":
                value: Number = int(tok[1:] if tok[0] == "$" else tok[2:], 16)
            elif kind == "bin":
                value = int(tok[2:], 2)
            elif re.fullmatch(r"[0-9]+", tok):
                value = int(tok)
            else:
                value = float(tok)
                if not math.isfinite(value):
                    raise ExprError(f"number {tok} is too large", pos + 1, text)
            out.append(Token("num", tok, pos + 1, value))
        elif kind != "ws":
            out.append(Token(kind, tok, pos + 1))
        pos = m.end()
    out.append(Token("end", "", len(text) + 1))
    return out


# -- the tree ----------------------------------------------------------------------------

class Context(Protocol):
    """What evaluation needs from outside: names and module reads."""

    def name(self, name: str, col: int) -> Number: ...

    def read(self, node: Read, text: str) -> Number: ...


@dataclass(frozen=True)
class Node:
    col: int
    text: str  # the source text of this node, as typed

    def evaluate(self, ctx: Context) -> Number:
        raise NotImplementedError

    def children(self) -> tuple[Node, ...]:
        return ()

    def walk(self) -> Iterator[Node]:
        yield self
        for child in self.children():
            yield from child.walk()


@dataclass(frozen=True)
class Num(Node):
    value: Number = 0

    def evaluate(self, ctx: Context) -> Number:
        return self.value


@dataclass(frozen=True)
class Name(Node):
    name: str = ""

    def evaluate(self, ctx: Context) -> Number:
        return ctx.name(self.name, self.col)


@dataclass(frozen=True)
class Unary(Node):
    op: str = "-"
    arg: Node = None  # type: ignore[assignment]

    def children(self) -> tuple[Node, ...]:
        return (self.arg,)

    def evaluate(self, ctx: Context) -> Number:
        v = self.arg.evaluate(ctx)
        if self.op == "not":
            return int(not v)
        return -v if self.op == "-" else v


def _divide(a: Number, b: Number, node: Node) -> Number:
    if b == 0:
        raise ExprError("division by zero", node.col)
    return a / b


def _modulo(a: Number, b: Number, node: Node) -> Number:
    if b == 0:
        raise ExprError("modulo by zero", node.col)
    return a % b


_ARITH: dict[str, Callable[[Number, Number, Node], Number]] = {
    "+": lambda a, b, n: a + b,
    "-": lambda a, b, n: a - b,
    "*": lambda a, b, n: a * b,
    "/": _divide,
    "%": _modulo,
}
COMPARISONS: dict[str, Callable[[Number, Number], bool]] = {
    "==": lambda a, b: a == b, "!=": lambda a, b: a != b, "<": lambda a, b: a < b,
    "<=": lambda a, b: a <= b, ">": lambda a, b: a > b, ">=": lambda a, b: a >= b,
}


@dataclass(frozen=True)
class Binary(Node):
    op: str = "+"
    left: Node = None  # type: ignore[assignment]
    right: Node = None  # type: ignore[assignment]

    def children(self) -> tuple[Node, ...]:
        return (self.left, self.right)

    def evaluate(self, ctx: Context) -> Number:
        if self.op == "and":
            return int(bool(self.left.evaluate(ctx)) and bool(self.right.evaluate(ctx)))
        if self.op == "or":
            return int(bool(self.left.evaluate(ctx)) or bool(self.right.evaluate(ctx)))
        a, b = self.left.evaluate(ctx), self.right.evaluate(ctx)
        if self.op in COMPARISONS:
            return int(COMPARISONS[self.op](a, b))
        return _check(_ARITH[self.op](a, b, self), self)


def _round(x: Number) -> int:
    return int(math.floor(x + 0.5)) if isinstance(x, float) else x  # half up, not banker's


def _bit(x: Number, n: Number) -> int:
    if not isinstance(x, int) or not isinstance(n, int) or not 0 <= n < 64:
        raise ValueError("bit(value, n) wants integers and 0 <= n < 64")
    return (x >> n) & 1


FUNCTIONS: dict[str, tuple[Callable[..., Number], int, int]] = {
    # name: (function, min args, max args)
    "abs": (abs, 1, 1),
    "min": (lambda *a: min(a), 1, 16),  # min(5) is 5, not "int is not iterable"
    "max": (lambda *a: max(a), 1, 16),
    "round": (_round, 1, 1),
    "int": (lambda x: int(x), 1, 1),  # truncates toward zero
    "bit": (_bit, 2, 2),
}


@dataclass(frozen=True)
class Call(Node):
    func: str = ""
    args: tuple[Node, ...] = ()

    def children(self) -> tuple[Node, ...]:
        return self.args

    def evaluate(self, ctx: Context) -> Number:
        fn = FUNCTIONS[self.func][0]
        values = [a.evaluate(ctx) for a in self.args]
        try:
            return _check(fn(*values), self)
        except (ValueError, OverflowError, TypeError, ArithmeticError) as exc:
            raise ExprError(f"{self.func}(): {exc}", self.col) from None


@dataclass(frozen=True)
class Read(Node):
    """A TMCL read as an operand: ``GAP 1, 0``. Operands are TMCL text or sub-expressions."""

    mnemonic: str = ""
    operands: tuple[str | Node, ...] = ()

    def children(self) -> tuple[Node, ...]:
        return tuple(o for o in self.operands if isinstance(o, Node))

    @property
    def static(self) -> bool:
        """No computed operand: the TMCL text is known before evaluation."""
        return all(isinstance(o, str) for o in self.operands)

    def tmcl(self, ctx: Context | None = None) -> str:
        parts = []
        for o in self.operands:
            if isinstance(o, str):
                parts.append(o)
            else:
                if ctx is None:
                    raise ExprError("computed operand needs a context", o.col)
                parts.append(format_number(o.evaluate(ctx)))
        return f"{self.mnemonic} {', '.join(parts)}"

    def evaluate(self, ctx: Context) -> Number:
        return ctx.read(self, self.tmcl(ctx))


def _check(value: Number, node: Node) -> Number:
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, float) and not math.isfinite(value):
        raise ExprError("result is not a finite number", node.col)
    if isinstance(value, int) and abs(value) > 2**96:
        raise ExprError("value too large", node.col)
    return value


# -- parsing -----------------------------------------------------------------------------

KEYWORDS = {"and", "or", "not"}
def read_mnemonics() -> set[str]:
    """The commands whose reply value is a reading (GAP ...), or is with some types (RFS
    STATUS: the instruction set's ``read_types``)."""
    return {s.mnemonic for s in isa.all_instructions() if s.reads or s.read_types}


class _Parser:
    def __init__(self, text: str):
        self.text = text
        self.toks = tokenize(text)
        self.i = 0
        self.depth = 0
        self.operators = 0
        self.reads = read_mnemonics()

    # helpers
    def peek(self, ahead: int = 0) -> Token:
        return self.toks[min(self.i + ahead, len(self.toks) - 1)]

    def take(self) -> Token:
        tok = self.peek()
        self.i += 1
        return tok

    def is_op(self, *ops: str) -> bool:
        tok = self.peek()
        return tok.kind == "op" and tok.text in ops

    def is_word(self, word: str) -> bool:
        tok = self.peek()
        return tok.kind == "name" and tok.text.lower() == word

    def error(self, msg: str, tok: Token | None = None) -> ExprError:
        tok = tok or self.peek()
        return ExprError(msg, tok.col, self.text)

    def span(self, start: int) -> str:
        """Source text from token index ``start`` up to the current token."""
        first = self.toks[start].col - 1
        last_tok = self.toks[self.i - 1]
        return self.text[first:last_tok.col - 1 + len(last_tok.text)].strip()

    def binary_op(self) -> Token:
        tok = self.take()
        self.operators += 1
        if self.operators > MAX_OPERATORS:
            raise self.error(f"expression has more than {MAX_OPERATORS} operators", tok)
        return tok

    def nested(self) -> None:
        self.depth += 1
        if self.depth > MAX_DEPTH:
            raise self.error("expression nested too deeply")

    # grammar
    def parse(self) -> Node:
        if self.peek().kind == "end":
            raise self.error("expression expected")
        node = self.or_()
        tok = self.peek()
        if tok.kind != "end":
            if tok.text == "=":
                raise self.error("'=' is not a comparison; write '=='", tok)
            raise self.error(f"unexpected {tok.text!r}", tok)
        return node

    def _binary(self, start: int, op: str, left: Node, right: Node) -> Node:
        return Binary(left.col, self.span(start), op, left, right)

    def or_(self) -> Node:
        start = self.i
        left = self.and_()
        while self.is_word("or"):
            self.binary_op()
            left = self._binary(start, "or", left, self.and_())
        return left

    def and_(self) -> Node:
        start = self.i
        left = self.not_()
        while self.is_word("and"):
            self.binary_op()
            left = self._binary(start, "and", left, self.not_())
        return left

    def not_(self) -> Node:
        if self.is_word("not"):
            start = self.i
            self.take()
            self.nested()
            arg = self.not_()
            self.depth -= 1
            return Unary(self.toks[start].col, self.span(start), "not", arg)
        return self.comparison()

    def comparison(self) -> Node:
        start = self.i
        left = self.sum()
        if self.is_op(*COMPARISONS):
            op = self.binary_op().text
            node = self._binary(start, op, left, self.sum())
            if self.is_op(*COMPARISONS):
                raise self.error("comparisons cannot be chained; join them with 'and'")
            return node
        return left

    def sum(self) -> Node:
        start = self.i
        left = self.product()
        while self.is_op("+", "-"):
            op = self.binary_op().text
            left = self._binary(start, op, left, self.product())
        return left

    def product(self) -> Node:
        start = self.i
        left = self.unary()
        while self.is_op("*", "/", "%"):
            op = self.binary_op().text
            left = self._binary(start, op, left, self.unary())
        return left

    def unary(self) -> Node:
        if self.is_op("-", "+"):
            start = self.i
            op = self.take().text
            self.nested()
            arg = self.unary()
            self.depth -= 1
            if op == "+":
                return arg
            if isinstance(arg, Num):  # fold literal negatives: -5 is a number
                return Num(self.toks[start].col, self.span(start), -arg.value)
            return Unary(self.toks[start].col, self.span(start), "-", arg)
        return self.primary()

    def primary(self) -> Node:
        start = self.i
        tok = self.take()
        if tok.kind == "num":
            return Num(tok.col, tok.text, tok.value)  # type: ignore[arg-type]
        if tok.kind == "op" and tok.text == "(":
            self.nested()
            inner = self.or_()
            self.depth -= 1
            if not self.is_op(")"):
                raise self.error(f"expected ')', found {self.peek().text or 'end of line'!r}")
            self.take()
            return inner
        if tok.kind == "name":
            word = tok.text
            if word.upper() in self.reads:
                if not self._starts_operand():
                    raise self.error(f"{word.upper()} needs its operands, e.g. "
                                     f"{word.upper()} 1, 0", tok)
                return self.read(start, word.upper())
            if self.is_op("("):
                if word.lower() not in FUNCTIONS:
                    raise self.error(f"unknown function {word!r} (functions: "
                                     f"{', '.join(FUNCTIONS)})", tok)
                return self.call(start, word.lower())
            if word.lower() in KEYWORDS:
                raise self.error(f"{word!r} needs operands on both sides", tok)
            return Name(tok.col, tok.text, tok.text)
        if tok.kind == "end":
            raise self.error("expression ends too early", tok)
        raise self.error(f"expected a number, a name or '(', found {tok.text!r}", tok)

    def _starts_operand(self) -> bool:
        tok = self.peek()
        return tok.kind in ("num", "name") or (tok.kind == "op" and tok.text in "-(")

    def call(self, start: int, func: str) -> Node:
        self.take()  # (
        self.nested()
        args = [] if self.is_op(")") else [self.or_()]  # min() is an arity error, below
        while args and self.is_op(","):
            self.take()
            args.append(self.or_())
        self.depth -= 1
        if not self.is_op(")"):
            raise self.error(f"expected ')' to close {func}(")
        self.take()
        _, lo, hi = FUNCTIONS[func]
        if not lo <= len(args) <= hi:
            want = str(lo) if lo == hi else f"{lo}..{hi}"
            raise self.error(f"{func}() takes {want} argument{'s' if hi > 1 else ''}, "
                             f"got {len(args)}", self.toks[start])
        return Call(self.toks[start].col, self.span(start), func, tuple(args))

    def read(self, start: int, mnemonic: str) -> Node:
        spec = isa.by_mnemonic(mnemonic)
        limit = len(spec.fields) if spec is not None else 2
        operands: list[str | Node] = [self.operand()]
        while len(operands) < limit and self.is_op(","):
            self.take()
            operands.append(self.operand())
        only = spec.read_types if spec is not None and not spec.reads else ()
        if only and not (isinstance(operands[0], str) and operands[0].upper() in only):
            form = f"{mnemonic} {'|'.join(only)}, {spec.motor_kind}"
            raise self.error(f"{mnemonic} can be read only as '{form}' (its other types act "
                             "on the module)", self.toks[start])
        return Read(self.toks[start].col, self.span(start), mnemonic, tuple(operands))

    def operand(self) -> str | Node:
        tok = self.peek()
        if tok.kind == "op" and tok.text == "(":
            self.take()
            self.nested()
            inner = self.or_()
            self.depth -= 1
            if not self.is_op(")"):
                raise self.error("expected ')'")
            self.take()
            return inner
        if tok.kind == "op" and tok.text == "-" and self.peek(1).kind == "num":
            self.take()
            return "-" + self.take().text
        if tok.kind in ("num", "name"):
            return self.take().text
        raise self.error(f"expected an operand (number, name or '(expr)'), "
                         f"found {tok.text or 'end of line'!r}", tok)


@dataclass(frozen=True)
class Expression:
    """A parsed expression and its source text."""

    text: str
    root: Node

    def evaluate(self, ctx: Context) -> Number:
        return self.root.evaluate(ctx)

    def reads(self) -> list[Read]:
        return [n for n in self.root.walk() if isinstance(n, Read)]

    def names(self) -> list[str]:
        return [n.name for n in self.root.walk() if isinstance(n, Name)]

    def __str__(self) -> str:
        return self.text


def parse(text: str) -> Expression:
    text = text.strip()
    return Expression(text, _Parser(text).parse())


def format_number(value: Number) -> str:
    """``5000``, ``0.5``, ``2`` for 2.0: how values appear in lines and messages."""
    if isinstance(value, float):
        if value.is_integer() and abs(value) < 2**63:
            return str(int(value))
        return f"{value:.6g}"
    return str(value)
