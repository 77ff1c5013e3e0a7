"""The monitor on a serial line: a tap that hears a master and its modules at once, and the
two directions of a bridge. Frames are built here from the manual's byte layout
(tests/responder.py), not by tmclsh; the live tap is fed by a real pyserial master talking
to a module written from the manual, the test copying both directions onto the tap with
noise and frames split in two, as an RS485 adapter on the line would hear them."""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import time
import tty

import pytest
import serial
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from conftest import ROOT, patience, tmclsh_env
from responder import PtyModule, reply, valid, version_reply
from tmclsh.ops.filter import Filter
from tmclsh.ops.monitor import (EVENT, NOISE_RUN, REPLY, REQUEST, TEXT, Exchange,
                                Monitor, SerialPair, SerialTap)
from tmclsh.tmcl.modules import load

OK, INVALID_VALUE, INVALID_COMMAND = 100, 4, 2


def request(addr: int, cmd: int, typ: int = 0, motor: int = 0, value: int = 0) -> bytes:
    """A request frame as the manual lays it out: address, command, type, motor, value
    (MSB first), 8-bit sum."""
    body = struct.pack(">BBBBi", addr, cmd, typ, motor, value)
    return body + bytes([sum(body) & 0xFF])


def feed(reader, chunks, t0: float = 100.0, step: float = 0.001) -> list:
    items, t = [], t0
    for chunk in chunks:
        t += step
        items += reader.feed(chunk, t)
    return items + reader.end(t + 5)


def kinds(items) -> list[tuple[str, bytes]]:
    return [(i.kind, i.raw) for i in items if not isinstance(i, Exchange)]


def exchanges(items) -> list[Exchange]:
    return [i for i in items if isinstance(i, Exchange)]


# -- a tap: both directions on one line ------------------------------------------------------

def test_requests_and_replies_are_told_apart_and_paired():
    conversation = [request(1, 136), version_reply("1311V111"),
                    request(1, 6, 4), reply(6, 51200),
                    request(3, 6, 1), reply(6, -77, module=3),
                    request(1, 5, 4, 0, -5), reply(5, -5, INVALID_VALUE),
                    reply(138, 1, 128),  # an event: target reached, motor 0
                    request(1, 200), reply(200, 0, INVALID_COMMAND),  # a command with no data
                    request(1, 137, 0, 0, 1234)]  # factory reset: no reply
    m = Monitor()
    items = feed(SerialTap(m), conversation)
    assert [r for k, r in kinds(items)] == conversation
    assert [k for k, _ in kinds(items)] == [REQUEST, REPLY] * 4 + [EVENT, REQUEST, REPLY,
                                                                    REQUEST]
    ex = exchanges(items)
    assert [(e.request.raw, e.reply.raw if e.reply else None, e.note) for e in ex] == [
        (conversation[0], conversation[1], ""), (conversation[2], conversation[3], ""),
        (conversation[4], conversation[5], ""), (conversation[6], conversation[7], ""),
        (conversation[9], conversation[10], ""), (conversation[11], None, "no reply expected")]
    assert all(e.latency == pytest.approx(0.001) for e in ex if e.reply is not None)
    # the 136 string named the module: parameter names from its data from then on
    assert m.module_for(1).name == "TMCM-1311" and m.module_for(3) is None
    s = m.summary
    assert (s.requests, s.replies, s.events, s.unanswered, s.noise) == (6, 5, 1, 0, 0)
    assert s.statuses == {OK: 3, INVALID_VALUE: 1, INVALID_COMMAND: 1}
    assert s.refused == 2 and s.modules == {1: "TMCM-1311 (1311V111)"}


def test_a_reply_whose_request_was_lost_and_a_request_without_reply():
    items = feed(SerialTap(Monitor()), [reply(6, 5), request(1, 6, 1), request(1, 6, 2),
                                        reply(6, 9)])
    ex = exchanges(items)
    assert [k for k, _ in kinds(items)] == [REPLY, REQUEST, REQUEST, REPLY]
    assert kinds(items)[0][1] == reply(6, 5) and items[0].answers is None
    assert ex[0].reply is None and ex[0].note == "no reply before the next request"
    assert ex[1].request.raw == request(1, 6, 2) and ex[1].reply.raw == reply(6, 9)


