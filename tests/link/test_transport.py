"""Transports: pyserial ports and URLs, the in-process simulator, python-can; a port that
disappears, and coming back with ``client.reconnect()``."""

from __future__ import annotations

import socket
import threading
import time
import uuid

import pytest

import tmclsh
from tmclsh.client.text import LineClient
from tmclsh.base.errors import TmclTimeoutError, TransportError, ValidationError
from tmclsh.tmcl.frames import Control, Reply, Request, Status
from tmclsh.sim import Simulator
from tmclsh.sim.serve import serve_can, serve_tcp
from tmclsh.link import open_can, open_serial, open_sim, parse_can
from tmclsh.link.sim import SimTransport
from conftest import patience

GAP, SAP, MVP = 6, 5, 4
GAP1 = Request(1, GAP, 1, 0).to_bytes()


# -- pyserial: device paths ----------------------------------------------------------------------

def test_serial_read_keeps_pyserial_timeout_meanings(pty_sim):
    sim, path = pty_sim
    t = open_serial(path, 115200)
    try:
        assert t.is_open and t.describe() == f"{path} @ 115200"
        assert t._fd is not None  # a plain device: reads and writes go to the descriptor
        t0 = time.monotonic()
        assert t.read(9, 0) == b""  # 0: never waits
        assert t.read(9, 0.1) == b""  # a deadline
        assert 0.09 <= time.monotonic() - t0 < patience(0.5)
        t.write(GAP1)
        reply = t.read(9, 1.0)  # returns as soon as the size arrived
        assert Reply.from_bytes(reply).opcode == GAP
        t.write(GAP1)
        t0 = time.monotonic()
        assert len(t.read(20, 0.15)) == 9  # fewer bytes than asked: at the deadline
        assert time.monotonic() - t0 >= 0.14
        t.write(GAP1 + GAP1)
        time.sleep(0.05)
        assert t.pending() == 18 and len(t.read_available()) == 18
    finally:
        t.close()
    assert not t.is_open
    t.close()  # twice is fine


def test_missing_port_and_bad_urls_say_what_is_wrong(tmp_path):
    with pytest.raises(TransportError, match="no such port"):
        open_serial(str(tmp_path / "ttyACM9"))
    with pytest.raises(ValidationError, match="socket://"):
        open_serial("serial:///dev/ttyACM0")  # not a pyserial scheme
    with pytest.raises(ValueError):
        open_serial("loop://", 0)


@pytest.mark.parametrize("url, said", [
    ("socket://127.0.0.1:99999", "the port must be a number 1..65535 (socket://HOST:PORT)"),
    ("socket://127.0.0.1:abc", "the port must be a number 1..65535 (socket://HOST:PORT)"),
    ("socket://127.0.0.1", "no port number: give socket://HOST:PORT"),
    ("socket://[::1:1", "not a valid address (Invalid IPv6 URL); give socket://HOST:PORT"),
    # .invalid never resolves (RFC 2606), with or without a network
    ("socket://nohost.invalid:1", "no host named 'nohost.invalid' is known"),
    ("rfc2217://nohost.invalid:1", "no host named 'nohost.invalid' is known"),
])
def test_a_network_url_that_cannot_be_opened_is_said_in_users_words(url, said):
    # pyserial's own text named its internals ("'debug|info|warning|error'", "'<=' not
    # supported ...") and repeated the URL
    with pytest.raises(TransportError) as err:
        open_serial(url)
    assert str(err.value).startswith(f"cannot open {url}: {said}")
    assert "Could not open port" not in str(err.value)


def test_a_file_that_is_no_serial_port_is_said_to_be_none(tmp_path):
    # (pyserial: "Could not configure port: (25, 'Inappropriate ioctl for device')")
    path = tmp_path / "capture.txt"
    path.write_text("not a port\n")
    with pytest.raises(TransportError) as err:
        open_serial(str(path))
    assert str(err.value) == f"cannot open {path}: not a serial port (see 'tmclsh ports')"


