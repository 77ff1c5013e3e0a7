"""A stand-in TMCL module written from the manual's byte tables (§4 binary command and reply
format), independent of tmclsh's protocol code and simulator: what tmclsh sends must make
sense to something that only knows the manual. It must never import tmclsh.

Serial (a pty, or TCP for pyserial's socket:// URL): request = address, command, type,
motor/bank, value (4 bytes, MSB first), checksum (8-bit sum of the other 8); reply = reply
address, module address, status, command, value, checksum. 136 type 0 answers the reply
address and 8 ASCII characters. ASCII mode (§4.4): ``<address char><command>`` CR, answered
``<host char><module char> <status> <value>`` CR. CAN: "leave out the first byte and the
checksum": the request is 7 data bytes on the module's CAN id, the reply 7 data bytes on the
reply id (the version string: its 8 characters).

``Responder`` is the line (framing, pty or TCP, what it heard); a test's module is a small
subclass that says what it answers (``answer`` for a binary frame, ``line`` for an ASCII
line). ``Module`` is a module with a value store for SAP/GAP/SGP/GGP. ``SharedLine`` puts
several modules on one pty (an RS485 bus): each hears every byte the host sends.

How a module finds frames in what it hears, the manuals do not say; they describe no receive
timeout. By default a responder searches: a frame with a wrong checksum is no frame, and it
looks one byte further. With ``nines=True`` it does what a module without a receive timeout
and without a search does: every nine bytes from the first it heard are a frame, whatever
they are; nine with a wrong checksum are answered status 1 (wrong checksum, §4.2.1) when
they start with the module's address, else dropped (``bad`` holds them). Such a module
stays out of step after any byte count that is not a multiple of nine.
"""

from __future__ import annotations

import os
import select
import socket
import struct
import termios
import threading
import time
import tty

OK, LOADED, INVALID_VALUE, INVALID_COMMAND, WRONG_CHECKSUM = 100, 101, 4, 2, 1


def reply(command: int, value: int, status: int = OK, module: int = 1, host: int = 2) -> bytes:
    """A binary reply frame with its checksum (value as 32 bits, MSB first)."""
    body = bytes([host, module, status, command]) + (value & 0xFFFFFFFF).to_bytes(4, "big")
    return body + bytes([sum(body) & 0xFF])


def version_reply(text: str, host: int = 2) -> bytes:
    """136 type 0: the reply address and the 8 characters, no checksum."""
    return bytes([host]) + text.encode("ascii")


def valid(raw: bytes) -> bool:
    return len(raw) == 9 and sum(raw[:8]) & 0xFF == raw[8]


def fields(raw: bytes) -> tuple[int, int, int, int, int]:
    """(address, command, type, motor, value) of a request frame, the value signed."""
    return struct.unpack(">BBBBi", raw[:8])


