"""The TMCL bootloader, read from ``bootloader.toml``, and the firmware images it takes.

A firmware update is a short protocol (the commands 242, 200-208 and 205 are entries of the
instruction set; their ``boot`` field names their role) over a memory of pages: the image's
bytes travel one 32-bit word at a time into a page buffer (201), each full page is written
(202), the memory's checksum is compared with the image's (203), length and checksum are
written (208), and the application is started (205). How words are laid out in a request,
what the checksum is, where a module in its bootloader answers and what 242's key is are facts
of ``bootloader.toml``; this module reads them once and does the arithmetic the updater
(``tmclsh.ops.firmware``) and the simulated bootloader (``tmclsh.sim.boot``) share, so the two
cannot disagree on them.

``Image`` is an Intel HEX file read with the ``intelhex`` package: its first address, its
bytes with the gaps filled, its checksum, and the application version strings it carries
(``1311V112``): what tells an image for this module from one for another.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cache, cached_property

from ..base.datafiles import load_toml
from ..base.errors import ValidationError
from .version import VersionString, parse_string

# An image spanning more than this is no application image (a HEX file with a record far
# away, such as option bytes or a bootloader of its own): refused before it is laid out.
MAX_SPAN = 16 * 1024 * 1024


class ImageError(ValidationError):
    """A firmware image that cannot be used: unreadable, no HEX, empty, no version string."""


@dataclass(frozen=True)
class Facts:
    """What ``bootloader.toml`` says, typed."""

    key: tuple[int, int, int]  # 242's type, motor, value
    address: int
    host_address: int
    baud: int
    can_id: int
    can_reply_id: int
    can_bitrate: int
    can_other_reply_ids: tuple[int, ...]
    usb_reconnect_s: float
    restart_s: float
    switch_s: float
    erase_s: float
    application_letter: str
    bootloader_letter: str
    version_digits: dict[int, str]  # digits of the type number -> "ddd" | "d.dd"
    info: dict[str, int]  # 206 types: page_size, start, size
    length: dict[str, int]  # 208 types: length, checksum
    word_bytes: int
    word_order: str  # "little" | "big"
    index_fields: tuple[str, ...]  # which request fields carry the word index, low byte first
    fill: int
    checksum_bits: int
    version_pattern: re.Pattern[bytes] = field(repr=False)

    @property
    def checksum_mask(self) -> int:
        return (1 << self.checksum_bits) - 1


@cache
def facts() -> Facts:
    d = load_toml(__package__, "bootloader.toml")
    link, ver = d["link"], d["version"]
    return Facts(
        key=(d["enter"]["type"], d["enter"]["motor"], d["enter"]["value"]),
        address=link["address"], host_address=link["host_address"], baud=link["baud"],
        can_id=link["can_id"], can_reply_id=link["can_reply_id"],
        can_bitrate=link["can_bitrate"],
        can_other_reply_ids=tuple(link.get("can_other_reply_ids", ())),
        usb_reconnect_s=float(link["usb_reconnect_s"]), restart_s=float(link["restart_s"]),
        switch_s=float(link["switch_s"]),
        erase_s=float(link["erase_s"]),
        application_letter=ver["application"], bootloader_letter=ver["bootloader"],
        version_digits={int(k): v for k, v in ver["digits"].items()},
        info=dict(d["info"]), length=dict(d["length"]),
        word_bytes=d["word"]["bytes"], word_order=d["word"]["order"],
        index_fields=tuple(d["word"]["index"]),
        fill=d["image"]["fill"], checksum_bits=d["image"]["checksum_bits"],
        version_pattern=re.compile(d["image"]["version"].encode("ascii")))


# -- the arithmetic both sides share ------------------------------------------------------

def checksum(data: bytes | bytearray | memoryview) -> int:
    """The bootloader's checksum: the sum of the bytes, wrapping (32 bits)."""
    return sum(data) & facts().checksum_mask


def word_at(data: bytes | bytearray | memoryview, offset: int) -> int:
    """The 32-bit word the bytes at ``offset`` make (little-endian; past the end: fill)."""
    f = facts()
    chunk = bytes(data[offset:offset + f.word_bytes])
    if len(chunk) < f.word_bytes:
        chunk += bytes((f.fill,)) * (f.word_bytes - len(chunk))
    return int.from_bytes(chunk, f.word_order)


def word_fields(offset_in_page: int) -> dict[str, int]:
    """The request fields (type, motor) that carry the index of the word at this byte offset
    of its page: its offset / 4, low byte first."""
    f = facts()
    index = offset_in_page // f.word_bytes
    fields = {}
    for name in f.index_fields:
        fields[name] = index & 0xFF
        index >>= 8
    if index:
        raise ValueError(f"word offset {offset_in_page} is beyond what "
                         f"{', '.join(f.index_fields)} can carry")
    return fields