def test_a_port_is_opened_by_one_program_only(pty_sim):
    sim, path = pty_sim
    with open_serial(path):
        with pytest.raises(TransportError, match="in use"):
            open_serial(path)
    open_serial(path).close()  # free again


def test_loop_url_echo_is_never_taken_for_a_reply():
    # loop:// returns what was sent, like an RS485 adapter with local echo: our own request
    # (address byte 1 where the host address belongs) must be ignored
    c = LineClient(open_serial("loop://"), module="TMCM-1311", timeout=0.1, retries=0)
    try:
        assert c.describe() == "loop://"
        with pytest.raises(TmclTimeoutError):
            c.send(GAP, 1, 0)
        assert c.stats["discarded"] == 9
    finally:
        c.close()


def test_spy_url_wraps_the_port_and_logs_the_bytes(pty_sim, tmp_path):
    sim, path = pty_sim
    log = tmp_path / "spy.txt"
    c = tmclsh.connect(port=f"spy://{path}?file={log}", module="TMCM-1311", timeout=0.5)
    try:
        assert c.transport._fd is None  # a URL handler: pyserial reads and writes
        assert c.send(GAP, 1, 0).ok
    finally:
        c.close()
    text = log.read_text()
    assert "TX" in text and "RX" in text and "01 06 01 00" in text.upper().replace("0X", "")


def test_socket_url_to_a_tcp_served_simulator(sim):
    server = serve_tcp(sim, "127.0.0.1", 0)
    try:
        host, port = server.address
        c = tmclsh.connect(port=f"socket://{host}:{port}", timeout=0.5)  # module asked with 136
        try:
            assert c.module.name == "TMCM-1311" and c.describe() == f"socket://{host}:{port}"
            c.send(SAP, 1, 0, 31337)
            assert c.send(GAP, 1, 0).value == 31337
        finally:
            c.close()
    finally:
        server.close()


# -- a port that disappears ----------------------------------------------------------------------

def test_unplugged_port_gives_a_clear_transport_error(sim):
    from tmclsh.sim.serve import serve_pty

    server = serve_pty(sim)
    c = LineClient(open_serial(server.path), module="TMCM-1311", timeout=0.3)
    try:
        assert c.send(GAP, 1, 0).ok
        server.close()  # the pty vanishes, as a USB CDC device does when unplugged
        with pytest.raises(TransportError, match="(?i)lost .*unplugged"):
            c.send(GAP, 1, 0)
        assert not c.connected
        with pytest.raises(TransportError, match="not connected"):
            c.send(GAP, 1, 0)
        with pytest.raises(TransportError, match="no such port"):
            c.reconnect()
    finally:
        c.close()
        server.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_reconnect_after_the_server_comes_back(sim):
    port = _free_port()
    server = serve_tcp(sim, "127.0.0.1", port)
    c = tmclsh.connect(port=f"socket://127.0.0.1:{port}", module="TMCM-1311", timeout=0.3)
    try:
        c.send(SAP, 1, 0, 4711)
        server.close()  # unplugged
        with pytest.raises(TransportError, match="lost socket://"):
            c.send(GAP, 1, 0)
        with pytest.raises(TransportError, match="connection refused"):
            c.reconnect()  # not back yet
        server = serve_tcp(sim, "127.0.0.1", port)  # plugged in again
        c.reconnect()
        assert c.connected and c.send(GAP, 1, 0).value == 4711
        # and once more, waiting for it to come back
        server.close()
        with pytest.raises(TransportError):
            c.send(GAP, 1, 0)
        holder = {}
        timer = threading.Timer(0.3, lambda: holder.setdefault(
            "server", serve_tcp(sim, "127.0.0.1", port)))
        timer.start()
        c.reconnect(wait=5)
        timer.join()
        server = holder["server"]
        assert c.send(GAP, 1, 0).value == 4711
        assert c.stats["reconnects"] == 2
    finally:
        c.close()
        server.close()


# -- the in-process simulator --------------------------------------------------------------------

