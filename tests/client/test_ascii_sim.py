"""ASCII mode as a transport, against the simulator: in process (``SimTransport``) and through
a pty served by ``serve_pty`` and opened with pyserial, plus the CLI in a subprocess.

Covered: all three echo modes, start-up in ASCII mode, 139 and BIN, RUN and STOP, backspace in
character-echo mode, a module at address 3, a host address other than 2, and that the mode
probes execute nothing in either mode.
"""

from __future__ import annotations

import json
import time

import pytest

from tmclsh.tmcl import asm
from tmclsh.client.ascii import (AsciiLink, Echo, Mode, ascii_probe_bytes, probe_frame, probe_mode)
from tmclsh.client.text import LineClient
from tmclsh.base.errors import StatusError, TmclTimeoutError, ValidationError
from tmclsh.tmcl.decoder import FRAME_PIECE, pieces
from tmclsh.tmcl.frames import Control, Reply, Request, Status
from tmclsh.sim import Simulator
from tmclsh.link.sim import SimTransport

TIMEOUT = 0.25
GAP, SAP, SGP, GGP = 6, 5, 9, 10


@pytest.fixture
def make():
    """``make(**simulator_kwargs) -> (sim, client)`` in process; everything closed after."""
    made: list[tuple[Simulator, LineClient]] = []

    def factory(address: int = 1, host_address: int = 2, client_host: int | None = None,
                module: str | None = "TMCM-1311", **kw) -> tuple[Simulator, LineClient]:
        sim = Simulator("TMCM-1311", address, host_address=host_address, **kw)
        t = SimTransport("TMCM-1311", address, simulator=sim)
        client = LineClient(t, address=address, module=module, timeout=TIMEOUT, retries=0,
                        host_address=host_address if client_host is None else client_host)
        made.append((sim, client))
        return sim, client

    yield factory
    for sim, client in made:
        client.close()
        sim.close()


def set_echo(client: LineClient, echo: Echo) -> None:
    """GP 67 echo bits, written in binary mode before attaching."""
    reply = client.request(Request(client.address, SGP, 67, 0, int(echo) << 4))
    assert reply is not None and reply.status == Status.OK


# -- in process ----------------------------------------------------------------------------------

@pytest.mark.parametrize("echo", [Echo.CHAR, Echo.LINE, Echo.NONE])
def test_echo_modes(make, echo):
    sim, client = make()
    set_echo(client, echo)
    link = AsciiLink.attach(client)
    assert sim.ascii_active and client.mode == "ascii"
    assert link.echo == echo and link.found == Mode.BINARY and link.entered
    for value in (-5000, 0, 123456):
        assert client.execute(f"SAP 1, 0, {value}").ok
        assert client.value("GAP 1, 0") == value
    # each GAP's answer is byte for byte the SAP's before it: on ASCII, where a reply names
    # no command, that may be a late copy of it, so the GAP is read once more (Client._judge)
    expected_echo_lines = 0 if echo == Echo.NONE else 9
    assert link.stats["echo_lines"] == expected_echo_lines
    assert link.stats["dropped_lines"] == 0
    client.close()
    assert not sim.ascii_active  # found in binary mode: BIN sent at exit


def test_replies_equal_binary_replies(make):
    sim, client = make()
    requests = [Request(1, SAP, 4, 0, 1234), Request(1, GAP, 4, 0, 0), Request(1, GGP, 76, 0, 0),
                Request(1, 15, 0, 0, 0), Request(1, GAP, 1, 0, 0), Request(1, SAP, 140, 0, 99)]
    binary = [client.request(r) for r in requests]
    AsciiLink.attach(client)
    over_ascii = [client.request(r) for r in requests]
    assert over_ascii == binary
    assert binary[-1].status == Status.INVALID_VALUE  # error statuses come through the same


def test_change_echo_mode_while_in_ascii(make):
    sim, client = make()
    link = AsciiLink.attach(client)
    assert link.echo == Echo.CHAR
    for echo in (Echo.LINE, Echo.NONE, Echo.CHAR):
        assert client.request(Request(1, SGP, 67, 0, int(echo) << 4)).ok
        assert link.refresh_echo() == echo
        assert client.value("GAP 1, 0") == 0


