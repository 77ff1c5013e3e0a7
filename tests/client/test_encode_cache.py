"""The client keeps the checked form of lines it has seen (LineClient.prepare), so a script or a
watch that repeats a line pays the parser once: what is sent stays what the line says, for
the module, mode and address of the moment."""

from __future__ import annotations

import pytest

from tmclsh.tmcl import asmline as asm  # (where the client reads a line: parse_line, encode)
from tmclsh.client import text as client_module
from tmclsh.client.ascii import AsciiLink
from tmclsh.base.errors import AsmError, TmclTimeoutError
from tmclsh.tmcl.modules import load
from tmclsh.tmcl.frames import Instruction
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session

SAP, GAP = 5, 6


@pytest.fixture
def counted(monkeypatch):
    """Every asm.encode call, as (line text, ascii)."""
    calls: list[tuple[str, bool]] = []
    real = asm.encode

    def encode(line, module, symbols=None, **kw):
        calls.append((line.text, kw.get("ascii", False)))
        return real(line, module, symbols, **kw)

    monkeypatch.setattr(asm, "encode", encode)
    return calls


def test_a_repeated_line_is_parsed_once_and_sends_the_same_frame(client, counted):
    frames = []
    client.add_tracer(lambda d, raw, decoded: frames.append(raw) if d == "tx" else None)
    values = [client.execute("SAP 4, 0, 1234").reply.status for _ in range(5)]
    assert values == [100] * 5
    assert counted == [("SAP 4, 0, 1234", False)]
    assert len(set(frames)) == 1 and len(frames) == 5
    assert client.value("GAP 4, 0") == 1234


def test_a_refused_line_is_refused_every_time_and_never_sent(client, counted):
    before = client.stats["sent"]
    for _ in range(3):
        with pytest.raises(AsmError, match="no motor 7"):
            client.execute("GAP 1, 7")
    assert client.stats["sent"] == before and len(counted) == 3


def test_another_module_checks_the_line_again(client):
    client.execute("SAP 5, 0, 1000")  # MaxAcceleration exists on the TMCM-1311
    client.module = load("TMCM-1640")  # ... and not on the TMCM-1640
    with pytest.raises(AsmError):
        client.execute("SAP 5, 0, 1000")
    client.module = load("TMCM-1311")
    assert client.execute("SAP 5, 0, 1000").ok


def test_another_mode_checks_the_line_again(client, counted):
    client.execute("GAP 1, 0")
    AsciiLink.attach(client)
    assert client.mode == "ascii"
    client.execute("GAP 1, 0")
    assert counted == [("GAP 1, 0", False), ("GAP 1, 0", True)]


def test_another_address_gets_its_own_request(make_pty_sim):
    from tmclsh.client.text import LineClient
    from tmclsh.link import open_serial

    sim, path = make_pty_sim(address=3)
    c = LineClient(open_serial(path), address=1, module="TMCM-1311", timeout=0.2, retries=0)
    try:
        with pytest.raises(TmclTimeoutError):
            c.execute("GAP 1, 0")  # nobody at address 1
        c.address = 3
        assert c.execute("GAP 1, 0").ok
    finally:
        c.close()


def test_the_cache_is_bounded(client, monkeypatch):
    monkeypatch.setattr(client_module, "ENCODE_CACHE", 8)
    for v in range(20):
        client.prepare(f"SAP 4, 0, {v}")
    assert len(client._encoded) <= 8
    enc, req = client.prepare("SAP 4, 0, 19")
    assert req.value == 19 and enc.instruction == Instruction(SAP, 4, 0, 19)


def test_variables_are_expanded_before_the_cache(client, counted):
    session = Session(client, Output())
    for speed in (100, 200, 100):
        session.variables["speed"] = speed
        session.run_line("SAP 4, 0, ${speed}")
        assert client.value("GAP 4, 0") == speed
    assert [text for text, _ in counted if text.startswith("SAP")] == ["SAP 4, 0, 100",
                                                                     "SAP 4, 0, 200"]