def test_sim_transport_is_a_stream_with_the_same_timeouts():
    t = open_sim("TMCM-1640", 3, host_address=4)
    try:
        assert t.simulated and t.describe() == "SIMULATED TMCM-1640"
        assert t.read(9, 0) == b""
        t.write(Request(3, GAP, 1, 0).to_bytes())
        r = Reply.from_bytes(t.read(9, 1.0))
        assert (r.host, r.module, r.opcode) == (4, 3, GAP)
        t0 = time.monotonic()
        assert t.read(9, 0.05) == b"" and time.monotonic() - t0 >= 0.04
    finally:
        t.close()
    with pytest.raises(TransportError):
        t.write(GAP1)


def test_sim_transport_leaves_a_given_simulator_running(sim):
    t = SimTransport(simulator=sim)
    c = LineClient(t, module="TMCM-1311", timeout=0.5)
    assert c.send(GAP, 1, 0).ok
    c.close()
    sim.write(GAP1)
    assert len(sim.read(1.0)) == 9  # still alive


def test_connect_sim_passes_address_and_host_address():
    c = tmclsh.connect(sim="TMCM-351", address=0, host_address=9, timeout=0.5)
    try:
        r = c.send(GAP, 1, 2)
        assert (r.host, r.module) == (9, 0) and c.transport.simulator.address == 0
    finally:
        c.close()


# -- python-can ----------------------------------------------------------------------------------

@pytest.fixture
def can_sim():
    """A TMCM-1311 (address/CAN id 1, reply id 2) on a fresh python-can virtual channel."""
    channel = f"tmclsh-{uuid.uuid4().hex[:8]}"
    sim = Simulator("TMCM-1311")
    server = serve_can(sim, "virtual", channel)
    yield sim, channel
    server.close()
    sim.close()


def test_can_client_identifies_and_talks(can_sim):
    sim, channel = can_sim
    c = tmclsh.connect(can=f"virtual:{channel}", timeout=0.5)
    try:
        assert c.is_can and c.describe() == f"CAN virtual:{channel}"
        assert c.module.name == "TMCM-1311" and c.version == "1311V111"
        c.send(SAP, 1, 0, -123456)
        assert c.send(GAP, 1, 0).value == -123456
        assert c.execute("GAP ActualPosition, 0").value == -123456
    finally:
        c.close()


def test_can_event_and_stale_reply(can_sim):
    sim, channel = can_sim
    c = tmclsh.connect(can=f"virtual:{channel}", module="TMCM-1311", timeout=0.2)
    events = []
    c.add_listener(events.append)
    try:
        c.send(SAP, 4, 0, 100_000)
        c.send(SAP, 5, 0, 2_000_000)
        c.send(MVP, 0, 0, 10000)
        assert c.send(Control.TARGET_REACHED_EVENT, 0, 0, 0).status == Status.OK
        deadline = time.monotonic() + 3
        while not events and time.monotonic() < deadline:
            assert c.send(GAP, 1, 0).opcode == GAP
        assert len(events) == 1 and events[0].status == Status.EVENT and events[0].value == 1
        # a late reply on CAN is not taken for the next request either
        sim.set_input(1, 0, 1111)
        sim.faults.delay = 0.3
        with pytest.raises(TmclTimeoutError, match="CAN"):
            c.request(Request(1, 15, 0, 1), retries=0)
        sim.faults.delay = 0.0
        sim.set_input(1, 0, 2222)
        assert c.send(15, 0, 1).value == 2222
    finally:
        c.close()


def test_can_ids(can_sim):
    sim, channel = can_sim
    c = tmclsh.connect(can=f"virtual:{channel}", module="TMCM-1311", timeout=0.1, retries=0)
    c.can_id = 5
    try:
        with pytest.raises(TmclTimeoutError, match="sent to id 5"):
            c.send(GAP, 1, 0)  # nobody listens on id 5
        c.can_id = 1
        c.reply_id = 3
        with pytest.raises(TmclTimeoutError, match="on id 3"):
            c.send(GAP, 1, 0)  # the module answers on id 2
        c.reply_id = 2
        assert c.send(GAP, 1, 0).ok
        # the module moved to other ids (GP 70 reply ID: its reply comes on the new one already,
        # GP 71 CAN ID)
        c.reply_id = 0x123
        assert c.send(9, 70, 0, 0x123).ok
        assert c.send(9, 71, 0, 0x45).ok
        c.can_id = 0x45
        assert c.send(GAP, 1, 0).ok
    finally:
        c.close()


