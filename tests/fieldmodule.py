"""A module as a technician meets one in the field, written from the manuals and issue 24's
bootloader table, independent of tmclsh's simulator and protocol code (it must never import
tmclsh): the bootloader of ``bootmodel.BootModule``, and an application that keeps every
parameter it is given (a value outside the manual's range too: the module's own data is not
this model's business) and a stored program.

Application commands (TMCM-1311 manual, §4): SAP 5 / GAP 6 / STAP 7 / RSAP 8 on
``values[("axis", type, motor)]``, SGP 9 / GGP 10 / STGP 11 / RSGP 12 on
``values[("global", type, bank)]`` (0 if never set); 132 starts download mode at the value's
address, where every following command below 128 is stored and answered with status 101,
133 ends it; 134 reads one stored instruction back (the reply's module, status and command
bytes hold its opcode, type and motor; the value its value; 0 where nothing was stored);
135 answers 0 (stopped); 136 type 1 the type number and version. ``stored`` is the program
memory; ``heard`` (from ``BootLogic``) every request as (command, type, motor, value).
"""

from __future__ import annotations

import struct

from bootmodel import BootModule
from responder import LOADED, OK, reply

AXIS_SET, AXIS_GET, GLOBAL_SET, GLOBAL_GET = 5, 6, 9, 10
KEEP = (7, 8, 11, 12, 128, 129, 130, 131)  # store/restore and program control: answered OK


class FieldModule(BootModule):
    def __init__(self, version: str = "1311V111", **kw):
        self.values: dict[tuple[str, int, int], int] = {}
        self.stored: dict[int, tuple[int, int, int, int]] = {}
        self.downloading = False
        self.download_at = 0
        super().__init__(version, **kw)

    def program(self) -> list[tuple[int, int, int, int]]:
        """The stored program up to the first cell never written (or opcode 0)."""
        out = []
        for at in range(len(self.stored) + 1):
            ins = self.stored.get(at, (0, 0, 0, 0))
            if ins[0] == 0:
                break
            out.append(ins)
        return out

    def answer(self, raw: bytes) -> bytes | None:
        addr, cmd = raw[0], raw[1]
        if (not self.in_bootloader and not self.silent and addr in self.addresses
                and cmd == 134 and not self.downloading):
            (at,) = struct.unpack(">i", raw[4:8])
            self.heard.append((cmd, raw[2], raw[3], at))
            op, typ, motor, value = self.stored.get(at, (0, 0, 0, 0))
            return reply(motor, value, typ, module=op)
        return super().answer(raw)

    def respond(self, addr: int, cmd: int, typ: int, motor: int, value: int):
        if self.in_bootloader or (cmd == 136 and typ == 0) or cmd == 242:
            return super().respond(addr, cmd, typ, motor, value)
        if not self.hears(addr, cmd, typ, motor, value):
            return None
        if self.downloading and cmd < 128:
            self.stored[self.download_at] = (cmd, typ, motor, value)
            self.download_at += 1
            return LOADED, value
        if cmd == 132:
            self.downloading, self.download_at = True, value
        elif cmd == 133:
            self.downloading = False
        elif cmd in (AXIS_SET, GLOBAL_SET):
            self.values[("axis" if cmd == AXIS_SET else "global", typ, motor)] = value
        elif cmd in (AXIS_GET, GLOBAL_GET):
            return OK, self.values.get(("axis" if cmd == AXIS_GET else "global", typ, motor), 0)
        elif cmd == 135:
            return OK, 0
        elif cmd == 136:
            return OK, int(self.version[:4]) << 16 | int(self.version[5:]) // 100 << 8 | \
                int(self.version[5:]) % 100
        elif cmd not in KEEP:
            return 2, value  # invalid command
        return OK, value
