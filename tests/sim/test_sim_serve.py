"""The simulator served to clients tmclsh did not write: pyserial over a pty and over TCP,
python-can on a virtual bus, pytrinamic over the pty, and the blocking ``run`` entry."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial

from tmclsh.tmcl.frames import Reply, ReplyKind, Request, Status
from tmclsh.sim import SimBus, Simulator
from tmclsh.sim.serve import serve_can, serve_pty, serve_tcp
from conftest import patience

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def sim():
    s = Simulator("TMCM-1311")
    yield s
    s.close()


def test_pty_with_pyserial(sim):
    with serve_pty(sim) as server, serial.Serial(server.path, timeout=1) as port:
        port.write(Request(1, 6, 4).to_bytes())
        assert Reply.from_bytes(port.read(9)).value == 51200
        port.write(Request(1, 136, 0).to_bytes())
        assert port.read(9) == b"\x021311V111"
        port.write(Request(1, 5, 4, 0, 1000).to_bytes())
        assert Reply.from_bytes(port.read(9)).ok
        start = time.perf_counter()
        for _ in range(200):
            port.write(Request(1, 6, 4).to_bytes())
            assert len(port.read(9)) == 9
        assert (time.perf_counter() - start) / 200 < 0.002  # no sleeps in the request path


def test_pty_ascii_mode_and_back(sim):
    with serve_pty(sim) as server, serial.Serial(server.path, timeout=1) as port:
        port.write(Request(1, 139).to_bytes())
        assert Reply.from_bytes(port.read(9)).ok
        port.write(b"AGAP 4, 0\r")
        assert port.read_until(b"51200\r") == b"AGAP 4, 0\rBA 100 51200\r"
        port.write(b"ABIN\r")
        assert port.read_until(b"BA 100 0\r").endswith(b"BA 100 0\r")
        port.write(Request(1, 6, 4).to_bytes())
        assert Reply.from_bytes(port.read(9)).value == 51200


def test_pty_reopen(sim):
    with serve_pty(sim) as server:
        for _ in range(2):
            with serial.Serial(server.path, timeout=1) as port:
                port.write(Request(1, 6, 1).to_bytes())
                assert Reply.from_bytes(port.read(9)).ok


def test_pty_serves_a_bus():
    bus = SimBus([Simulator("TMCM-1311", 1), Simulator("TMCM-351", 2)])
    with bus, serve_pty(bus) as server, serial.Serial(server.path, timeout=1) as port:
        port.write(Request(2, 136, 0).to_bytes())
        assert port.read(9) == b"\x020351V103"
        port.write(Request(1, 136, 0).to_bytes())
        assert port.read(9) == b"\x021311V111"


def test_tcp_with_socket_url(sim):
    with serve_tcp(sim, "127.0.0.1", 0) as server:
        host, port_no = server.address
        assert port_no != 0
        for _ in range(2):  # one client after the other
            with serial.serial_for_url(f"socket://{host}:{port_no}", timeout=1) as port:
                port.write(Request(1, 6, 4).to_bytes())
                assert Reply.from_bytes(port.read(9)).value == 51200


def test_can_virtual_bus(sim):
    can = pytest.importorskip("can")
    channel = f"sim-test-{os.getpid()}-{time.monotonic_ns()}"
    with serve_can(sim, "virtual", channel):
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            bus.send(can.Message(arbitration_id=1, data=Request(1, 6, 4).to_can(),
                                 is_extended_id=False))
            msg = bus.recv(1)
            assert msg.arbitration_id == 2
            assert Reply.from_can(2, msg.data).value == 51200
            bus.send(can.Message(arbitration_id=1, data=Request(1, 136, 0).to_can(),
                                 is_extended_id=False))
            msg = bus.recv(1)
            assert Reply.from_can(2, msg.data, ReplyKind.VERSION_STRING).version == "1311V111"
            bus.send(can.Message(arbitration_id=7, data=Request(1, 6, 4).to_can(),
                                 is_extended_id=False))
            assert bus.recv(0.05) is None
            bus.send(can.Message(arbitration_id=1, data=Request(1, 4, 0, 0, 500).to_can(),
                                 is_extended_id=False))
            assert Reply.from_can(2, bus.recv(1).data).ok
            bus.send(can.Message(arbitration_id=1, data=Request(1, 138).to_can(),
                                 is_extended_id=False))
            assert Reply.from_can(2, bus.recv(1).data).status == Status.OK
            event = Reply.from_can(2, bus.recv(3).data)
            assert (event.status, event.opcode) == (Status.EVENT, 138)
        finally:
            bus.shutdown()


def test_pytrinamic_reads_and_writes_parameters(sim):
    pytest.importorskip("pytrinamic")
    from pytrinamic.connections import ConnectionManager

    with serve_pty(sim) as server:
        iface = ConnectionManager(
            f"--interface serial_tmcl --port {server.path} --data-rate 9600").connect()
        try:
            assert iface.get_axis_parameter(4, 0) == 51200
            iface.set_axis_parameter(4, 0, 1000)
            assert iface.get_axis_parameter(4, 0) == 1000
            assert sim.param("axis", 4) == 1000
            iface.set_global_parameter(0, 2, -42)
            assert iface.get_global_parameter(0, 2, signed=True) == -42
            iface.set_digital_output(3)
            assert iface.get_digital_output(3) == 1
            sim.set_input(1, 0, 1234)
            assert iface.get_analog_input(0) == 1234
            assert iface.get_version_string() == "1311V111"
            iface.set_axis_parameter(1, 0, -77)
            assert iface.get_axis_parameter(1, 0, signed=True) == -77
        finally:
            iface.close()


def test_run_entry_point_tcp_and_signal():
    code = ("import logging, sys; logging.basicConfig(level=logging.WARNING);"
            "from tmclsh.sim.serve import run;"
            "sys.exit(run('TMCM-351', 2, tcp='127.0.0.1:0'))")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, cwd=ROOT, text=True)
    try:
        first = proc.stdout.readline().strip()
        host, port_no = first.rsplit(":", 1)
        with serial.serial_for_url(f"socket://{host}:{port_no}", timeout=2) as port:
            port.write(Request(2, 136, 0).to_bytes())
            assert port.read(9) == b"\x020351V103"
        time.sleep(0.6)  # stdin is closed: the server must keep running
        assert proc.poll() is None
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(patience(5)) == 0
    finally:
        if proc.poll() is None:
            proc.kill()


def test_run_entry_point_pty():
    code = "import sys; from tmclsh.sim.serve import run; sys.exit(run('TMCM-1311', 1, pty=True))"
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, cwd=ROOT, text=True)
    try:
        path = proc.stdout.readline().strip()
        with serial.Serial(path, timeout=2) as port:
            port.write(Request(1, 6, 4).to_bytes())
            assert Reply.from_bytes(port.read(9)).value == 51200
        proc.send_signal(signal.SIGINT)
        assert proc.wait(patience(5)) == 0
    finally:
        if proc.poll() is None:
            proc.kill()


def test_run_rejects_bad_arguments():
    from tmclsh.sim.serve import run

    assert run("TMCM-1311", 1) == 2
    assert run("TMCM-1311", 1, pty=True, tcp="x:1") == 2
    assert run("TMCM-1311", 1, tcp="nonsense") == 2
    assert run("TMCM-1311", 300, pty=True) == 2


def _frame(address: int, opcode: int, type_: int = 0, value: int = 0) -> bytes:
    """A request built here from the manual's table, not by tmclsh."""
    body = bytes([address, opcode, type_, 0]) + (value & 0xFFFFFFFF).to_bytes(4, "big")
    return body + bytes([sum(body) & 0xFF])


