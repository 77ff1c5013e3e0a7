"""A module with a TMCL bootloader, written from issue 24's table of the protocol (as
PyTrinamic's updater uses it), independent of tmclsh's simulator and protocol code: what
``tmclsh firmware`` sends must make sense to something that only knows that table. It must
never import tmclsh.

| command | type, motor, value | reply |
| 242 enter bootloader | 0x81, 0x92, 0xA3B4C5D6 (anything else is ignored) | none: the module resets |
| 200 erase all | 0, 0, 0 | yes |
| 201 write buffer | type = low byte, motor = high byte of the word's index in the page
|                  | (byte offset / 4); value = the 32-bit word the image's four bytes make
|                  | read little-endian | yes |
| 202 write page | value = absolute start address of the page | yes |
| 203 get checksum | value = address of the last byte; reply: 32-bit sum from the start | yes |
| 205 start application | 0, 0, 0 | none |
| 206 get info | type 0 page size, 1 start address, 2 size | yes |
| 208 write length | type 0 length, type 1 checksum | yes |

In its bootloader the module answers at address 1 and 115200 baud only, its 136 string with
``B`` where the application has ``V``. Its application (``version``) answers at ``address``
and ``app_speed``, knows 136 and 242 and answers anything else with status 100.

Memory here: pages of 256 bytes from 0x4000, 0x20000 bytes (not the simulator's choice). A
page write stores the buffer as it is (no flash AND): this module is simpler than flash, the
updater must not depend on either. ``hooks[command]`` (a callable taking the model) runs when
a request with that command arrives, before it is answered: tests interrupt the updater at a
chosen phase there.
"""

from __future__ import annotations

import re
import struct
import termios

from responder import OK, Responder, fields, reply, version_reply

PAGE, START, SIZE = 256, 0x4000, 0x20000
BOOT_KEY = (0x81, 0x92, 0xA3B4C5D6)
APP_VERSION = re.compile(rb"(\d{4})V(\d{3})")


class BootLogic:
    """The module's state and answers, whatever the line (a pty, TCP, CAN)."""

    def _setup(self, version: str, address: int, in_bootloader: bool, boot_version: str) -> None:
        self.app_version, self.app_address = version, address
        self.type_number = version[:4]
        self.boot_version = boot_version
        self.memory = bytearray(b"\xff") * SIZE
        self.buffer = bytearray(b"\xff") * PAGE
        self.length = self.checksum = 0
        self.in_bootloader = in_bootloader
        self.erases = 0
        self.heard: list[tuple[int, int, int, int]] = []  # (command, type, motor, value)
        self.hooks: dict[int, object] = {}
        self.silent = False  # a test makes it stop answering (a cable pulled)
        if not in_bootloader:  # a valid application, as the factory left it
            image = bytes(range(256)) * 8
            image = image[:100] + version.encode() + image[108:]
            self.memory[:len(image)] = image
            self.length, self.checksum = len(image), sum(image) & 0xFFFFFFFF

    @property
    def version(self) -> str:
        if self.in_bootloader:
            return f"{self.type_number}B{self.boot_version}"
        return self.app_version

    @property
    def addresses(self) -> frozenset:
        return frozenset({1 if self.in_bootloader else self.app_address})

    def commands(self) -> list[int]:
        return [h[0] for h in self.heard]

    def hears(self, addr: int, cmd: int, typ: int, motor: int, value: int) -> bool:
        """Whether a frame to ``addr`` is answered: one this module takes is recorded and
        its command's hook run (which may silence it)."""
        if addr not in self.addresses or self.silent:
            return False
        self.heard.append((cmd, typ, motor, value))
        hook = self.hooks.get(cmd)
        if hook is not None:
            hook(self)
        return not self.silent

    def respond(self, addr: int, cmd: int, typ: int, motor: int, value: int):
        """The version string, (status, value), or None for silence."""
        if not self.hears(addr, cmd, typ, motor, value):
            return None
        if cmd == 136 and typ == 0:
            return self.version
        if self.in_bootloader:
            return self.boot(cmd, typ, motor, value & 0xFFFFFFFF)
        if cmd == 242:
            if (typ, motor, value & 0xFFFFFFFF) == BOOT_KEY:
                self.reset_to(True)
            return None
        return OK, value

    def reset_to(self, bootloader: bool) -> None:
        self.in_bootloader = bootloader

    def boot(self, cmd: int, typ: int, motor: int, value: int) -> tuple[int, int] | None:
        if cmd == 200:
            self.memory[:] = b"\xff" * SIZE
            self.length = self.checksum = 0
            self.erases += 1
        elif cmd == 201:
            offset = (typ | motor << 8) * 4
            if offset + 4 > PAGE:
                return 4, value
            self.buffer[offset:offset + 4] = struct.pack("<I", value)
        elif cmd == 202:
            if value % PAGE or not START <= value < START + SIZE:
                return 4, value
            self.memory[value - START:value - START + PAGE] = self.buffer
        elif cmd == 203:
            if not START <= value < START + SIZE:
                return 4, value
            return OK, sum(self.memory[:value - START + 1]) & 0xFFFFFFFF
        elif cmd == 205:
            self.start()
            return None
        elif cmd == 206:
            if typ not in (0, 1, 2):
                return 3, value
            return OK, (PAGE, START, SIZE)[typ]
        elif cmd == 208:
            if typ == 0:
                self.length = value
            elif typ == 1:
                self.checksum = value
            else:
                return 3, value
        else:
            return 2, value  # no such command in the bootloader (136 type 1, 242, GAP, ...)
        return OK, value

    def start(self) -> None:
        """205: the application runs only when length and checksum agree with the memory."""
        data = bytes(self.memory[:self.length])
        if not 0 < self.length <= SIZE or sum(data) & 0xFFFFFFFF != self.checksum:
            return
        found = APP_VERSION.search(data)
        if found is None or found.group(1).decode() != self.type_number:
            return
        self.app_version = found.group(0).decode()
        self.reset_to(False)