def test_noise_and_a_frame_split_in_two():
    gap = request(1, 6, 4)
    items = feed(SerialTap(Monitor()), [gap, reply(6, 1), b"\x00\xff\x13",
                                        gap[:4], gap[4:], reply(6, 2)[:3], reply(6, 2)[3:]])
    assert kinds(items) == [(REQUEST, gap), (REPLY, reply(6, 1)), (NOISE_RUN, b"\x00\xff\x13"),
                            (REQUEST, gap), (REPLY, reply(6, 2))]


def test_a_partial_frame_is_shown_as_such_when_the_line_goes_quiet():
    tap = SerialTap(Monitor())
    items = tap.feed(request(1, 6, 4), 1.0) + tap.feed(reply(6, 1)[:5], 1.001)
    assert kinds(items) == [(REQUEST, request(1, 6, 4))]
    items = tap.quiet(1.2)
    assert kinds(items) == [(NOISE_RUN, reply(6, 1)[:5])]
    assert "partial frame: 5 of 9 bytes" in items[0].note


def test_a_frame_that_adds_up_inside_noise_is_noise_unless_it_fits_the_traffic():
    stray = request(77, 250, 1, 2, 3)  # adds up: unknown command, to an address never seen
    m = Monitor()
    items = feed(SerialTap(m), [request(1, 6, 4), reply(6, 1), b"\x5a" + stray + b"\x33",
                                request(1, 6, 4), reply(6, 2)])
    assert kinds(items)[2] == (NOISE_RUN, b"\x5a" + stray + b"\x33")
    assert [k for k, _ in kinds(items)] == [REQUEST, REPLY, NOISE_RUN, REQUEST, REPLY]
    # the same frame where no noise came before it is a frame: shown raw, never dropped
    items = feed(SerialTap(Monitor()), [stray])
    assert kinds(items) == [(REQUEST, stray)]


def test_a_134_read_back_and_a_late_reply():
    stored = bytes([2, 4, 1, 0]) + struct.pack(">i", 5000)  # MVP REL 0, 5000 stored
    stored += bytes([sum(stored) & 0xFF])
    m = Monitor(timeout=0.5)
    tap = SerialTap(m)
    items = tap.feed(request(1, 134, 0, 0, 7), 1.0) + tap.feed(stored, 1.01)
    (ex,) = exchanges(items)
    assert ex.reply.reply.stored.opcode == 4 and ex.reply.reply.stored.value == 5000
    items = tap.feed(request(1, 6, 4), 2.0) + tap.quiet(3.0) + tap.feed(reply(6, 7), 3.1)
    gave_up, late = exchanges(items)
    assert gave_up.reply is None and "no reply within 0.5 s" in gave_up.note
    assert late.reply.late and late.request is gave_up.request
    assert m.summary.late == 1 and m.summary.unanswered == 0


exchange = st.one_of(
    st.tuples(st.sampled_from([6, 10]), st.integers(0, 255), st.integers(-2**31, 2**31 - 1),
              st.sampled_from([OK, INVALID_VALUE])),
    st.tuples(st.just(5), st.integers(0, 255), st.integers(-2**31, 2**31 - 1),
              st.sampled_from([OK, INVALID_VALUE])))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(exchange, st.binary(max_size=12), st.integers(1, 9)),
                min_size=1, max_size=8), st.data())
def test_every_frame_is_found_and_noise_is_never_a_frame(plan, data):
    """Exchanges with noise between them, cut into chunks anywhere: every frame comes out
    paired, and every noise byte as noise. (Noise in which nine bytes happen to add up is
    left out: no reader can tell it from a frame.)"""
    stream, frames, noise_at = b"", [], []
    for (cmd, typ, value, status), noise, _ in plan:
        req = request(1, cmd, typ, 0, value)
        rep = reply(cmd, value, status)
        if stream and noise:
            noise_at += range(len(stream), len(stream) + len(noise))
            stream += noise
        frames += [req, rep]
        stream += req + rep
    assume(not any(valid(stream[i:i + 9]) for i in noise_at))
    cuts = sorted(data.draw(st.sets(st.integers(1, max(1, len(stream) - 1)), max_size=10)))
    chunks = [stream[a:b] for a, b in zip([0] + cuts, cuts + [len(stream)])]
    m = Monitor()
    items = feed(SerialTap(m), chunks)
    assert [r for k, r in kinds(items) if k in (REQUEST, REPLY)] == frames
    assert sum(len(r) for k, r in kinds(items) if k == NOISE_RUN) == len(noise_at)
    assert all(e.reply is not None for e in exchanges(items))
    assert m.summary.unpaired == 0