def test_sim_serves_a_bus_paced_at_its_baud_rate(run_tmclsh):
    """`tmclsh sim --pty --address 1,2,2 --baud 19200`: each address answers its own frames,
    the address given twice answers twice, and the line carries 10 bits a byte: a request
    and its reply (18 bytes) take at least 9.4 ms at 19200 baud."""
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "sim", "--pty", "--address", "1,2,2",
                             "--baud", "19200"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, cwd=ROOT, text=True)
    try:
        path = proc.stdout.readline().strip()
        with serial.Serial(path, timeout=0.3) as port:
            replies = {}
            for address in (1, 2, 3):
                port.write(_frame(address, 136, 1))
                replies[address] = port.read(27)
            assert [len(replies[a]) for a in (1, 2, 3)] == [9, 18, 0]
            assert replies[2][:9] == replies[2][9:] and replies[2][1] == 2
            start = time.perf_counter()
            for _ in range(40):
                port.write(_frame(1, 6, 4))
                assert len(port.read(9)) == 9
            took = time.perf_counter() - start
        assert took >= 40 * 18 * 10 / 19200
        proc.send_signal(signal.SIGINT)
        assert proc.wait(patience(5)) == 0
    finally:
        if proc.poll() is None:
            proc.kill()


def test_sim_refuses_a_bus_on_can():
    from tmclsh.sim.serve import run

    assert run("TMCM-1311", [1, 2], can="virtual:x") == 2
    assert run("TMCM-1311", 1, can="virtual:x", baud=9600) == 2