class BootModule(BootLogic, Responder):
    """The module on a pty (``path``) or, with ``tcp``, a TCP port (``url``): the
    application answers only at ``app_speed``, the bootloader only at ``boot_speed``."""

    def __init__(self, version: str = "1311V111", *, address: int = 1, in_bootloader=False,
                 app_speed: int = termios.B9600, boot_speed: int = termios.B115200,
                 boot_version: str = "107", tcp: bool = False, line=None):
        self._setup(version, address, in_bootloader, boot_version)
        self.app_speed, self.boot_speed = app_speed, boot_speed
        # (on a SharedLine the line's speed is not looked at: both answer at any rate)
        Responder.__init__(self, speed=None if tcp or line is not None else (
            boot_speed if in_bootloader else app_speed), tcp=tcp, line=line)

    def reset_to(self, bootloader: bool) -> None:
        self.in_bootloader = bootloader
        if self.speed is not None:
            self.speed = self.boot_speed if bootloader else self.app_speed

    def answer(self, raw: bytes) -> bytes | None:
        addr, cmd, typ, motor, value = fields(raw)
        out = self.respond(addr, cmd, typ, motor, value)
        if out is None:
            return None
        if isinstance(out, str):
            return version_reply(out)
        return reply(cmd, out[1], out[0], module=addr)


class CanBootModule(BootLogic):
    """The module on a python-can bus: requests on id 1; the application replies on id 2,
    the bootloader on ``boot_reply_id`` (some CAN bootloaders answer on 0x7FF)."""

    def __init__(self, bus, version: str = "1311V111", *, boot_reply_id: int = 0x7FF,
                 in_bootloader: bool = False):
        import threading

        import can

        self._setup(version, 1, in_bootloader, "107")
        self.can, self.bus, self.boot_reply_id = can, bus, boot_reply_id
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(0.05)
            if msg is None or msg.arbitration_id != 1 or len(msg.data) != 7:
                continue
            d = bytes(msg.data)
            (val,) = struct.unpack(">i", d[3:7])
            reply_id = self.boot_reply_id if self.in_bootloader else 2
            out = self.respond(1, d[0], d[1], d[2], val)
            if out is None:
                continue
            if isinstance(out, str):
                data = out.encode("ascii")
            else:
                data = bytes([1, out[0], d[0]]) + struct.pack(">I", out[1] & 0xFFFFFFFF)
            self.bus.send(self.can.Message(arbitration_id=reply_id, data=data,
                                           is_extended_id=False))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1)
        self.bus.shutdown()


def hex_image(version: str, size: int, start: int = START, seed: int = 7) -> str:
    """Intel HEX text written here by hand (record type 00 and the end record, each with its
    checksum): ``size`` bytes from ``start`` carrying ``version`` at offset 0x40."""
    data = bytearray((i * seed + 11) & 0xFF for i in range(size))
    data[0x40:0x40 + len(version)] = version.encode()
    lines = []
    upper = None
    for at in range(0, size, 16):
        addr = start + at
        if addr >> 16 != upper:
            upper = addr >> 16
            body = bytes([2, 0, 0, 4, upper >> 8, upper & 0xFF])
            lines.append(":" + (body + bytes([-sum(body) & 0xFF])).hex().upper())
        chunk = bytes(data[at:at + 16])
        body = bytes([len(chunk), addr >> 8 & 0xFF, addr & 0xFF, 0]) + chunk
        lines.append(":" + (body + bytes([-sum(body) & 0xFF])).hex().upper())
    lines.append(":00000001FF")
    return "\n".join(lines) + "\n"