# -- a bridge: the two directions apart ------------------------------------------------------

def test_the_two_directions_of_a_bridge_and_ascii_mode_as_text():
    m = Monitor()
    pair = SerialPair(m)
    items = []
    for direction, data in [("tx", request(1, 6, 1)), ("rx", reply(6, 3)),
                            ("tx", request(1, 139)), ("rx", reply(139, 0)),
                            ("tx", b"AGAP 1, 0\r"), ("rx", b"AGAP 1, 0\rBA 10"),
                            ("rx", b"0 3\r"), ("tx", b"ABIN\r"), ("rx", b"ABIN\rBA 100 0\r"),
                            ("tx", request(1, 6, 1)), ("rx", reply(6, 3))]:
        items += pair.feed(direction, data, 1.0)
    items += pair.end(2.0)
    texts = [(i.direction, i.raw) for i in items if not isinstance(i, Exchange)
             and i.kind == TEXT]
    assert texts == [("tx", b"AGAP 1, 0"), ("rx", b"AGAP 1, 0"), ("rx", b"BA 100 3"),
                     ("tx", b"ABIN"), ("rx", b"ABIN"), ("rx", b"BA 100 0")]
    assert [e.request.raw for e in exchanges(items) if e.reply is not None] == [
        request(1, 6, 1), request(1, 139), request(1, 6, 1)]


def test_filters():
    m = Monitor(load("TMCM-1311"))
    items = feed(SerialTap(m), [request(1, 6, 1), reply(6, 3), request(2, 6, 4),
                                reply(6, 9, module=2), request(1, 10, 66), reply(10, 1)])
    shown = [e.request.raw for e in exchanges(items) if Filter(params=["ActualPosition"],
                                                                 monitor=m)(e)]
    assert shown == [request(1, 6, 1)]
    assert [e.request.raw for e in exchanges(items) if Filter(addresses=[2])(e)] == [
        request(2, 6, 4)]
    assert [e.request.raw for e in exchanges(items) if Filter(ops=[10])(e)] == [
        request(1, 10, 66)]
    assert [e.request.raw for e in exchanges(items) if Filter(params=[66], ops=[6])(e)] == []


# -- the live tap ----------------------------------------------------------------------------

def _monitor(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "tmclsh", "monitor", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=tmclsh_env(), cwd=str(ROOT))


def _wait_listening(proc: subprocess.Popen) -> None:
    line = proc.stderr.readline()
    assert line.startswith("listening on"), line + proc.stderr.read()


@pytest.mark.parametrize("sig, status, words", [
    (signal.SIGINT, 0, None),
    (signal.SIGTERM, 143, "terminated (SIGTERM)"),
    (signal.SIGHUP, 129, "hung up (SIGHUP)")])
def test_a_signal_ends_the_monitor_with_its_words_and_status(sig, status, words):
    """Ctrl-C is how a monitor ends (0); SIGTERM and SIGHUP end it as they end every other
    command: the signal named on stderr in the words ``-f`` uses, its exit status (143, 129;
    it was 0), and the summary as ever. Sent as soon as it says it listens (see below)."""
    tap_master, tap_slave = os.openpty()
    tty.setraw(tap_slave)
    proc = _monitor("--port", os.ttyname(tap_slave))
    try:
        _wait_listening(proc)
        os.write(tap_master, request(1, 6, 4) + reply(6, 1000))
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=patience(20))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        os.close(tap_master)
        os.close(tap_slave)
    assert proc.returncode == status, err
    assert "Traceback" not in err, err
    if words is None:
        assert "stopped listening" not in err, err
    else:
        assert f"{words}: stopped listening" in err, err
    assert "frames in" in err.splitlines()[-1], err  # (the summary, last, as ever)


