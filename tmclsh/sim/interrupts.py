"""Where a stored program's interrupts come from (TMCM-1311 §5.6): input pin edges, the three
timers and the first motor's target and stop switches, each raised in the program's VM when
the module's configuration (GP bank 3) asks for it.

Timer periods count in module time from when they are set; the deadlines they give cut the
simulation's steps, so a timer keeps its period however long one update of the model is.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..tmcl import instructions as isa
from ..tmcl.frames import Status
from .model import GLOBAL, Live

if TYPE_CHECKING:
    from .device import Simulator

IRQ = isa.interrupts()
TIMERS = ("TI_TIMER0", "TI_TIMER1", "TI_TIMER2")


def _edge(config: int, old: bool, new: bool) -> bool:
    """Does a level change from ``old`` to ``new`` raise an interrupt configured ``config``
    (1 rising, 2 falling, 3 both)?"""
    return old != new and (config == 3 or (config == 1 and new) or (config == 2 and not new))


class InterruptSources:
    """The levels and times last seen, and the interrupts their changes raise."""

    def __init__(self, host: Simulator) -> None:
        self._host = host  # its module, parameters, I/O, motors, program and clock
        self.timer_due: dict[int, tuple[float, float]] = {}  # irq -> (period, due)
        self._prev: dict[str, object] = {}

    def register(self) -> None:
        """The timer periods (GP bank 3 #0-2) as live parameters: a period counts from when
        it is set."""
        store = self._host.store
        for irq in (IRQ[name] for name in TIMERS):
            timer = store.param(GLOBAL, irq, 3)
            if timer is not None:
                store.add_live(GLOBAL, timer.name, self._timer_period(irq))

    def _timer_period(self, irq: int) -> Live:
        key = (GLOBAL, 3, irq)
        store = self._host.store

        def set_period(bank: int, value: int) -> int:
            store.ram[key] = value
            if value > 0:
                t = self._host.clock()
                self.timer_due[irq] = (value / 1000.0, t + value / 1000.0)
            else:
                self.timer_due.pop(irq, None)
            return Status.OK

        return Live(lambda b: store.ram.get(key, 0), set_period)

    def pin_levels(self) -> dict[int, int]:
        io = self._host.io
        return {p.port: io.get(0, p.port) for p in io.ports(0, ("digital_in",))}

    def _config(self, irq: int) -> int:
        return self._host.store.read(GLOBAL, irq, 3, check_access=False)[1]

    def pin_edges(self, before: dict[int, int], after: dict[int, int]) -> None:
        """Input levels changed from ``before`` to ``after``: the edges configured raise."""
        host = self._host
        if not host.module.interrupts:
            return
        for port, new in after.items():
            irq = IRQ["TI_PIN0"] + port
            if port < 8 and _edge(self._config(irq), bool(before.get(port)), bool(new)):
                host.vm.raise_interrupt(irq)

    def snapshot(self) -> None:
        """Remember the first motor's levels, the ones its interrupts watch."""
        axis = self._host.axes[0]
        self._prev = {"reached": axis.reached, "left": axis.switch("left"),
                      "right": axis.switch("right")}

    def deadlines(self) -> list[float]:
        """Module times at which a timer interrupt falls due."""
        return [due for _, due in self.timer_due.values()]

    def step(self) -> None:
        """A step of module time ended: the timers due and the motor's changes raise."""
        host = self._host
        if not host.module.interrupts:
            return
        vm, t = host.vm, host.clock()
        for name in TIMERS:
            irq = IRQ[name]
            period = self._config(irq) / 1000.0
            last = self.timer_due.get(irq)
            if period <= 0:
                self.timer_due.pop(irq, None)
            elif last is None or last[0] != period:
                self.timer_due[irq] = (period, t + period)  # counted from when it is set
            elif t >= last[1] - 1e-9:
                vm.raise_interrupt(irq)
                due = last[1] + period
                self.timer_due[irq] = (period, due if due > t else t + period)
        axis, prev = host.axes[0], self._prev
        if axis.reached and not prev.get("reached"):
            vm.raise_interrupt(IRQ["TI_TARGET"])
        for side, name in (("left", "TI_STOPL"), ("right", "TI_STOPR")):
            level = axis.switch(side)
            if _edge(self._config(IRQ[name]), bool(prev.get(side)), level):
                vm.raise_interrupt(IRQ[name])
        self.snapshot()
