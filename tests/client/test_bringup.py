"""One bring-up (tmclsh/client/bringup.py), at connect and after every reconnect, checked
against modules written here from the manuals (tests/responder.py), not the simulator.

* A TMCM-1640 answers 136 type 1 version first (TMCM-1640 manual §4.5.25, 003:2275-2288:
  "1 Version number, low byte ... 4 Type number, high byte"); a TMCM-1311 type first. A
  136 type 0 string garbled on the line (it has no checksum) is confirmed through that
  value, read in the module's own byte order, and ``scan`` names the module from it.
* After a reconnect the module is checked exactly as at connect: a module left in download
  mode is brought out of it, one now in its ASCII mode is recognised and driven through it,
  a garbled string is confirmed, another module type is said and taken.
"""

from __future__ import annotations

import pytest

from responder import (INVALID_COMMAND, OK, PtyModule, Responder, TcpModule, reply,
                       version_reply)

from tmclsh.client.connect import connect
from tmclsh.link import open_serial
from tmclsh.ops.scan import scan

GET_VERSION, ENTER_ASCII, GGP = 136, 139, 10


def version_first(type_number: int, version: int) -> int:
    """The 136 type 1 value as the TMCM-1640 manual lays it out."""
    return int.from_bytes(bytes([version & 0xFF, version >> 8, type_number & 0xFF,
                                 type_number >> 8]), "big")


class Garbled1640(PtyModule):
    """A TMCM-1640 whose first ``garbled`` version strings come damaged (a bit flipped on
    the line: ``1640V210`` -> ``1640v210``); 136 type 1 as its manual prints it."""

    garbled = 1

    def __init__(self, **kw):
        super().__init__(version="1640V210", **kw)

    def respond(self, command, type_, motor, value):
        if command == GET_VERSION and type_ == 0:
            self.got.append((command, type_, motor, value))
            self.garbled -= 1
            return "1640v210" if self.garbled >= 0 else self.version
        if command == GET_VERSION and type_ == 1:
            self.got.append((command, type_, motor, value))
            return OK, version_first(1640, 210)
        return super().respond(command, type_, motor, value)


@pytest.fixture
def modules():
    made: list[Responder] = []

    def make(cls, **kw):
        made.append(cls(**kw))
        return made[-1]

    yield make
    for m in made:
        m.close()


def test_a_garbled_1640_string_is_confirmed_through_its_version_first_type_1(modules):
    m = modules(Garbled1640)
    c = connect(port=m.path, timeout=0.3)
    try:
        assert c.module.name == "TMCM-1640" and c.version == "1640V210"
        # the string, the binary value, the string again (now whole), then download mode
        assert [g[:2] for g in m.got][:3] == [(136, 0), (136, 1), (136, 0)]
    finally:
        c.close()


def test_scan_names_a_1640_from_its_binary_answer_when_its_string_stays_garbled(modules):
    m = modules(Garbled1640)
    m.garbled = 1000  # the string never comes whole: the binary answer names the module
    c = connect(port=m.path, module="generic", timeout=0.3)  # (connect needs no identity)
    try:
        found = scan(c, [1, 2], timeout=0.05)
    finally:
        c.close()
    assert [(f.address, f.module) for f in found] == [(1, "TMCM-1640")]


class Switchable(TcpModule):
    """A TMCM-1311 on TCP that can be put, while the link is down, in download mode (every
    command below 128 stored, answered 101, until 133) or in its ASCII mode (lines
    ``A<command>`` answered ``BA <status> <value>``; BIN back to binary, 139 into it)."""

    def __init__(self, **kw):
        super().__init__(version="1311V111", **kw)
        self.downloading = False
        self.gp67 = 0x21  # (what GGP 67 answers in ASCII mode: start in ASCII, no echo)

    def answer(self, raw):
        cmd = raw[1]
        if cmd == ENTER_ASCII:
            self.ascii = True
            return None
        if cmd in (132, 133):
            self.got.append((cmd, raw[2], raw[3], 0))
            self.downloading = cmd == 132
            return reply(cmd, 0)
        if self.downloading and cmd < 128:
            self.got.append((cmd, raw[2], raw[3], 0))
            return reply(cmd, 0, status=101)
        if cmd == GET_VERSION and raw[2] == 0:
            self.got.append((cmd, 0, 0, 0))
            return version_reply(self.version)
        return super().answer(raw)

    def line(self, text):
        if not text.startswith("A"):
            return None  # another address, or the bytes of a binary frame
        cmd = text[1:].strip().upper().replace(" ", "")
        self.got.append((-1, 0, 0, 0))  # (an ASCII line)
        if cmd == "BIN":
            self.ascii = False
            return None
        if cmd == "GGP67,0":
            return f"BA {OK} {self.gp67}"
        if cmd.startswith("GAP4,0"):
            return f"BA {OK} 4321"
        return f"BA {INVALID_COMMAND} 0"


def _connected(m: Switchable):
    c = connect(port=m.url, timeout=0.3, retries=1)
    assert c.module.name == "TMCM-1311" and c.mode == "binary"
    return c


def test_after_a_reconnect_download_mode_is_ended_before_the_line_runs(modules):
    m = modules(Switchable)
    c = _connected(m)
    notices = []
    c.on_notice = notices.append
    try:
        m.downloading = True  # (an upload broke off on another master meanwhile)
        c.reconnect()
        m.got.clear()
        assert c.value("GAP 4, 0") == 0 and not m.downloading
        cmds = [g[0] for g in m.got]
        assert 133 in cmds and cmds.index(133) < len(cmds) - 1 and cmds[-1] == 6
        assert any("download mode" in n for n in notices)
    finally:
        c.close()