def test_can_sent_only_tracer_is_told_each_request(can_sim):
    """On CAN too a tracer that only watches what is sent gets every request (the end-of-run
    note about motors left turning), and is not told the replies."""
    sim, channel = can_sim
    c = tmclsh.connect(can=f"virtual:{channel}", timeout=0.5)
    try:
        sent = []
        c.add_tracer(lambda d, raw, dec: sent.append((d, bytes(raw), dec)), sent_only=True)
        c.execute("ROR 0, 500")
        c.send(GAP, 1, 0)
        ror, gap = Request(1, 1, 0, 0, 500), Request(1, GAP, 1, 0)
        assert sent == [("tx", ror.to_can(), ror), ("tx", gap.to_can(), gap)]
    finally:
        c.close()


def test_can_spec_errors():
    assert parse_can("slcan:/dev/ttyACM0") == ("slcan", "/dev/ttyACM0")
    with pytest.raises(ValidationError, match="IFACE:CHANNEL"):
        open_can("can0")
    with pytest.raises(TransportError, match="cannot open CAN"):
        open_can("nosuchinterface:x")


def test_a_lost_port_names_the_failure_once():
    """pyserial's own text often starts with "read failed:"; the message must not say it twice."""
    from tmclsh.link.serial import SerialTransport

    t = SerialTransport("loop://")
    err = t._lost("read", OSError("read failed: device reports readiness to read but returned no data"))
    assert str(err).count("read failed") == 1, err
    err = t._lost("write", OSError("[Errno 5] Input/output error"))
    assert "write failed: [Errno 5]" in str(err), err


# -- transact: the request path's write-and-read in one call -------------------------------------

class _PtyResponder:
    """The other end of a pty, answering each 9-byte frame as ``answer(frame)`` says: a list of
    (delay seconds, bytes) pieces. Written here from the manual's reply layout (host, module,
    status 100, opcode, value, sum), not with tmclsh's code."""

    def __init__(self, answer):
        import os
        import tty

        self.answer = answer
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        import os
        import select

        buf = b""
        while not self._stop.is_set():
            if not select.select([self.master], [], [], 0.05)[0]:
                continue
            try:
                buf += os.read(self.master, 64)
            except OSError:
                return
            while len(buf) >= 9:
                frame, buf = buf[:9], buf[9:]
                for delay, piece in self.answer(frame):
                    time.sleep(delay)
                    os.write(self.master, piece)

    def close(self) -> None:
        import os

        self._stop.set()
        self._thread.join(1)
        os.close(self.master)
        os.close(self._slave)


def _reply_to(frame: bytes, value: int = 1234) -> bytes:
    body = bytes((2, frame[0], 100, frame[1])) + value.to_bytes(4, "big")
    return body + bytes((sum(body) & 0xFF,))


@pytest.mark.parametrize("pieces", [
    lambda f: [(0, _reply_to(f))],  # whole, the common case
    lambda f: [(0, _reply_to(f)[:3]), (0.03, _reply_to(f)[3:])],  # the rest comes later
    lambda f: [(0, _reply_to(f)[:1]), (0.02, _reply_to(f)[1:5]), (0.02, _reply_to(f)[5:])],
], ids=["whole", "two pieces", "three pieces"])
def test_transact_returns_the_whole_answer_however_it_comes(pieces):
    responder = _PtyResponder(pieces)
    t = open_serial(responder.path, 115200)
    try:
        assert t._fd is not None  # the descriptor path, not pyserial's read
        got = t.transact(GAP1, 9, 1.0)
        assert got == _reply_to(GAP1)
        # and through the client: the value the responder gave
        c = LineClient(t, module="TMCM-1311")
        assert c.request(Request(1, GAP, 1, 0)).value == 1234
    finally:
        t.close()
        responder.close()