def test_startup_in_ascii_mode(make):
    sim, client = make(ascii_startup=True)
    assert sim.ascii_active
    assert probe_mode(client).mode == Mode.ASCII
    link = AsciiLink.attach(client)
    assert link.found == Mode.ASCII and not link.entered
    assert link.gp67 == 1
    assert client.value("GGP 67, 0") == 1
    client.close()
    assert sim.ascii_active  # found in ASCII mode: stays there


def test_startup_in_ascii_mode_unknown_module(make):
    """136 does not exist in ASCII mode: attach steps out with BIN, identifies, and goes back."""
    sim, client = make(ascii_startup=True, module=None)
    link = AsciiLink.attach(client)
    assert client.module is not None and client.module.name == "TMCM-1311"
    assert link.found == Mode.ASCII and sim.ascii_active
    client.close()
    assert sim.ascii_active


def test_bin_and_back(make):
    sim, client = make()
    link = AsciiLink.attach(client)
    link.detach()
    assert not sim.ascii_active and client.mode == "binary"
    assert client.request(Request(1, Control.GET_VERSION, 0, 0, 0)).version.startswith("1311")
    assert AsciiLink.attach(client) is link and sim.ascii_active
    assert client.value("GAP 1, 0") == 0


def test_mode_found_is_restored_after_switching(make):
    sim, client = make(ascii_startup=True)
    link = AsciiLink.attach(client)
    link.detach()  # .mode binary
    assert not sim.ascii_active
    client.close()
    assert sim.ascii_active  # 139 sent at exit: left as found


def test_on_exit_override(make):
    sim, client = make()
    link = AsciiLink.attach(client)
    link.on_exit = Mode.ASCII  # told otherwise (.mode ascii --keep)
    client.close()
    assert sim.ascii_active


def _upload(client: LineClient, source: str) -> None:
    prog = asm.assemble(source, client.require_module())
    client._downloading = True
    try:
        assert client.request(Request(1, Control.START_DOWNLOAD, 0, 0, 0)).ok
        for ins in prog.instructions:
            assert client.request(Request(1, ins.opcode, ins.type, ins.motor, ins.value)).ok
        assert client.request(Request(1, Control.QUIT_DOWNLOAD, 0, 0, 0)).ok
    finally:
        client._downloading = False


def test_run_and_stop(make):
    sim, client = make()
    _upload(client, "Loop: SAP 4, 0, 1000\n WAIT TICKS, 0, 1\n JA Loop\n")
    link = AsciiLink.attach(client)
    assert sim.program_state == 0
    reply = link.run()
    assert reply.status == Status.OK and reply.opcode == Control.RUN_APPLICATION
    assert sim.program_state == 1
    assert client.value("GAP 4, 0") == 1000  # the shell keeps working while it runs
    link.stop_program()
    assert sim.program_state == 0


def test_a_sent_only_tracer_is_told_the_request_each_ascii_line_carries(make):
    """ASCII lines go out as text; a tracer that watches what is sent (the end-of-run note
    about motors left running) is told the request, RUN and STOP included."""
    sim, client = make()
    _upload(client, "Loop: SAP 4, 0, 1000\n WAIT TICKS, 0, 1\n JA Loop\n")
    link = AsciiLink.attach(client)
    sent = []
    client.add_tracer(lambda d, raw, dec: sent.append((d, dec)), sent_only=True)
    client.execute("ROR 0, 500")
    link.run()
    link.stop_program()
    assert sent == [("tx", Request(1, 1, 0, 0, 500)),
                    ("tx", Request(1, Control.RUN_APPLICATION, 0, 0, 0)),
                    ("tx", Request(1, Control.STOP_APPLICATION, 0, 0, 0))]


def test_refused_139_is_named(make):
    sim, client = make()
    client._downloading = True
    client.request(Request(1, Control.START_DOWNLOAD, 0, 0, 0))
    client._downloading = False
    with pytest.raises(StatusError, match=r"refused to enter ASCII mode \(139\): status 6"):
        AsciiLink.attach(client)  # in download mode 139 is not available
    assert client.mode == "binary" and not sim.ascii_active