def test_a_tap_on_the_line_of_a_pyserial_master_and_a_module(tmp_path):
    """The master (pyserial) talks to a module written from the manual; everything on the
    line reaches the tap, with noise and a frame split in two; ``tmclsh monitor --port``
    shows the exchanges, and ``-o`` keeps the bytes for ``--log`` to show them again."""
    module = PtyModule(version="1311V111")
    tap_master, tap_slave = os.openpty()
    tty.setraw(tap_slave)
    capture = tmp_path / "tap.txt"
    proc = _monitor("--port", os.ttyname(tap_slave), "--json", "-o", str(capture))
    try:
        _wait_listening(proc)
        master = serial.Serial(module.path, timeout=1)
        sent = [request(1, 136), request(1, 5, 4, 0, 1000), request(1, 6, 4),
                request(1, 10, 66), request(1, 6, 1)]
        for i, req in enumerate(sent):
            master.write(req)
            answer = master.read(9)
            assert len(answer) == 9
            if i == 2:  # noise on the line between two exchanges
                os.write(tap_master, b"\xff\x00\x13")
            if i == 3:  # the request reaches the tap in two pieces
                os.write(tap_master, req[:4])
                time.sleep(0.02)
                os.write(tap_master, req[4:])
            else:
                os.write(tap_master, req)
            time.sleep(0.01)
            os.write(tap_master, answer)
            time.sleep(0.01)
        os.write(tap_master, request(1, 6, 2)[:6])  # cut off: a partial frame
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=patience(10))
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(tap_master)
        os.close(tap_slave)
        module.close()
    assert proc.returncode == 0, err
    objs = [json.loads(line) for line in out.splitlines()]
    frames = [o for o in objs if o.get("frame") in ("request", "reply")]
    assert [o["frame"] for o in frames] == ["request", "reply"] * 5
    assert frames[1]["version"] == "1311V111"
    assert (frames[4]["line"], frames[4]["param"]) == ("GAP 4, 0", "MaxPositioningSpeed")
    assert frames[5]["value"] == 1000 and frames[5]["status"] == 100
    # a latency is given (0.0 when a busy machine let the tap read request and reply at once:
    # the 10 ms between them is the test's, not something the monitor must see)
    assert isinstance(frames[5]["latency"], (int, float)) and frames[5]["latency"] >= 0
    assert frames[6]["line"] == "GGP 66, 0" and frames[7]["param"] == "SerialAddress"
    noise = [o for o in objs if o.get("frame") == "noise"]
    assert [n["bytes"] for n in noise] == ["ff 00 13", request(1, 6, 2)[:6].hex(" ")]
    assert "partial frame" in noise[1]["note"]
    summary = objs[-1]["summary"]
    assert summary["requests"] == 5 and summary["replies"] == 5 and summary["noise"] == 2
    assert summary["modules"] == {"1": "TMCM-1311 (1311V111)"}
    # the capture replays as the line did
    replay = subprocess.run([sys.executable, "-m", "tmclsh", "monitor", "--log", str(capture),
                             "--json"], capture_output=True, text=True, env=tmclsh_env(),
                            cwd=str(ROOT), timeout=30)
    assert replay.returncode == 0, replay.stderr
    again = [json.loads(line) for line in replay.stdout.splitlines()]
    assert [(o["frame"], o["bytes"]) for o in again if "frame" in o] == [
        (o["frame"], o["bytes"]) for o in objs if "frame" in o]


def test_a_tap_that_goes_away_ends_the_run_with_its_summary():
    tap_master, tap_slave = os.openpty()
    tty.setraw(tap_slave)
    proc = _monitor("--port", os.ttyname(tap_slave))
    try:
        _wait_listening(proc)
        os.write(tap_master, request(1, 6, 1) + reply(6, 7))
        time.sleep(0.3)
        os.close(tap_slave)
        os.close(tap_master)  # the adapter is unplugged
        out, err = proc.communicate(timeout=patience(10))
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, err
    assert "GAP 1, 0  =>  100 ok, GAP value 7" in out
    assert "tmclsh: lost " in err and "2 frames in" in err and "Traceback" not in err