def word_offset(fields: dict[str, int]) -> int:
    """The byte offset within its page of the word a write-buffer request names."""
    f = facts()
    index = 0
    for shift, name in enumerate(f.index_fields):
        index |= fields[name] << (8 * shift)
    return index * f.word_bytes


def value_bytes(value: int) -> bytes:
    """The image bytes a write-buffer request's value stands for."""
    f = facts()
    return (value & 0xFFFFFFFF).to_bytes(f.word_bytes, f.word_order)


def bootloader_string(type_number: int, version: int) -> str:
    """The 136 string a module of this type answers in its bootloader: ``1311B100``,
    ``351B1.00`` (the application's, with the bootloader's letter)."""
    f = facts()
    digits = f.version_digits.get(len(str(type_number)), "ddd")
    text = f"{version % 1000:03d}"
    if "." in digits:
        text = f"{text[0]}.{text[1:]}"
    return f"{type_number}{f.bootloader_letter}{text}"


def versions_in(data: bytes | bytearray | memoryview) -> tuple[VersionString, ...]:
    """The application version strings in an image's bytes, each once, in order."""
    seen: dict[str, VersionString] = {}
    for m in facts().version_pattern.finditer(bytes(data)):
        text = m.group(0).decode("ascii")
        parsed = parse_string(text)
        if parsed is not None and not parsed.bootloader:
            seen.setdefault(text, parsed)
    return tuple(seen.values())


# -- images -------------------------------------------------------------------------------

@dataclass(frozen=True)
class Page:
    """One page of an image: its address and the write-buffer requests' (type, motor, value)
    for each of its words that the image covers."""

    address: int
    words: tuple[tuple[int, int, int], ...]
    size: int  # bytes of the image in this page


