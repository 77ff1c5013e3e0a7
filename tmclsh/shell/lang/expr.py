"""The shell's expression language on a session: names from its variables, reads sent on its
client and counted in its statistics, ``${...}`` substituted first. The language itself is
``tmcl/expr.py`` (pure), evaluating on a module ``ops/expr.py``; their names are here too,
so the shell's features say ``expr.parse``, ``expr.ExprError``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from ...base import limits
from ...ops import expr as ops_expr
from ...ops.expr import can_doubt as _can_doubt
from ...tmcl.expr import (COMPARISONS, FUNCTIONS, KEYWORDS, MAX_DEPTH,
                          MAX_LENGTH, MAX_LITERAL, MAX_OPERATORS, Binary, Call, Context,
                          ExprError, Expression, Name, Node, Num, Number, Read, Token, Unary,
                          format_number, parse, read_mnemonics, tokenize)

if TYPE_CHECKING:
    from ...tmcl.asm import Encoded
    from .session import Session

__all__ = ["COMPARISONS", "FUNCTIONS", "KEYWORDS", "MAX_DEPTH", "MAX_LENGTH", "MAX_LITERAL",
           "MAX_OPERATORS", "Binary", "Call", "Context", "ExprError", "Expression", "Name",
           "Node", "Num", "Number", "Read", "Token", "Unary", "format_number", "parse",
           "read_mnemonics", "tokenize", "SessionContext", "TrackedContext", "can_doubt",
           "encode_read", "read_value", "validate", "evaluate", "seconds"]


def _counter(session: Session):
    def counted() -> None:
        session.stats.commands += 1
    return counted


class SessionContext(ops_expr.Context):
    """An ``ops.expr.Context`` on the session: its client, its variables, each read counted
    as a command sent."""

    def __init__(self, session: Session, extra: Mapping[str, Number] | None = None,
                 **kw: Any):
        super().__init__(session.client, session.variables, extra or {},
                         counted=_counter(session), **kw)
        self.session = session


class TrackedContext(ops_expr.TrackedContext):
    """An ``ops.expr.TrackedContext`` on the session (see ``SessionContext``)."""

    def __init__(self, session: Session, extra: Mapping[str, Number] | None = None,
                 **kw: Any):
        super().__init__(session.client, session.variables, extra or {},
                         counted=_counter(session), **kw)
        self.session = session


def can_doubt(session: Session) -> bool:
    """Whether answers can be in doubt on the session's link (see ``ops.expr.can_doubt``)."""
    return _can_doubt(session.client)


def encode_read(session: Session, text: str) -> Encoded:
    return ops_expr.encode_read(session.client, text)


def read_value(session: Session, text: str) -> Number:
    """One read sent (``ops.expr.read_value``), counted as a command sent."""
    return ops_expr.read_value(session.client, text, _counter(session))


def validate(session: Session, expression: Expression) -> None:
    """Check every read with fixed operands against the module (no bus I/O)."""
    ops_expr.validate(session.client, expression)


def evaluate(session: Session, text: str, extra: Mapping[str, Number] | None = None) -> Number:
    """Parse and evaluate ``text`` (``${...}`` inside it substituted first)."""
    expression = parse(session.expand(text))
    return expression.evaluate(SessionContext(session, extra or {}))


# -- option splitting for dot-commands ------------------------------------------------------

def seconds(key: str, value: Number, what: str) -> float:
    """An evaluated duration (``.sleep 2*60``) within the bounds of ``limits.LIMITS[key]``."""
    return float(limits.check(key, value, what))
