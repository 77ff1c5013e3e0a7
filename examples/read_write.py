"""Read and write parameters by name, as the manual names them; a value the module does
not accept is refused before anything is sent.

    python examples/read_write.py [PORT | sim]
"""

from __future__ import annotations

import sys

import tmclsh


def main(port: str | None = None, sim: str | None = None) -> None:
    with tmclsh.connect(port, sim=sim) as c:
        before = c.value("GAP MaxPositioningSpeed, 0")
        c.execute("SAP MaxPositioningSpeed, 0, 1200")
        print(f"MaxPositioningSpeed: {before} -> {c.value('GAP MaxPositioningSpeed, 0')}")
        print(f"MaxAcceleration: {c.value('GAP MaxAcceleration, 0')}")
        try:
            c.execute("SAP MicrostepResolution, 0, 12")  # the manual allows 0..8
        except tmclsh.RangeError as exc:
            print(f"refused, nothing sent: {exc}")
        try:
            c.execute("SGP 73, 0, 1234")  # lock the configuration EEPROM ...
            c.execute("STAP MaxPositioningSpeed, 0")  # ... so storing is refused
        except tmclsh.StatusError as exc:
            print(f"the module said no: {exc}")
        finally:
            c.execute("SGP 73, 0, 0")  # and unlocked again
        c.execute(f"SAP MaxPositioningSpeed, 0, {before}")


if __name__ == "__main__":
    where = sys.argv[1] if len(sys.argv) > 1 else None
    try:
        main(sim="TMCM-1311") if where == "sim" else main(where)
    except tmclsh.TmclError as exc:  # a bad file, no module, a lost link: one line
        sys.exit(f"read_write: {exc}")
