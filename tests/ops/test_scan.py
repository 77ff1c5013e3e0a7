"""``tmclsh scan`` (modules on an RS485 line or a CAN bus), ``tmclsh ports``, and how the CLI
picks a connection (``open_transport``)."""

from __future__ import annotations

import json
import uuid

import pytest
from serial.tools import list_ports
from serial.tools.list_ports_common import ListPortInfo

from tmclsh.cli import main as cli
from tmclsh.client import connect as connection
from tmclsh.base.errors import ConnectError
from tmclsh.tmcl.frames import Reply, Request
from tmclsh.sim import SimBus, Simulator
from tmclsh.sim.serve import serve_can


@pytest.fixture
def rs485_line(make_pty_sim):
    """A TMCM-1311 at address 1 and a TMCM-351 at address 3 on one pty-served line."""
    bus = SimBus([Simulator("TMCM-1311", 1), Simulator("TMCM-351", 3)])
    return make_pty_sim(target=bus)


def test_scan_lists_the_modules_on_an_rs485_line(rs485_line, run_tmclsh):
    bus, path = rs485_line
    p = run_tmclsh("scan", "--port", path, "--to", "5")
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert len(lines) == 2, p.stdout
    assert lines[0].split() == ["address", "1", "TMCM-1311", "firmware", "1311V111"]
    assert lines[1].split() == ["address", "3", "TMCM-351", "firmware", "0351V103"]
    assert "scanning addresses 1..5" in p.stderr


def test_scan_json_and_range(rs485_line, run_tmclsh):
    bus, path = rs485_line
    p = run_tmclsh("scan", "--port", path, "--from", "2", "--to", "4", "--json")
    assert p.returncode == 0, p.stderr
    rows = [json.loads(line) for line in p.stdout.splitlines()]
    assert rows == [{"address": 3, "module": "TMCM-351", "version": "0351V103"}]


def test_scan_finding_nothing_fails(rs485_line, run_tmclsh):
    bus, path = rs485_line
    p = run_tmclsh("scan", "--port", path, "--from", "4", "--to", "6", "--timeout", "0.02")
    assert p.returncode == 3 and p.stdout == ""
    assert f"nothing answered; tried addresses 4..6 on {path} @ 9600 (20 ms each)" in p.stderr
    assert "--baud auto" in p.stderr
    # the timeout given before the subcommand is the same option, not lost
    p = run_tmclsh("--timeout", "0.03", "scan", "--port", path, "--from", "4", "--to", "5")
    assert p.returncode == 3 and "(30 ms each)" in p.stderr, p.stderr


def test_scan_over_python_can_virtual(monkeypatch, capsys):
    monkeypatch.setenv("TMCLSH_CONFIG", "/dev/null")
    channel = f"scan-{uuid.uuid4().hex[:8]}"
    sims = [Simulator("TMCM-1311", 1), Simulator("TMCM-351", 3)]
    # every module leaves the factory with CAN ID 1 (GP 71): give the second its own first,
    # over its serial port, as a technician would before putting it on the bus
    sims[1].write(Request(3, 9, 71, 0, 3).to_bytes())
    assert Reply.from_bytes(sims[1].read(1.0)).ok and sims[1].can_id == 3
    servers = [serve_can(s, "virtual", channel) for s in sims]
    try:
        rc = cli.main(["scan", "--can", f"virtual:{channel}", "--to", "4", "--json"])
    finally:
        for server, sim in zip(servers, sims):
            server.close()
            sim.close()
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert [json.loads(line) for line in out.splitlines()] == [
        {"address": 1, "module": "TMCM-1311", "version": "1311V111"},
        {"address": 3, "module": "TMCM-351", "version": "0351V103"}]
    assert "scanning CAN ids 1..4" in err


