"""The ASCII terminal's Ctrl-T conveniences on their own: hex lines, timestamps at line
starts, the log file, the lines of a file to send, recognising BIN and .quit; and the raw
mode's key handling, with a link that records what would be sent."""

from __future__ import annotations

import re

import pytest

from tmclsh.base.errors import ValidationError
from tmclsh.shell.features import termtools as tt
from tmclsh.shell.features import terminal as tm
from tmclsh.shell.features import termloops as tl
from tmclsh.shell.features import termview as tv


def test_hex_lines():
    assert tt.hex_lines(b"BA 100 0\r") == [
        "42 41 20 31 30 30 20 30 0d" + " " * 21 + "  |BA 100 0.|"]
    rows = tt.hex_lines(bytes(range(40)))
    assert len(rows) == 3 and rows[1].startswith("10 11 12")
    assert all(len(r.split("  |")[0]) == 47 for r in rows)


def test_timestamps_go_where_lines_start_even_across_pieces():
    ticks = iter([1.25, 2.5, 3.75])
    st = tt.Stamper(clock=lambda: next(ticks))
    out = st("BA 1") + st("00 0\r\nBA") + st(" 100 5\r\n")
    stamps = re.findall(r"\[\d\d:\d\d:\d\d\.(\d{3})\] ", out)
    assert stamps == ["250", "500"]  # two lines, each stamped when it began
    assert re.sub(r"\[[^]]*\] ", "", out) == "BA 100 0\r\nBA 100 5\r\n"
    assert st.at_line_start
    off = tt.Stamper(clock=lambda: 0.0)
    assert off("x\ny", on=False) == "x\ny" and not off.at_line_start


def test_the_log_is_plain_text(tmp_path):
    log = tt.SessionLog.open(str(tmp_path / "s.log"))
    log.write("\x1b[32mBA 100 0\x1b[0m   ok\r\n")
    log.close()
    assert (tmp_path / "s.log").read_text() == "BA 100 0   ok\n"
    with pytest.raises(ValidationError, match="cannot log to"):
        tt.SessionLog.open(str(tmp_path / "no" / "such" / "dir.log"))
    with pytest.raises(ValidationError, match="no file name"):
        tt.SessionLog.open("  ")


def test_file_lines_skip_blanks_and_comments(tmp_path):
    f = tmp_path / "x.tmcl"
    f.write_text("# setup\nSAP 4, 0, 100\n\n  // read back\nGAP 4, 0\n")
    assert tt.file_lines(str(f)) == ["SAP 4, 0, 100", "GAP 4, 0"]
    with pytest.raises(ValidationError, match="no such file"):
        tt.file_lines(str(tmp_path / "missing.tmcl"))


def test_file_to_send_is_read_bounded(tmp_path):
    """Ctrl-T u with /dev/zero (or a huge file) grew the terminal until the machine gave out."""
    huge = tmp_path / "huge.txt"
    with open(huge, "wb") as fh:
        fh.truncate(17 * 1024 * 1024)  # sparse: no disk used
    with pytest.raises(ValidationError, match=r"huge.txt: file larger than 16 MiB; not read"):
        tt.file_lines(str(huge))
    with pytest.raises(ValidationError, match="it is a directory"):
        tt.file_lines(str(tmp_path))


@pytest.mark.parametrize("line, address, expected", [
    (b"ABIN", 1, True), (b"abin", 1, True), (b"A BIN", 1, True), (b"BBIN", 2, True),
    (b"BBIN", 1, False),  # another module's BIN
    (b"ABINX", 1, False), (b"AGAP 1, 0", 1, False), (b"BIN", 1, False),
])
def test_is_bin(line, address, expected):
    assert tt.is_bin(line, address) is expected


def test_menu_switches():
    st = tt.MenuState()
    assert st.toggle("e") == "local echo on" and st.local_echo
    assert st.toggle("H") == "hex view on"
    assert st.toggle("x") is None
    assert "e echo [on]" in tt.menu_hint(st) and "t time [off]" in tt.menu_hint(st)
    assert any(line.strip().startswith("u  send a file") for line in tt.menu_text(st))


# -- raw mode's keys -----------------------------------------------------------------------

class _Link:
    def __init__(self):
        self.sent = bytearray()

    def write_raw(self, data: bytes) -> None:
        self.sent += data


class _Term:
    """What RawKeys needs of the terminal, recording notes."""

    def __init__(self):
        self.link = _Link()
        self.menu = tt.MenuState()
        self.raw_view = tv.RawView()
        self.left_ascii = False
        self.notes: list[str] = []
        self.session = type("S", (), {"client": type("C", (), {"address": 1})()})()

    def note(self, text):
        self.notes.append(text)

    def stop_motors(self):
        self.notes.append("stopped")

    def menu_key(self, key):
        return tm.Terminal.menu_key(self, key)  # type: ignore[arg-type]

    def write(self, segments):
        pass


def press(keys: tl.RawKeys, data: bytes) -> list[str | None]:
    return [keys.press(k) for k in tl.translate_keys(data)]


def test_raw_keys_go_through_but_menu_and_quit_do_not():
    term = _Term()
    keys = tl.RawKeys(term)  # type: ignore[arg-type]
    press(keys, b"AGAP 1, 0\r")
    assert bytes(term.link.sent) == b"AGAP 1, 0\r"
    term.link.sent.clear()
    assert press(keys, b"\x14t") == [None, None]  # Ctrl-T t: timestamps, nothing sent
    assert term.menu.timestamps and term.link.sent == b""
    assert press(keys, b"\x14\x14") == [None, None]  # Ctrl-T Ctrl-T: the module gets one
    assert term.link.sent == b"\x14"
    term.link.sent.clear()
    assert press(keys, b"\x14f") == [None, "f"]  # the loop asks for the file name
    assert press(keys, b".quit\r")[-1] == "leave"
    assert term.link.sent == b".quit" + b"\x08" * 5  # typed, then erased: no CR
    assert press(keys, b"\x1d") == ["leave"]


def test_raw_bin_leaves():
    term = _Term()
    keys = tl.RawKeys(term)  # type: ignore[arg-type]
    assert press(keys, b"ABIN\r")[-1] == "leave"
    assert term.left_ascii and term.link.sent == b"ABIN\r"
