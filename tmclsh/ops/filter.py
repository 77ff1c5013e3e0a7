"""Which of the traffic ``ops.monitor`` reads is shown: ``monitor``'s and ``bridge``'s
``--address``, ``--op`` and ``--param`` (kept apart from the reading and pairing, which
every frame goes through whatever is shown)."""

from __future__ import annotations

from collections.abc import Iterable

from ..tmcl.frames import Instruction
from ..tmcl.modules import Module
from .monitor import EVENT, REPLY, REQUEST, Exchange, Item, Monitor

_PARAM_KINDS = {"axis_param": "axis", "global_param": "global"}


class Filter:
    """Which frames and exchanges are shown: ``--address``, ``--op``, ``--param``.

    ``addresses``: module addresses (a request's address or CAN id, a reply's module).
    ``ops``: command numbers. ``params``: parameter names or numbers, matched against the
    parameter a request names (read through the module data of its address, or of ``-m``,
    or, when neither is known, of any module tmclsh has data for). Frames that belong to no
    module (noise, text lines, other CAN traffic) are shown only when no filter is given.
    """

    def __init__(self, addresses: Iterable[int] = (), ops: Iterable[int] = (),
                 params: Iterable[str | int] = (), monitor: Monitor | None = None):
        self.addresses = frozenset(addresses)
        self.ops = frozenset(ops)
        self.params = tuple(params)
        self.monitor = monitor
        self.active = bool(self.addresses or self.ops or self.params)
        if monitor is not None:
            monitor.summary.filtered = self.active
        self._names = {_norm(p) for p in self.params if isinstance(p, str)}
        self._numbers = {p for p in self.params if isinstance(p, int)}

    def __call__(self, item: Item) -> bool:
        if not self.active:
            return True
        seen = item.request if isinstance(item, Exchange) else item
        req = seen.answers if seen.kind == REPLY and seen.answers is not None else seen
        if self.addresses and req.address not in self.addresses \
                and seen.address not in self.addresses:
            return False
        ins = req.instruction
        if self.ops:
            op = ins.opcode if ins is not None else (
                seen.reply.opcode if seen.reply is not None else None)
            if op not in self.ops:
                return False
        if self.params:
            if ins is None or not self._names_param(ins, req.address):
                return False
        return seen.kind in (REQUEST, REPLY, EVENT)

    def _names_param(self, ins: Instruction, address: int | None) -> bool:
        from ..tmcl import instructions as isa

        spec = isa.by_opcode(ins.opcode)
        kind = _PARAM_KINDS.get(spec.type_kind) if spec is not None else None
        if kind is None:
            return False
        if ins.type in self._numbers:
            return True
        if not self._names:
            return False
        mod = self.monitor.module_for(address) if self.monitor is not None else None
        for m in [mod] if mod is not None else _all_modules():
            p = m.axis(ins.type) if kind == "axis" else m.glob(ins.type, ins.motor)
            if p is not None and _norm(p.name) in self._names:
                return True
        return False


def _norm(name: str) -> str:
    return "".join(c for c in name.lower() if c.isalnum())


def _all_modules() -> list[Module]:
    from ..tmcl.modules import catalogue

    return catalogue()


def parameter_known(name: str, module: Module | None = None) -> bool:
    """Does ``module`` (else any module tmclsh has data for) have a parameter of this name?"""
    for m in [module] if module is not None else _all_modules():
        if any(_norm(p.name) == _norm(name) for p in (*m.axis_params, *m.global_params)):
            return True
    return False