def test_the_wait_the_reported_baud_and_baud_auto_ask_one_question(pty_sim):
    """scan.line_baud says whether a link has a baud rate; the first pass's wait adds wire
    time exactly when it has one, and ``--baud auto`` refuses exactly the links without."""
    from tmclsh.ops import scan
    from tmclsh.link import open_sim
    from tmclsh.link.base import CanTransport
    from tmclsh.link.serial import SerialTransport

    class Can(CanTransport):
        open = close = send = recv = lambda *a: None
        is_open = True

    _, pty_path = pty_sim
    sim = open_sim("TMCM-1311")
    try:
        links = {"pty": SerialTransport(pty_path, 19200), "rs485": SerialTransport("/dev/ttyUSB7"),
                 "tcp": SerialTransport("socket://127.0.0.1:1"), "sim": sim, "can": Can("x:y"),
                 # a serial port on a server: its baud rate is set through RFC 2217
                 "rfc2217": SerialTransport("rfc2217://127.0.0.1:1", 9600)}
        bauds = {k: scan.line_baud(t) for k, t in links.items()}
        waits = {k: scan.address_timeout(t) for k, t in links.items()}
    finally:
        sim.close()
    assert bauds == {"pty": 19200, "rs485": 9600, "tcp": None, "sim": None, "can": None,
                     "rfc2217": 9600}
    assert waits["rfc2217"] == pytest.approx(scan.wire_time(9600) + scan.MARGIN_USB
                                             + scan.MARGIN_RS485)
    assert waits["pty"] == pytest.approx(scan.wire_time(19200) + scan.MARGIN_LOCAL)
    assert waits["rs485"] == pytest.approx(scan.wire_time(9600) + scan.MARGIN_RS485)
    assert (waits["tcp"], waits["sim"], waits["can"]) == (
        scan.MARGIN_USB * 2, scan.MARGIN_LOCAL, scan.CAN_TIMEOUT)


@pytest.mark.parametrize("argv", [["--sim", "TMCM-351", "scan"], ["--sim", "scan"],
                                  ["--json", "--sim", "TMCM-351", "scan"]])
def test_connection_options_before_scan_reach_it(run_tmclsh, argv):
    """The scan subcommand's own copies of the options, not given, reset those given before
    it: `tmclsh --sim TMCM-351 scan` looked for an attached module (exit 3)."""
    p = run_tmclsh(*argv, "--to", "2")
    assert p.returncode == 0, p.stderr
    module = "TMCM-351" if "TMCM-351" in argv else "TMCM-1311"
    if "--json" in argv:
        assert json.loads(p.stdout)["module"] == module
    else:
        assert p.stdout.split()[:3] == ["address", "1", module]


def test_two_links_named_around_scan_are_a_usage_error(run_tmclsh):
    p = run_tmclsh("--sim", "scan", "--port", "/dev/null")
    assert p.returncode == 2 and p.stdout == ""
    assert p.stderr == "tmclsh: --port and --sim both name the link; give one of them\n"


def test_scan_rejects_an_empty_range(run_tmclsh):
    p = run_tmclsh("scan", "--sim", "--from", "5", "--to", "2")
    assert p.returncode == 1 and "above" in p.stderr


# -- ports -----------------------------------------------------------------------------------------

def _port(device: str, vid=None, pid=None, description="n/a", serial=None) -> ListPortInfo:
    p = ListPortInfo(device)
    p.vid, p.pid, p.description, p.serial_number = vid, pid, description, serial
    return p


@pytest.fixture
def fake_ports(monkeypatch):
    """What the operating system reports as serial ports (pyserial's own data objects)."""
    ports: list[ListPortInfo] = []
    monkeypatch.setattr(list_ports, "comports", lambda *a, **k: list(ports))
    monkeypatch.setenv("TMCLSH_CONFIG", "/dev/null")
    for var in ("TMCLSH_PORT", "TMCLSH_CAN", "TMCLSH_PROFILE"):
        monkeypatch.delenv(var, raising=False)
    return ports