def test_transact_keeps_the_timeout_and_says_what_came():
    responder = _PtyResponder(lambda f: [(0, _reply_to(f)[:4])])  # a reply cut short
    t = open_serial(responder.path, 115200)
    try:
        t0 = time.monotonic()
        assert t.transact(GAP1, 9, 0.2) == _reply_to(GAP1)[:4]  # what came, at the deadline
        assert 0.18 <= time.monotonic() - t0 < patience(1.0)
        silent = _PtyResponder(lambda f: [])
        s = open_serial(silent.path, 115200)
        try:
            t0 = time.monotonic()
            assert s.transact(GAP1, 9, 0.15) == b""
            assert 0.14 <= time.monotonic() - t0 < patience(1.0)
        finally:
            s.close()
            silent.close()
    finally:
        t.close()
        responder.close()


def test_transact_reads_what_came_behind_the_reply_with_it():
    """A copy right behind a reply (a line that repeats a frame) is read with the reply, in
    the same read: the framing then takes it in before the next request, without a look at
    the port of its own (``emptied`` says when the port was found empty)."""
    responder = _PtyResponder(lambda f: [(0, _reply_to(f) * 2)])
    t = open_serial(responder.path, 115200)
    try:
        # (one write of the other end's: the pty hands the eighteen bytes over at once)
        assert t.transact(GAP1, 9, patience(1.0)) == _reply_to(GAP1) * 2
        assert t.emptied > 0
        c = LineClient(t, module="TMCM-1311")
        first = c.request(Request(1, GAP, 1, 0))
        second = c.request(Request(1, GAP, 2, 0))
        assert first.value == second.value == 1234
        assert c.stats["flushed"] >= 1 and c.stats["timeouts"] == 0  # the copies, before
    finally:
        t.close()
        responder.close()


def test_no_look_at_the_port_within_a_frame_of_a_read_that_emptied_it():
    """A run of requests does not ask the port whether anything waits while less than one
    frame's wire time has passed since the reply's read took all it held: nothing whole can
    have come since. At 50 baud a frame takes 1.8 s, far longer than a run's steps."""
    responder = _PtyResponder(lambda f: [(0, _reply_to(f))])
    t = open_serial(responder.path, 115200)
    try:
        t.set_baudrate(50)  # (a pty carries bytes at once whatever it is set to)
        c = LineClient(t, module="TMCM-1311", timeout=patience(1.0))
        looks = []
        ready = c._framing._ready
        c._framing._ready = lambda: looks.append(1) or ready()
        reqs = [Request(1, GAP, i % 8, 0) for i in range(50)]
        assert [r.value for r in c.requests(reqs)] == [1234] * 50
        assert len(looks) <= 1, len(looks)  # (the first request: nothing read before it)
        before = len(looks)
        t.write(GAP1)  # anything written but by transact may be answered at once: look again
        assert t.emptied == 0.0
        c._framing.waiting()
        assert len(looks) == before + 1
    finally:
        t.close()
        responder.close()


def test_after_a_pause_a_frame_that_came_meanwhile_is_taken_in_before_the_request():
    """Once a frame's wire time has passed since the last read, the port is asked again: a
    stray frame that came in the pause is no answer to the next request."""
    stray = bytes((2, 1, 100, GAP)) + (99).to_bytes(4, "big")
    stray += bytes((sum(stray) & 0xFF,))
    sent = []

    def answer(frame):
        sent.append(frame)
        pieces = [(0, _reply_to(frame))]
        return pieces + [(0.05, stray)] if len(sent) == 1 else pieces

    responder = _PtyResponder(answer)
    t = open_serial(responder.path, 115200)
    try:
        c = LineClient(t, module="TMCM-1311", timeout=patience(1.0))
        assert c.request(Request(1, GAP, 1, 0)).value == 1234
        end = time.monotonic() + patience(2.0)
        while t.pending() < 9 and time.monotonic() < end:  # the stray has come
            time.sleep(0.005)
        assert t.pending() == 9
        assert c.request(Request(1, GAP, 1, 0)).value == 1234
        assert c.stats["flushed"] == 9  # (bytes)
    finally:
        t.close()
        responder.close()