def test_binary_only_commands_are_refused(make):
    sim, client = make()
    AsciiLink.attach(client)
    with pytest.raises(ValidationError, match=r"\.mode binary"):
        client.request(Request(1, Control.RESET_APPLICATION, 0, 0, 0))
    assert client.value("GAP 1, 0") == 0  # and the link is fine afterwards
    # 135 has a line that asks the same in ASCII mode (the instruction set's ascii_line)
    assert client.request(Request(1, Control.GET_STATUS, 0, 0, 0)).value == \
        client.value("GGP 128, 0")


def _collect(link: AsciiLink, until: bytes, timeout: float = 1.0) -> bytes:
    data = b""
    end = time.monotonic() + timeout
    while until not in data and time.monotonic() < end:
        data += link.read_raw(0.05)
    return data


def test_backspace_in_char_echo_mode(make):
    sim, client = make()
    client.request(Request(1, SAP, 1, 0, 77))
    link = AsciiLink.attach(client)
    assert link.echo == Echo.CHAR
    link.write_raw(b"AGAX\x08P 1, 0\r")  # a typo, erased with backspace
    data = _collect(link, b"BA 100 77\r")
    assert data == b"AGAX\b \bP 1, 0\rBA 100 77\r"
    link.write_raw(b"AGAP 1, 0\x7f\x7f\x7f2, 0\r")  # DEL erases too
    assert _collect(link, b"\rBA 100").endswith(b"BA 100 0\r")  # AP 2: target speed


def test_address_3_host_5(make):
    sim, client = make(address=3, host_address=5)
    link = AsciiLink.attach(client)
    assert client.execute("SAP 4, 0, 2000").ok
    reply = client.request(Request(3, GAP, 4, 0, 0))
    assert (reply.host, reply.module, reply.value) == (5, 3, 2000)
    link.write_raw(b"CGAP 4, 0\r")
    assert _collect(link, b"EC 100 2000\r").endswith(b"EC 100 2000\r")


def test_wrong_host_address_is_named(make):
    sim, client = make(host_address=5, client_host=2)
    with pytest.raises(ValidationError, match="--host-address 5"):
        AsciiLink.attach(client)


def test_wrong_host_address_in_ascii_mode_is_named(make):
    sim, client = make(host_address=4, client_host=2, ascii_startup=True)
    with pytest.raises(ValidationError, match="--host-address 4"):
        AsciiLink.attach(client)


def test_nobody_there(make):
    sim, client = make(address=1)
    client.address = 9
    with pytest.raises(TmclTimeoutError, match="binary or ASCII"):
        probe_mode(client, timeout=0.1)


def test_probes_execute_nothing():
    """The binary probe in ASCII mode, and the ASCII probe in binary mode, do nothing."""
    with Simulator("TMCM-1311", 1, ascii_startup=True) as sim:
        sim.write(probe_frame(1) + b"\r")
        time.sleep(0.05)
        assert sim.read(0.1) == b""  # unaddressed line: no echo, no reply
        assert sim.ascii_active
    with Simulator("TMCM-1311", 1) as sim:
        time.sleep(0.06)
        sim.write(ascii_probe_bytes(1))
        out = sim.read(0.1)
        found = list(pieces(out, 2))
        assert all(kind == FRAME_PIECE for kind, _ in found)  # (nothing at all, mostly)
        assert all(Reply.from_frame(raw).status == Status.WRONG_CHECKSUM for _, raw in found)
        assert not sim.ascii_active


# -- through a pty, with pyserial -------------------------------------------------------------------

def _serial_client(path: str, **kw) -> LineClient:
    from tmclsh.link import open_serial

    return LineClient(open_serial(path, 115200), module="TMCM-1311", timeout=0.5, retries=0, **kw)


@pytest.mark.parametrize("echo", [Echo.CHAR, Echo.LINE, Echo.NONE])
def test_pty_echo_modes(make_pty_sim, echo):
    sim, path = make_pty_sim()
    client = _serial_client(path)
    try:
        set_echo(client, echo)
        link = AsciiLink.attach(client)
        assert link.echo == echo
        client.execute("SAP 1, 0, -5000")
        assert client.value("GAP 1, 0") == -5000
        if echo == Echo.CHAR:
            link.write_raw(b"AGAX\bP 1, 0\r")
            assert _collect(link, b"BA 100 -5000\r") == b"AGAX\b \bP 1, 0\rBA 100 -5000\r"
    finally:
        client.close()
    assert not sim.ascii_active


