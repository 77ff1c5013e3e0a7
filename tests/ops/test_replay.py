"""``tmclsh replay``: a session captured by tmclsh's own bridge (serial) or by python-can's
writers (a virtual CAN bus) is sent again to modules written from the manuals
(tests/responder.py) and to the simulator; the same module gives no difference, a parameter
changed in it is found and named, writes are refused without --yes, a CAN capture whose
replies carry eight data bytes replays, several modules replay each at its own id."""

from __future__ import annotations

import json
import signal
import struct
import subprocess
import sys
import time

import can
import pytest
import serial

from conftest import ROOT, patience, tmclsh_env
from responder import CanModule, PtyModule, SharedLine, reply
from tmclsh.cli import main as cli
from tmclsh.ops import replay as rp

GAP, SAP, GGP = 6, 5, 10


def request(addr: int, cmd: int, typ: int = 0, motor: int = 0, value: int = 0) -> bytes:
    body = struct.pack(">BBBBi", addr, cmd, typ, motor, value)
    return body + bytes([sum(body) & 0xFF])


def objects(text: str) -> list[dict]:
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def _bridge_capture(module_path: str, out: str, frames: list[bytes]) -> None:
    """Traffic of a master tmclsh did not write (raw pyserial) through ``tmclsh bridge -o``."""
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "bridge", "--pty", "--port",
                             module_path, "-o", out, "--json"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=tmclsh_env(),
                            cwd=str(ROOT))
    try:
        endpoint = proc.stdout.readline().strip()
        assert endpoint, proc.stderr.read()
        with serial.Serial(endpoint, 9600, timeout=5) as master:
            for f in frames:
                master.write(f)
                assert len(master.read(9)) == 9
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 0, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


READS = [request(1, GAP, 4, 0), request(1, GGP, 0, 0), request(1, GAP, 6, 0),
         request(1, 136, 1, 0)]


@pytest.fixture
def module():
    m = PtyModule(version="1161V130")
    m.values[(4, 0, False)] = 51200
    m.values[(6, 0, False)] = 128
    yield m
    m.close()


def test_a_bridge_capture_replays_to_the_same_module_without_differences(module, tmp_path,
                                                                          capsys):
    cap = str(tmp_path / "session.txt")
    _bridge_capture(module.path, cap, READS)
    module.got.clear()
    assert cli.main(["replay", cap, "--port", module.path, "--json"]) == 0
    objs = objects(capsys.readouterr().out)
    assert objs[-1]["replayed"] == 4 and objs[-1]["differences"] == 0, objs
    assert [g for g in module.got if g[0] != 136][-3:] == [(GAP, 4, 0, 0), (GGP, 0, 0, 0),
                                                           (GAP, 6, 0, 0)]


def test_a_parameter_changed_in_the_module_is_found_and_named(module, tmp_path, capsys):
    cap = str(tmp_path / "session.txt")
    _bridge_capture(module.path, cap, READS)
    module.values[(6, 0, False)] = 99  # someone changed the motor current since
    assert cli.main(["replay", cap, "--port", module.path, "--json"]) == 1
    objs = objects(capsys.readouterr().out)
    diffs = [o for o in objs if o.get("differs")]
    assert len(diffs) == 1, objs
    d = diffs[0]
    assert (d["op"], d["type"], d["motor"]) == (GAP, 6, 0)
    assert d["captured"]["value"] == 128 and d["now"]["value"] == 99
    assert d["differences"] == ["value 128 -> 99"]
    assert d["latency_captured"] is not None and d["latency"] is not None
    assert objs[-1]["exit"] == 1
    # the table names the command and both values
    assert cli.main(["replay", cap, "--port", module.path]) == 1
    out = capsys.readouterr().out
    assert "GAP 6, 0" in out and "value 128 -> 99" in out and "1 difference" in out


def test_a_module_at_another_address_is_found_where_the_capture_says(tmp_path, capsys):
    m = PtyModule(version="1161V130", address=5)
    try:
        m.values[(4, 0, False)] = 7
        cap = str(tmp_path / "at5.txt")
        _bridge_capture(m.path, cap, [request(5, GAP, 4, 0), request(5, 136, 1, 0)])
        m.got.clear()
        assert cli.main(["replay", cap, "--port", m.path, "--json"]) == 0  # (no -a 5)
        assert objects(capsys.readouterr().out)[-1]["addresses"] == [5]
        assert (GAP, 4, 0, 0) in m.got
    finally:
        m.close()