class _Echo:
    """A target that answers every chunk with itself, and asks the server to wait on a
    pipe beside its client (``beside``): what comes on the pipe goes to the client too."""

    def __init__(self):
        self.on_output = None
        self.r, self.w = os.pipe()
        os.set_blocking(self.r, False)
        self.threads: set[str] = set()
        self.beside = (self.r, self.ready)

    def write(self, data: bytes) -> None:
        import threading

        self.threads.add(threading.current_thread().name)
        self.on_output(data)

    def ready(self) -> None:
        import threading

        self.threads.add(threading.current_thread().name)
        try:
            data = os.read(self.r, 4096)
        except OSError:
            self.beside = None  # (its descriptor gone bad: the server stops waiting on it)
            return
        self.on_output(b"beside:" + data)


@pytest.mark.parametrize("kind", ["pty", "tcp"])
def test_a_descriptor_beside_the_client_is_served_on_the_server_s_thread(kind):
    """The bridge's one-thread forwarding rests on this: what a target puts ``beside`` is
    waited on with the client by the server's own thread, both ways served in turn; a
    descriptor that goes bad is dropped and the client is still served."""
    target = _Echo()
    server = serve_pty(target) if kind == "pty" else serve_tcp(target, "127.0.0.1", 0)
    url = server.path if kind == "pty" else "socket://%s:%d" % server.address
    try:
        with serial.serial_for_url(url, timeout=patience(5)) as port:
            port.write(b"ping")
            assert port.read(4) == b"ping"
            os.write(target.w, b"x")
            assert port.read(8) == b"beside:x"
            port.write(b"pong")
            assert port.read(4) == b"pong"
            assert len(target.threads) == 1  # (one thread carried both)
            os.close(target.r)  # gone bad under the server's wait
            port.write(b"still")
            assert port.read(5) == b"still"
            assert target.beside is None
    finally:
        server.close()
        os.close(target.w)


def test_a_second_tcp_client_is_hung_up_on_while_one_is_served_and_its_bytes_never_go():
    """One client at a time: a second that connects meanwhile is hung up on at once, so
    what it sent never reaches the target once the first has gone (through a bridge: a
    motor started for a program that had long given up). After the first leaves, a new
    client is served as ever."""
    import socket as so

    heard: list[bytes] = []

    class Target:
        on_output = None

        def write(self, data: bytes) -> None:
            heard.append(data)
            self.on_output(b"ok")

    server = serve_tcp(Target(), "127.0.0.1", 0)
    try:
        first = so.create_connection(server.address, timeout=patience(5))
        first.sendall(b"A1")
        assert first.recv(2) == b"ok"
        second = so.create_connection(server.address, timeout=patience(5))
        second.sendall(b"B-stale")
        try:
            assert second.recv(16) == b""  # (hung up on)
        except ConnectionResetError:
            pass  # (hung up on with its bytes unread: a reset)
        second.close()
        first.sendall(b"A2")
        assert first.recv(2) == b"ok"
        first.close()
        third = so.create_connection(server.address, timeout=patience(5))
        third.sendall(b"C1")
        assert third.recv(2) == b"ok"
        third.close()
    finally:
        server.close()
    assert b"".join(heard) == b"A1A2C1"
