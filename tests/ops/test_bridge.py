"""``tmclsh bridge``: a program tmclsh did not write (PyTrinamic, raw pyserial) talks to the
simulator through the bridge; every frame arrives unchanged and is seen and decoded."""

from __future__ import annotations

import json
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

import pytest
import serial

from conftest import ROOT, patience, tmclsh_env
from tmclsh.cli import main as cli
from tmclsh.sim import Simulator
from tmclsh.sim.serve import serve_can


def request(addr: int, cmd: int, typ: int = 0, motor: int = 0, value: int = 0) -> bytes:
    body = struct.pack(">BBBBi", addr, cmd, typ, motor, value)
    return body + bytes([sum(body) & 0xFF])


# the exit status each signal ends a bridge with (Ctrl-C is its way to end; SIGTERM and SIGHUP
# end it with the status every command ends with on them)
ENDS = {signal.SIGINT: 0, signal.SIGTERM: 143, signal.SIGHUP: 129}
WORDS = {signal.SIGTERM: "terminated (SIGTERM)", signal.SIGHUP: "hung up (SIGHUP)"}


class Bridge:
    """``tmclsh bridge ... --json`` in its own process: ``endpoint`` is its first line."""

    def __init__(self, *args: str):
        self.proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "bridge", *args,
                                      "--json"], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, env=tmclsh_env(),
                                     cwd=str(ROOT))
        self.endpoint = self.proc.stdout.readline().strip()
        assert self.endpoint, self.proc.stderr.read()

    def stop(self, sig: int = signal.SIGINT) -> tuple[list[dict], str]:
        time.sleep(0.3)  # (what was forwarded last is read before the signal)
        self.proc.send_signal(sig)
        out, err = self.proc.communicate(timeout=20)
        assert self.proc.returncode == ENDS[sig], err
        return [json.loads(line) for line in out.splitlines()], err

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()


def test_pytrinamic_through_the_bridge(make_pty_sim):
    pytest.importorskip("pytrinamic")
    from pytrinamic.connections import ConnectionManager

    sim, path = make_pty_sim()
    bridge = Bridge("--pty", "--port", path)
    try:
        iface = ConnectionManager(
            f"--interface serial_tmcl --port {bridge.endpoint} --data-rate 9600").connect()
        try:
            assert iface.get_version_string() == "1311V111"
            assert iface.get_axis_parameter(4, 0) == 51200
            iface.set_axis_parameter(4, 0, 1000)
            assert iface.get_axis_parameter(4, 0) == 1000
            iface.set_global_parameter(0, 2, -42)
            assert iface.get_global_parameter(0, 2, signed=True) == -42
            assert iface.get_digital_output(3) == 0
        finally:
            iface.close()
        objs, err = bridge.stop()
    finally:
        bridge.kill()
    assert sim.param("axis", 4) == 1000
    got = [o for o in objs if "frame" in o]
    assert [o["frame"] for o in got] == ["request", "reply"] * 7, "\n".join(
        f'{o["frame"]} {o.get("line")} {o["bytes"]} {o["t"]}' for o in got)
    assert [(o["op"], o["type"], o["motor"], o["value"]) for o in got[::2]] == [
        (136, 0, 0, 0), (6, 4, 0, 0), (5, 4, 0, 1000), (6, 4, 0, 0), (9, 0, 2, -42),
        (10, 0, 2, 0), (15, 3, 2, 0)]
    assert all(o["direction"] == "tx" for o in got[::2])
    assert all(o["direction"] == "rx" and o["latency"] > 0 for o in got[1::2])
    assert got[1]["version"] == "1311V111"
    assert (got[3]["param"], got[3]["value"]) == ("MaxPositioningSpeed", 51200)
    assert got[7]["value"] == 1000 and got[11]["value"] == -42
    assert got[8]["line"] == "SGP 0, 2, -42"
    assert objs[-1]["summary"]["requests"] == 7 and objs[-1]["summary"]["errors"] == 0


