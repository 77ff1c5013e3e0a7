"""CAN the way python-can users set it up: --bitrate, --can alone (python-can's own
configuration), channels with colons, against a responder written from the manual's CAN frame
description (tests/responder.py) on python-can's virtual bus, in process."""

from __future__ import annotations

import json
import subprocess
import sys

import can
import pytest

from conftest import tmclsh_env
from responder import CanModule
from tmclsh.cli import main as cli
from tmclsh.sim import Simulator
from tmclsh.sim.serve import serve_can


@pytest.fixture
def bus_kwargs(monkeypatch):
    """What tmclsh hands to python-can's Bus (the real one is still made)."""
    seen: list[dict] = []
    real = can.Bus

    def spy(*args, **kw):
        seen.append(dict(kw))
        return real(*args, **kw)

    monkeypatch.setattr(can, "Bus", spy)
    return seen


def _module(channel: str, **kw) -> CanModule:
    return CanModule(can.Bus(interface="virtual", channel=channel), **kw)


def _isolate(monkeypatch, tmp_path):
    monkeypatch.setenv("TMCLSH_CONFIG", str(tmp_path / "none.toml"))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))
    for var in ("TMCLSH_CAN", "TMCLSH_PORT", "TMCLSH_PROFILE", "CAN_INTERFACE", "CAN_CHANNEL",
                "CAN_BITRATE"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.chdir(tmp_path)  # no ./can.ini of the checkout's


def test_bitrate_reaches_python_can_and_the_module_answers(monkeypatch, tmp_path, capsys,
                                                           bus_kwargs):
    _isolate(monkeypatch, tmp_path)
    m = _module("reach-a", version="1311V111")
    try:
        rc = cli.main(["--can", "virtual:reach-a", "--bitrate", "1000000", "--json", "-c",
                       "SAP 4, 0, 777; GAP 4, 0"])
        out = capsys.readouterr()
        assert rc == 0, out.err
        assert json.loads(out.out.splitlines()[-1])["reply"] == 777
        assert m.got == [(136, 0, 0, 0), (10, 129, 0, 0), (5, 4, 0, 777), (6, 4, 0, 0)]
        ours = [kw for kw in bus_kwargs if kw.get("channel") == "reach-a"]
        assert ours and ours[-1]["bitrate"] == 1000000
    finally:
        m.close()


def test_can_alone_takes_python_cans_configuration(monkeypatch, tmp_path, capsys, bus_kwargs):
    _isolate(monkeypatch, tmp_path)
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", "reach:b:1")  # colons in the channel, as IPv6 groups have
    monkeypatch.setenv("CAN_BITRATE", "500000")
    m = _module("reach:b:1", version="1161V130")  # and a type without data: generic mode
    try:
        rc = cli.main(["--can", "--json", "-c", "GAP 1, 0"])
        out = capsys.readouterr()
        assert rc == 0, out.err
        assert json.loads(out.out)["reply"] == 0 and m.got[-1] == (6, 1, 0, 0)
        assert "no parameter data" in out.err
        ours = [kw for kw in bus_kwargs if kw.get("channel") == "reach:b:1" and
                kw.get("interface") == "virtual"]
        assert ours[-1]["bitrate"] == 500000
    finally:
        m.close()


def test_can_alone_reads_the_config_file(monkeypatch, tmp_path, capsys):
    _isolate(monkeypatch, tmp_path)
    monkeypatch.setenv("HOME", str(tmp_path))
    (tmp_path / "can.conf").write_text("[default]\ninterface = virtual\nchannel = reach-c\n")
    m = _module("reach-c")
    try:
        rc = cli.main(["--can", "-c", "GAP 4, 0"])
        assert rc == 0, capsys.readouterr().err
        assert m.got[-1] == (6, 4, 0, 0)
    finally:
        m.close()


def test_can_alone_without_configuration_says_what_to_set(monkeypatch, tmp_path, capsys):
    _isolate(monkeypatch, tmp_path)
    monkeypatch.setenv("HOME", str(tmp_path))
    rc = cli.main(["--can", "-c", "GAP 4, 0"])
    err = capsys.readouterr().err
    assert rc == 3 and "CAN_INTERFACE" in err and "names no interface" in err


def test_can_alone_without_configuration_scan_exits_as_c_does(monkeypatch, tmp_path, capsys):
    _isolate(monkeypatch, tmp_path)
    monkeypatch.setenv("HOME", str(tmp_path))
    rc = cli.main(["--can", "scan"])
    err = capsys.readouterr().err
    assert rc == 3 and "names no interface" in err  # was 1: 'a command failed'


def test_channel_with_colons_on_the_command_line(monkeypatch, tmp_path, capsys):
    _isolate(monkeypatch, tmp_path)
    m = _module("bench:1")
    try:
        assert cli.main(["--can", "virtual:bench:1", "-c", "GAP 4, 0"]) == 0
        assert m.got[-1] == (6, 4, 0, 0)
    finally:
        m.close()


def test_profile_bitrate(monkeypatch, tmp_path, capsys, bus_kwargs):
    _isolate(monkeypatch, tmp_path)
    cfg = tmp_path / "config.toml"
    cfg.write_text('[profiles.can]\ncan = "virtual:reach-d"\nbitrate = 250000\n')
    monkeypatch.setenv("TMCLSH_CONFIG", str(cfg))
    m = _module("reach-d")
    try:
        assert cli.main(["--profile", "can", "-c", "GAP 4, 0"]) == 0, capsys.readouterr().err
        assert [kw for kw in bus_kwargs if kw.get("channel") == "reach-d"][-1]["bitrate"] == 250000
    finally:
        m.close()


@pytest.mark.parametrize("argv", [["--can", "can0", "-c", "GAP 1, 0"],
                                  ["--can", ":x", "-c", "GAP 1, 0"],
                                  ["--profile", "nosuch", "-c", "GAP 1, 0"]])
def test_malformed_can_and_unknown_profile_are_usage_errors(argv, monkeypatch, tmp_path, capsys):
    _isolate(monkeypatch, tmp_path)
    assert cli.main(argv) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_sim_reads_iface_channel_as_the_client_does(tmp_path):
    """The server's endpoint line is the spec as parsed; a channel keeps its colons."""
    p = subprocess.Popen([sys.executable, "-m", "tmclsh", "sim", "--can", "virtual:grp:ff15::1"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=tmclsh_env())
    try:
        assert p.stdout.readline().strip() == "virtual:grp:ff15::1"
    finally:
        p.terminate()
        p.wait(10)
    from tmclsh.link import parse_can

    assert parse_can("virtual:grp:ff15::1") == ("virtual", "grp:ff15::1")


def test_sim_that_cannot_start_is_3_and_bad_arguments_2(run_tmclsh):
    assert run_tmclsh("sim", "--can", "nosuchiface:x").returncode == 3
    assert run_tmclsh("sim", "--can", "nocolon").returncode == 2
    assert run_tmclsh("sim", "--tcp", "127.0.0.1:notaport").returncode == 2


def test_help_offers_what_works_across_processes(run_tmclsh):
    out = " ".join(run_tmclsh("--help").stdout.split())
    assert "virtual:bench" not in out
    assert "one process only" in out or "inside one process" in out
    assert "1000000" in out and "GP 69" in out
    sim_help = " ".join(run_tmclsh("sim", "--help").stdout.split())
    assert "virtual" in sim_help and "another process" in sim_help
    assert "Windows" in sim_help


@pytest.mark.parametrize("argv", [["--can", "scan"], ["scan", "--can"]])
def test_can_alone_before_or_after_scan_scans_the_configured_bus(monkeypatch, tmp_path,
                                                                  capsys, argv):
    """`tmclsh --can scan` took `scan` for the CAN spec (a usage error, no scan)."""
    _isolate(monkeypatch, tmp_path)
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", "reach-scan")
    sim = Simulator("TMCM-1311", 1)
    server = serve_can(sim, "virtual", "reach-scan")
    try:
        rc = cli.main([*argv, "--to", "2", "--json"])
    finally:
        server.close()
        sim.close()
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert [json.loads(line) for line in out.splitlines()] == [
        {"address": 1, "module": "TMCM-1311", "version": "1311V111"}]
    assert "scanning CAN ids 1..2 on CAN virtual:reach-scan" in err


@pytest.mark.parametrize("eighth", ["sum", "zero"])
def test_replies_with_eight_data_bytes_are_taken(eighth):
    """Some modules answer with DLC 8 (a TMCM-1260 candump in PyTrinamic's tracker): the
    eighth byte, their sum or padding, is left out; the value is the seven bytes' as ever."""
    import can

    from responder import CanModule

    from tmclsh.client.connect import connect

    bus = can.Bus(interface="virtual", channel=f"eight-{eighth}")
    m = CanModule(bus, version="1311V111", eighth=eighth)
    m.values[(4, 0, False)] = 51200
    c = connect(can=f"virtual:eight-{eighth}", timeout=0.5)
    try:
        assert c.module.name == "TMCM-1311"
        assert c.value("GAP 4, 0") == 51200 and c.execute("SAP 4, 0, 1000").ok
        assert c.stats["discarded"] == 0
    finally:
        c.close()
        m.close()
