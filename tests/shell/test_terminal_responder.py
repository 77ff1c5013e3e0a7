"""The ASCII terminal noticing a typed BIN, against a module written here from the manual's
byte tables (not the project's simulator): binary frames of 9 bytes, 136 and 139, and the
ASCII command line with echo off (GP 67 bits 5/4 = 10), left with BIN."""

from __future__ import annotations

import os

import pytest

from responder import Responder, fields, reply, version_reply

pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pty")


class AsciiCapableModule(Responder):
    """A TMCM-1311 at address 1 (host 2) on a pty (tests/responder.py).

    Binary: ``136`` type 1 answers value 05 1F 6F 00 (type 1311, version 111), type 0 the
    string ``1311V111``; ``139`` enters ASCII mode; ``GAP`` (6) answers the position.
    ASCII: ``A<command>`` + CR answered ``BA <status> <value>`` + CR, no echo; ``ABIN``
    answers and returns to binary. It records every ASCII line (``lines``) and, in ``log``,
    every binary frame."""

    position = 0

    def __init__(self):
        self.lines: list[str] = []
        super().__init__()

    def answer(self, raw: bytes) -> bytes | None:
        addr, cmd, type_, _, value = fields(raw)
        if addr != 1:
            return None
        if cmd == 136 and type_ == 0:
            return version_reply("1311V111")
        if cmd == 136:
            return reply(136, 0x051F6F00)
        if cmd == 139:
            self.ascii = True
            return reply(139, 0)
        if cmd == 6 and type_ == 1:
            return reply(6, self.position)
        if cmd == 5 and type_ == 1:
            self.position = value
            return reply(5, value)
        return reply(cmd, 0, status=2)  # invalid command

    def line(self, text: str) -> str | None:
        text = text.strip()
        self.lines.append(text)
        if not text.upper().startswith("A"):
            return None  # another module's line
        words = text[1:].replace(",", " ").split()
        word = words[0].upper() if words else ""
        if word == "BIN":
            self.ascii = False
            return "BA 100 0"
        if word == "GGP" and words[1:3] == ["67", "0"]:
            return "BA 100 32"  # echo none
        if word == "GAP" and words[1:2] == ["1"]:
            return f"BA 100 {self.position}"
        if word == "SAP" and words[1:2] == ["1"]:
            self.position = int(words[3])
            return f"BA 100 {self.position}"
        return "BA 2 0"


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
    # (the probe's line and the typed lines get spaces after the address character: whole
    # nine-byte blocks, CR included, for the binary modules on a shared line)
    assert [ln for ln in module.lines if ln.replace(" ", "") != "AGGP67,0"] == [
        "A   SAP 1, 0, 321", "A    BIN"]
    assert res.stdout.splitlines()[-1] == "ActualPosition = 321 µsteps"
    assert module.commands()[-1] == 6 and not module.ascii