def test_bytes_pass_unchanged_noise_too_and_a_motor_left_turning_is_stopped(make_pty_sim):
    sim, path = make_pty_sim()
    bridge = Bridge("--tcp", "127.0.0.1:0", "--port", path)
    try:
        with serial.serial_for_url(f"socket://{bridge.endpoint}", timeout=2) as port:
            port.write(b"\x55\x13" + request(1, 6, 4))  # noise before the frame: forwarded
            assert port.read(9) == bytes.fromhex("02 01 64 06 00 00 c8 00 35")
            port.write(request(1, 1, 0, 0, 800))  # ROR 0, 800: and then the bridge closes
            assert port.read(9)[2] == 100
            time.sleep(0.2)
            assert sim.param("axis", 3) != 0
            objs, err = bridge.stop(signal.SIGTERM)
    finally:
        bridge.kill()
    got = [o for o in objs if "frame" in o]
    assert got[0] == {"t": got[0]["t"], "frame": "noise", "direction": "tx",
                      "note": "2 bytes that are no frame", "bytes": "55 13"}
    assert [o["line"] for o in got if o["frame"] == "request"] == ["GAP 4, 0", "ROR 0, 800"]
    assert "left a motor or the stored program started at address 1" in err
    assert "stopped motor 0" in err
    assert sim.param("axis", 3) == 0


def test_ascii_mode_through_the_bridge_is_shown_as_text_and_left_at_the_end(make_pty_sim):
    sim, path = make_pty_sim()
    bridge = Bridge("--pty", "--port", path)
    try:
        with serial.Serial(bridge.endpoint, timeout=1) as port:
            port.write(request(1, 139))
            assert port.read(9)[2] == 100
            port.write(b"AGAP 4, 0\r")
            deadline = time.monotonic() + 2
            got = b""
            while b"BA 100 51200" not in got and time.monotonic() < deadline:
                got += port.read(1)
            assert b"BA 100 51200" in got
            objs, err = bridge.stop()
    finally:
        bridge.kill()
    texts = [(o["direction"], o["text"]) for o in objs if o.get("frame") == "text"]
    assert ("tx", "AGAP 4, 0") in texts and ("rx", "BA 100 51200") in texts
    assert "left the module in ASCII mode at address 1" in err
    assert "stays in ASCII mode" not in err  # (it does not: the bridge ends it)
    # the module is back in binary mode: it answers a frame
    with serial.Serial(path, timeout=1) as port:
        port.write(request(1, 6, 4))
        assert port.read(9)[:4] == bytes([2, 1, 100, 6])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_serial_program_reaches_a_can_module(capfd):
    # (capfd: the bridge describes in a process of its own, writing to the same stdout)
    channel = "bridge-can"
    sim = Simulator("TMCM-1311")
    server = serve_can(sim, "virtual", channel)
    port_no = _free_port()
    rc: list[int] = []
    thread = threading.Thread(target=lambda: rc.append(cli.main(
        ["bridge", "--tcp", f"127.0.0.1:{port_no}", "--can", f"virtual:{channel}", "--json",
         "--count", "4"])))
    thread.start()
    try:
        deadline = time.monotonic() + 5
        while True:
            try:
                port = serial.serial_for_url(f"socket://127.0.0.1:{port_no}", timeout=2)
                break
            except serial.SerialException:
                assert time.monotonic() < deadline
                time.sleep(0.05)
        with port:
            port.write(request(1, 136))
            assert port.read(9) == b"\x021311V111"
            port.write(request(1, 6, 4))
            reply = port.read(9)
            assert reply[:4] == bytes([2, 1, 100, 6]) and sum(reply[:8]) & 0xFF == reply[8]
        thread.join(10)
    finally:
        server.close()
        sim.close()
    assert rc == [0]
    lines = capfd.readouterr().out.splitlines()
    assert f"127.0.0.1:{port_no}" in lines  # the endpoint, for a program to connect to
    objs = [json.loads(line) for line in lines if line.startswith("{")]
    got = [o for o in objs if "frame" in o]
    assert [(o["frame"], o["can_id"]) for o in got] == [("request", 1), ("reply", 2)] * 2
    assert got[1]["version"] == "1311V111" and got[3]["param"] == "MaxPositioningSpeed"


def test_the_bridge_refuses_what_it_cannot_do(run_tmclsh):
    r = run_tmclsh("bridge", "--pty")
    assert r.returncode == 2 and "one of the arguments --port --can is required" in r.stderr
    r = run_tmclsh("bridge", "--pty", "--port", "/nonexistent/tty")
    assert r.returncode == 3 and "no such port" in r.stderr
    assert "Traceback" not in r.stderr
    r = run_tmclsh("bridge", "--tcp", "nowhere", "--port", "x")
    assert r.returncode == 2 and "HOST:PORT" in r.stderr
    assert not os.path.exists("x")


