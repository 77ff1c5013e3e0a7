"""What should answer on a line, from Python: the inventory file (``scan --save`` writes it,
``scan --expect`` checks the line against it) and the comparison of a scan's findings with
it. Plain functions returning data, never printing; ``tmclsh scan`` is the front end.

A technician's question is "is this line as it should be?", asked after a module was
swapped or a cabinet rewired. The scan already knows who answers where, in which mode and
with which firmware; this adds what was meant to be there and names each way the two part.
The inventory is TOML a person can write and read::

    [[module]]
    address = 1                # or can_id = 1 on a CAN bus
    type = "TMCM-1311"
    firmware = "1311V111"      # exactly this; or lowest = "1311V110": this or a newer one
    mode = "binary"            # or "ascii": found in its ASCII mode
    backup = "axis1.tmcl"      # optional: its settings must match this backup (.save)

The file is read bounded (``base.files``) and checked as a whole before anything is sent, so
a typo is one error naming the line, never a "matches". Settings are compared only for a
module that is the type the inventory names, in binary mode, out of its bootloader and alone
at its address: reading another module's parameters would compare nothing meaningful, and
only addresses the scan found answering are read.

From Python::

    inv = inventory.read_inventory("line.toml")
    found = scan.scan(client, inv.addresses(), timeout=0.05, ascii_also=inv.addresses())
    check = inventory.compare(inv, found, client=client)   # client: settings too
    check.matches, [d.text for d in check.differences]
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

from ..base import files
from ..base.errors import TmclError, UsageError, ValidationError
from ..tmcl.version import parse_string

if TYPE_CHECKING:
    from ..client.core import Client
    from .scan import Found

MAX_INVENTORY = 1024 * 1024  # bytes: a line of 255 modules is a few dozen kilobytes
ADDRESS, CAN_ID = "address", "can_id"
BINARY, ASCII = "binary", "ascii"
SETTINGS_RETRIES = 2  # a scan asks once; a backup's reads are the client's, retried as usual
_KEYS = ("address", "can_id", "type", "firmware", "lowest", "mode", "backup")

# the kinds of difference, in the order a technician deals with them
MISSING, EXTRA, DOUBLED, BOOTLOADER, TYPE, FIRMWARE, MODE, SETTINGS = (
    "missing", "extra", "doubled", "bootloader", "type", "firmware", "mode", "settings")
KINDS = (MISSING, EXTRA, DOUBLED, BOOTLOADER, TYPE, FIRMWARE, MODE, SETTINGS)


class InventoryError(UsageError):
    """An inventory file that cannot be used: unreadable, not TOML, or an entry that says
    something tmclsh cannot check. Raised before anything is sent."""


@dataclass(frozen=True)
class Expected:
    """What should answer at one address (or CAN id)."""

    address: int
    module: str  # a module name tmclsh knows, or the type number for one it does not
    firmware: str | None = None  # exactly this version ("1311V111", or "111": after the V)
    lowest: str | None = None  # this version or a newer one
    mode: str = BINARY
    backup: Path | None = None

    def as_json(self) -> dict:
        row: dict = {"module": self.module, "mode": self.mode}
        if self.firmware is not None:
            row["firmware"] = self.firmware
        if self.lowest is not None:
            row["lowest"] = self.lowest
        if self.backup is not None:
            row["backup"] = str(self.backup)
        return row


@dataclass(frozen=True)
class Inventory:
    modules: tuple[Expected, ...]
    ids: str = ADDRESS  # what the numbers are: serial addresses or CAN ids
    path: Path | None = None

    def addresses(self) -> list[int]:
        return sorted(e.address for e in self.modules)

    def at(self, address: int) -> Expected | None:
        return next((e for e in self.modules if e.address == address), None)


@dataclass(frozen=True)
class Difference:
    """One way the line differs from the inventory; ``text`` says it for people."""

    kind: str  # one of KINDS
    address: int
    text: str
    expected: Expected | None = None
    found: Found | None = None
    settings: tuple = ()  # ops.backup.Difference for each parameter that differs
    error: str | None = None  # why the settings could not be compared

    def as_json(self, ids: str = ADDRESS) -> dict:
        row: dict = {"difference": self.kind, ids: self.address, "text": self.text,
                     "expected": self.expected.as_json() if self.expected else None,
                     "found": _found_json(self.found) if self.found else None}
        if self.kind == SETTINGS:
            row["backup"] = str(self.expected.backup) if self.expected else None
            row["settings"] = [d.to_json() for d in self.settings]
            if self.error is not None:
                row["error"] = self.error
        return row


@dataclass(frozen=True)
class Check:
    inventory: Inventory
    found: tuple[Found, ...]
    differences: tuple[Difference, ...] = field(default=())

    @property
    def matches(self) -> bool:
        return not self.differences


def _found_json(found: Found) -> dict:
    row = found.as_json()
    row.pop("address", None)
    row.pop("baud", None)
    return row


# -- the file ----------------------------------------------------------------------------

def version_part(text: str) -> str:
    """The version a firmware string carries (``1311V111`` -> ``111``); text that is not a
    whole version string is taken as the version itself."""
    parsed = parse_string(text)
    return parsed.version if parsed is not None else text.strip()


def _version_key(version: str) -> tuple:
    """Versions in order: by number where they are numbers (``1.11`` and ``111`` alike),
    else as text."""
    digits = version.replace(".", "")
    return (0, int(digits), "") if digits.isdigit() else (1, 0, version)


def parse_inventory(text: str, path: Path | str = "inventory") -> Inventory:
    """Check an inventory's text as a whole; ``path`` names it in errors and anchors the
    backups it names (relative to its folder)."""
    import tomllib

    path = Path(path)
    beyond = files.toml_limits(text)
    if beyond is not None:
        raise InventoryError(f"{path}:{beyond[0]}: {beyond[1]}")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InventoryError(f"{path}: not TOML: {exc}") from None
    extra = set(data) - {"module"}
    if extra:
        raise InventoryError(f"{path}: unknown key(s) {', '.join(sorted(extra))}; an "
                             "inventory holds [[module]] entries only")
    entries = data.get("module", [])
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise InventoryError(f"{path}: 'module' must be entries written [[module]]")
    if not entries:
        raise InventoryError(f"{path}: no [[module]] entries: nothing to compare "
                             "(tmclsh scan --save writes an inventory)")
    kinds: set[str] = set()
    modules: list[Expected] = []
    seen: set[int] = set()
    for n, entry in enumerate(entries, 1):
        where = f"{path}: module {n}"
        expected, ids = _entry(entry, where, path)
        kinds.add(ids)
        if expected.address in seen:
            raise InventoryError(f"{where}: {ids.replace('_', ' ')} {expected.address} is named "
                                 "twice; one module per address")
        seen.add(expected.address)
        modules.append(expected)
    if len(kinds) > 1:
        raise InventoryError(f"{path}: entries name both addresses and CAN ids; an inventory "
                             "is of one line or one bus")
    return Inventory(tuple(modules), kinds.pop(), path)


def _entry(entry: dict, where: str, path: Path) -> tuple[Expected, str]:
    from ..base import limits
    from ..tmcl import modules as moddb

    bad = set(entry) - set(_KEYS)
    if bad:
        raise InventoryError(f"{where}: unknown key(s) {', '.join(sorted(bad))}; known: "
                             + ", ".join(_KEYS))
    named = [k for k in (ADDRESS, CAN_ID) if k in entry]
    if len(named) != 1:
        raise InventoryError(f"{where}: give 'address' (a serial line) or 'can_id' (a CAN "
                             "bus), one of them")
    ids = named[0]
    number = entry[ids]
    if not isinstance(number, int) or isinstance(number, bool):
        raise InventoryError(f"{where}: {ids} must be a whole number")
    try:
        limits.check(ids, number, f"{where} {ids}")
    except ValidationError as exc:
        raise InventoryError(str(exc)) from None
    strings = {}
    for key in ("type", "firmware", "lowest", "mode", "backup"):
        value = entry.get(key)
        if value is not None and (not isinstance(value, str) or not value.strip()):
            raise InventoryError(f"{where}: {key} must be text in quotes")
        strings[key] = value.strip() if isinstance(value, str) else None
    module = strings["type"]
    if module is None:
        raise InventoryError(f"{where}: 'type' is missing (a module name, TMCM-1311, or the "
                             "type number of one tmclsh does not know)")
    if not module.isdigit():
        try:
            module = moddb.load(module).name
        except ValidationError as exc:
            raise InventoryError(f"{where}: {exc}") from None
    if strings["firmware"] is not None and strings["lowest"] is not None:
        raise InventoryError(f"{where}: give 'firmware' (exactly that version) or 'lowest' "
                             "(that one or newer), not both")
    mode = (strings["mode"] or BINARY).lower()
    if mode not in (BINARY, ASCII):
        raise InventoryError(f"{where}: mode is \"binary\" or \"ascii\", not {strings['mode']!r}")
    backup = strings["backup"]
    backup_path = None
    if backup is not None and mode == ASCII:
        raise InventoryError(f"{where}: a backup is compared in binary mode only; this entry "
                             "names ASCII mode")
    if backup is not None:
        backup_path = Path(backup).expanduser()
        if not backup_path.is_absolute():
            backup_path = path.parent / backup_path
    firmware = strings["firmware"]
    lowest = strings["lowest"]
    return Expected(number, module, firmware, lowest, mode, backup_path), ids


def read_inventory(path: Path | str) -> Inventory:
    """Read and check an inventory file (bounded: ``MAX_INVENTORY`` bytes)."""
    path = Path(path)
    try:
        text = files.read_text(path, MAX_INVENTORY, what="inventory")
    except files.FileError as exc:
        raise InventoryError(str(exc)) from None
    return parse_inventory(text, path)


def _type_of(found: Found) -> str | None:
    """The type an inventory names for a found module: its name, else its type number."""
    if found.module is not None:
        return found.module
    parsed = parse_string(found.version)
    return str(parsed.type_number) if parsed is not None else None


def inventory_text(found: list[Found], *, can: bool = False, where: str = "",
                   when: datetime | None = None) -> str:
    """The inventory of what answered, as ``scan --save`` writes it: each module's type, its
    firmware exactly and its mode; what could not be told (a module in its bootloader, two at
    one address) is said in a comment beside the entry, so the file reads as the line was."""
    when = when or datetime.now(timezone.utc)
    ids = CAN_ID if can else ADDRESS
    lines = ["# tmclsh inventory: what should answer on this line",
             f"# written by tmclsh scan --save on {when:%Y-%m-%d %H:%M} UTC"
             + (f" ({_one_line(where)})" if where else ""),
             "# tmclsh scan --expect FILE compares the line with it. Per module: type, and",
             "# firmware = \"VERSION\" (exactly) or lowest = \"VERSION\" (that or newer), mode =",
             "# \"binary\" or \"ascii\", backup = \"FILE\" (its settings must match that backup).",
             ""]
    for hit in found:
        lines.append("[[module]]")
        if hit.answers > 1:
            lines.append("# two modules answered at this address when this was saved")
        lines.append(f"{ids} = {hit.address}")
        kind = _type_of(hit)
        if kind is None:
            lines.append("# its type could not be read when this was saved")
            lines.append('# type = ""')
        else:
            lines.append(f"type = {json.dumps(kind)}")
        if hit.bootloader:
            lines.append(f"# in its bootloader ({_one_line(str(hit.version))}) when this was "
                         "saved: its firmware version is not known")
        elif hit.version is not None:
            lines.append(f"firmware = {json.dumps(hit.version)}")
        lines.append(f'mode = "{ASCII if hit.ascii else BINARY}"')
        lines.append("")
    return "\n".join(lines)


def _one_line(text: str) -> str:
    """Text that stays inside a comment (a path or an answer may hold a line break)."""
    return "".join(c if c.isprintable() else "?" for c in text)


def write_inventory(path: Path | str, text: str) -> None:
    """All or nothing (``base.files``): a failed write leaves the old inventory as it was."""
    files.write_file(path, text)


# -- the comparison ----------------------------------------------------------------------

def _firmware_text(found: Found) -> str:
    return found.version or "?"


def compare(inventory: Inventory, found: list[Found], *, client: Client | None = None
            ) -> Check:
    """Every way ``found`` (a scan of the inventory's addresses) differs from ``inventory``,
    by address. With ``client`` (the scan's, still open) the settings of each module whose
    entry names a backup are read and compared; nothing is read from any other module."""
    diffs: list[Difference] = []
    by_address = {f.address: f for f in found}
    ids_word = "CAN id" if inventory.ids == CAN_ID else "address"
    for address in sorted(set(by_address) | set(inventory.addresses())):
        want, hit = inventory.at(address), by_address.get(address)
        where = f"{ids_word} {address}"
        if hit is None:
            assert want is not None
            diffs.append(Difference(MISSING, address, f"{where}: nothing answered, "
                                    f"expected a {want.module}", want))
            continue
        if want is None:
            diffs.append(Difference(EXTRA, address, f"{where}: a {hit.module or 'module'} "
                                    f"({_firmware_text(hit)}) answered; the inventory names "
                                    "none here", None, hit))
            continue
        diffs += _differences(want, hit, where, client)
    return Check(inventory, tuple(found), tuple(diffs))


def _differences(want: Expected, hit: Found, where: str, client: Client | None
                 ) -> list[Difference]:
    out: list[Difference] = []

    def say(kind: str, text: str) -> None:
        out.append(Difference(kind, hit.address, f"{where}: {text}", want, hit))

    if hit.answers > 1:  # its answers are two modules': nothing else it says can be trusted
        say(DOUBLED, f"two modules answer at this address (every reply came twice); "
                     f"expected one {want.module}")
        return out
    kind = _type_of(hit)
    other_type = kind != want.module
    if other_type:  # (its firmware is another type's: not compared)
        say(TYPE, f"a {kind or 'module of unknown type'} ({_firmware_text(hit)}) answered, "
                  f"expected a {want.module}")
    if hit.bootloader:
        say(BOOTLOADER, f"in its bootloader ({_firmware_text(hit)}): a firmware update did "
                        "not complete")
    elif hit.version is not None and not other_type:
        have = _version_key(version_part(hit.version))
        if want.firmware is not None and have != _version_key(version_part(want.firmware)):
            say(FIRMWARE, f"firmware {hit.version}, expected {want.firmware}")
        if want.lowest is not None and have < _version_key(version_part(want.lowest)):
            say(FIRMWARE, f"firmware {hit.version}, expected {want.lowest} or newer")
    if hit.ascii and want.mode == BINARY:
        say(MODE, "in ASCII mode, expected binary mode")
    elif not hit.ascii and want.mode == ASCII:
        say(MODE, "in binary mode, expected ASCII mode")
    if want.backup is not None and client is not None:
        if out:
            return out  # another module, or not one tmclsh can read: settings left unread
        out += _settings(client, want, hit, where)
    return out


def _settings(client: Client, want: Expected, hit: Found, where: str) -> list[Difference]:
    """The module's settings against its backup (``ops.backup``); one Difference naming
    each parameter that differs, or why they could not be read."""
    from ..tmcl import modules as moddb
    from . import backup

    assert want.backup is not None
    client.address = hit.address
    if client.is_can:
        client.can_id = hit.address
    client.module = moddb.load(want.module) if not want.module.isdigit() else None
    client.version = hit.version
    retries, client.retries = client.retries, max(client.retries, SETTINGS_RETRIES)
    try:
        saved = backup.read_backup(client, want.backup, command=".diff")
        diffs = backup.compare(client, saved)
    except TmclError as exc:
        return [Difference(SETTINGS, hit.address, f"{where}: settings not compared with "
                           f"{want.backup}: {exc}", want, hit, error=str(exc))]
    finally:
        client.retries = retries
    if not diffs:
        return []
    shown = "; ".join(f"{d.slot.title()} saved {d.slot.value}, live {d.live}"
                      for d in diffs[:3])
    more = f"; and {len(diffs) - 3} more" if len(diffs) > 3 else ""
    n = len(diffs)
    return [Difference(SETTINGS, hit.address,
                       f"{where}: {n} setting{'s differ' if n != 1 else ' differs'} from "
                       f"{want.backup}: {shown}{more}", want, hit, tuple(diffs))]

