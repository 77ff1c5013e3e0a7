"""Move a motor and wait until it is there, reading the position back.

    python examples/move.py [PORT | sim]

The motor turns: on real hardware, run it only with the motor free to move.
"""

from __future__ import annotations

import sys

import tmclsh

TARGET = 3200  # microsteps


def main(port: str | None = None, sim: str | None = None) -> None:
    with tmclsh.connect(port, sim=sim) as c:
        c.execute("SAP MaxPositioningSpeed, 0, 2000")
        c.execute("SAP MaxAcceleration, 0, 5000")
        start = c.value("GAP ActualPosition, 0")
        c.execute(f"MVP ABS, 0, {start + TARGET}")
        try:
            # read the flag until it is set; TmclTimeoutError if it is not within 60 s
            c.wait_until(lambda: c.value("GAP TargetPositionReached, 0") == 1, timeout=60)
        except BaseException:
            c.execute("MST 0")  # never leave it running when the wait ends early
            raise
        print(f"reached {c.value('GAP ActualPosition, 0')} (from {start})")


if __name__ == "__main__":
    where = sys.argv[1] if len(sys.argv) > 1 else None
    try:
        main(sim="TMCM-1311") if where == "sim" else main(where)
    except tmclsh.TmclError as exc:  # a bad file, no module, a lost link: one line
        sys.exit(f"move: {exc}")