def test_a_module_that_goes_away_ends_the_bridge():
    from responder import PtyModule

    module = PtyModule(version="1311V111")
    bridge = Bridge("--pty", "--port", module.path)
    try:
        with serial.Serial(bridge.endpoint, timeout=1) as port:
            port.write(request(1, 6, 1))
            assert len(port.read(9)) == 9
            module.close()  # unplugged
            out, err = bridge.proc.communicate(timeout=patience(10))
    finally:
        bridge.kill()
    assert bridge.proc.returncode == 1, err
    assert "bridge: lost " in err and "Traceback" not in err
    assert "Reconnect" not in err, err  # (the bridge has ended: nothing to reconnect)
    objs = [json.loads(line) for line in out.splitlines()]  # (the endpoint line was read)
    assert [o.get("frame") for o in objs] == ["request", "reply", None]
    assert objs[-1]["summary"]["frames"] == 2


def test_a_request_with_a_bad_checksum_is_shown_as_one_and_paired_with_its_answer():
    from responder import PtyModule

    module = PtyModule(version="1311V111", nines=True)  # answers a bad sum with status 1
    bridge = Bridge("--pty", "--port", module.path)
    try:
        with serial.Serial(bridge.endpoint, timeout=5) as port:
            bad = bytearray(request(1, 6, 4))
            bad[8] ^= 0x5A
            port.write(bytes(bad))
            assert port.read(9)[:4] == bytes([2, 1, 1, 6])  # status 1: wrong checksum
            port.write(request(1, 6, 4))  # and the line goes on
            assert port.read(9)[2] == 100
            objs, err = bridge.stop()
    finally:
        bridge.kill()
        module.close()
    got = [o for o in objs if "frame" in o]
    assert [o["frame"] for o in got] == ["request", "reply", "request", "reply"], got
    assert got[0]["line"] == "GAP 4, 0" and got[0]["note"].startswith("bad checksum")
    assert got[1]["status"] == 1 and got[1]["latency"] > 0  # paired with it
    assert objs[-1]["summary"]["unpaired"] == 0 and objs[-1]["summary"]["noise"] == 0


def test_the_capture_holds_the_stop_the_bridge_sends_when_it_closes(tmp_path):
    from responder import PtyModule
    from tmclsh.ops.capture import read_capture

    module = PtyModule(version="1311V111")
    out = tmp_path / "cap.txt"
    bridge = Bridge("--pty", "--port", module.path, "-o", str(out))
    try:
        with serial.Serial(bridge.endpoint, timeout=5) as port:
            port.write(request(1, 1, 0, 0, 800))  # ROR 0, 800: and then the bridge closes
            assert port.read(9)[2] == 100
            objs, err = bridge.stop(signal.SIGTERM)
    finally:
        bridge.kill()
        module.close()
    assert "ending that" in err
    sent = [raw for _, direction, raw in read_capture(out) if direction == "tx"]
    assert sent[0][:2] == bytes([1, 1])  # the program's ROR
    stops = [raw for raw in sent[1:] if raw[:2] == bytes([1, 3])]  # MST to address 1
    assert stops, [raw.hex(" ") for raw in sent]


# -- a tap never holds up the link (issue 34) --------------------------------------------------

def _exchange(port, req: bytes) -> bytes:
    port.write(req)
    return port.read(9)


