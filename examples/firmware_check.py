"""Check a firmware image against a module: what an update would do, writing nothing.

    python examples/firmware_check.py IMAGE.hex [PORT | sim]

The same check as ``tmclsh firmware IMAGE.hex --check``; ``FirmwareUpdate.run()`` would
then do the update (the module restarts into its bootloader: it is not switched off).
"""

from __future__ import annotations

import sys

import tmclsh


def main(path: str, port: str | None = None, sim: str | None = None) -> None:
    image = tmclsh.read_firmware(path)  # a file that is no Intel HEX image: ImageError
    print(f"image {image.name}: {image.length} bytes at 0x{image.start:08X}, "
          f"checksum 0x{image.checksum:08X}, versions {[v.text for v in image.versions]}")
    update = tmclsh.FirmwareUpdate({"port": port, "sim": sim}, image)
    try:
        plan = update.check()
    finally:
        update.close()
    print(f"module {plan.module} runs {plan.version}")
    if plan.problem:
        print(f"refused: {plan.problem}")
    elif plan.nothing_to_do:
        print("it runs this version already")
    else:
        print(f"would update it to {plan.image_version.text}")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    where = sys.argv[2] if len(sys.argv) > 2 else None
    try:
        main(sys.argv[1], sim="TMCM-1311") if where == "sim" else main(sys.argv[1], where)
    except tmclsh.TmclError as exc:  # a bad file, no module, a lost link: one line
        sys.exit(f"firmware_check: {exc}")
