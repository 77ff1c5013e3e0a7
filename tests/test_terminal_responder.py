"""The ASCII terminal noticing a typed BIN, against a module written here from the manual's
byte tables (not the project's simulator): binary frames of 9 bytes, 136 and 139, and the
ASCII command line with echo off (GP 67 bits 5/4 = 10), left with BIN."""

from __future__ import annotations

import os
import threading
import tty

import pytest

pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pty")


class AsciiCapableModule:
    """A TMCM-1311 at address 1 (host 2) on a pty.

    Binary: ``136`` type 1 answers value 05 1F 6F 00 (type 1311, version 111), type 0 the
    string ``1311V111``; ``139`` enters ASCII mode; ``GAP`` (6) answers the position.
    ASCII: ``A<command>`` + CR answered ``BA <status> <value>`` + CR, no echo; ``ABIN``
    answers and returns to binary. It records every ASCII line and binary command."""

    def __init__(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.ascii = False
        self.position = 0
        self.lines: list[str] = []
        self.binary: list[int] = []
        self._stop = False
        threading.Thread(target=self._serve, daemon=True).start()

    def _send(self, data: bytes) -> None:
        os.write(self.master, data)

    def _frame(self, cmd: int, value: int, status: int = 100) -> bytes:
        body = bytes([2, 1, status, cmd]) + (value & 0xFFFFFFFF).to_bytes(4, "big")
        return body + bytes([sum(body) & 0xFF])

    def _binary(self, frame: bytes) -> None:
        addr, cmd, type_, motor = frame[:4]
        value = int.from_bytes(frame[4:8], "big", signed=True)
        self.binary.append(cmd)
        if addr != 1:
            return
        if cmd == 136 and type_ == 0:
            self._send(bytes([2]) + b"1311V111")
        elif cmd == 136:
            self._send(self._frame(136, 0x051F6F00))
        elif cmd == 139:
            self._send(self._frame(139, 0))
            self.ascii = True
        elif cmd == 6 and type_ == 1:
            self._send(self._frame(6, self.position))
        elif cmd == 5 and type_ == 1:
            self.position = value
            self._send(self._frame(5, value))
        else:
            self._send(self._frame(cmd, 0, status=2))  # invalid command

    def _line(self, text: str) -> None:
        self.lines.append(text)
        if not text.upper().startswith("A"):
            return  # another module's line
        words = text[1:].replace(",", " ").split()
        word = words[0].upper() if words else ""
        if word == "BIN":
            self._send(b"BA 100 0\r")
            self.ascii = False
        elif word == "GGP" and words[1:3] == ["67", "0"]:
            self._send(b"BA 100 32\r")  # echo none
        elif word == "GAP" and words[1:2] == ["1"]:
            self._send(f"BA 100 {self.position}\r".encode())
        elif word == "SAP" and words[1:2] == ["1"]:
            self.position = int(words[3])
            self._send(f"BA 100 {self.position}\r".encode())
        else:
            self._send(b"BA 2 0\r")

    def _serve(self) -> None:
        buf = b""
        while not self._stop:
            try:
                buf += os.read(self.master, 256)
            except OSError:
                return
            while buf:
                if self.ascii:
                    cut = buf.find(b"\r")
                    if cut < 0:
                        break
                    line, buf = buf[:cut], buf[cut + 1:]
                    self._line(line.decode("latin-1").strip())
                elif len(buf) >= 9:
                    if sum(buf[:8]) & 0xFF == buf[8]:
                        frame, buf = buf[:9], buf[9:]
                        self._binary(frame)
                    else:
                        buf = buf[1:]  # not a frame (a stray CR): look further
                else:
                    break

    def close(self) -> None:
        self._stop = True
        os.close(self.slave)
        os.close(self.master)


@pytest.fixture
def module():
    m = AsciiCapableModule()
    yield m
    m.close()


def test_bin_typed_in_the_terminal_against_an_independent_module(module, run_tmclsh):
    res = run_tmclsh("--port", module.path, "-m", "TMCM-1311", "-c", ".ascii\nGAP 1, 0",
                     input="SAP 1, 0, 321\nBIN\nGAP 1, 0\n")
    assert res.returncode == 0, res.stderr
    notes = res.stderr.splitlines()
    assert "--- module left ASCII mode (BIN): back to the shell on the binary link" in notes
    assert not any("send BIN" in n for n in notes)
    # the line after BIN did not go out as ASCII; the -c line after .ascii went in binary
    assert [ln for ln in module.lines if ln != "AGGP 67, 0"] == ["ASAP 1, 0, 321", "ABIN"]
    assert res.stdout.splitlines()[-1] == "ActualPosition = 321 µsteps"
    assert module.binary[-1] == 6 and not module.ascii