def test_after_a_reconnect_a_module_now_in_ascii_mode_is_recognised(modules):
    m = modules(Switchable)
    c = _connected(m)
    notices = []
    c.on_notice = notices.append
    try:
        m.ascii = True  # (power-cycled with GP 67 bit 0 set: it starts in ASCII mode)
        c.reconnect()
        assert c.value("GAP 4, 0") == 4321  # through its ASCII command line
        assert c.mode == "ascii" and any("ASCII mode" in n for n in notices)
    finally:
        c.close()


def test_after_a_reconnect_a_module_driven_in_ascii_mode_is_found_in_binary_again(modules):
    """It was driven through ASCII mode and restarted in binary mode meanwhile: the ASCII
    link is set up again (139) as at connect, not left talking to a module that no longer
    listens to lines."""
    m = modules(Switchable)
    c = connect(port=m.url, timeout=0.3, retries=1, ascii=True)
    try:
        assert c.mode == "ascii" and m.ascii
        m.ascii = False  # (restarted: binary mode)
        c.reconnect()
        assert c.value("GAP 4, 0") == 4321 and c.mode == "ascii" and m.ascii
    finally:
        c.close()


def test_after_a_reconnect_a_garbled_string_is_confirmed_as_at_connect(modules):
    m = modules(Garbled1640)
    m.garbled = 0
    c = connect(port=m.path, timeout=0.3)
    try:
        assert c.module.name == "TMCM-1640"
        m.garbled = 1
        c.transport.close()  # (the port went away and came back)
        c.reconnect()
        assert c.value("GAP 1, 0") == 0 and c.module.name == "TMCM-1640"
        assert (136, 1, 0, 0) in m.got  # confirmed through the binary value
    finally:
        c.close()


def test_the_binary_bring_up_reads_the_module_it_opened(modules):
    """The bring-up after a reconnect is the one at connect: opening a port by hand and
    bringing the client up gives the same module and version as ``connect``."""
    from tmclsh.client.bringup import start
    from tmclsh.client.text import LineClient

    m = modules(Garbled1640)
    m.garbled = 0
    c = start(LineClient(open_serial(m.path), timeout=0.3))
    try:
        assert (c.module.name, c.version) == ("TMCM-1640", "1640V210")
    finally:
        c.close()


class RefusesVersionWhileDownloading(Responder):
    """Left in download mode, and refusing 136 there with status 2 (invalid command): the
    manuals do not say what a module in download mode answers to 136. Every command below 128
    is stored (status 101) until 133."""

    downloading = True

    def answer(self, raw):
        cmd = raw[1]
        if cmd in (132, 133):
            self.downloading = cmd == 132
            return reply(cmd, 0)
        if self.downloading and cmd == GET_VERSION:
            return reply(cmd, 0, status=INVALID_COMMAND)
        if self.downloading and cmd < 128:
            return reply(cmd, 0, status=101)
        return super().answer(raw)


@pytest.mark.parametrize("module", [None, "generic", "TMCM-1311"])
def test_a_module_in_download_mode_that_refuses_136_is_brought_out(modules, run_tmclsh,
                                                                    module):
    m = modules(RefusesVersionWhileDownloading)
    p = run_tmclsh("--port", m.path, *(("-m", module) if module else ()), "-c", "GAP 1, 0")
    assert p.returncode == 0, p.stderr
    assert "download mode" in p.stderr and not m.downloading
    assert "refused the version request" not in p.stderr


class OddString(PtyModule):
    """A TMCM-1311 whose 136 string is in a form tmclsh does not read (another firmware's):
    its 136 type 1 is as the TMCM-1311 manual prints it (type first)."""

    def respond(self, command, type_, motor, value):
        if command == GET_VERSION and type_ == 1:
            self.got.append((command, type_, motor, value))
            return OK, int.from_bytes(bytes([1311 >> 8, 1311 & 0xFF, 111, 0]), "big")
        return super().respond(command, type_, motor, value)


def test_a_string_in_an_unknown_form_falls_back_to_the_binary_version(modules):
    m = modules(OddString, version="TMCL1.11")
    c = connect(port=m.path, timeout=0.3)
    try:
        assert c.module.name == "TMCM-1311" and c.version == "TMCL1.11"
    finally:
        c.close()


@pytest.mark.parametrize("text, name", [("351V1.03", "TMCM-351"), ("0351V103", "TMCM-351"),
                                         ("1311V111", "TMCM-1311")])
def test_the_forms_of_the_string_modules_use(text, name):
    """Three-digit type numbers are written NNNVd.dd (PyTrinamic's updater expects it)."""
    from tmclsh.tmcl.modules import identify

    assert identify(text).name == name


def test_a_string_nothing_names_says_the_way_out(modules, run_tmclsh):
    class Nameless(PtyModule):
        def respond(self, command, type_, motor, value):
            if command == GET_VERSION and type_ == 1:
                return OK, 0  # names no type either
            return super().respond(command, type_, motor, value)

    m = modules(Nameless, version="????????")
    p = run_tmclsh("--port", m.path, "-c", "GAP 1, 0")
    assert p.returncode == 3
    assert "-m NAME (at the prompt: .module NAME)" in p.stderr