def test_a_live_tap_whose_output_nobody_reads_keeps_reading_the_line():
    """``monitor --port`` with its stdout a pipe nobody reads: it still reads the line as
    fast as it comes (the bytes on the tap never back up) and counts every frame; the lines
    nobody took are dropped and counted."""
    import threading

    tap_master, tap_slave = os.openpty()
    tty.setraw(tap_slave)
    proc = _monitor("--port", os.ttyname(tap_slave), "--json")
    n = 3000
    chunk = b"".join(request(1, 6, 4, 0, 0) + reply(6, i) for i in range(100))
    done = threading.Event()

    def line() -> None:  # (a write blocks when the tap stops reading: the pty fills up)
        for _ in range(n // 100):
            os.write(tap_master, chunk)
            time.sleep(0.01)
        done.set()
    try:
        _wait_listening(proc)
        threading.Thread(target=line, daemon=True).start()
        assert done.wait(120), "the tap stopped reading the line"
        time.sleep(1.5)  # (the last requests' replies are read; nothing waits)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        os.close(tap_master)
        os.close(tap_slave)
    assert proc.returncode == 143, err  # (SIGTERM's status, as every command's)
    summary = json.loads(out.splitlines()[-1])["summary"]
    assert (summary["requests"], summary["replies"], summary["unanswered"]) == (n, n, 0)
    shown = sum(1 for text in out.splitlines() if '"frame"' in text)
    assert summary["dropped_lines"] > 0 and shown + summary["dropped_lines"] == 2 * n
    assert summary["shown"] == shown  # (what reached the output, not what was dropped too)


def test_a_live_tap_ends_when_the_reader_of_its_output_has_gone():
    """``monitor --port TAP | head -3``: once ``head`` has its lines and leaves, the monitor
    ends (quietly, exit 1, as other tools on a broken pipe) instead of listening on for
    ever with nobody to tell; its summary still reaches stderr."""
    import threading

    from conftest import patience

    tap_master, tap_slave = os.openpty()
    tty.setraw(tap_slave)
    proc = _monitor("--port", os.ttyname(tap_slave))
    stop = threading.Event()

    def line() -> None:  # a master polling a module, as long as the test runs
        while not stop.is_set():
            os.write(tap_master, request(1, 6, 1) + reply(6, 7))
            time.sleep(0.02)
    try:
        _wait_listening(proc)
        threading.Thread(target=line, daemon=True).start()
        assert "GAP 1, 0" in proc.stdout.readline()
        proc.stdout.close()  # the reader has what it wanted, and goes
        proc.wait(timeout=patience(30))
        err = proc.stderr.read()
    finally:
        stop.set()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(tap_master)
        os.close(tap_slave)
    assert proc.returncode == 1, err
    assert "Traceback" not in err and "Broken pipe" not in err, err
    assert " frames in " in err, err



def test_the_monitor_says_it_listens_only_once_a_signal_ends_it_as_it_should(monkeypatch):
    """"listening on" is the moment a user (or a test, or a supervisor) may signal it: by
    then SIGINT, SIGTERM and SIGHUP must end it with its summary. It said so before setting
    them (a Ctrl-C at once was Python's own, exit 130: seen once in CI under load)."""
    from tmclsh.cli.main import main
    from tmclsh.shell.features import monitor as front

    order: list[str] = []
    real = front.interruptible
    monkeypatch.setattr(front, "interruptible", lambda: (order.append("handlers"), real())[1])
    real_print = print

    def noting(*args, **kw):
        if args and str(args[0]).startswith("listening on"):
            order.append("listening")
        real_print(*args, **kw)

    monkeypatch.setattr("builtins.print", noting)
    tap_master, tap_slave = os.openpty()
    tty.setraw(tap_slave)
    try:
        assert main(["monitor", "--port", os.ttyname(tap_slave), "--duration", "0.3"]) == 0
    finally:
        os.close(tap_master)
        os.close(tap_slave)
    assert order == ["handlers", "listening"], order