@dataclass(frozen=True)
class Image:
    """A firmware image: its first address and its bytes (gaps filled)."""

    name: str
    start: int
    data: bytes
    # (first address, address after, line in the file) of each data record, when read
    # from a file: what a refusal names
    records: tuple[tuple[int, int, int], ...] = field(default=(), repr=False, compare=False)

    @property
    def length(self) -> int:
        return len(self.data)

    @property
    def end(self) -> int:
        """The address after its last byte."""
        return self.start + len(self.data)

    @cached_property
    def checksum(self) -> int:
        return checksum(self.data)

    @cached_property
    def versions(self) -> tuple[VersionString, ...]:
        return versions_in(self.data)

    def line_at(self, address: int) -> int | None:
        """The line of the file whose record holds this address."""
        return _line_at(self.records, address)

    def where(self, address: int) -> str:
        """``name:line`` of the record holding ``address`` (the name alone if not known)."""
        line = self.line_at(address)
        return f"{self.name}:{line}" if line else self.name

    def version_for(self, type_number: int) -> VersionString | None:
        """Its version string for a module of this type number, if it carries one."""
        return next((v for v in self.versions if v.type_number == type_number), None)

    def other_types(self, type_number: int) -> list[int]:
        """Type numbers its version strings name besides ``type_number``."""
        return sorted({v.type_number for v in self.versions} - {type_number})

    def pages(self, page_size: int) -> Iterator[Page]:
        """The image page by page, as the write-buffer requests carry it (an image starts on
        a word: it starts where the bootloader's memory does)."""
        step = facts().word_bytes
        if self.start % step:
            raise ValueError(f"an image must start on a {step}-byte word, not 0x{self.start:X}")
        first = self.start - self.start % page_size
        for page in range(first, self.end, page_size):
            lo, hi = max(page, self.start), min(page + page_size, self.end)
            words = []
            for addr in range(lo, hi, step):
                f = word_fields(addr - page)
                words.append((f.get("type", 0), f.get("motor", 0),
                              word_at(self.data, addr - self.start)))
            yield Page(page, tuple(words), hi - lo)

    def page_count(self, page_size: int) -> int:
        first = self.start - self.start % page_size
        return -(-(self.end - first) // page_size)


def image_from_hex(text: str, name: str = "<image>") -> Image:
    """An image from Intel HEX text, read by ``intelhex`` and checked whole: its end-of-file
    record present (a file cut at a record boundary reads as valid records otherwise), no
    record given twice (overlaps), no hole inside it (a gap: the file does not say what
    belongs there, and the bootloader's checksum covers it). Every refusal names the file's
    line."""
    from intelhex import HexReaderError, IntelHex

    from ..base.files import bounded_read

    ih = IntelHex()
    lines = _Lines(text)
    try:
        with bounded_read(name, "HEX file"):
            ih.loadhex(lines)
    except HexReaderError as exc:
        line = getattr(exc, "line", None)
        where = f"{name}:{line}" if line else name
        raise ImageError(f"{where}: not a valid Intel HEX file: {_hex_fault(exc)}") from None
    except (ValueError, UnicodeError) as exc:
        raise ImageError(f"{name}: not a valid Intel HEX file: {exc}") from None
    if lines.read_to_end:
        raise ImageError(f"{name}:{lines.last}: the file ends without its end-of-file record "
                         "(:00000001FF): it is cut short, the image may be incomplete")
    lo, hi = ih.minaddr(), ih.maxaddr()
    if lo is None or hi is None:
        raise ImageError(f"{name}: the HEX file holds no data")
    records = _records(lines.lines)
    if hi + 1 - lo > MAX_SPAN:
        far = _line_at(records, hi)
        raise ImageError(f"{name}:{far}: the image spans {hi + 1 - lo} bytes, from 0x{lo:08X} "
                         f"to 0x{hi:08X}: more than any module's application memory (a record "
                         "far from the others?)")
    segments = ih.segments()
    if len(segments) > 1:
        (_, stop), (after, _) = segments[0], segments[1]
        raise ImageError(f"{name}:{_line_at(records, after)}: a gap before this record: the "
                         f"file gives nothing for 0x{stop:08X}..0x{after - 1:08X} "
                         f"({after - stop} bytes) inside the image; a firmware image is one "
                         "block (the bootloader would be given bytes the file does not hold)")
    ih.padding = facts().fill
    return Image(name, lo, ih.tobinstr(start=lo, end=hi), records)


class _Lines:
    """The text's lines as ``intelhex`` reads them, noting whether it read them all: it
    stops at the end-of-file record, so reading past the last line means there was none."""

    def __init__(self, text: str):
        self.lines = text.splitlines(keepends=True)
        self.read_to_end = False
        # the last line with text: where the end-of-file record was missed
        self.last = next((n for n in range(len(self.lines), 0, -1)
                          if self.lines[n - 1].strip()), 1)

    def __iter__(self) -> Iterator[str]:
        yield from self.lines
        self.read_to_end = True

    def read(self) -> str:
        """(``loadhex`` takes an object with ``read`` for a file; it then iterates it.)"""
        return "".join(self.lines)


def _records(lines: list[str]) -> tuple[tuple[int, int, int], ...]:
    """(first address, address after, line) of each data record, for naming a line: the
    file is valid Intel HEX by now (``intelhex`` read it), so only addresses are followed."""
    out = []
    base = 0
    for number, raw in enumerate(lines, 1):
        s = raw.strip()
        if not s:
            continue
        rec = bytes.fromhex(s[1:])
        count, address, kind, data = rec[0], rec[1] << 8 | rec[2], rec[3], rec[4:4 + rec[0]]
        if kind == 0:
            out.append((base + address, base + address + count, number))
        elif kind == 2:
            base = int.from_bytes(data, "big") << 4
        elif kind == 4:
            base = int.from_bytes(data, "big") << 16
        elif kind == 1:
            break
    return tuple(out)


def _line_at(records: tuple[tuple[int, int, int], ...], address: int) -> int | None:
    return next((line for lo, hi, line in records if lo <= address < hi), None)


_HEX_FAULTS = {
    "RecordChecksumError": "the record's checksum is wrong",
    "RecordLengthError": "the record's length does not match its data",
    "RecordTypeError": "a record type Intel HEX does not have",
    "EOFRecordError": "a malformed end-of-file record",
    "ExtendedSegmentAddressRecordError": "a malformed extended segment address record",
    "ExtendedLinearAddressRecordError": "a malformed extended linear address record",
    "StartSegmentAddressRecordError": "a malformed start segment address record",
    "StartLinearAddressRecordError": "a malformed start linear address record",
    "DuplicateStartAddressRecordError": "a second start address record",
    "HexRecordError": "not an Intel HEX record",
}


def _hex_fault(exc: Exception) -> str:
    kind = type(exc).__name__
    if kind == "AddressOverlapError":
        return (f"the record gives 0x{exc.address:08X} again (it overlaps an earlier "
                "record)")
    return _HEX_FAULTS.get(kind) or _hex_reason(exc)


def _hex_reason(exc: Exception) -> str:
    text = str(exc).strip().rstrip(".")
    return text[:1].lower() + text[1:] if text else type(exc).__name__


def read_image(path: str) -> Image:
    """The image in the Intel HEX file ``path`` (read bounded; one clear error if not)."""
    from ..base.files import read_bytes

    data = read_bytes(path, what="firmware image")
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        raise ImageError(f"{path}: not an Intel HEX file (it holds bytes that are no text; "
                         "tmclsh firmware takes the firmware's .hex file)") from None
    return image_from_hex(text, str(path))