class Responder:
    """A module on a pty (``path``) or, with ``tcp``, a TCP port (``url``, one client at a
    time). Binary frames with a wrong checksum are no frame: it looks one byte further (a
    module hears noise, it does not answer it). ``log`` holds every frame (bytes) and ASCII
    line (bytes, without CR) it got. ``speed``: answer only while the pty is set to this
    termios speed (at another baud rate a module hears noise). ``delay``: seconds before
    each answer. ``nines``: frame in nines, without search (see the module docstring).
    ``line``: a ``SharedLine`` this module sits on (it then opens nothing of its own).

    This one is a plain binary TMCM-1311 at address 1: the version string, 136 type 1, and
    status 100 with value 0 for everything else."""

    version = "1311V111"
    addresses = frozenset({1})
    host = 2

    def __init__(self, *, tcp: bool = False, ascii: bool = False, speed: int | None = None,
                 delay: float = 0.0, nines: bool = False, line: SharedLine | None = None):
        self.ascii, self.speed, self.delay, self.nines = ascii, speed, delay, nines
        self.log: list[bytes] = []
        self.bad: list[bytes] = []  # nines with a wrong checksum (nines=True)
        self.held = b""  # what it heard of a frame or line not yet complete
        self._stop = threading.Event()
        self._conn: socket.socket | None = None
        self._line = line
        if line is not None:
            line.modules.append(self)
            return
        if tcp:
            self.server = socket.create_server(("127.0.0.1", 0))
            self.url = f"socket://127.0.0.1:{self.server.getsockname()[1]}"
            self._thread = threading.Thread(target=self._serve_tcp, daemon=True)
        else:
            self.master, self._slave = os.openpty()
            tty.setraw(self._slave)
            self.path = os.ttyname(self._slave)
            self._thread = threading.Thread(target=self._serve_pty, daemon=True)
        self._thread.start()

    # -- what the module says: override these ----------------------------------------------

    def answer(self, raw: bytes) -> bytes | None:
        """The reply to one (valid) binary frame, or None for silence."""
        addr, cmd, typ = raw[0], raw[1], raw[2]
        if addr not in self.addresses:
            return None
        if cmd == 136 and typ == 0:
            return version_reply(self.version, self.host)
        if cmd == 136:
            return reply(cmd, (int(self.version[:4]) << 16) | 0x0101, module=addr, host=self.host)
        return reply(cmd, 0, module=addr, host=self.host)

    def line(self, text: str) -> str | None:
        """The reply (without CR) to one ASCII line while ``ascii`` is set, or None."""
        return None

    # -- the line ----------------------------------------------------------------------------

    def write(self, data: bytes) -> None:
        if self._line is not None:
            self._line.write(data)
        elif self._conn is not None:
            self._conn.sendall(data)
        else:
            os.write(self.master, data)

    def send(self, data: bytes) -> None:
        if self.delay:
            time.sleep(self.delay)
        self.write(data)

    def _take(self, buf: bytes) -> bytes:
        """Answer what ``buf`` holds; returns what is left (an incomplete frame or line)."""
        while buf:
            if self.ascii:
                if b"\r" not in buf:
                    break
                text, _, buf = buf.partition(b"\r")
                self.log.append(text)
                out = self.line(text.decode("latin-1"))
                if out is not None:
                    self.send(out.encode() + b"\r")
                continue
            if len(buf) < 9:
                break
            if not valid(buf[:9]):
                if not self.nines:
                    buf = buf[1:]  # no frame starts here
                    continue
                raw, buf = buf[:9], buf[9:]  # nine bytes, frame or not
                self.bad.append(raw)
                if raw[0] in self.addresses:
                    self.send(reply(raw[1], 0, WRONG_CHECKSUM, raw[0], self.host))
                continue
            raw, buf = buf[:9], buf[9:]
            self.log.append(raw)
            out = self.answer(raw)
            if out is not None:
                self.send(out)
        return buf

    def _serve_pty(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.02)
            if not ready:
                continue
            try:
                data = os.read(self.master, 1024)
            except OSError:
                return
            if self.speed is not None and termios.tcgetattr(self.master)[4] != self.speed:
                continue  # framing errors at the wrong rate: nothing the module understands
            self.hear(data)

    def hear(self, data: bytes) -> None:
        """Bytes from the host, after what it holds of a frame or line."""
        self.held = self._take(self.held + data)

    def _serve_tcp(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            with conn:
                self._conn, self.held = conn, b""
                while True:
                    try:
                        data = conn.recv(1024)
                    except OSError:
                        break
                    if not data:
                        break
                    try:
                        self.hear(data)
                    except OSError:
                        break
                self._conn = None

    def commands(self) -> list[int]:
        """The command byte of every binary frame heard."""
        return [raw[1] for raw in self.log if len(raw) == 9]

    def close(self) -> None:
        self._stop.set()
        if self._line is not None:
            return  # (the line closes itself)
        if hasattr(self, "server"):
            self.server.close()
            self._thread.join(2)
        else:
            self._thread.join(2)
            os.close(self.master)
            os.close(self._slave)


class Module(Responder):
    """Axis and global parameters as plain numbers: ``values[(type, motor, is_global)]``, set
    by SAP/SGP, read by GAP/GGP (0 if never set); ``refuse`` holds (command, type, motor)
    answered with status 4 (invalid value) and not stored. ``got`` holds every command heard
    as (command, type, motor, value). 136 type 1 answers the module number and version 1.30;
    the other commands known here answer status 100 with their value, anything else status 2
    (invalid command)."""

    KNOWN = (1, 2, 3, 4, 7, 8, 11, 12, 14, 15)

    def __init__(self, version: str = "1161V130", address: int = 1, host: int = 2, **kw):
        self.version, self.address, self.host = version, address, host
        self.addresses = frozenset({address})
        self.values: dict[tuple[int, int, bool], int] = {}
        self.refuse: set[tuple[int, int, int]] = set()
        self.got: list[tuple[int, int, int, int]] = []  # (command, type, motor, value)
        super().__init__(**kw)

    def answer(self, raw: bytes) -> bytes | None:
        addr, cmd, typ, motor, value = fields(raw)
        if addr != self.address:
            return None
        ans = self.respond(cmd, typ, motor, value)
        if isinstance(ans, str):
            return version_reply(ans, self.host)
        return reply(cmd, ans[1], ans[0], self.address, self.host)

    def respond(self, command: int, type_: int, motor: int, value: int) -> tuple[int, int] | str:
        """(status, value), or the version string for 136 type 0."""
        self.got.append((command, type_, motor, value))
        if command == 136 and type_ == 0:
            return self.version
        if (command, type_, motor) in self.refuse:
            return INVALID_VALUE, value
        if command in (5, 9):  # SAP, SGP
            self.values[(type_, motor, command == 9)] = value
        elif command in (6, 10):  # GAP, GGP
            return OK, self.values.get((type_, motor, command == 10), 0)
        elif command == 136:
            return OK, int(self.version[:4]) << 16 | 0x0130
        elif command not in self.KNOWN:
            return INVALID_COMMAND, 0
        return OK, value

    def commands(self) -> list[int]:
        return [g[0] for g in self.got]


class TcpModule(Module):
    """The module on a TCP port (``socket://127.0.0.1:PORT``), one client at a time."""

    def __init__(self, **kw):
        super().__init__(tcp=True, **kw)


class PtyModule(Module):
    """The module on a pty (``path``)."""


class DownloadModeModule(Responder):
    """Left in download mode (tmclsh was killed mid-upload): every command but the control
    commands (128 and up) is stored and answered with status 101, until 133 ends the mode
    (132 starts it). GAP answers ``position``."""

    downloading = True
    position = -5000

    def answer(self, raw: bytes) -> bytes | None:
        addr, cmd, _, _, value = fields(raw)
        if cmd in (132, 133):
            self.downloading = cmd == 132
            return reply(cmd, 0)
        if self.downloading and cmd < 128:
            return reply(cmd, value, LOADED)
        if cmd == 6:
            return reply(cmd, self.position)
        return super().answer(raw)


class CanModule(Module):
    """The module on a python-can bus: requests on ``can_id``, replies on ``reply_id``."""

    def __init__(self, bus, can_id: int = 1, reply_id: int = 2, version: str = "1161V130",
                 address: int = 1, host: int = 2, eighth: str | None = None):
        import can

        # eighth: some modules answer with eight data bytes (DLC 8): "sum" adds the sum of
        # the seven, "zero" a 0 byte
        self.eighth = eighth

        self.version, self.address, self.host = version, address, host
        self.values, self.refuse, self.got = {}, set(), []
        self.can, self.bus, self.can_id, self.reply_id = can, bus, can_id, reply_id
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(0.05)
            if msg is None or msg.arbitration_id != self.can_id or len(msg.data) != 7:
                continue
            d = bytes(msg.data)
            (val,) = struct.unpack(">i", d[3:7])
            ans = self.respond(d[0], d[1], d[2], val)
            if isinstance(ans, str):
                data = ans.encode("ascii")
            else:
                data = bytes([self.address, ans[0], d[0]]) + struct.pack(">i", ans[1])
                if self.eighth == "sum":
                    data += bytes([sum(data) & 0xFF])
                elif self.eighth == "zero":
                    data += b"\x00"
            self.bus.send(self.can.Message(arbitration_id=self.reply_id, data=data,
                                           is_extended_id=False))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1)
        self.bus.shutdown()


