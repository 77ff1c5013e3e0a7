"""Traffic counted per module, for a table beside the line stream of ``monitor`` and
``bridge``: a person watching a busy line wants to see at a glance which module is
answering, how fast, which errors it gives and what its parameters last read, without
reading every line go by.

``Tally`` takes the items the monitor's readers already return (ops/monitor.py pairs each
request with its reply and says why one got none) and keeps, per module (its address, or
on CAN the id requests go to): the exchanges, their rate over a sliding window, the error
statuses by their names (tmcl/status.py), the slowest exchange, the requests left
unanswered, replies whose request was never seen, and the last value of each parameter
(read by a reply, or written by a request the module accepted). ``rows`` returns them as
data; what draws them is the front end's (shell/features/livetable.py). No I/O, no
clock of its own: times are the items' (a log's own seconds, or the wire's), and the rate is
asked for at a time the caller gives, so the rate falls when the traffic stops.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import cache

from ..tmcl import instructions as isa
from ..tmcl.asm import disassemble_instruction
from ..tmcl.frames import Instruction
from ..tmcl.modules import Module, Parameter
from ..tmcl.status import status_ok, status_text
from .monitor import REPLY, Exchange, Item, Seen

WINDOW = 5.0  # s of traffic the rate is taken over
# what a command's type field names when it names something with a value to remember
_VALUED = ("axis_param", "global_param", "port", "coordinate")


@dataclass(frozen=True, slots=True)
class Slowest:
    """The exchange that took longest: its time, the seconds it took, the request as the
    shell writes it, and as it was sent."""

    t: float
    latency: float
    command: str
    instruction: Instruction


@dataclass(frozen=True, slots=True)
class Value:
    """A parameter's (or port's, or coordinate's) last value: ``name`` from the module
    file where it names it, else the command that reads it (``GIO 3, 2``); ``param`` the
    module file's entry, for units and meanings."""

    name: str
    value: int
    t: float
    param: Parameter | None = None


@dataclass(frozen=True, slots=True)
class Row:
    """One module's line of the table."""

    address: int | None
    can: bool  # the module is reached by a CAN id (``address`` is that id)
    module: str | None  # its type, where known (``-m``, or learnt from its 136 answers)
    exchanges: int
    per_second: float
    errors: dict[str, int]  # status name -> replies with it
    unanswered: int
    unpaired: int  # replies for which no request was seen
    slowest: Slowest | None
    values: tuple[Value, ...]  # in the order first seen

    @property
    def where(self) -> str:
        if self.address is None:
            return "?"
        return f"id {self.address}" if self.can else f"@{self.address}"


@dataclass(slots=True)
class _Module:
    can: bool
    exchanges: int = 0
    times: deque = field(default_factory=deque)  # exchange times within the window
    first: float | None = None
    errors: Counter = field(default_factory=Counter)
    unanswered: int = 0
    unpaired: int = 0
    slowest: tuple[float, float, Instruction] | None = None  # (latency, t, request)
    values: dict[tuple[str, int, int], tuple[int, float]] = field(default_factory=dict)


@cache
def _reader_of(type_kind: str) -> str | None:
    """The mnemonic that reads what a type of this kind names (GAP, GGP, GIO, GCO)."""
    for spec in isa.all_instructions():
        if spec.type_kind == type_kind and spec.reads:
            return spec.mnemonic
    return None


@cache
def _valued(opcode: int) -> tuple[str, bool] | None:
    """(the kind of thing the command's type names, whether the reply carries its value);
    None for a command that neither reads nor writes a value of such a thing."""
    spec = isa.by_opcode(opcode)
    if spec is None or spec.type_kind not in _VALUED:
        return None
    if spec.reads:
        return spec.type_kind, True
    if spec.access == "write" and "value" in spec.fields:
        return spec.type_kind, False
    return None


