"""The module's ASCII mode is a framing (link/ascii.py) behind the interface of the serial
and CAN framings: the client swaps framings on a mode change, and an operation's request
goes as the line the instruction set names for it. Against a module written from the manual
(tests/responder.py), not the simulator.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from tmclsh.base.errors import ValidationError
from tmclsh.client.ascii import AsciiLink
from tmclsh.client.text import LineClient
from tmclsh.link import open_serial
from tmclsh.link.ascii import AsciiFraming, command_bytes
from tmclsh.link.framing import SerialFraming
from tmclsh.tmcl.frames import Control, Request

from conftest import ROOT
from responder import OK, AsciiModeModule


class _StatusModule(AsciiModeModule):
    """In ASCII mode: GGP 128 (application status) reads 3 (reset); RUN answers."""

    def line(self, text: str) -> str | None:
        word = text[1:].strip().upper().replace(" ", "")
        if text.startswith(self.char) and word in ("GGP128,0", "RUN"):
            return f"{chr(0x40 + self.host)}{self.char} {OK} {3 if word != 'RUN' else 0}"
        return super().line(text)


@pytest.fixture
def module():
    m = _StatusModule()
    yield m
    m.close()


def test_the_client_swaps_framings_on_a_mode_change(module) -> None:
    c = LineClient(open_serial(module.path), module="TMCM-1311", timeout=1.0, retries=0)
    try:
        binary = c._framing
        assert isinstance(binary, SerialFraming)
        link = AsciiLink.attach(c)
        assert isinstance(c._framing, AsciiFraming) and c._framing is link.framing
        # the request path is the framing's: a line padded to whole nine-byte blocks
        heard = len(module.log)
        assert c.request(Request(1, Control.GET_STATUS, 0, 0, 0)).value == 3
        assert module.log[heard:] == [command_bytes(1, "GGP 128, 0")[:-1]]
        link.detach()  # BIN, then a binary 136 type 1 to be sure
        assert c._framing is binary and c.mode == "binary"
        assert module.modes == ["ascii", "binary"]
    finally:
        c.close()


def test_what_the_ascii_mode_has_no_line_for_is_refused_unsent(module) -> None:
    c = LineClient(open_serial(module.path), module="TMCM-1311", timeout=1.0, retries=0)
    try:
        AsciiLink.attach(c)
        heard = list(module.log)
        assert c.refusal(Request(1, Control.STEP_APPLICATION, 0, 0, 0)) is not None
        assert c.refusal(Request(1, Control.RUN_APPLICATION, 1, 0, 5)) is not None
        assert c.refusal(Request(1, Control.RUN_APPLICATION, 0, 0, 0)) is None
        with pytest.raises(ValidationError, match=r"ASCII mode.*\.mode binary"):
            c.request(Request(1, Control.STEP_APPLICATION, 0, 0, 0))
        with pytest.raises(ValidationError, match="RUN"):
            c.execute("129 0, 0, 0")  # a typed line goes as typed: refused, RUN named
        assert module.log == heard
        assert c.request(Request(1, Control.RUN_APPLICATION, 0, 0, 0)).ok
        assert module.log[len(heard):] == [command_bytes(1, "RUN")[:-1]]
    finally:
        c.close()


def test_no_import_circle_between_layers() -> None:
    """client.core -> bringup -> ascii -> core was the last one: the ASCII line codec lives
    in link/, below the client."""
    tool = ROOT.parent / "shared" / "tools" / "layers.py"
    if not tool.exists():
        pytest.skip("the project's shared tools are not next to this checkout")
    out = subprocess.run([sys.executable, str(tool), "--fine", str(ROOT)], capture_output=True,
                         text=True, timeout=120).stdout
    assert "0 import circle(s)" in out, out
