"""A simulated module whose time moves only when the test moves it.

A test that samples a running module in real time (a timer's period, a move between two
positions, a start-up that takes half a second) sees only what its samples catch: on a busy
machine a sample may come a second late, and edges, states and moves pass unseen. Here module
time stands still between the test's steps, so every sample is taken exactly where the test
says, however slowly the machine runs the test; what the module does in that time is the
same code (``Simulator.now`` is the one clock of the model).
"""

from __future__ import annotations

from tmclsh.sim import Simulator


class SteppedSimulator(Simulator):
    """``Simulator`` on a clock of the test's: ``step(seconds)`` moves module time."""

    module_time = 0.0

    def now(self) -> float:
        return self.module_time

    def step(self, seconds: float) -> None:
        self.module_time += seconds

    def run_for(self, seconds: float, every: float, sample=None) -> list:
        """Move module time ``seconds`` on in steps of ``every``; ``sample(t)`` after each,
        its results returned as ``(t, result)``."""
        got = []
        for _ in range(round(seconds / every)):
            self.step(every)
            if sample is not None:
                got.append((self.module_time, sample(self.module_time)))
        return got
