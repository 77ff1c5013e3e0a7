"""A stand-in TMCL module written from the manual's byte tables (§4 binary command and reply
format), independent of tmclsh's protocol code and simulator: what tmclsh sends must make
sense to something that only knows the manual.

Serial (TCP here, for pyserial's socket:// URL): request = address, command, type,
motor/bank, value (4 bytes, MSB first), checksum (8-bit sum of the other 8); reply = reply
address, module address, status, command, value, checksum. 136 type 0 answers the reply
address and 8 ASCII characters. CAN: "leave out the first byte and the checksum": the request
is 7 data bytes on the module's CAN id, the reply 7 data bytes on the reply id (the version
string: its 8 characters).
"""

from __future__ import annotations

import socket
import struct
import threading


class Module:
    """Axis and global parameters as plain numbers; every frame it got, for the tests."""

    def __init__(self, version: str = "1161V130", address: int = 1, host: int = 2):
        self.version, self.address, self.host = version, address, host
        self.axis: dict[tuple[int, int], int] = {}
        self.glob: dict[tuple[int, int], int] = {}
        self.got: list[tuple[int, int, int, int]] = []  # (command, type, motor, value)

    def answer(self, command: int, type_: int, motor: int, value: int) -> tuple[int, int] | str:
        """(status, value), or the version string for 136 type 0."""
        self.got.append((command, type_, motor, value))
        if command == 136 and type_ == 0:
            return self.version
        if command == 5:  # SAP
            self.axis[(type_, motor)] = value
        elif command == 6:  # GAP
            return 100, self.axis.get((type_, motor), 0)
        elif command == 9:  # SGP
            self.glob[(type_, motor)] = value
        elif command == 10:  # GGP
            return 100, self.glob.get((type_, motor), 0)
        elif command == 136:
            return 100, int(self.version[:4]) << 16 | 0x0130
        elif command not in (1, 2, 3, 4, 7, 8, 11, 12, 14, 15):
            return 2, 0  # invalid command
        return 100, value

    def commands(self) -> list[int]:
        return [g[0] for g in self.got]


class TcpModule(Module):
    """The module on a TCP port (``socket://127.0.0.1:PORT``), one client at a time."""

    def __init__(self, **kw):
        super().__init__(**kw)
        self.server = socket.create_server(("127.0.0.1", 0))
        self.url = f"socket://127.0.0.1:{self.server.getsockname()[1]}"
        self._stop = False
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while not self._stop:
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            with conn:
                buf = b""
                while True:
                    try:
                        chunk = conn.recv(64)
                    except OSError:
                        break
                    if not chunk:
                        break
                    buf += chunk
                    while len(buf) >= 9:
                        frame, buf = buf[:9], buf[9:]
                        if sum(frame[:8]) & 0xFF != frame[8] or frame[0] != self.address:
                            continue
                        cmd, typ, mot = frame[1], frame[2], frame[3]
                        (val,) = struct.unpack(">i", frame[4:8])
                        ans = self.answer(cmd, typ, mot, val)
                        if isinstance(ans, str):
                            out = bytes([self.host]) + ans.encode("ascii")
                        else:
                            body = bytes([self.host, self.address, ans[0], cmd]) + struct.pack(">i", ans[1])
                            out = body + bytes([sum(body) & 0xFF])
                        conn.sendall(out)

    def close(self) -> None:
        self._stop = True
        self.server.close()


class CanModule(Module):
    """The module on a python-can bus: requests on ``can_id``, replies on ``reply_id``."""

    def __init__(self, bus, can_id: int = 1, reply_id: int = 2, **kw):
        super().__init__(**kw)
        import can

        self.can, self.bus, self.can_id, self.reply_id = can, bus, can_id, reply_id
        self._stop = False
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop:
            msg = self.bus.recv(0.05)
            if msg is None or msg.arbitration_id != self.can_id or len(msg.data) != 7:
                continue
            d = bytes(msg.data)
            (val,) = struct.unpack(">i", d[3:7])
            ans = self.answer(d[0], d[1], d[2], val)
            if isinstance(ans, str):
                data = ans.encode("ascii")
            else:
                data = bytes([self.address, ans[0], d[0]]) + struct.pack(">i", ans[1])
            self.bus.send(self.can.Message(arbitration_id=self.reply_id, data=data,
                                           is_extended_id=False))

    def close(self) -> None:
        self._stop = True
        self._thread.join(1)
        self.bus.shutdown()