def test_pty_startup_ascii_address_3_host_7(make_pty_sim):
    sim, path = make_pty_sim(address=3, host_address=7, ascii_startup=True)
    client = _serial_client(path, address=3, host_address=7)
    try:
        link = AsciiLink.attach(client)
        assert link.found == Mode.ASCII
        reply = client.request(Request(3, GGP, 76, 0, 0))
        assert (reply.host, reply.module, reply.value) == (7, 3, 7)
        assert link.run().ok  # empty program memory: it stops again at once
        assert link.stop_program().ok
        assert sim.program_state == 0
    finally:
        client.close()
    assert sim.ascii_active


def test_cli_ascii_prints_the_same(make_pty_sim, run_tmclsh):
    sim, path = make_pty_sim()
    lines = "SAP 1, 0, -5000; GAP 1, 0; GGP 67, 0; GIO 0, 0"
    plain = run_tmclsh("--port", path, "-c", lines)
    over_ascii = run_tmclsh("--port", path, "--ascii", "-c", lines)
    assert plain.returncode == 0, plain.stderr
    assert over_ascii.returncode == 0, over_ascii.stderr
    assert over_ascii.stdout == plain.stdout
    assert "-5000" in plain.stdout
    assert not sim.ascii_active  # BIN at exit
    js_plain = run_tmclsh("--port", path, "--json", "-c", "GAP 1, 0")
    js_ascii = run_tmclsh("--port", path, "--json", "--ascii", "-c", "GAP 1, 0")
    assert json.loads(js_ascii.stdout) == json.loads(js_plain.stdout)
    assert json.loads(js_plain.stdout)["reply"] == -5000


def test_cli_ascii_on_a_module_in_ascii_mode(make_pty_sim, run_tmclsh):
    sim, path = make_pty_sim(ascii_startup=True)
    res = run_tmclsh("--port", path, "--ascii", "-c", "GAP 1, 0")
    assert res.returncode == 0, res.stderr
    assert sim.ascii_active  # found in ASCII mode: left there
    res = run_tmclsh("--port", path, "--ascii", "-c", "135 0, 0, 0")
    assert res.returncode != 0 and ".mode binary" in res.stderr


class _LosesProbes(SimTransport):
    """The link loses the first ``n`` ASCII mode probes sent after a 139 (a bad RS485 line):
    the module enters ASCII mode but tmclsh does not hear it say so."""

    def __init__(self, sim: Simulator, n: int):
        super().__init__("TMCM-1311", 1, simulator=sim)
        self.lose, self.after_139 = n, False

    def write(self, data: bytes) -> None:
        if len(data) == 9 and data[1] == Control.ENTER_ASCII:
            self.after_139 = True
        elif self.after_139 and self.lose and b"GGP" in data:
            self.lose -= 1
            return
        super().write(data)


def _lossy(n: int) -> tuple[Simulator, LineClient]:
    sim = Simulator("TMCM-1311", 1)
    client = LineClient(_LosesProbes(sim, n), module="TMCM-1311", timeout=TIMEOUT, retries=0)
    return sim, client


def test_attach_asks_again_when_the_probe_after_139_is_lost():
    sim, client = _lossy(1)
    try:
        link = AsciiLink.attach(client)
        assert sim.ascii_active and client.ascii_link is link
        assert client.request(Request(1, GAP, 1, 0, 0)).status == Status.OK
    finally:
        client.close()
        sim.close()


def test_attach_that_fails_after_139_leaves_the_module_in_binary_mode():
    """The module did enter ASCII mode; nothing proves it. It must not stay there while the
    shell goes on in binary frames (every later command would go unanswered)."""
    sim, client = _lossy(99)
    try:
        with pytest.raises(Exception, match="did not answer in ASCII mode"):
            AsciiLink.attach(client)
        assert client.ascii_link is None and not sim.ascii_active
        assert client.request(Request(1, GAP, 1, 0, 0)).status == Status.OK
    finally:
        client.close()
        sim.close()