def test_output_nobody_reads_never_stops_the_forwarding():
    """The bridge's stdout is a pipe nobody reads (a paused pager, a full pipe): the other
    master still gets every reply in time; the lines nobody took are dropped and counted,
    the frames all read and counted."""
    from responder import PtyModule

    module = PtyModule(version="1311V111")
    bridge = Bridge("--pty", "--port", module.path)  # (only its first line is read)
    n, timeouts, wrong = 2000, 0, 0
    try:
        with serial.Serial(bridge.endpoint, timeout=10) as port:
            for i in range(n):
                got = _exchange(port, request(1, 5, 4, 0, i))
                if len(got) < 9:
                    timeouts += 1
                    break  # (stuck: no use waiting out the rest)
                wrong += got[:4] != bytes([2, 1, 100, 5]) or got[4:8] != i.to_bytes(4, "big")
        bridge.proc.send_signal(signal.SIGTERM)
        out, err = bridge.proc.communicate(timeout=60)  # (now read: the rest comes)
    finally:
        bridge.kill()
        module.close()
    assert (timeouts, wrong) == (0, 0)
    assert bridge.proc.returncode == 143, err
    summary = json.loads(out.splitlines()[-1])["summary"]
    assert (summary["requests"], summary["replies"], summary["unanswered"]) == (n, n, 0)
    # 2 objects per exchange; what the pipe took is in out, the rest was dropped, counted
    shown = sum(1 for line in out.splitlines() if '"frame"' in line)
    # (how many are dropped depends on how far the describing got while nobody read: on a
    # busy machine it may lag behind, and then shows them all once they are read)
    assert shown + summary["dropped_lines"] == 2 * n
    assert summary["shown"] == shown  # (what reached the output, not what was dropped too)
    assert summary["untold"] == 0


class _Bootloading(__import__("responder").PtyModule):
    """A module that enters its bootloader on 242 and restarts on 205: no reply to either,
    as PyTrinamic's send_boot and the bootloader's 205 do."""

    def answer(self, raw: bytes) -> bytes | None:
        return None if raw[1] in (242, 205) else super().answer(raw)


def test_pipelined_requests_are_paired_and_no_reply_by_design_is_no_error():
    """A master that sends fifty requests before reading a reply: each reply is paired with
    its own request, none called unanswered; 242 and 205, which answer nothing by design,
    are not counted as errors."""
    module = _Bootloading(version="1311V111")
    bridge = Bridge("--pty", "--port", module.path)
    reqs = [request(1, 6 if i % 2 else 5, 4, 0, i) for i in range(50)]
    try:
        with serial.Serial(bridge.endpoint, timeout=10) as port:
            port.write(b"".join(reqs))
            replies = port.read(9 * 50)
            assert len(replies) == 9 * 50
            port.write(request(1, 242, 0x81, 0x92, 0xA3B4C5D6 - 2**32) + request(1, 205))
            time.sleep(0.2)
            assert _exchange(port, request(1, 6, 4))[2] == 100
        objs, err = bridge.stop(signal.SIGTERM)
    finally:
        bridge.kill()
        module.close()
    got = [o for o in objs if "frame" in o]
    assert [o["frame"] for o in got].count("unanswered") == 0, [
        (o["frame"], o.get("line"), o.get("note")) for o in got]
    answered = [o for o in got if o["frame"] == "reply"]
    assert len(answered) == 51 and all(o["latency"] > 0 for o in answered)
    # each reply carries its own request's command and value (SAP echoes it, GAP reads 0)
    assert [(o["op"], o["value"] if o["op"] == 5 else None) for o in answered[:50]] == [
        (6 if i % 2 else 5, None if i % 2 else i) for i in range(50)]
    no_reply = [o for o in got if o["frame"] == "no-reply"]
    assert [o["op"] for o in no_reply] == [242, 205]
    s = objs[-1]["summary"]
    assert (s["unanswered"], s["late"], s["unpaired"], s["errors"]) == (0, 0, 0, 0)


# -- the describing in a process of its own (issue 34: the bridge's p99) ----------------------

def _describer_of(pid: int) -> int:
    """The bridge's describing process: its one child."""
    deadline = time.monotonic() + 20
    while True:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            kids = [int(k) for k in f.read().split()]
        if kids:
            return kids[0]
        assert time.monotonic() < deadline, "the bridge has no describing process"
        time.sleep(0.05)


