"""A watch's sampling, from Python: expressions over module reads, read once per sample, each
answer judged before it is shown as the module's value. Plain code on a client and a mapping
of variables, never printing; ``.watch`` (``shell/features/watch.py``) keeps the display, the plot,
the CSV file and the keys.

* ``poll(client, items, t)`` reads once (identical reads within a sample are sent once) and
  gives a ``Sample``: the values, the errors, when each was read, which are still in doubt.
* An answer in doubt is never given as the module's value. On a line that brings a reply
  twice, the copy may be taken for the next request's answer (same command, same layout);
  the client finds that out when the real answer comes while nothing waits for it
  (``Doubts.suspect_seqs``). A read found so during its sample (by a later read's request)
  is read again at once, then one 136 type 1 exchange lets the line's last answer arrive
  (``Reading.settle``). A value still in doubt is None and named in ``Sample.suspect``.
  No exchange is added while nothing is in doubt.

From Python::

    c = tmclsh.connect(sim="TMCM-1311")
    items = watch.parse_items(c, "pos=GAP ActualPosition, 0; speed=GAP ActualSpeed, 0")
    sample = watch.poll(c, items, 0.0)
    sample.values  # {"pos": 0, "speed": 0}
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..base.errors import TmclError, TransportError, ValidationError
from ..client.ledger import CONFIRM_ROUNDS
from ..tmcl import expr
from . import expr as ops_expr
from .certain import read_until_certain

Number = int | float

TOGETHER_SLACK = 0.01  # s a row's reads may lie apart beyond the line's own pace, "together"


# -- what is watched ---------------------------------------------------------------------

@dataclass(frozen=True)
class Item:
    name: str
    expression: expr.Expression


def parse_items(client: Any, text: str,
                expand: Callable[[str], str] | None = None) -> list[Item]:
    """``pos=GAP 1, 0; GIO 0, 0`` -> items; a name is optional (the expression is its name).
    Every read with fixed operands is checked against the client's module (no bus I/O).
    ``expand``: what is done to each expression's text first (the shell's ``${...}``)."""
    items: list[Item] = []
    parts = text.split(";")
    for i, part in enumerate(parts):
        part = part.strip()
        if not part:
            continue
        m = re.match(r"([A-Za-z_][A-Za-z0-9_]*)\s*=(?!=)(.*)$", part, re.DOTALL)
        name, body = (m.group(1), m.group(2)) if m else (None, part)
        try:
            expression = expr.parse(expand(body) if expand is not None else body)
            ops_expr.validate(client, expression)
        except TmclError as exc:
            if i == 0:
                raise
            raise ValidationError(_after_semicolon(parts, i, exc)) from None
        name = name or expression.text
        if any(i.name == name for i in items):
            raise ValidationError(f"{name!r} is watched twice")
        items.append(Item(name, expression))
    if not items:
        raise ValidationError("nothing to watch")
    return items


def _after_semicolon(parts: list[str], i: int, exc: TmclError) -> str:
    """An expression after a ';' did not parse: perhaps it was meant as the next command."""
    before = ";".join(parts[:i]).strip()
    after = ";".join(parts[i:]).strip()
    return (f"{parts[i].strip()!r} after ';' is not a watch expression ({exc}); .watch takes "
            f"the rest of its line, ';' separating its expressions. To run {after!r} after "
            f"the watch, put it on a line of its own:\n  .watch {before}\n  {after}")


def default_items(client: Any) -> list[Item]:
    """What a watch with no expressions shows: the position and speed of the first three
    motors."""
    motors = min(client.require_module().motors, 3)
    text = "; ".join(f"pos{m}=GAP ActualPosition, {m}; speed{m}=GAP ActualSpeed, {m}"
                     for m in range(motors))
    return parse_items(client, text)


# -- samples and snapshots -----------------------------------------------------------------

@dataclass(frozen=True)
class Sample:
    t: float  # seconds since the watch started: when its first value was read
    values: dict[str, Number | None]
    errors: dict[str, str] = field(default_factory=dict)
    lost: str | None = None  # the link was lost during this sample: why
    suspect: tuple[str, ...] = ()  # values whose answer may have been another request's
    times: dict[str, float] = field(default_factory=dict)  # name -> when its value was read
    together: bool = True  # its values were read back to back (no retry, wait or read again)


class SendClock:
    """When the last request went out (a sent-only tracer: it leaves the receive path as it
    is). A read's time is the sending of the request whose answer was taken: a retry's, not
    the first attempt's; and not the answer's arrival, which a slow line holds back while
    the module read its value at the request. ``fastest``: the quickest exchange seen (a
    request sent to its answer taken), the measure of "back to back" on this line."""

    def __init__(self) -> None:
        self.sent = 0.0
        self.fastest: float | None = None

    def __call__(self, direction: str, raw: bytes, decoded: object) -> None:
        self.sent = time.monotonic()

    def took(self, sent: float, answered: float) -> None:
        took = answered - sent
        if self.fastest is None or took < self.fastest:
            self.fastest = took

    def together(self, times: Sequence[float]) -> bool:
        """Whether reads sent at ``times`` followed one another as fast as this line goes:
        within three of the fastest exchanges per read, plus 10 ms (scheduling)."""
        if len(times) < 2:
            return True
        span = max(times) - min(times)
        return span <= (len(times) - 1) * 3 * (self.fastest or 0.0) + TOGETHER_SLACK


@dataclass
class _TimedContext(ops_expr.TrackedContext):
    """A ``TrackedContext`` that notes when each read was made (``read_at``: text ->
    monotonic time its answered request went out, per ``SendClock``)."""

    clock: SendClock | None = None
    read_at: dict[str, float] = field(default_factory=dict)

    def read(self, node: expr.Read, text: str) -> Number:
        if self.cache is not None and text in self.cache:
            self.used.add(text)
            return self.cache[text]
        before = time.monotonic()
        try:
            return super().read(node, text)
        finally:
            clock = self.clock
            sent = clock.sent if clock is not None and clock.sent >= before else before
            if text in self.trace or clock is None:
                self.read_at[text] = sent
            if clock is not None and text in self.trace:
                clock.took(sent, time.monotonic())


def poll(client: Any, items: Sequence[Item], t: float,
         variables: Mapping[str, Any] | None = None) -> Sample:
    """One sample: every item evaluated once; a read failing shows as None plus its error.
    A lost link ends the sample at once (``Sample.lost``). Its answers are judged on what the
    client knows so far and then once more after a 136 type 1 exchange (see ``_Reading``).
    ``t``: seconds since the watch began, when this sample starts (its times count from
    ``time.monotonic() - t``). ``variables``: what names in the expressions stand for."""
    reading = Reading(client, items, t, variables=variables)
    reading.settle(confirm=True)
    return reading.sample()


class _Lost(Exception):
    """The link was lost while reading again (the sample ends: ``Reading.lost``)."""


class Reading:
    """One sample's reads, with the reply that answered each (``ops.expr.TrackedContext``),
    so a read whose answer is found in doubt can be read again or marked."""

    def __init__(self, client: Any, items: Sequence[Item], t: float,
                 clock: SendClock | None = None, start: float | None = None, *,
                 variables: Mapping[str, Any] | None = None,
                 counted: Callable[[], None] | None = None):
        """``t``: seconds since the watch began (``start``, monotonic), now; ``variables``:
        the names the expressions use; ``counted``: told of every read sent."""
        self.client, self.items, self.t = client, items, t
        self.start = time.monotonic() - t if start is None else start
        self.ctx = _TimedContext(client, variables if variables is not None else {},
                                 cache={}, counted=counted, clock=clock)
        self.values: dict[str, Number | None] = {}
        self.errors: dict[str, str] = {}
        self.uses: dict[str, set[str]] = {}  # item name -> the reads it used
        self.suspect: list[str] = []
        self.reread = 0  # answers read again (found in doubt, then certain or not)
        self.lost: str | None = None
        self.judged = False  # every answer judged (a request has followed the last one)
        for item in items:
            if not self._evaluate(item):
                break

    def _evaluate(self, item: Item) -> bool:
        """Evaluate one item; False if the link was lost (the sample ends)."""
        ctx = self.ctx
        ctx.used = set()
        try:
            self.values[item.name] = item.expression.evaluate(ctx)
            self.errors.pop(item.name, None)
        except TransportError as exc:
            self.lost = str(exc)
            return False
        except TmclError as exc:
            self.values[item.name] = None
            self.errors[item.name] = str(exc)
        finally:
            self.uses[item.name] = ctx.used
        return True

    def settle(self, *, confirm: bool, again: bool = True, followed: bool = False) -> None:
        """Judge the answers: ``confirm`` sends one 136 type 1 first, so the line's last
        answer has arrived (without it, the last read stays unjudged unless a suspect was
        found: reading again ends with that exchange). ``again``: read an answer in doubt
        again (``CONFIRM_ROUNDS`` times at most), else mark it at once (too late to be
        this sample's value). ``followed``: a request has been sent since the last read
        (the next sample's), so every answer can be judged without an exchange."""
        if self.lost is not None or self.judged:
            return
        ctx, client = self.ctx, self.client

        def read(doubt: set[str] | None) -> dict[int, str]:
            """Read the reads in doubt again: every item that used one is evaluated again
            (the others' reads come from this sample's cache)."""
            assert doubt is not None and ctx.cache is not None
            self.reread += len(doubt)
            client._doubts.settle(ctx.answered)
            for seq in [q for q, text in ctx.answered.items() if text in doubt]:
                del ctx.answered[seq]
            for text in doubt:
                ctx.cache.pop(text, None)
            before = set(ctx.answered)
            for item in self.items:
                if self.uses.get(item.name, set()) & doubt and not self._evaluate(item):
                    raise _Lost
            return {q: text for q, text in ctx.answered.items() if q not in before}

        try:
            found = read_until_certain(client, read, first=dict(ctx.answered), confirm=confirm,
                                       again=CONFIRM_ROUNDS if again else 0)
        except _Lost:
            self.judged = confirm or followed or not ops_expr.can_doubt(client)
            return
        doubt = found.doubt
        self.judged = (confirm or followed or not ops_expr.can_doubt(client)
                       or found.again > 0)
        if doubt:
            names = [i.name for i in self.items if self.uses.get(i.name, set()) & doubt]
            for name in names:
                self.values[name] = None
                self.errors.pop(name, None)
            self.suspect += [n for n in names if n not in self.suspect]
        if self.judged:
            client._doubts.settle(ctx.answered)

    def sample(self) -> Sample:
        if self.lost is not None:
            return Sample(self.t, {i.name: None for i in self.items}, {}, lost=self.lost)
        read_at = self.ctx.read_at
        times: dict[str, float] = {}
        for item in self.items:  # (an expression of several reads: midway between them)
            when = [read_at[r] for r in self.uses.get(item.name, ()) if r in read_at]
            if when and self.values.get(item.name) is not None:
                times[item.name] = (min(when) + max(when)) / 2 - self.start
        used = [read_at[r] for r in set().union(*self.uses.values()) if r in read_at] \
            if self.uses else []
        clock = self.ctx.clock
        together = clock.together(used) if clock is not None else True
        t = min(times.values()) if times else self.t
        return Sample(t, dict(self.values), dict(self.errors), suspect=tuple(self.suspect),
                      times=times, together=together)
