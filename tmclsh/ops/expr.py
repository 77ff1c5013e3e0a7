"""Expressions evaluated on a module, from Python: names from a mapping of variables, reads
sent on a client (``tmcl/expr.py`` parses; this is the half that talks to the module). The
shell's ``.let``, ``.expect``, ``.wait`` and ``.watch`` give it the session's client and
variables (``shell/lang/expr.py``); a watch's sampling (``ops/watch.py``) needs nothing more.

From Python::

    c = tmclsh.connect(sim="TMCM-1311")
    expr.evaluate(c, "GAP ActualPosition, 0 / 51200", {})
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from ..base.errors import StatusError, TmclError
from ..tmcl.expr import ExprError, Expression, Number, Read, parse
from ..tmcl.frames import status_ok, status_text

if TYPE_CHECKING:
    from ..tmcl.asm import Encoded


@dataclass
class Context:
    """Evaluates names from ``variables`` (plus ``extra``) and sends reads on ``client``.

    ``trace`` collects every read and its value, for messages ("GAP 1, 0 is 4800").
    Encoded reads are cached per text, so a watch does not re-parse its lines each sample.
    ``counted`` is told of each read sent (the shell counts them as commands).
    """

    client: Any
    variables: Mapping[str, Any] = field(default_factory=dict)
    extra: Mapping[str, Number] = field(default_factory=dict)
    trace: dict[str, Number] = field(default_factory=dict)
    cache: dict[str, Number] | None = None  # per-sample: identical reads sent once
    counted: Callable[[], None] | None = None

    def name(self, name: str, col: int) -> Number:
        if name in self.extra:
            return self.extra[name]
        if name in self.variables:
            value = self.variables[name]
            if isinstance(value, str):
                raise ExprError(f"{name} is text ({value!r}), not a number: ${{{name}}} puts "
                                "it into a line as it is")
            return value
        raise ExprError(f"unknown variable {name!r} (set it with .let {name} = ...)")

    def read(self, node: Read, text: str) -> Number:
        if self.cache is not None and text in self.cache:
            return self.cache[text]
        value = read_value(self.client, text, self.counted)
        self.trace[text] = value
        if self.cache is not None:
            self.cache[text] = value
        return value


@dataclass
class TrackedContext(Context):
    """A ``Context`` that remembers which reply answered each read (``answered``:
    ``Client._replies`` after it -> the read's text), so a read whose answer the client finds
    suspect later (``Doubts.suspect_seqs``) can be named, read again or marked. ``used``:
    the texts read (or taken from the cache) since it was last cleared."""

    answered: dict[int, str] = field(default_factory=dict)
    used: set[str] = field(default_factory=set)

    def read(self, node: Read, text: str) -> Number:
        self.used.add(text)
        if self.cache is not None and text in self.cache:
            return self.cache[text]
        client = self.client
        try:
            value = read_value(client, text, self.counted)
        finally:
            seq = getattr(client, "_replies", None)
            if isinstance(seq, int):
                self.answered[seq] = text  # (an error reply is an answer too)
        self.trace[text] = value
        if self.cache is not None:
            self.cache[text] = value
        return value


def can_doubt(client: Any) -> bool:
    """Whether answers can be in doubt on this link (not in ASCII mode, whose replies are
    lines in order)."""
    return not client.judges_as_read


def encode_read(client: Any, text: str) -> Encoded:
    """Check a read's TMCL text against the module (no bus I/O; the client keeps the result
    for the module and mode, so a watch pays the parser once per expression)."""
    return client.encode(text)


def read_value(client: Any, text: str, counted: Callable[[], None] | None = None) -> Number:
    """Send one read (``GAP 1, 0``) and return its value; StatusError on an error reply.

    Goes straight to the client: a read inside an expression is not shown, recorded or
    added to a history (the shell counts it as a command sent, ``counted``).
    """
    enc, req = client.prepare(text)
    reply = client.request(req)
    if counted is not None:
        counted()
    if reply is None:
        raise ExprError(f"{text} gives no reply value")
    if not status_ok(reply.status):
        raise StatusError(reply.status, reply,
                          f"{text}: module answered status {reply.status}: "
                          f"{status_text(reply.status)}")
    p = enc.parameter
    return reply.value if p is None else p.reading(reply.value)


def validate(client: Any, expression: Expression) -> None:
    """Check every read with fixed operands against the module (no bus I/O)."""
    for node in expression.reads():
        if node.static:
            text = node.tmcl()
            try:
                encode_read(client, text)
            except TmclError as exc:
                raise ExprError(f"{text}: {exc}") from None


def evaluate(client: Any, text: str, variables: Mapping[str, Any] | None = None,
             extra: Mapping[str, Number] | None = None) -> Number:
    """Parse and evaluate ``text`` on ``client``, names from ``variables``."""
    return parse(text).evaluate(Context(client, variables or {}, extra or {}))