@pytest.mark.skipif(not os.path.exists("/proc/self/task"), reason="reads /proc (Linux)")
def test_the_describing_is_not_the_forwarding_s_process_and_its_loss_stops_nothing(tmp_path):
    """The frames are described in another process, which Ctrl-C does not reach by itself
    (the bridge ends it); killed outright, the forwarding goes on, and the bridge says at the
    end that it cannot tell what the traffic left."""
    from responder import PtyModule

    module = PtyModule(version="1311V111")
    cap = tmp_path / "cap.txt"
    bridge = Bridge("--pty", "--port", module.path, "-o", str(cap))
    try:
        describer = _describer_of(bridge.proc.pid)
        with serial.Serial(bridge.endpoint, timeout=5) as port:
            deadline = time.monotonic() + 30
            while not any(" tx " in p.read_text() for p in tmp_path.glob(".cap.txt.*")):
                # (the -o file is pushed to the disk every half second, on a write)
                assert _exchange(port, request(1, 6, 4))[2] == 100
                assert time.monotonic() < deadline
                time.sleep(0.1)
            os.kill(describer, signal.SIGINT)  # (a Ctrl-C to it alone: ignored)
            assert _exchange(port, request(1, 6, 4))[2] == 100
            os.kill(describer, signal.SIGKILL)
            for i in range(50):
                assert _exchange(port, request(1, 5, 4, 0, i))[2] == 100
            time.sleep(0.5)  # (the bridge looks at it ten times a second)
        bridge.proc.send_signal(signal.SIGINT)
        out, err = bridge.proc.communicate(timeout=30)
    finally:
        bridge.kill()
        module.close()
    assert bridge.proc.returncode == 1, err  # (the bridge could not do all it does)
    assert "the process that shows the traffic has ended" in err
    assert "is not known (the process that showed the traffic ended): check the module" in err
    assert "Traceback" not in err
    # the -o file keeps what reached the disk before, under its own name
    from tmclsh.ops.capture import read_capture
    assert f"{cap} keeps what was written until now" in err
    assert [raw[:2] for _, d, raw in read_capture(cap) if d == "tx"][:1] == [bytes([1, 6])]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.skipif(not os.path.exists("/proc/self/task"), reason="reads /proc (Linux)")
def test_the_bridge_killed_outright_leaves_no_describer_behind():
    from responder import PtyModule

    module = PtyModule(version="1311V111")
    bridge = Bridge("--pty", "--port", module.path)
    try:
        describer = _describer_of(bridge.proc.pid)
        with serial.Serial(bridge.endpoint, timeout=5) as port:
            assert _exchange(port, request(1, 6, 4))[2] == 100
        bridge.proc.kill()
        out, _ = bridge.proc.communicate(timeout=30)  # (ends when the describer's stdout does)
    finally:
        bridge.kill()
        module.close()
    assert not os.path.exists(f"/proc/{describer}") or \
        open(f"/proc/{describer}/stat").read().split(") ")[1][0] == "Z"
    objs = [json.loads(line) for line in out.splitlines()]
    # what was shown stays; nothing is written after the bridge's end (a shell may be back
    # at its prompt), and the describer has ended
    assert [o.get("frame") for o in objs] == ["request", "reply"]


def test_a_signal_as_soon_as_the_endpoint_is_out_ends_the_bridge_cleanly(make_pty_sim):
    sim, path = make_pty_sim()
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        bridge = Bridge("--pty", "--port", path)
        try:
            bridge.proc.send_signal(sig)
            out, err = bridge.proc.communicate(timeout=30)
        finally:
            bridge.kill()
        # Ctrl-C is the bridge's way to end (0); SIGTERM and SIGHUP end it as they end every
        # command: said in the same words, with the signal's status (it was 0)
        assert bridge.proc.returncode == ENDS[sig], err
        if sig in WORDS:
            assert f"{WORDS[sig]}: stopped forwarding" in err, err
        else:
            assert "stopped forwarding" not in err, err
        assert "Traceback" not in err
        assert json.loads(out.splitlines()[-1])["summary"]["frames"] == 0



def test_a_reader_that_goes_away_ends_nothing_in_a_traceback(make_pty_sim):
    """``tmclsh bridge --json | head -1``: the forwarding goes on to the end; the lines and
    the summary nobody reads any more end quietly, exit 1 (as every tmclsh command whose
    reader went away)."""
    sim, path = make_pty_sim()
    bridge = Bridge("--pty", "--port", path)
    try:
        bridge.proc.stdout.close()  # (the reader has gone, after the endpoint)
        with serial.Serial(bridge.endpoint, timeout=5) as port:
            for _ in range(5):
                assert _exchange(port, request(1, 6, 4))[2] == 100
        time.sleep(0.3)
        bridge.proc.send_signal(signal.SIGINT)
        _, err = bridge.proc.communicate(timeout=30)
    finally:
        bridge.kill()
    assert "Traceback" not in err and "failed" not in err, err
    assert bridge.proc.returncode == 1