def test_two_modules_on_one_line_replay_each_at_its_address(tmp_path, capsys):
    bus = SharedLine()
    a = PtyModule(version="1161V130", address=1, line=bus)
    b = PtyModule(version="1161V130", address=5, line=bus)
    try:
        a.values[(4, 0, False)], b.values[(4, 0, False)] = 11, 55
        cap = str(tmp_path / "two.txt")
        _bridge_capture(bus.path, cap, [request(1, GAP, 4, 0), request(5, GAP, 4, 0),
                                        request(1, GGP, 0, 0)])
        assert rp.read_capture(cap).addresses == [1, 5]
        assert cli.main(["replay", cap, "--port", bus.path, "--json"]) == 0
        assert objects(capsys.readouterr().out)[-1]["differences"] == 0
        b.values[(4, 0, False)] = 56
        assert cli.main(["replay", cap, "--port", bus.path, "--json"]) == 1
        diffs = [o for o in objects(capsys.readouterr().out) if o.get("differs")]
        assert [(d["address"], d["differences"]) for d in diffs] == [(5, ["value 55 -> 56"])]
    finally:
        bus.close()


def test_writes_are_refused_without_yes_and_named(module, tmp_path, capsys):
    cap = str(tmp_path / "session.txt")
    _bridge_capture(module.path, cap, READS[:1] + [request(1, SAP, 4, 0, 1000),
                                                    request(1, 1, 0, 0, 500)])
    module.got.clear()
    assert cli.main(["replay", cap, "--port", module.path]) == 2
    err = capsys.readouterr().err
    # (and the bridge's own closing stop, which the capture holds: it crossed the line)
    assert "commands that write, store or move" in err
    assert "#2" in err and "SAP 4, 0, 1000" in err and "#3" in err and "ROR 0, 500" in err
    assert "nothing was sent" in err
    assert module.got == []  # not even a connect
    assert cli.main(["replay", cap, "--port", module.path, "--json"]) == 2
    (obj,) = objects(capsys.readouterr().out)
    assert [(w["op"], w["value"]) for w in obj["writes"]][:2] == [(SAP, 1000), (1, 500)]
    assert module.got == []
    # with --yes they are named, sent, and the safety stop ends the run
    module.values[(4, 0, False)] = 51200  # (as it was when the capture began)
    module.got.clear()
    assert cli.main(["replay", cap, "--port", module.path, "--yes"]) == 0
    err = capsys.readouterr().err
    assert "commands that write, store or move" in err and "SAP 4, 0, 1000" in err
    sent = module.commands()
    assert SAP in sent and 1 in sent
    assert 3 in sent[sent.index(1):]  # MST after the ROR: the stop
    assert module.values[(4, 0, False)] == 1000


def test_the_closing_stop_of_several_modules_says_whose_motors_each_line_names(tmp_path,
                                                                               capsys):
    bus = SharedLine()
    PtyModule(version="1161V130", address=1, line=bus)  # (each joins the line itself)
    PtyModule(version="1161V130", address=5, line=bus)
    try:
        cap = str(tmp_path / "two.txt")
        _bridge_capture(bus.path, cap, [request(1, SAP, 4, 0, 1000), request(5, SAP, 4, 0, 5)])
        assert cli.main(["replay", cap, "--port", bus.path]) == 2
        assert "holds 2 commands that write, store or move" in capsys.readouterr().err
        assert cli.main(["replay", cap, "--port", bus.path, "--yes"]) == 0
        err = capsys.readouterr().err
        # "replay ended: stopped motor 0" twice said nothing of which module's motor 0
        assert "replay ended (address 1): stopped motor" in err, err
        assert "replay ended (address 5): stopped motor" in err, err
    finally:
        bus.close()


def test_the_closing_stop_leaves_alone_an_address_the_capture_only_read(tmp_path, capsys):
    bus = SharedLine()
    a = PtyModule(version="1161V130", address=1, line=bus)
    b = PtyModule(version="1161V130", address=5, line=bus)
    try:
        cap = str(tmp_path / "two.txt")
        _bridge_capture(bus.path, cap, [request(1, SAP, 4, 0, 1000), request(5, GAP, 4, 0)])
        # one command: said in the singular
        assert cli.main(["replay", cap, "--port", bus.path]) == 2
        assert "holds 1 command that writes, stores or moves" in capsys.readouterr().err
        a.got.clear()
        b.got.clear()
        assert cli.main(["replay", cap, "--port", bus.path, "--yes"]) == 0
        err = capsys.readouterr().err
        assert "replay ended (address 1): stopped motor" in err, err
        assert "(address 5)" not in err, err
        assert 3 in a.commands() and b.commands() == [GAP], b.got  # (no MST at 5)
    finally:
        bus.close()


