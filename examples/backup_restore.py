"""Back up a module's axis parameters and restore them.

    python examples/backup_restore.py [PORT | sim]

INTEGRATOR: backup, compare and restore still live in the shell (``.save``, ``.diff``,
``.restore`` in tmclsh/shell/clone.py); until they are operations tmclsh exports, this
example reads and writes the parameters itself, from the module data: every axis
parameter that can be read and written and is not part of the link identity (address,
baud rate, CAN ids) or the module's running state.
"""

from __future__ import annotations

import sys

import tmclsh


def settings(c: tmclsh.LineClient) -> dict[tuple[str, int], int]:
    """(parameter name, motor) -> the value the module holds."""
    saved = {}
    for p in c.module.axis_params:
        if p.readable and p.writable and not p.state and not p.link:
            for motor in range(c.module.motors):
                saved[(p.name, motor)] = c.value(f"GAP {p.name}, {motor}")
    return saved


def main(port: str | None = None, sim: str | None = None) -> None:
    with tmclsh.connect(port, sim=sim) as c:
        backup = settings(c)
        print(f"backed up {len(backup)} values")
        c.execute("SAP MaxPositioningSpeed, 0, 777")  # someone changes one
        changed = {k: v for k, v in settings(c).items() if backup[k] != v}
        print(f"changed since: {changed}")
        for (name, motor), value in backup.items():
            # "!": the value as the module held it, even one outside the manual's range
            c.execute(f"!SAP {name}, {motor}, {value}")
        print(f"restored; differences now: {[k for k, v in settings(c).items() if backup[k] != v]}")


if __name__ == "__main__":
    where = sys.argv[1] if len(sys.argv) > 1 else None
    main(sim="TMCM-1311") if where == "sim" else main(where)
