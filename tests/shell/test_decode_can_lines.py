"""``.decode`` takes a CAN frame as users paste it from their logs (PyTrinamic's issues have
candump output): candump's screen line, a candump -L line and a Vector .asc line, the latter
two read by python-can's own readers. The lines are written by python-can here where it
writes them."""

from __future__ import annotations

import io
import json

import can
import pytest

from tmclsh.base.errors import TmclError
from tmclsh.client.connect import connect
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session


@pytest.fixture
def session():
    s = Session(connect(sim="TMCM-1311", timeout=0.3, retries=0), Output())
    yield s
    s.client.close()


def _logged(writer_class, msg: can.Message) -> str:
    """The line python-can's writer makes of ``msg``."""
    out = io.StringIO()
    writer = writer_class(out)
    writer.on_message_received(msg)
    lines = [ln for ln in out.getvalue().splitlines() if ln.strip()
             and not ln.lower().startswith(("date", "base", "internal", "begin", "end",
                                            "no internal"))
             and "Start of measurement" not in ln]
    return lines[-1]


def test_a_candump_line(session, capsys):
    session.run_line(".decode can0  001   [7]  06 01 00 00 00 00 00")
    out = capsys.readouterr().out
    assert "06 01 00 00 00 00 00" in out
    assert "CAN request to id 1: GAP 1, 0  // ActualPosition" in out
    session.run_line(".decode  (1700000000.123456)  can0  002   [7]  01 64 06 FF FF EC 78")
    out = capsys.readouterr().out
    assert "CAN reply on id 2: from address 1: 100 ok, GAP value -5000" in out


def test_lines_python_can_writes(session, capsys):
    reply = can.Message(timestamp=1.5, arbitration_id=2, is_extended_id=False,
                        data=bytes.fromhex("01 64 06 00 00 03 e8"))
    session.run_line(".decode " + _logged(can.CanutilsLogWriter, reply))
    assert "CAN reply on id 2: from address 1: 100 ok, GAP value 1000" in \
        capsys.readouterr().out
    version = can.Message(timestamp=1.5, arbitration_id=2, is_extended_id=False,
                          data=b"1311V111")
    session.run_line(".decode " + _logged(can.ASCWriter, version))
    assert "'1311V111'" in capsys.readouterr().out
    req = can.Message(timestamp=1.5, arbitration_id=5, is_extended_id=False,
                      data=bytes.fromhex("05 04 00 00 00 03 e8"))
    session.run_line(".decode " + _logged(can.ASCWriter, req))
    assert "CAN request to id 5: SAP 4, 0, 1000  // MaxPositioningSpeed" in \
        capsys.readouterr().out


def test_a_hint_and_json(session, capsys):
    session.out.json = True
    session.run_line(".decode reply can0  001   [7]  01 64 06 00 00 03 e8")
    obj = json.loads(capsys.readouterr().out)
    assert obj["bytes"] == "01 64 06 00 00 03 e8"
    assert [r["kind"] for r in obj["readings"]] == ["CAN reply on id 1"]


def test_lines_that_are_no_tmcl_frame(session, capsys):
    session.run_line(".decode can0  123   [3]  01 02 03")
    assert "3 data bytes: no TMCL frame" in capsys.readouterr().out
    with pytest.raises(TmclError, match=r"says \[7\] and carries 3 bytes"):
        session.run_line(".decode can0  001   [7]  01 02 03")


def test_decode_then_decode_on_one_line_is_two_commands(run_tmclsh):
    """Issue 35: `.decode HEX; .decode HEX` took the whole line as hex. A ';' that a
    dot-command follows ends the line .decode owns; pasted bytes may still hold ';'."""
    p = run_tmclsh("--sim", "TMCM-1311", "-c",
                   ".decode request 01 06 04 00 00 00 00 00 0b; .decode request 01 05 04 00 "
                   "00 00 03 e8 f5")
    assert p.returncode == 0, p.stderr
    assert p.stdout.count("request") >= 2 and "GAP" in p.stdout and "SAP" in p.stdout, p.stdout
    p = run_tmclsh("--sim", "TMCM-1311", "-c", ".decode request 01 06 04 00; 00 00 00 00 0b")
    assert p.returncode == 0 and "GAP" in p.stdout, p.stdout + p.stderr
