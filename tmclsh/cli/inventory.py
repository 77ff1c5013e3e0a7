"""``tmclsh scan --save INVENTORY`` and ``--expect INVENTORY``: the front end of
``tmclsh.ops.inventory``. The scan itself is ``cmd_scan``'s; this reads the inventory before
anything is sent, writes one after, and shows a comparison: a table on a terminal, one line
per difference in a pipe, one JSON object per difference with ``--json``.
"""

from __future__ import annotations

import argparse
import sys

from ..base.edges import write_json
from ..base.errors import EXIT_FAILED, EXIT_OK, UsageError


def before_scan(args: argparse.Namespace):
    """The inventory ``--expect`` names, read and checked before the link is opened (a bad
    file is one error and nothing sent); None without ``--expect``."""
    from ..ops.inventory import read_inventory

    if args.save is not None and args.expect is not None:
        raise UsageError("--save writes an inventory, --expect compares with one; give one "
                         "of them")
    if args.save is not None:
        _check_new(args.save)
    if args.expect is None:
        return None
    inventory = read_inventory(args.expect)
    outside = [a for a in inventory.addresses() if not args.first <= a <= args.last]
    if outside:
        words = ", ".join(map(str, outside))
        raise UsageError(f"{args.expect} names {words}, outside the scanned range "
                         f"{args.first}..{args.last} (--from/--to take them in)")
    return inventory


def _check_new(path: str) -> None:
    """An inventory is edited by hand (a ``backup =`` line, ``lowest`` firmware), so a scan
    does not write over one: refused before anything is sent, as ``.save`` asks first."""
    from pathlib import Path

    if Path(path).exists():
        raise UsageError(f"{path} exists: not replaced (an inventory may hold lines written "
                         "by hand); remove it or give --save another file")


def check_link(inventory, client) -> None:
    """An inventory of CAN ids is checked on a CAN bus, one of addresses on a serial line."""
    from ..ops.inventory import CAN_ID

    if inventory is None:
        return
    if (inventory.ids == CAN_ID) != client.is_can:
        have = "CAN ids" if inventory.ids == CAN_ID else "serial addresses"
        link = "a CAN bus" if client.is_can else "a serial line"
        raise UsageError(f"{inventory.path} names {have}; this link is {link}")


def save(args: argparse.Namespace, found: list, client) -> None:
    """Write what answered to ``--save``'s file, said on standard error (JSON: one object)."""
    from ..ops.inventory import inventory_text, write_inventory

    write_inventory(args.save, inventory_text(found, can=client.is_can,
                                              where=client.describe()))
    n = len(found)
    if args.json:
        write_json({"saved": args.save, "modules": n})
    print(f"inventory of {n} module{'s' if n != 1 else ''} saved to {args.save}",
          file=sys.stderr)
    odd = [f.address for f in found if f.answers > 1 or f.bootloader]
    if odd:
        print(f"tmclsh: the inventory records what answered, as it answered: "
              f"{', '.join(map(str, odd))} (two modules, or in its bootloader) will be "
              "named by scan --expect until that is put right", file=sys.stderr)


def expect(args: argparse.Namespace, inventory, found: list, client) -> int:
    """Compare and show; the exit status (0 the line matches, 1 it differs)."""
    from ..ops.inventory import compare

    check = compare(inventory, found, client=client)
    if args.json:
        for diff in check.differences:
            write_json(diff.as_json(inventory.ids))
        write_json({"inventory": args.expect, "match": check.matches,
                    "differences": len(check.differences)})
    elif check.differences and sys.stdout.isatty():
        _table(check, inventory)
    else:
        for diff in check.differences:
            print(f"differs: {diff.text}", flush=True)
    n, m = len(check.differences), len(inventory.modules)
    out = sys.stderr if args.json else sys.stdout  # (stdout stays JSON)
    if check.matches:
        print(f"the line matches {args.expect} ({m} module{'s' if m != 1 else ''})",
              file=out, flush=True)
        return EXIT_OK
    print(f"{n} difference{'s' if n != 1 else ''} from {args.expect}", file=out, flush=True)
    return EXIT_FAILED


def _table(check, inventory) -> None:
    """The differences as a rich table (stdout is a terminal)."""
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    from ..ops.inventory import CAN_ID

    table = Table(title=f"differences from {inventory.path}", title_justify="left")
    table.add_column("CAN id" if inventory.ids == CAN_ID else "address", justify="right")
    table.add_column("difference")
    table.add_column("what is there")
    for diff in check.differences:
        table.add_row(str(diff.address), diff.kind, Text(diff.text.split(": ", 1)[-1]))
    Console(highlight=False).print(table)