def test_an_address_that_never_answered_gets_no_stop_and_no_alarm(module, tmp_path, capsys):
    # a master asked at address 5, where no module is (a capture by hand, as the bridge
    # writes it): the stop after the replay's write at 1 does not wait out address 5's
    # retries and report a module "stopped answering" that never was there
    cap = tmp_path / "lone.txt"
    lines = ["# tmclsh capture of a serial line: time (s since the epoch), tx/rx where the "
             "link tells, bytes in hex"]
    t = 1796427344.0
    for i, req in enumerate([request(1, SAP, 4, 0, 1000), request(5, GAP, 1, 0)]):
        lines.append(f"{t + i:.6f} tx {req.hex(' ')}")
        if req[0] == 1:
            lines.append(f"{t + i + 0.001:.6f} rx {reply(SAP, 1000).hex(' ')}")
    cap.write_text("\n".join(lines) + "\n")
    assert rp.read_capture(str(cap)).addresses == [1, 5]
    cli.main(["replay", str(cap), "--port", module.path, "--yes", "--timeout", "0.2"])
    err = capsys.readouterr().err
    assert "replay ended (address 1): stopped motor" in err, err
    assert "address 5" not in err and "check the connection" not in err, err


def test_ctrl_c_ends_a_replay_that_wrote_with_the_safety_stop(module, tmp_path, capsys):
    """Paced as captured, the second request is half a minute away; Ctrl-C comes first."""
    import _thread
    import threading

    cap = tmp_path / "paced.txt"
    t = 1_700_000_000.0
    cap.write_text("".join(f"{when:.6f} {d} {data.hex(' ')}\n" for when, d, data in [
        (t, "tx", request(1, 1, 0, 0, 500)), (t + 0.001, "rx", reply(1, 500)),
        (t + 30, "tx", request(1, GAP, 4, 0)), (t + 30.001, "rx", reply(GAP, 51200))]))
    module.got.clear()

    def interrupt() -> None:
        deadline = time.monotonic() + 20
        while not any(g[0] == 1 for g in module.got) and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.2)
        _thread.interrupt_main()

    threading.Thread(target=interrupt, daemon=True).start()
    started = time.monotonic()
    assert cli.main(["replay", str(cap), "--port", module.path, "--yes", "--as-captured"]) \
        == 130
    assert time.monotonic() - started < 25
    sent = module.commands()
    assert 1 in sent and 3 in sent[sent.index(1):], sent  # ROR, then MST: the stop
    assert (GAP, 4, 0, 0) not in module.got  # the rest was not sent
    captured = capsys.readouterr()
    assert "replay ended: stopped motor" in captured.err
    assert "replayed 1 of 2 exchanges" in captured.out and "(interrupted)" in captured.out


# -- CAN: python-can's writers on a virtual bus --------------------------------------------------

def _record(channel: str, path: str, drive, heard, replies: frozenset = frozenset({2})) -> None:
    """What crosses the bus while ``drive()`` runs, written by python-can's own writer; it
    ends once the writer has taken every request the modules heard (``heard()`` of them)
    and a reply (a frame on one of ``replies``) to each, however long a busy machine takes
    to hand them over."""
    listener = can.Bus(interface="virtual", channel=channel)
    writer = can.Logger(path)
    seen = {"requests": 0, "replies": 0}

    class Count(can.Listener):
        def on_message_received(self, msg: can.Message) -> None:
            seen["replies" if msg.arbitration_id in replies else "requests"] += 1

    notifier = can.Notifier(listener, [writer, Count()])  # (the writer first: in order)
    try:
        drive()
        deadline = time.monotonic() + patience(30)
        while min(seen.values()) < heard() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert min(seen.values()) >= heard() > 0, (seen, heard())
    finally:
        notifier.stop()
        writer.stop()
        listener.shutdown()


@pytest.mark.parametrize("eighth", [None, "sum"])
def test_a_can_log_replays_and_eight_byte_replies_are_paired(eighth, tmp_path, capsys):
    """The vendor's TMCM-1260 answers with eight data bytes: the capture pairs them."""
    from tmclsh.client.connect import connect

    channel = f"replay-{eighth}"
    m = CanModule(can.Bus(interface="virtual", channel=channel), version="1311V111",
                  eighth=eighth)
    m.values[(4, 0, False)] = 51200
    log = str(tmp_path / "session.asc")
    try:
        def drive() -> None:
            c = connect(can=f"virtual:{channel}", timeout=1.0)
            try:
                c.send("GAP", 4, 0)
                c.send("GGP", 0, 0)
            finally:
                c.close()

        _record(channel, log, drive, lambda: len(m.got))
        cap = rp.read_capture(log)
        assert cap.link == "can" and all(c.reply is not None for c in cap.exchanges)
        assert cli.main(["replay", log, "--can", f"virtual:{channel}", "--json"]) == 0
        assert objects(capsys.readouterr().out)[-1]["differences"] == 0
        m.values[(4, 0, False)] = 1000
        assert cli.main(["replay", log, "--can", f"virtual:{channel}", "--json"]) == 1
        diffs = [o for o in objects(capsys.readouterr().out) if o.get("differs")]
        assert [(d["op"], d["type"], d["differences"]) for d in diffs] == [
            (GAP, 4, ["value 51200 -> 1000"])]
    finally:
        m.close()


