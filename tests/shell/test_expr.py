"""The shell's expression language (tmclsh.shell.lang.expr): grammar, semantics, errors, safety.

Pure tests: reads go to a small recording context here; reads against the simulator are in
test_script.py.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tmclsh.base.errors import ValidationError
from tmclsh.shell.lang import expr


class Ctx:
    """Names from a dict; reads answered from a dict and recorded in order."""

    def __init__(self, names=None, reads=None):
        self.names = names or {}
        self.reads = reads or {}
        self.sent: list[str] = []

    def name(self, name, col):
        if name not in self.names:
            raise expr.ExprError(f"unknown variable {name!r}")
        return self.names[name]

    def read(self, node, text):
        self.sent.append(text)
        return self.reads[text]


def ev(text, **names):
    return expr.parse(text).evaluate(Ctx(names))


@pytest.mark.parametrize("text, value", [
    ("1 + 2 * 3", 7),
    ("(1 + 2) * 3", 9),
    ("10 - 4 - 3", 3),  # left associative
    ("-2 * -3", 6),
    ("- -3", 3),
    ("+5", 5),
    ("7 % 3", 1),
    ("$1F", 31), ("0x1f", 31), ("0b101", 5),
    ("1.5 * 2", 3.0), (".5", 0.5), ("1e3", 1000.0),
    ("1 < 2", 1), ("2 <= 1", 0), ("3 == 3", 1), ("3 != 3", 0), ("2 > 1", 1), ("1 >= 2", 0),
    ("1 < 2 and 2 < 3", 1), ("1 > 2 or 2 > 3", 0), ("not 0", 1), ("not 5", 0),
    ("not 1 == 2", 1),  # not binds looser than comparison
    ("1 + 1 == 2 and not 0", 1),
    ("abs(-4)", 4), ("min(3, 1, 2)", 1), ("max(3, 1, 2)", 3),
    ("round(2.5)", 3), ("round(-2.5)", -2), ("int(-2.7)", -2), ("int(7 / 2)", 3),
    ("bit(5, 0)", 1), ("bit(5, 1)", 0),
])
def test_values(text, value):
    result = ev(text)
    assert result == value
    assert type(result) is type(value)


def test_division_is_true_division_and_modulo_is_pythons():
    assert ev("7 / 2") == 3.5
    assert ev("6 / 2") == 3.0 and isinstance(ev("6 / 2"), float)
    assert ev("-7 % 3") == 2


def test_variables():
    assert ev("speed * 2 + offset", speed=1000, offset=-5) == 1995
    with pytest.raises(expr.ExprError, match="unknown variable 'nope'"):
        ev("nope + 1")


def test_and_or_short_circuit():
    assert ev("0 and 1 / 0") == 0
    assert ev("1 or 1 / 0") == 1
    ctx = Ctx(reads={"GAP 1, 0": 5})
    assert expr.parse("0 and GAP 1, 0 == 5").evaluate(ctx) == 0
    assert ctx.sent == []  # the read on the right was never sent


def test_reads_are_operands_with_atomic_operands():
    ctx = Ctx(names={"m": 2}, reads={"GAP 1, 0": 102400, "GIO 0, 0": 1, "GAP 1, 2": 7,
                                     "GAP ActualPosition, 0": 3, "RFS STATUS, 0": 0,
                                     "GGP 0, 2": -5, "GAP 1, -1": 9})
    def run(text):
        return expr.parse(text).evaluate(ctx)

    assert run("GAP 1, 0 / 51200") == 2.0  # the read ends at its second operand
    assert run("GAP 1, 0 == 102400") == 1
    assert run("gap 1, 0") == 102400  # mnemonics are case-insensitive
    assert run("GAP ActualPosition, 0 + 1") == 4  # names pass through as TMCL text
    assert run("GAP 1, (m)") == 7  # a computed operand, in parentheses
    assert run("max(GAP 1, 0, 5)") == 102400  # GAP takes two operands; the third is max's
    assert run("bit(GIO 0, 0, 0)") == 1
    assert run("RFS STATUS, 0 == 0") == 1
    assert run("-GGP 0, 2") == 5
    assert run("GAP 1, -1") == 9
    assert ctx.sent[:3] == ["GAP 1, 0", "GAP 1, 0", "GAP 1, 0"]


def test_read_text_and_static():
    e = expr.parse("GAP 1, 0 + GAP 3, (m)")
    first, second = e.reads()
    assert first.static and first.tmcl() == "GAP 1, 0"
    assert not second.static
    assert second.tmcl(Ctx(names={"m": 1})) == "GAP 3, 1"


@pytest.mark.parametrize("text, message", [
    ("1 < 2 < 3", "cannot be chained"),
    ("a = 3", "write '=='"),
    ("(1 + 2", r"expected '\)'"),
    ("1 +", "ends too early"),
    ("", "expression expected"),
    ("1 2", "unexpected '2'"),
    ("and 1", "needs operands on both sides"),
    ("GAP", "GAP needs its operands"),
    ("RFS START, 0", "RFS can be read only as 'RFS STATUS, motor'"),
    ("MVP ABS, 0, 100", "unexpected"),  # a command that moves is not an operand
    ("foo(1)", "unknown function 'foo'"),
    ("max()", r"max\(\) takes 1..16 arguments, got 0"),
    ("round(1, 2)", "takes 1 argument"),
    ("2 @ 3", "unexpected character '@'"),
    ("__import__('os')", "unexpected character"),
])
def test_syntax_errors(text, message):
    with pytest.raises(expr.ExprError, match=message):
        expr.parse(text)


def test_errors_give_the_column():
    with pytest.raises(expr.ExprError) as info:
        expr.parse("1 + (2 * 3")
    assert info.value.col == 11
    assert "column 11" in str(info.value)
    assert isinstance(info.value, ValidationError)  # the shell's "refused" error


@pytest.mark.parametrize("text, message", [
    ("1 / 0", "division by zero"), ("1 % 0", "modulo by zero"),
    ("1e308 * 10", "not a finite number"), ("bit(1.5, 0)", "bit"),
])
def test_evaluation_errors(text, message):
    with pytest.raises(expr.ExprError, match=message):
        ev(text)


def test_resource_limits():
    with pytest.raises(expr.ExprError, match="nested too deeply"):
        expr.parse("(" * 200 + "1" + ")" * 200)
    with pytest.raises(expr.ExprError, match="too long"):
        expr.parse("1" * 100)
    with pytest.raises(expr.ExprError, match="longer than"):
        expr.parse("1+" * 2000 + "1")
    with pytest.raises(expr.ExprError, match="too large"):
        ev("x * x * x * x", x=2**40)


def test_format_number():
    assert expr.format_number(5000) == "5000"
    assert expr.format_number(2.0) == "2"
    assert expr.format_number(0.5) == "0.5"
    assert expr.format_number(1 / 3) == "0.333333"


# -- property: the evaluator agrees with integer arithmetic done on the tree ---------------

_ints = st.integers(min_value=-10**6, max_value=10**6)


@st.composite
def trees(draw, depth=0):
    if depth > 4 or draw(st.booleans()):
        n = draw(_ints)
        return (str(n) if n >= 0 else f"({n})"), n
    op = draw(st.sampled_from(["+", "-", "*", "<", "==", "and", "or"]))
    (lt, lv), (rt, rv) = draw(trees(depth + 1)), draw(trees(depth + 1))
    value = {"+": lambda: lv + rv, "-": lambda: lv - rv, "*": lambda: lv * rv,
             "<": lambda: int(lv < rv), "==": lambda: int(lv == rv),
             "and": lambda: int(bool(lv) and bool(rv)),
             "or": lambda: int(bool(lv) or bool(rv))}[op]()
    return f"({lt} {op} {rt})", value


@settings(max_examples=300, deadline=None)
@given(trees())
def test_evaluator_matches_integer_arithmetic(tree):
    text, value = tree
    try:
        assert expr.parse(text).evaluate(Ctx()) == value
    except expr.ExprError as exc:  # only the size guard may refuse
        assert "too large" in str(exc)


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=60))
def test_arbitrary_text_parses_or_fails_cleanly(text):
    try:
        expr.parse(text)
    except expr.ExprError:
        pass