class AsciiModeModule(Responder):
    """A module that starts in its ASCII mode (GP 67 bit 0 set; §4.4): it ignores binary
    frames there; a line ``<address char><command>`` CR is answered ``<host char><module
    char> <status> <value>`` CR, without echo (GP 67 = 0x21). ``BIN`` returns it to binary
    mode (answered like any line), binary 139 puts it back into ASCII mode (no reply).
    ``modes`` records each mode it entered, so a test sees whether it was left as found."""

    def __init__(self, version: str = "1311V111", address: int = 1, **kw):
        self.version, self.addresses = version, frozenset({address})
        self.char = chr(0x40 + address)
        self.modes: list[str] = ["ascii"]
        super().__init__(ascii=True, **kw)

    def answer(self, raw: bytes) -> bytes | None:
        if raw[0] in self.addresses and raw[1] == 139:
            self.ascii = True
            self.modes.append("ascii")
            return None
        return super().answer(raw)

    def line(self, text: str) -> str | None:
        if not text.startswith(self.char):
            return None  # another address's line, or the bytes of binary frames
        word = text[1:].strip().upper().replace(" ", "")
        host = chr(0x40 + self.host)
        if word == "BIN":
            self.ascii = False
            self.modes.append("binary")
            return f"{host}{self.char} {OK} 0"
        if word == "GGP67,0":
            return f"{host}{self.char} {OK} 33"
        return f"{host}{self.char} {INVALID_COMMAND} 0"


