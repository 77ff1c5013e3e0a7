"""The simulated module's bootloader: an application memory of flash pages, a page buffer,
and the length and checksum that make the application valid.

Command 242 (with its key) switches the simulated module to it; 200-208 and 205 act on the
memory as ``tmcl/bootloader.toml`` says the protocol goes (the same word layout and
checksum the updater uses: ``tmclsh.tmcl.bootloader``). 205 starts the application only when
the written length and checksum agree with the memory and the memory holds an application
version string; the module then runs as the type and version that string names.

The memory is the module data's where its file gives one (``firmware_start`` and
``firmware_size``), else this simulator's choice (the protocol lets each bootloader say its
own through 206): pages of ``PAGE_SIZE`` bytes from ``START``, ``SIZE`` bytes in all; erased flash reads
0xFF, and writing a page can only clear bits (a page written twice without an erase holds
the AND of both), as flash does. The page buffer reads 0xFF again once a page is written,
so a 202 repeated after a lost reply leaves the page as it was.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..tmcl import bootloader as bl
from ..tmcl import instructions as isa
from ..tmcl.frames import Instruction, Status
from ..tmcl.version import VersionString

ERASED = 0xFF


@dataclass
class BootAnswer:
    """What the bootloader answers to one request."""

    status: int = Status.OK
    value: int = 0
    silent: bool = False  # 205: no reply, the application starts
    start: bool = False


class Bootloader:
    """The bootloader of one simulated module (see the module docstring)."""

    PAGE_SIZE = 0x800  # 2 KiB
    START = 0x8000  # the application starts after a 32 KiB bootloader
    SIZE = 0x38000  # 224 KiB: a 256 KiB flash less the bootloader
    VERSION = 100  # its own version: 1311B100

    def __init__(self, start: int | None = None, size: int | None = None) -> None:
        if start is not None and size is not None:  # (the module data's, as 206 answers)
            self.START, self.SIZE = start, size
        self.memory = bytearray([ERASED]) * self.SIZE
        self.buffer = bytearray([ERASED]) * self.PAGE_SIZE
        # written by 208, kept in flash beside the application: what makes it valid
        self.length = 0
        self.checksum = 0
        self.active = False  # the module runs its bootloader (not its application)

    # -- the flash, as a factory programmed it --------------------------------------------
    def install(self, version_string: str, size: int = 16 * 1024) -> None:
        """A valid application of ``size`` bytes that carries ``version_string`` (what the
        simulated module runs before anyone updates it)."""
        size = min(size, self.SIZE)
        data = bytearray((i * 7 + 3) & 0xFF for i in range(size))
        text = version_string.encode("ascii")
        data[0x100:0x100 + len(text)] = text
        self.memory[:] = bytes([ERASED]) * self.SIZE
        self.memory[:size] = data
        self.length, self.checksum = size, bl.checksum(data)

    def application(self) -> VersionString | None:
        """The application 205 would start: its version string when length and checksum
        agree with the memory; None when the memory holds no valid application."""
        if not 0 < self.length <= self.SIZE:
            return None
        data = memoryview(self.memory)[:self.length]
        if bl.checksum(data) != self.checksum:
            return None
        found = bl.versions_in(data)
        return found[0] if found else None

    # -- the protocol -------------------------------------------------------------------
    def execute(self, ins: Instruction) -> BootAnswer:
        """One request to the bootloader (136 is the simulator's: it knows the module)."""
        ctl = isa.control(ins.opcode)
        role = ctl.boot if ctl is not None else None
        value = ins.value & 0xFFFFFFFF
        handler = getattr(self, f"_{role}", None) if role not in (None, "enter") else None
        if handler is None:
            return BootAnswer(Status.INVALID_COMMAND, ins.signed_value)
        return handler(ins, value)

    def _erase(self, ins: Instruction, value: int) -> BootAnswer:
        self.memory[:] = bytes([ERASED]) * self.SIZE
        self.buffer[:] = bytes([ERASED]) * self.PAGE_SIZE
        self.length = self.checksum = 0
        return BootAnswer(value=ins.signed_value)

    def _write_word(self, ins: Instruction, value: int) -> BootAnswer:
        offset = bl.word_offset({"type": ins.type, "motor": ins.motor})
        word = bl.value_bytes(value)
        if offset + len(word) > self.PAGE_SIZE:
            return BootAnswer(Status.INVALID_VALUE, ins.signed_value)
        self.buffer[offset:offset + len(word)] = word
        return BootAnswer(value=ins.signed_value)

    def _write_page(self, ins: Instruction, value: int) -> BootAnswer:
        at = value - self.START
        if at % self.PAGE_SIZE or not 0 <= at < self.SIZE:
            return BootAnswer(Status.INVALID_VALUE, ins.signed_value)
        page = int.from_bytes(self.memory[at:at + self.PAGE_SIZE], "little")
        self.memory[at:at + self.PAGE_SIZE] = (
            page & int.from_bytes(self.buffer, "little")).to_bytes(self.PAGE_SIZE, "little")
        self.buffer[:] = bytes([ERASED]) * self.PAGE_SIZE
        return BootAnswer(value=ins.signed_value)

    def _checksum(self, ins: Instruction, value: int) -> BootAnswer:
        at = value - self.START
        if not 0 <= at < self.SIZE:
            return BootAnswer(Status.INVALID_VALUE, ins.signed_value)
        return BootAnswer(value=bl.checksum(memoryview(self.memory)[:at + 1]))

    def _read(self, ins: Instruction, value: int) -> BootAnswer:
        at = value - self.START
        if not 0 <= at < self.SIZE:
            return BootAnswer(Status.INVALID_VALUE, ins.signed_value)
        return BootAnswer(value=bl.word_at(self.memory, at))

    def _info(self, ins: Instruction, value: int) -> BootAnswer:
        info = bl.facts().info
        answers = {info["page_size"]: self.PAGE_SIZE, info["start"]: self.START,
                   info["size"]: self.SIZE}
        if ins.type not in answers:
            return BootAnswer(Status.WRONG_TYPE, ins.signed_value)
        return BootAnswer(value=answers[ins.type])

    def _length(self, ins: Instruction, value: int) -> BootAnswer:
        what = bl.facts().length
        if ins.type == what["length"]:
            if value > self.SIZE:
                return BootAnswer(Status.INVALID_VALUE, ins.signed_value)
            self.length = value
        elif ins.type == what["checksum"]:
            self.checksum = value
        else:
            return BootAnswer(Status.WRONG_TYPE, ins.signed_value)
        return BootAnswer(value=ins.signed_value)

    def _start(self, ins: Instruction, value: int) -> BootAnswer:
        return BootAnswer(silent=True, start=True)
