"""What a technician reads and how lines are cut (issue 16, "What users read" and "Lines"),
through the in-process simulator and the real command line."""

from __future__ import annotations

import json
import socket
import threading

import pytest

from tmclsh.client import connect
from tmclsh.errors import TmclError
from tmclsh.shell.render import Output
from tmclsh.shell.session import Session


@pytest.fixture(autouse=True)
def wide_console(monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")


def make_session(module="TMCM-1311", json_mode=False, **kw):
    client = connect(sim=module, timeout=0.3, retries=0)
    return Session(client, Output(json_mode=json_mode), **kw)


@pytest.fixture
def s351():
    s = make_session("TMCM-351")
    yield s
    s.client.close()


# -- what users read ---------------------------------------------------------------------

def test_help_140_on_the_351_shows_user_text_only(s351, capsys):
    s351.run_line("help 140")
    out = capsys.readouterr().out
    assert "0..6" in out and "note" in out and "AP 211" in out
    assert "\u011e" not in out and "decoded" not in out and "printed" not in out
    assert "source" not in out


def test_param_source_shows_how_the_entry_was_read(s351, capsys):
    s351.run_line(".param --source 140")
    out = capsys.readouterr().out
    assert "source" in out and "decoded 0…6" in out
    s351.run_line(".param --source MaxPositioningSpeed")  # no source: says it is as printed
    assert "as the manual prints it" in capsys.readouterr().out


def test_no_default_shown_where_no_manual_gives_one(capsys):
    s = make_session("TMCM-1640")
    try:
        s.run_line("help gp 66")
        out = capsys.readouterr().out
        assert "SerialAddress" in out and "default" not in out
        s.run_line("help gp 65")  # the manual: 0 = 9600 baud "Default"
        assert "default" in capsys.readouterr().out
        # the simulated module still answers at the factory address
        s.run_line("GGP SerialAddress, 0")
        assert "= 1" in capsys.readouterr().out
    finally:
        s.client.close()


def test_param_json_has_the_note_and_source_only_on_request(capsys):
    s = make_session("TMCM-351", json_mode=True)
    try:
        s.run_line(".param 140")
        obj = json.loads(capsys.readouterr().out.splitlines()[0])
        assert obj["note"].startswith("Full and half step") and "source" not in obj
        s.run_line(".param --source 140")
        obj = json.loads(capsys.readouterr().out.splitlines()[0])
        assert "decoded" in obj["source"]
    finally:
        s.client.close()


def _value(session: Session, line: str) -> int:
    result = session.run_tmcl(line, show=False)
    assert result.reply is not None
    return result.reply.value


def test_1311_encoder_mode_takes_bit_combinations_and_ap198_sets_bit_2():
    s = make_session("TMCM-1311")
    try:
        s.run_tmcl("SAP 201, 0, 20", show=False)  # bit 4 (polarity) + bit 2 (clear on next)
        assert _value(s, "GAP 201, 0") == 20
        s.run_tmcl("SAP 198, 0, 0", show=False)  # "Delete bit 2 of axis parameter 201"
        assert _value(s, "GAP 201, 0") == 16
        assert _value(s, "GAP 198, 0") == 0
        s.run_tmcl("SAP 198, 0, 1", show=False)  # "set bit 2 of axis parameter 201"
        assert _value(s, "GAP 201, 0") == 20
        s.run_tmcl("SAP 201, 0, 0", show=False)  # what AP 198 can leave behind is legal
        assert _value(s, "GAP 198, 0") == 0
        sent = s.stats.commands
        with pytest.raises(TmclError, match="out of range"):
            s.run_tmcl("SAP 201, 0, 5", show=False)  # bit 0 is not documented
        assert s.stats.commands == sent
    finally:
        s.client.close()


# -- .version against a responder written from the TMCM-1311 manual's byte tables ---------------

def _reply(opcode: int, value: int) -> bytes:
    """"Please use the normal reply format": host 2, module 1, status 100, opcode, value BE."""
    body = bytes((2, 1, 100, opcode)) + (value & 0xFFFFFFFF).to_bytes(4, "big")
    return body + bytes((sum(body) & 0xFF,))


def _responder(binary_value: int) -> tuple[int, threading.Thread]:
    """A TCP module: 136 type 0 answers '1311V111' (host address + 8 characters, no checksum),
    136 type 1 answers ``binary_value``; anything else status 100, value 0."""
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(10)

    def serve() -> None:
        with server:
            conn, _ = server.accept()
            with conn:
                conn.settimeout(10)
                buf = b""
                while True:
                    try:
                        data = conn.recv(64)
                    except OSError:
                        return
                    if not data:
                        return
                    buf += data
                    while len(buf) >= 9:
                        frame, buf = buf[:9], buf[9:]
                        if frame[1] == 136 and frame[2] == 0:
                            conn.sendall(b"\x02" + b"1311V111")
                        elif frame[1] == 136:
                            conn.sendall(_reply(136, binary_value))
                        else:
                            conn.sendall(_reply(frame[1], 0))

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return server.getsockname()[1], thread


@pytest.mark.parametrize("binary, agrees", [(0x051F6F00, True), (0x051F7000, False)])
def test_version_shows_the_binary_bytes_and_checks_them_against_the_string(
        run_tmclsh, binary, agrees):
    port, thread = _responder(binary)
    out = run_tmclsh("--port", f"socket://127.0.0.1:{port}", "-m", "TMCM-1311", "-c",
                     ".version", timeout=30)
    thread.join(5)
    text = out.stdout + out.stderr
    lines = [line for line in text.splitlines() if line.strip()]
    first = next(line for line in lines if line.startswith("firmware"))
    binary_line = next(line for line in lines if "136 type 1" in line)
    assert first.startswith("firmware 1311V111") and "136 type 1" not in first
    raw = " ".join(f"{b:02X}" for b in binary.to_bytes(4, "big"))
    assert raw in binary_line and "module type 1311 (05 1F)" in binary_line
    version = (binary >> 8) & 0xFF
    assert f"version {version} ({version:02X} 00, low byte first)" in binary_line
    if agrees:
        assert "the same as the string" in binary_line
    else:
        assert "does not match the string" in binary_line
        assert "111" not in binary_line.split(":", 1)[1]  # never both versions on one line
