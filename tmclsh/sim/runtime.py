"""Module time and what runs in it: the motors' motion, the stored program (whose host this
is: its clock, its commands, its WAIT conditions), the interrupt sources, the 138 events
waiting for a motor, and the serial heartbeat; and the background thread that moves it on.

Module time runs ``speed`` times faster than real time; an update covers the time since the
last one in steps short enough for the motion, cut at every WAIT deadline and timer period so
that they keep module time exactly however long the update is.
"""

from __future__ import annotations

import logging
import math
import time
from typing import TYPE_CHECKING

from ..tmcl.frames import Control, Instruction, Status
from .model import GLOBAL
from .requests import Answer
from .vm import TICK as VM_TICK
from .vm import WAIT

if TYPE_CHECKING:
    from .device import Simulator
    from .motion import Limits

log = logging.getLogger(__name__)


class Runtime:
    """The module clock of one simulated module, stepped under its host's lock."""

    TICK = 0.005  # s between background steps while something moves or runs
    IDLE_TICK = 0.05
    MAX_STEP = 0.01  # s of module time per physics/program step
    MAX_STEPS = 50  # steps per advance; beyond that the steps get longer
    MAX_DEADLINE_CUTS = 1000  # extra (shorter) steps per update for WAIT and timer deadlines
    INSTRUCTIONS_PER_SECOND = 10_000  # stored-program execution rate (module time)
    MAX_CREDIT = 200
    MIN_BURST = 16  # instructions a step may run on credit

    def __init__(self, host: Simulator) -> None:
        self._host = host  # its motors, program, commands, interrupts and replies
        self.t = 0.0  # module time of the step being executed
        self.tick_base = 0.0  # module time at which the tick timer (GP 132) read 0
        self._credit = 0.0
        self.events: list[tuple[int, str, int]] = []  # 138: (motor, channel, address)
        self._last_command = time.monotonic()
        self._heartbeat_fired = False

    def restart(self) -> None:
        """A power cycle: the clock is the module's now, the tick timer starts at 0, no
        event waits."""
        self.events.clear()
        self.t = self._host.now()
        self.tick_base = self.t

    def heard(self, rearm: bool = True) -> None:
        """A command arrived: the serial heartbeat counts from now (and, ``rearm``, stops
        the motors again when it runs out; a frame with a wrong checksum only delays it)."""
        self._last_command = time.monotonic()
        if rearm:
            self._heartbeat_fired = False

    # -- the stored program's host (vm.py) ----------------------------------------------------
    def clock(self) -> float:
        """Module time of the step being executed: WAIT ticks count on the same clock as
        motion, timers and the tick timer, however long one update is."""
        return self.t

    def command(self, ins: Instruction, accu: int | None) -> tuple[int, int]:
        return self._host.commands.execute(ins, accu)

    def condition(self, kind: int, motor: int) -> bool | None:
        host = self._host
        if not 0 <= motor < host.module.motors:
            return True
        axis = host.axes[motor]
        if kind == WAIT["POS"]:
            return axis.reached
        if kind == WAIT["REFSW"]:
            return axis.switch("ref")
        if kind == WAIT["LIMSW"]:
            return axis.switch("left") or axis.switch("right")
        if kind == WAIT["RFS"]:
            return not axis.rfs
        return True

    # -- time ---------------------------------------------------------------------------------
    def busy(self) -> bool:
        """Something moves, runs or waits: the clock needs short steps."""
        host = self._host
        return host.vm.active or bool(self.events) or any(a.moving for a in host.axes)

    def advance(self) -> None:
        """Bring the model up to the module's time now."""
        now = self._host.now()
        dt = now - self.t
        if dt <= 0:
            return
        if not self.busy():
            self.t = now
            self._host.interrupts.snapshot()
            return
        n = min(self.MAX_STEPS, max(1, math.ceil(dt / self.MAX_STEP)))
        h = dt / n
        limits = self._limits()
        # Steps end early at a WAIT deadline or a timer period, so that WAIT TICKS and
        # timer interrupts keep module time exactly however long the update is.
        for _ in range(n + self.MAX_DEADLINE_CUTS):
            left = now - self.t
            if left <= 1e-12:
                break
            step = min(h, left)
            due = self._next_deadline()
            if due is not None and self.t + 1e-9 < due < self.t + step:
                step = due - self.t
            limits = self._step(step, limits)
        else:
            if now > self.t:
                self._step(now - self.t, limits)

    def _step(self, h: float, limits: list[Limits]) -> list[Limits]:
        host = self._host
        for axis, lim in zip(host.axes, limits):
            if axis.moving:
                axis.advance(h, lim, now=self.t + h)
        self.t += h
        host.interrupts.step()
        vm = host.vm
        if vm.active:
            self._credit = min(self._credit + h * self.INSTRUCTIONS_PER_SECOND,
                               self.MAX_CREDIT)
            # A short step (cut at a deadline) still runs what follows at once: a few
            # instructions on credit, paid back from the next steps.
            ran = vm.tick(max(int(self._credit), self.MIN_BURST))
            self._credit = max(self._credit - ran, -self.MAX_CREDIT)
            if ran:
                limits = self._limits()  # the program may have changed speeds
        self.check_events()
        return limits

    def _next_deadline(self) -> float | None:
        """The next module time at which a WAIT times out or a timer interrupt falls due."""
        host = self._host
        times = []
        w = host.vm.wait
        if w is not None and w.ticks:
            times.append(w.start + w.ticks * VM_TICK)
        if host.vm.active:
            times += host.interrupts.deadlines()
        return min(times) if times else None

    def _limits(self) -> list[Limits]:
        host = self._host
        return [host.commands.limits(m) for m in range(host.module.motors)]

    def check_events(self) -> None:
        """138: the motors that reached their target are told."""
        if not self.events:
            return
        host = self._host
        waiting = []
        for motor, channel, module in self.events:
            if host.axes[motor].reached:
                host._send_reply(channel, module, Control.TARGET_REACHED_EVENT,
                                 Answer(Status.EVENT, 1 << motor))
            else:
                waiting.append((motor, channel, module))
        self.events = waiting

    def _heartbeat(self) -> None:
        host = self._host
        limit = host.store.get(GLOBAL, "SerialHeartbeat")
        if limit > 0 and not self._heartbeat_fired and \
                time.monotonic() - self._last_command > limit / 1000.0:
            log.info("serial heartbeat timeout: motors stopped")
            self._heartbeat_fired = True
            for axis in host.axes:
                axis.stop()

    # -- the background thread ----------------------------------------------------------------
    def run(self) -> None:
        """Move the clock on until the module is closed: often while something moves, runs
        or waits, seldom when idle, and when a held-back reply falls due."""
        host = self._host
        while not host._closed.is_set():
            try:
                with host._lock:
                    self.advance()
                    self.check_events()
                    self._heartbeat()
                    busy = self.busy()
                host.out.drain()
            except Exception:
                log.exception("simulator step failed")
                busy = False
            timeout = self.TICK if busy else self.IDLE_TICK
            due = host.out.next_due()
            if due is not None:
                timeout = min(timeout, max(0.0, due - time.monotonic()))
            host._idle = not busy
            host._wake.wait(timeout)
            host._wake.clear()