def test_the_describer_gives_way_between_the_chunks_it_describes(monkeypatch):
    """A describer reading in a rhythm describes a batch at a time; between two chunks it
    lets whatever woke meanwhile run (the forwarding, the programs either side of it)
    instead of holding the core for the whole batch."""
    import io

    from tmclsh.ops.filter import Filter
    from tmclsh.ops.handoff import END, FINISH, LEFT, RX, START, TX, LocalPipe
    from tmclsh.ops.monitor import Monitor, SerialPair
    from tmclsh.shell.features import bridge as front
    from tmclsh.shell.features.monitor import Limits, View

    monitor = Monitor(None, timeout=1.0)
    view = View(monitor, json_mode=True, stream=io.StringIO())
    teller = front._Teller(SerialPair(monitor), view, Filter((), (), (), monitor), monitor,
                           (None, lambda: None), Limits(None, None, False), False)
    order: list[str] = []
    real_take = teller.take

    def take(event, back):
        order.append(event[0])
        return real_take(event, back)

    monkeypatch.setattr(teller, "take", take)
    monkeypatch.setattr(front, "give_way", lambda: order.append("way"))
    notes, back = LocalPipe(), LocalPipe()
    reply = bytes.fromhex("02 01 64 06 00 00 00 00 6d")  # (GAP 1's answer: 0)
    chunks = [(TX, request(1, 6, 1), 1.0), (RX, reply, 1.001)] * 10
    for event in [(START,), *chunks, (END,), (FINISH, 0)]:
        assert notes.put(event)
    teller.run(notes, back)  # (the whole batch is there: one take)
    assert order == ["start", "way"] + ["tx", "way", "rx", "way"] * 10 + ["end", "way", "finish"]
    said = back.take(0)
    assert said and said[0][0] == LEFT
    lines = [json.loads(line) for line in view.stream.getvalue().splitlines()]
    assert [(o["frame"], o["line"]) for o in lines[:-1]] == [("request", "GAP 1, 0"),
                                                             ("reply", "GAP 1, 0")] * 10
    assert lines[-1]["summary"]["replies"] == 10  # (described as ever, each in its turn)


def test_a_serial_module_s_traffic_is_forwarded_both_ways_by_one_thread():
    """A module on a port with a descriptor: the server's thread waits on it beside the
    master's end and forwards both ways, so no exchange waits for a second thread to be
    woken (and the notes still come in the wire's order); a port without one (a pyserial
    URL) is read by a thread of its own."""
    from responder import PtyModule
    from tmclsh.link import open_serial
    from tmclsh.ops.bridge import RX, TX, SerialBridge

    module = PtyModule(version="1311V111")
    for url in (module.path, f"spy://{module.path}?file=/dev/null"):
        link = open_serial(url, 9600)
        notes: list[tuple[str, bytes, str]] = []
        bridge = SerialBridge(link, lambda e: notes.append(
            (e[0], e[1], threading.current_thread().name)) or True, pty=True)
        try:
            with serial.Serial(bridge.endpoint, timeout=patience(5)) as port:
                for n in range(3):
                    port.write(request(1, 6, 1))
                    assert len(port.read(9)) == 9
                deadline = time.monotonic() + patience(5)
                while sum(len(d) for k, d, _ in notes if k == RX) < 27:
                    assert time.monotonic() < deadline, notes
                    time.sleep(0.01)
        finally:
            bridge.close()
            link.close()
        assert [k for k, _, _ in notes][:2] == [TX, RX]
        threads = {t for _, _, t in notes}
        if url == module.path:
            assert len(threads) == 1 and threads != {"bridge-module"}, threads
        else:
            assert "bridge-module" in threads and len(threads) == 2, threads
    module.close()