def test_ready_says_whether_anything_waits_and_goes_with_the_port():
    """The client asks ``ready`` before every request (what waits cannot be its answer): it
    must say what ``pending`` says, also once bytes were read, and be gone with the port (on
    Linux an epoll descriptor of its own: reopening a port again and again leaks none)."""
    import os
    import select

    def fds() -> int:
        return len(os.listdir("/proc/self/fd")) if os.path.isdir("/proc/self/fd") else 0

    before = fds()
    responder = _PtyResponder(lambda f: [(0, _reply_to(f))])
    t = open_serial(responder.path, 115200)
    try:
        if hasattr(select, "epoll"):
            assert t._poll is not None
        assert t.ready() is False and t.pending() == 0
        t.write(GAP1)
        end = time.monotonic() + patience(2.0)
        while t.pending() < 9 and time.monotonic() < end:
            time.sleep(0.005)
        assert t.pending() == 9 and t.ready() is True
        assert t.read_available() == _reply_to(GAP1)
        assert t.ready() is False
        for _ in range(3):  # closed and opened again, as a reconnect does
            t.close()
            with pytest.raises(TransportError):
                t.ready()
            t.open()
            assert t.ready() is False
    finally:
        t.close()
        responder.close()
    assert fds() == before


def test_the_same_answer_twice_is_the_same_reply_and_another_is_another():
    values = iter([7, 7, -5])
    responder = _PtyResponder(lambda f: [(0, _reply_to(f, next(values) & 0xFFFFFFFF))])
    t = open_serial(responder.path, 115200)
    try:
        c = LineClient(t, module="TMCM-1311")
        got = [c.request(Request(1, GAP, 1, 0)) for _ in range(3)]
        assert [r.value for r in got] == [7, 7, -5]
        assert got[0] == got[1] and got[1] != got[2]
    finally:
        t.close()
        responder.close()


def test_transact_when_the_output_is_full_writes_the_rest_and_still_reads_the_answer():
    """The port's output buffer full (the other end reads nothing for a while): os.write takes
    part of the frame or none of it (BlockingIOError); the rest goes out as write() sends it,
    and the answer is read as usual once the other end catches up."""
    import os
    import select
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    t = open_serial(path, 115200)
    heard = bytearray()

    def late_reader():
        time.sleep(0.3)  # the port's output stays full until then
        while GAP1 not in heard:
            if select.select([master], [], [], 2.0)[0]:
                heard.extend(os.read(master, 65536))
            else:
                return
        os.write(master, _reply_to(GAP1, 77))

    try:
        filled = 0
        while True:  # fill the output with noise the other end will skip
            try:
                filled += os.write(t._fd, bytes(512))
            except BlockingIOError:
                break
        reader = threading.Thread(target=late_reader, daemon=True)
        reader.start()
        assert filled > 0
        got = t.transact(GAP1, 9, 2.0)
        reader.join(3)
        assert got == _reply_to(GAP1, 77)
        assert heard.endswith(GAP1)
    finally:
        t.close()
        os.close(master)
        os.close(slave)


def test_transact_without_a_descriptor_goes_through_pyserial(pty_sim, monkeypatch):
    """Windows (no descriptor to select on) and URL handlers: transact is pyserial's write and
    read, with the read timeout set once, not per request."""
    sim, path = pty_sim
    t = open_serial(path, 115200)
    try:
        t._fd = None  # as on Windows
        sets = []
        ser_type = type(t._ser)
        real = ser_type.timeout

        def spy(self, value):
            sets.append(value)
            real.fset(self, value)

        monkeypatch.setattr(ser_type, "timeout", property(real.fget, spy))
        c = LineClient(t, module="TMCM-1311", timeout=0.5)
        assert [c.request(Request(1, GAP, 1, 0)).status for _ in range(5)] == [Status.OK] * 5
        assert sets == [0.5]  # once, for the first read; the rest ask with the same timeout
        assert t.transact(GAP1, 9, 0.5)[:4] == bytes((2, 1, 100, GAP))
    finally:
        t.close()