class Tally:
    """Counts per module from the monitor's items (``take``); ``rows(now)`` the table.

    ``module_for``: the module at an address (``Monitor.module_for``), asked when the rows
    are made, so names appear once a module is learnt. ``window``: the seconds the rate is
    taken over."""

    def __init__(self, module_for: Callable[[int | None], Module | None] | None = None,
                 window: float = WINDOW):
        self.module_for = module_for or (lambda address: None)
        self.window = window
        self.latest: float | None = None
        self._modules: dict[tuple[bool, int | None], _Module] = {}

    def _module(self, seen: Seen) -> _Module:
        can = seen.can_id is not None and seen.kind != REPLY
        key = (can, seen.address)
        mod = self._modules.get(key)
        if mod is None:
            mod = self._modules[key] = _Module(can)
        return mod

    def take_all(self, items: Iterable[Item]) -> None:
        for item in items:
            self.take(item)

    def take(self, item: Item) -> None:
        """Count an exchange, or a reply that answers no request seen; other items (the
        request and reply an exchange is made of, events, noise, text) count nothing here."""
        if item.__class__ is Exchange:
            self._exchange(item)
        elif item.kind == REPLY and item.answers is None:
            mod = self._module(item)
            mod.unpaired += 1
            if not status_ok(item.reply.status):
                mod.errors[status_text(item.reply.status)] += 1

    def _exchange(self, ex: Exchange) -> None:
        req, reply = ex.request, ex.reply
        t = req.t
        mod = self._module(req)
        mod.exchanges += 1
        if mod.first is None:
            mod.first = t
        if self.latest is None or t > self.latest:
            self.latest = t
        mod.times.append(t)
        self._trim(mod, self.latest)
        if reply is None:
            if not ex.by_design:
                mod.unanswered += 1
            return
        latency = reply.latency
        if latency is not None and not reply.late and (
                mod.slowest is None or latency > mod.slowest[0]):
            mod.slowest = (latency, t, req.instruction)
        answer = reply.reply
        if not status_ok(answer.status):
            mod.errors[status_text(answer.status)] += 1
            return
        ins = req.instruction
        valued = _valued(ins.opcode)
        if valued is None or answer.version is not None or answer.stored is not None:
            return
        kind, from_reply = valued
        value = answer.value if from_reply else ins.signed_value
        mod.values[(kind, ins.type, ins.motor)] = (value, reply.t)

    def _trim(self, mod: _Module, now: float) -> None:
        times, start = mod.times, now - self.window
        while times and times[0] <= start:
            times.popleft()

    def rows(self, now: float | None = None) -> list[Row]:
        """The table at ``now`` (default: the latest exchange's time), one row per module in
        the order of their addresses."""
        if now is None:
            now = self.latest if self.latest is not None else 0.0
        out = []
        for (can, address), mod in sorted(self._modules.items(),
                                          key=lambda kv: (kv[0][0], kv[0][1] is None,
                                                          kv[0][1] or 0)):
            self._trim(mod, now)
            module = self.module_for(address)
            slowest = None
            if mod.slowest is not None:
                latency, t, ins = mod.slowest
                slowest = Slowest(t, latency, disassemble_instruction(ins, module)[0], ins)
            out.append(Row(address, can, module.name if module is not None else None,
                           mod.exchanges, self._rate(mod, now), dict(mod.errors),
                           mod.unanswered, mod.unpaired, slowest,
                           tuple(_value(key, v, t, module)
                                 for key, (v, t) in mod.values.items())))
        return out

    def _rate(self, mod: _Module, now: float) -> float:
        """Exchanges per second over the window; a module heard for less than the window
        is rated over the time since it was first heard (a second at least: a first
        exchange alone is not a thousand a second)."""
        if not mod.times or mod.first is None:
            return 0.0
        span = min(self.window, max(now - mod.first, 1.0))
        return len(mod.times) / span


def _value(key: tuple[str, int, int], value: int, t: float, module: Module | None) -> Value:
    kind, type_, motor = key
    param = None
    if module is not None:
        if kind == "axis_param":
            param = module.axis(type_)
        elif kind == "global_param":
            param = module.glob(type_, motor)
        elif kind == "port":
            port = module.port(motor, type_)
            if port is not None:
                return Value(f"{port.name} (bank {motor})" if motor else port.name, value, t)
    if param is None:
        return Value(f"{_reader_of(kind) or kind} {type_}, {motor}", value, t)
    if kind == "axis_param":
        name = f"{param.name} (motor {motor})" if module.motors > 1 else param.name
    else:
        name = f"{param.name} (bank {motor})" if motor else param.name
    return Value(name, value, t, param)


__all__ = ["Tally", "Row", "Slowest", "Value", "WINDOW"]
