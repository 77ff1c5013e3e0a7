"""What command 136 says a module is, read one way everywhere.

136 type 0 answers eight ASCII characters, ``1311V111``: the module's type number, ``V`` for
its application firmware (``B`` in its bootloader), then the firmware version. They carry no
checksum, so a bit flipped on the line can make ``1311V111`` read ``1711V111``.

136 type 1 answers a normal frame (with a checksum) whose value holds the type number and the
version as 16-bit numbers, in a byte order the manuals disagree on: the TMCM-1311 manual puts
the type first (type high, type low, version low, version high), the TMCM-1640 manual the
version first (version low, version high, type low, type high). The order is a fact about a
module, kept in its data file (``version_layout``); nothing here knows module names.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

TYPE_FIRST = "type_first"
VERSION_FIRST = "version_first"
LAYOUTS = (TYPE_FIRST, VERSION_FIRST)

# (leading zeros) the type number, V (application) or B (bootloader), the version
_STRING = re.compile(r"\s*0*(\d{1,9})([VB])(\S*)\s*")


@dataclass(frozen=True)
class VersionString:
    """A 136 type 0 answer taken apart: ``1311V111`` -> type 1311, version ``111``."""

    text: str
    type_number: int
    version: str
    bootloader: bool = False  # B in place of V: the module runs its bootloader

    @property
    def number(self) -> int | None:
        """The version as the type 1 answer carries it (``111``; ``1.23`` -> 123)."""
        digits = self.version.replace(".", "")
        return int(digits) if digits.isdigit() else None


def parse_string(text: str | None) -> VersionString | None:
    """The parts of a version string; None for text that names no type number."""
    m = _STRING.fullmatch(text or "")
    if m is None:
        return None
    return VersionString(text.strip(), int(m.group(1)), m.group(3), m.group(2) == "B")


def decode_type1(value: int, layout: str = TYPE_FIRST) -> tuple[int, int]:
    """``(type number, version)`` from a 136 type 1 value laid out as ``layout`` says."""
    b = (value & 0xFFFFFFFF).to_bytes(4, "big")
    if layout == VERSION_FIRST:
        return b[2] | b[3] << 8, b[0] | b[1] << 8
    return b[0] << 8 | b[1], b[2] | b[3] << 8


def encode_type1(type_number: int, version: int, layout: str = TYPE_FIRST) -> int:
    """The 136 type 1 value a module of that layout answers (the simulator's)."""
    t, v = type_number & 0xFFFF, version & 0xFFFF
    if layout == VERSION_FIRST:
        raw = (v & 0xFF, v >> 8, t & 0xFF, t >> 8)
    else:
        raw = (t >> 8, t & 0xFF, v & 0xFF, v >> 8)
    return int.from_bytes(bytes(raw), "big")


def type1_bytes(layout: str = TYPE_FIRST) -> tuple[slice, slice]:
    """Which two of the four value bytes hold the type, which the version (for a reader
    who wants them shown as they came)."""
    return (slice(2, 4), slice(0, 2)) if layout == VERSION_FIRST else (slice(0, 2),
                                                                          slice(2, 4))