def test_what_the_module_sent_before_the_bridge_began_is_forwarded_not_a_failure():
    """The server's thread may find the module's descriptor readable as soon as it starts
    (bytes came between opening the port and the bridge): the bridge forwards them and goes
    on; it does not end at its first step."""
    import tty

    from tmclsh.link import open_serial
    from tmclsh.ops.bridge import RX, SerialBridge

    for _ in range(20):  # (the race it guards against was lost about every other time)
        module, slave = os.openpty()
        tty.setraw(slave)
        link = open_serial(os.ttyname(slave), 9600)
        os.write(module, b"\x02\x01\x64\x06\x00\x00\x00\x00\x6d")
        notes: list[tuple] = []
        bridge = SerialBridge(link, lambda e: notes.append(e) or True, pty=True)
        try:
            deadline = time.monotonic() + patience(5)
            while not any(e[0] == RX for e in notes):
                assert time.monotonic() < deadline, notes
                time.sleep(0.005)
            assert bridge.lost is None, bridge.lost
        finally:
            bridge.close()
            link.close()
            os.close(module)
            os.close(slave)


def test_a_motor_left_turning_is_stopped_when_nobody_reads_stderr_either(make_pty_sim):
    """``tmclsh bridge ... 2>&1 | head -3`` (or ``|& less``, then q): both streams' reader
    has gone. Ctrl-C still stops the motor the other master left turning (what the bridge
    would say about it has nobody to go to)."""
    sim, path = make_pty_sim()
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "bridge", "--pty", "--port",
                             path, "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=tmclsh_env(), cwd=str(ROOT))
    try:
        endpoint = proc.stdout.readline().strip()
        assert endpoint, proc.stderr.read()
        assert "bridging" in proc.stderr.readline()
        proc.stdout.close()  # (the reader of both has gone)
        proc.stderr.close()
        with serial.Serial(endpoint, timeout=patience(5)) as port:
            assert _exchange(port, request(1, 1, 0, 0, 500))[2] == 100  # ROR 0, 500
        time.sleep(0.3)  # (what was forwarded last is read before the signal)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=patience(20)) == 1  # (its reader gone, as other commands)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    with serial.Serial(path, timeout=patience(5)) as port:
        reply = _exchange(port, request(1, 6, 3))  # GAP 3: the actual speed
    assert struct.unpack(">i", reply[4:8])[0] == 0, reply.hex()


def test_a_closing_stop_that_leaves_a_motor_turning_fails_the_run():
    """The motor the other master started still reads a speed after the bridge's MST (a
    drive that does not stop): the bridge says so and exits 1, not 0."""
    from responder import PtyModule

    module = PtyModule(version="1311V111")
    module.values[(3, 0, False)] = 500  # (GAP 3, the actual speed, reads 500 whatever comes)
    bridge = Bridge("--pty", "--port", module.path)
    try:
        with serial.Serial(bridge.endpoint, timeout=patience(5)) as port:
            assert _exchange(port, request(1, 1, 0, 0, 500))[2] == 100  # ROR 0, 500
        time.sleep(0.3)
        bridge.proc.send_signal(signal.SIGINT)
        _, err = bridge.proc.communicate(timeout=patience(20))
    finally:
        bridge.kill()
        module.close()
    assert 3 in module.commands()  # (MST was sent)
    assert bridge.proc.returncode == 1, err
    assert "500" in err and "Traceback" not in err, err


def test_a_hang_up_ends_the_bridge_and_stops_the_motor_it_left_turning(make_pty_sim):
    """The terminal closed or the SSH session dropped: SIGHUP reaches both of the bridge's
    processes. The run ends as at Ctrl-C, and the motor the other master left turning is
    stopped (before, both died at once and it turned on)."""
    sim, path = make_pty_sim()
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "bridge", "--pty", "--port",
                             path, "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=tmclsh_env(), cwd=str(ROOT),
                            start_new_session=True)
    try:
        endpoint = proc.stdout.readline().strip()
        assert endpoint, proc.stderr.read()
        with serial.Serial(endpoint, timeout=patience(5)) as port:
            assert _exchange(port, request(1, 1, 0, 0, 500))[2] == 100  # ROR 0, 500
        time.sleep(0.3)  # (what was forwarded last is read before the signal)
        os.killpg(proc.pid, signal.SIGHUP)  # (both processes, as a hang-up does)
        _, err = proc.communicate(timeout=patience(20))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert "stopped motor 0" in err, err
    assert proc.returncode == 129 and "hung up (SIGHUP): stopped forwarding" in err, err
    with serial.Serial(path, timeout=patience(5)) as port:
        reply = _exchange(port, request(1, 6, 3))  # GAP 3: the actual speed
    assert struct.unpack(">i", reply[4:8])[0] == 0, reply.hex()