class TwoAtOneAddress(Responder):
    """Two modules given the same address on one line (both arrived at address 1): every
    frame to that address is answered by each, one reply after the other, each with its own
    version (a TMCM-1311 and a TMCM-1161; ``versions``: others, two alike for modules that
    agree in every answer). ``offset``: seconds the second one answers after
    the first (it is slower to reply). ``alone``: addresses a single module answers at on the
    same line (a TMCM-1311)."""

    versions = ("1311V111", "1161V130")

    def __init__(self, *, offset: float = 0.0, alone: tuple[int, ...] = (),
                 versions: tuple[str, str] | None = None, **kw):
        if versions is not None:
            self.versions = versions
        self.offset = offset
        self.replied = 0  # replies written, both modules' (a test waits for all of them)
        self.alone = frozenset(alone)
        self.addresses = frozenset({1}) | self.alone
        super().__init__(**kw)

    def answer(self, raw: bytes) -> bytes | None:
        if raw[0] in self.alone:
            self.version = self.versions[0]
            return super().answer(raw)
        replies = []
        for version in self.versions:
            self.version = version
            one = super().answer(raw)
            if one is not None:
                replies.append(one)
        if self.offset and len(replies) == 2:
            self.send(replies[0])
            time.sleep(self.offset)
            return replies[1]
        return b"".join(replies) or None

    def write(self, data: bytes) -> None:
        super().write(data)
        self.replied += len(data) // 9


class SharedLine(Responder):
    """Several modules on one pty, as on an RS485 bus: every byte the host sends reaches each
    module, which frames it in its own way (``nines``, ASCII mode); their answers go out on
    the one line. Make it, then the modules with ``line=`` it: ``Module(address=5,
    nines=True, line=bus)``."""

    def __init__(self, **kw):
        self.modules: list[Responder] = []
        super().__init__(**kw)

    def hear(self, data: bytes) -> None:
        for module in list(self.modules):
            module.hear(data)

    def close(self) -> None:
        for module in self.modules:
            module.close()
        super().close()
