"""Back up a module's configuration to a file, then restore what changed since.

    python examples/backup_restore.py [PORT | sim]

The file is the one ``.save`` writes (and ``.restore``/``tmclsh -f`` read): every setting the
module holds, values outside the manual's ranges as it holds them, and its link identity
(address, baud rate, CAN ids) in a section of its own that a restore leaves alone unless
``with_link=True``.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import tmclsh


def main(port: str | None = None, sim: str | None = None) -> None:
    with tmclsh.connect(port, sim=sim) as c, tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "module.tmcl"
        conf = tmclsh.read_configuration(c)
        tmclsh.write_backup(path, conf.text())
        print(f"backed up {len(conf.restorable)} settings "
              f"({len(conf.link)} more are its place on the line)")
        c.execute("SAP MaxPositioningSpeed, 0, 777")  # someone changes one
        saved = tmclsh.read_backup(c, path)
        changed = tmclsh.compare_backup(c, saved)
        print("changed since: " + ", ".join(f"{d.slot.name} {d.slot.value} -> {d.live}"
                                            for d in changed))
        written, _link = tmclsh.restore_backup(c, changed)
        print(f"restored {len(written)}; differences now: {len(tmclsh.compare_backup(c, saved))}")


if __name__ == "__main__":
    where = sys.argv[1] if len(sys.argv) > 1 else None
    try:
        main(sim="TMCM-1311") if where == "sim" else main(where)
    except tmclsh.TmclError as exc:  # a bad file, no module, a lost link: one line
        sys.exit(f"backup_restore: {exc}")