def test_ports_lists_usb_ids_and_marks_trinamic_first(fake_ports, capsys):
    fake_ports += [_port("/dev/ttyS0"),
                   _port("/dev/ttyUSB0", 0x0403, 0x6001, "FT232R USB UART", "A50285BI"),
                   _port("/dev/ttyACM1", 0x2A3C, 0x0100, "TMCM-1311", "0042")]
    assert cli.main(["ports"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["/dev/ttyACM1", "2a3c:0100", "TMCM-1311", "serial", "0042",
                                "[TRINAMIC]"]
    assert lines[1].split() == ["/dev/ttyS0", "-"]
    assert "ftdi" not in lines[2].lower() and lines[2].split()[:2] == ["/dev/ttyUSB0", "0403:6001"]
    assert "TRINAMIC" not in lines[2]
    assert cli.main(["--json", "ports"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert rows[0] == {"device": "/dev/ttyACM1", "vid": 0x2A3C, "pid": 0x100,
                       "description": "TMCM-1311", "serial": "0042", "trinamic": True}
    assert rows[1]["trinamic"] is False and rows[1]["description"] is None


def test_ports_with_none_found(fake_ports, capsys):
    assert cli.main(["ports"]) == 0
    assert "no serial ports found" in capsys.readouterr().err


# -- which connection the CLI opens ----------------------------------------------------------

def test_default_connection_is_the_one_attached_trinamic_module(fake_ports, pty_sim):
    sim, path = pty_sim
    fake_ports += [_port("/dev/ttyS0"), _port(path, 0x2A3C, 0x0100, "TMCM-1311")]
    settings = {"baud": 9600, "address": 1, "host_address": 2, "timeout": 0.5, "retries": 2}
    client = connection.open_client(settings)
    try:
        assert settings["port"] == path and not client.transport.simulated
        assert client.module.name == "TMCM-1311"  # identified with 136
        assert client.send(6, 1, 0).ok
    finally:
        client.close()


def test_two_attached_modules_are_named_never_guessed(fake_ports):
    fake_ports += [_port("/dev/ttyACM0", 0x2A3C, 1, "TMCM-1311", "0042"),
                   _port("/dev/ttyACM1", 0x2A3C, 1, "TMCM-351")]
    for fallback in (False, True):  # the interactive shell does not pick one either
        with pytest.raises(ConnectError, match=r"2 Trinamic USB modules attached: "
                           r"/dev/ttyACM0 \(TMCM-1311, serial 0042\), /dev/ttyACM1 \(TMCM-351\); "
                           "pick one with --port"):
            connection.open_transport({"address": 1}, fallback=fallback)


def test_no_module_falls_back_to_the_simulator_only_when_asked(fake_ports):
    with pytest.raises(ConnectError, match="no module found.*--sim to simulate"):
        connection.open_transport({"address": 0})
    settings: dict = {"address": 0, "host_address": 5}
    t = connection.open_transport(settings, fallback=True)
    try:
        assert t.simulated and settings["sim"] == "TMCM-1311"
        assert t.simulator.address == 0 and t.simulator.host_address == 5  # 0 is an address
    finally:
        t.close()


def test_open_client_uses_the_settings(pty_sim):
    sim, path = pty_sim
    client = connection.open_client({"port": path, "baud": 115200, "module": "TMCM-1311", "address": 1,
                              "host_address": 2, "timeout": 0.25, "retries": 0})
    try:
        assert (client.timeout, client.retries) == (0.25, 0)
        assert client.describe() == f"{path} @ 115200"
    finally:
        client.close()


# -- what a scan must not miss or miscount (issue 23) ---------------------------------------

@pytest.fixture
def responders():
    from responder import Responder

    made: list[Responder] = []

    def make(cls, **kw):
        made.append(cls(**kw))
        return made[-1]

    yield make
    for m in made:
        m.close()


def test_scan_finds_a_module_in_ascii_mode_and_leaves_it_so(run_tmclsh, responders):
    """A module that starts in ASCII mode ignores the binary probes: nothing answered in
    binary, so the addresses are asked on the ASCII command line (the bring-up's probe)."""
    from responder import AsciiModeModule

    m = responders(AsciiModeModule, address=2)
    p = run_tmclsh("scan", "--port", m.path, "--to", "4", "--json")
    assert p.returncode == 0, p.stderr
    assert [json.loads(line) for line in p.stdout.splitlines()] == [
        {"address": 2, "module": "TMCM-1311", "version": "1311V111", "mode": "ascii"}]
    assert m.ascii and m.modes[-1] == "ascii"  # stepped out for 136, and back


def test_ascii_scan_on_a_mixed_line(make_pty_sim, run_tmclsh):
    """`tmclsh --ascii scan` also asks the addresses silent in binary when others answered."""
    bus = SimBus([Simulator("TMCM-1311", 1, ascii_startup=True), Simulator("TMCM-351", 3)])
    _, path = make_pty_sim(target=bus)
    plain = run_tmclsh("scan", "--port", path, "--to", "4")
    assert plain.returncode == 0 and plain.stdout.split()[:2] == ["address", "3"], plain.stderr
    p = run_tmclsh("scan", "--ascii", "--port", path, "--to", "4")
    assert p.returncode == 0, p.stderr
    assert [line.split() for line in p.stdout.splitlines()] == [
        ["address", "3", "TMCM-351", "firmware", "0351V103"],
        ["address", "1", "TMCM-1311", "firmware", "1311V111", "ASCII", "mode"]]
    assert bus.simulators[0].ascii_active


def test_two_modules_at_one_address_are_said(run_tmclsh, responders):
    from responder import TwoAtOneAddress

    m = responders(TwoAtOneAddress)
    p = run_tmclsh("scan", "--port", m.path, "--to", "3", "--json")
    assert p.returncode == 0, p.stderr
    rows = [json.loads(line) for line in p.stdout.splitlines()]
    assert [(r["address"], r.get("answers")) for r in rows] == [(1, 2)]
    assert "two modules answer at address 1" in p.stderr
    assert "2 modules found at 1 (two)" in p.stderr  # (both counted)


def test_the_simulated_bus_with_a_shared_address(run_tmclsh):
    """`tmclsh sim --pty --address 1,2,2` as the second witness: 2 is shared, 1 is not."""
    import subprocess
    import sys

    from conftest import ROOT, tmclsh_env

    sim = subprocess.Popen([sys.executable, "-m", "tmclsh", "sim", "--pty", "--address",
                            "1,2,2"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                           stdin=subprocess.DEVNULL, text=True, env=tmclsh_env(), cwd=str(ROOT))
    try:
        path = sim.stdout.readline().strip()
        p = run_tmclsh("scan", "--port", path, "--to", "3")
    finally:
        sim.terminate()
        sim.wait(5)
    assert p.returncode == 0, p.stderr
    assert [line.split()[1] for line in p.stdout.splitlines()] == ["1", "2"]
    assert "TWO MODULES" in p.stdout.splitlines()[1]
    assert "TWO MODULES" not in p.stdout.splitlines()[0]


def test_baud_auto_where_the_rate_has_no_effect_reports_each_module_once(make_pty_sim,
                                                                         run_tmclsh):
    """The simulator on a pty answers at any rate the port is set to: found at 9600 and
    answering at 14400 too, it is reported once and the other rates are not scanned."""
    _, path = make_pty_sim(target=SimBus([Simulator("TMCM-1311", 1),
                                          Simulator("TMCM-351", 3)]))
    p = run_tmclsh("scan", "--port", path, "--baud", "auto", "--to", "4", "--json")
    assert p.returncode == 0, p.stderr
    rows = [json.loads(line) for line in p.stdout.splitlines()]
    assert [(r["address"], r["baud"]) for r in rows] == [(1, 9600), (3, 9600)]
    assert "answer at 14400 too: the baud rate has no effect" in p.stderr
    assert sum(line.startswith("scanning") for line in p.stderr.splitlines()) == 1


def test_baud_auto_over_tcp_scans_once(run_tmclsh, responders):
    from responder import TcpModule

    m = responders(TcpModule, version="1311V111", address=2)
    p = run_tmclsh("scan", "--port", m.url, "--baud", "auto", "--to", "3")
    assert p.returncode == 0, p.stderr
    assert [line.split()[:3] for line in p.stdout.splitlines()] == [["address", "2",
                                                                     "TMCM-1311"]]
    assert "bytes over TCP carry no baud rate): one pass" in p.stderr


def test_the_ascii_pass_waits_for_the_padded_probe_its_echo_and_the_reply():
    """The probe line is padded to whole nine-byte blocks (issue 31): the wait per address
    in the ASCII pass counts its bytes as they are on the wire."""
    from tmclsh.client.ascii import MAX_ADDRESS, ascii_probe_line
    from tmclsh.ops.scan import ASCII_WIRE_BYTES

    longest = max(len(ascii_probe_line(a)) for a in range(1, MAX_ADDRESS + 1))
    assert ASCII_WIRE_BYTES >= 2 * longest + len(b"BA 100 33\r")


def test_scan_of_a_module_in_ascii_mode_says_nothing_of_checksums(run_tmclsh, responders):
    """A scan reads nothing twice: the paragraph about ASCII reads is not its to say."""
    from responder import AsciiModeModule

    m = responders(AsciiModeModule, address=1)
    p = run_tmclsh("scan", "--port", m.path, "--to", "3")
    assert p.returncode == 0, p.stderr
    assert "TMCM-1311" in p.stdout and "checksum" not in p.stderr + p.stdout, p.stderr
