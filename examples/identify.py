"""Connect and identify: which module answers, its firmware, and a first read.

    python examples/identify.py [PORT | sim]

Without PORT it opens the one Trinamic USB module attached; ``sim`` is the built-in
simulator (a TMCM-1311).
"""

from __future__ import annotations

import sys

import tmclsh


def main(port: str | None = None, sim: str | None = None) -> None:
    with tmclsh.connect(port, sim=sim) as c:
        print(f"{c.module.name} at address {c.address} on {c.describe()}")
        print(f"firmware {c.version}")  # asked with 136 at connect, not assumed
        print(f"{c.module.motors} motor(s); position now "
              f"{c.value('GAP ActualPosition, 0')}")


if __name__ == "__main__":
    where = sys.argv[1] if len(sys.argv) > 1 else None
    try:
        main(sim="TMCM-1311") if where == "sim" else main(where)
    except tmclsh.TmclError as exc:  # a bad file, no module, a lost link: one line
        sys.exit(f"identify: {exc}")