def test_several_modules_replay_each_at_its_own_id(tmp_path, capsys):
    from tmclsh.client.connect import connect

    channel = "replay-two"
    a = CanModule(can.Bus(interface="virtual", channel=channel), can_id=1, reply_id=2,
                  version="1311V111")
    b = CanModule(can.Bus(interface="virtual", channel=channel), can_id=3, reply_id=4,
                  version="1311V111", address=3)
    a.values[(4, 0, False)], b.values[(4, 0, False)] = 111, 333
    log = str(tmp_path / "two.asc")
    try:
        def drive() -> None:
            for can_id, reply_id in ((1, 2), (3, 4)):
                c = connect(can=f"virtual:{channel}", can_id=can_id, reply_id=reply_id,
                            timeout=1.0)
                try:
                    c.send("GAP", 4, 0)
                finally:
                    c.close()

        _record(channel, log, drive, lambda: len(a.got) + len(b.got),
                replies=frozenset({2, 4}))
        cap = rp.read_capture(log)
        assert cap.addresses == [1, 3]
        a.got.clear()
        b.got.clear()
        assert cli.main(["replay", log, "--can", f"virtual:{channel}", "--json"]) == 0
        assert objects(capsys.readouterr().out)[-1]["differences"] == 0
        assert (GAP, 4, 0, 0) in a.got and (GAP, 4, 0, 0) in b.got
        b.values[(4, 0, False)] = 7
        assert cli.main(["replay", log, "--can", f"virtual:{channel}", "--json"]) == 1
        diffs = [o for o in objects(capsys.readouterr().out) if o.get("differs")]
        assert [(d["address"], d["differences"]) for d in diffs] == [(3, ["value 333 -> 7"])]
    finally:
        a.close()
        b.close()


# -- the simulator, and the other formats ------------------------------------------------------

def _sim_capture(path: str, lines: list[str]) -> None:
    from tmclsh.client.connect import connect
    from tmclsh.ops.capture import CaptureWriter

    c = connect(sim="TMCM-1311")
    w = CaptureWriter(path)
    remove = c.add_tracer(lambda d, raw, _: w.write(time.time(), bytes(raw), d)
                          if d in ("tx", "rx") else None)
    try:
        for line in lines:
            c.execute(line)
    finally:
        remove()
        w.close()
        c.close()


def test_the_simulator_replays_a_capture_of_itself(tmp_path, capsys):
    cap = str(tmp_path / "sim.txt")
    _sim_capture(cap, ["GAP 4, 0", "GGP 66, 0", "GIO 0, 0", "SAP 4, 0, 2000", "GAP 4, 0"])
    assert cli.main(["replay", cap, "--sim", "--yes", "--as-captured", "--json"]) == 0
    objs = objects(capsys.readouterr().out)
    assert objs[-1]["differences"] == 0 and objs[-1]["simulated"] is True
    assert objs[-1]["replayed"] == 5


def test_no_module_is_exit_3_and_the_one_error_record(tmp_path, capsys):
    cap = str(tmp_path / "sim.txt")
    _sim_capture(cap, ["GAP 4, 0"])
    missing = str(tmp_path / "no-such-port")
    assert cli.main(["replay", cap, "--port", missing]) == 3
    assert cli.main(["replay", cap, "--port", missing, "--json"]) == 3
    (record,) = objects(capsys.readouterr().out)
    assert list(record)[0] == "line" and record["line"] is None
    assert missing in record["error"] and record["exit"] == 3


def test_candump_lines_and_transcripts_are_read(tmp_path):
    dump = tmp_path / "dump.txt"
    dump.write_text("  can0  001   [7]  06 04 00 00 00 00 00\n"
                    "  can0  002   [8]  01 64 06 00 00 c8 00 33\n")
    cap = rp.read_capture(dump)
    assert cap.link == "can" and len(cap.exchanges) == 1
    assert cap.exchanges[0].reply.value == 51200
    log = tmp_path / "unit.log"
    log.write_text("12:00:00.000 tx> 01 06 04 00 00 00 00 00 0b  GAP 4, 0\n"
                   "12:00:00.004 <rx 02 01 64 06 00 00 c8 00 35  100 ok, value 51200\n"
                   "12:00:00.005 out GAP 4, 0 = 51200\n")
    cap = rp.read_capture(log)
    (ex,) = cap.exchanges
    assert ex.reply.value == 51200 and abs(ex.latency - 0.004) < 1e-6


def test_bad_captures_are_one_line_and_nothing_sent(tmp_path, capsys):
    junk = tmp_path / "junk.txt"
    junk.write_text("hello there\n")
    assert cli.main(["replay", str(junk), "--sim"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nothing was sent" in err and "Traceback" not in err
