"""The monitor on CAN: a python-can virtual bus with a master the test drives through python-can
and the simulator answering, in one process; and log files written by python-can's own writers
(several formats) from frames this test builds, read back through ``can.LogReader``."""

from __future__ import annotations

import json
import struct
import threading
import time

import can
import pytest

from tmclsh.cli import main as cli
from tmclsh.sim import Simulator
from tmclsh.sim.serve import serve_can

OK, INVALID_COMMAND = 100, 2
T0 = 1_700_000_000.0


def instruction(cmd: int, typ: int = 0, motor: int = 0, value: int = 0) -> bytes:
    """A CAN request's data: command, type, motor, value MSB first (the manual's layout)."""
    return struct.pack(">BBBi", cmd, typ, motor, value)


def answer(cmd: int, value: int, status: int = OK, module: int = 1) -> bytes:
    """A CAN reply's data: module address, status, command, value."""
    return struct.pack(">BBBi", module, status, cmd, value)


def msg(t: float, arb: int, data: bytes, **kw) -> can.Message:
    return can.Message(timestamp=t, arbitration_id=arb, data=data, is_extended_id=False, **kw)


def objects(text: str) -> list[dict]:
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def frames(objs: list[dict]) -> list[dict]:
    return [o for o in objs if "frame" in o]


# -- a live bus --------------------------------------------------------------------------------

def _subscribers(channel: str) -> int:
    from can.interfaces import virtual

    return len(virtual.channels.get(channel, ()))


def _listening(channel: str, before: int) -> None:
    deadline = time.monotonic() + 5
    while _subscribers(channel) <= before:
        assert time.monotonic() < deadline, "the monitor did not join the bus"
        time.sleep(0.01)


def test_a_master_and_the_simulator_on_a_virtual_bus(capsys):
    channel = "monitor-live"
    sim = Simulator("TMCM-1311")
    server = serve_can(sim, "virtual", channel)
    master = can.Bus(interface="virtual", channel=channel)
    rc: list[int] = []
    before = _subscribers(channel)
    thread = threading.Thread(target=lambda: rc.append(cli.main(
        ["monitor", "--can", f"virtual:{channel}", "--json", "--count", "13"])))
    thread.start()
    try:
        _listening(channel, before)
        sent = [instruction(136), instruction(6, 4), instruction(5, 4, 0, 1234),
                instruction(10, 66), instruction(250), instruction(134, 0, 0, 0)]
        for data in sent:
            master.send(msg(0, 1, data))
            got = master.recv(1)
            assert got is not None and got.arbitration_id == 2
        master.send(msg(0, 0x123, b"\x01\x02\x03"))  # other traffic on the bus
        thread.join(10)
    finally:
        master.shutdown()
        server.close()
        sim.close()
    assert rc == [0]
    objs = objects(capsys.readouterr().out)
    got = frames(objs)
    assert [o["frame"] for o in got] == ["request", "reply"] * 6 + ["other"]
    assert all(o["can_id"] == 1 for o in got[0:12:2]) and all(
        o["can_id"] == 2 for o in got[1:12:2])
    assert got[1]["version"] == "1311V111"
    # the module was learnt from its version string: names from its data
    assert (got[2]["line"], got[2]["param"]) == ("GAP 4, 0", "MaxPositioningSpeed")
    assert got[5]["status"] == OK and got[5]["value"] == 1234 and got[5]["latency"] >= 0
    assert got[7]["param"] == "SerialAddress"
    assert got[8]["line"] == "250 0, 0, 0" and got[9]["status"] == INVALID_COMMAND  # no such
    assert got[9]["error"] == "invalid command"
    assert got[11]["stored"]["op"] == 0  # empty program memory reads back as zeros
    assert got[12] == {"t": got[12]["t"], "frame": "other", "can_id": 0x123,
                       "note": "id 291: no TMCL id", "bytes": "01 02 03"}
    assert objs[-1]["summary"]["requests"] == 6 and objs[-1]["summary"]["other"] == 1


# -- log files ---------------------------------------------------------------------------------

def _traffic() -> list[can.Message]:
    """A master's session as a log holds it: requests on id 1, replies on id 2, 0.5 ms apart."""
    out, t = [], T0
    for req, rep in [(instruction(136), b"1311V111"),
                     (instruction(6, 1), answer(6, -5000)),
                     (instruction(5, 4, 0, 1000), answer(5, 1000)),
                     (instruction(9, 77, 0, 5), answer(9, 5, 4)),
                     (instruction(200), answer(200, 0, INVALID_COMMAND)),
                     (instruction(134, 0, 0, 3), struct.pack(">BBBi", 4, 1, 0, 500)),
                     (instruction(4, 0, 0, 100), answer(4, 100))]:
        out += [msg(t, 1, req), msg(t + 0.0005, 2, rep)]
        t += 0.01
    out.append(msg(t, 2, answer(138, 1, 128)))  # target reached, motor 0
    out.append(msg(t + 0.01, 1, instruction(242, 0x81, 0x92, 0xA3B4C5D6 - 2**32)))
    out.append(msg(t + 0.02, 0x300, b"\xaa"))
    return out


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".trc", ".log", ".csv"])
def test_logs_of_every_format_python_can_writes(tmp_path, capsys, suffix):
    path = tmp_path / f"bus{suffix}"
    with can.Logger(str(path)) as log:
        for m in _traffic():
            log.on_message_received(m)
    assert cli.main(["monitor", "--log", str(path), "--json"]) == 0
    objs = objects(capsys.readouterr().out)
    got = frames(objs)
    assert [o["frame"] for o in got] == ["request", "reply"] * 7 + [
        "event", "request", "no-reply", "other"]
    assert got[1]["version"] == "1311V111"
    assert (got[2]["line"], got[2]["param"], got[3]["value"]) == (
        "GAP 1, 0", "ActualPosition", -5000)
    assert got[3]["latency"] == pytest.approx(0.0005, abs=2e-5)
    assert got[7]["status"] == 4 and got[7]["error"] == "invalid value"
    # bootloader commands (200 erase, 242 enter the bootloader), decoded or by number
    assert (got[8]["op"], got[8]["bytes"]) == (200, "c8 00 00 00 00 00 00")
    assert got[9]["error"] == "invalid command"
    assert got[11]["stored"] == {"op": 4, "type": 1, "motor": 0, "value": 500}
    assert got[14]["event"] == 138 and got[14]["motors"] == [0]
    assert (got[15]["op"], got[15]["type"], got[15]["motor"]) == (242, 0x81, 0x92)
    assert got[15]["bytes"] == "f2 81 92 a3 b4 c5 d6"
    # 242 answers nothing by design (the instruction set's reply = "none"): no error
    assert got[16]["op"] == 242 and got[16]["note"] == "no reply expected"
    assert got[17]["can_id"] == 0x300
    s = objs[-1]["summary"]
    assert (s["requests"], s["replies"], s["events"], s["other"]) == (8, 7, 1, 1)
    assert s["unanswered"] == 0
    assert s["statuses"] == {"2": 1, "4": 1, "100": 5}
    assert s["modules"] == {"1": "TMCM-1311 (1311V111)"}


def test_a_log_shown_for_people_with_filters_and_written_again(tmp_path, capsys):
    path = tmp_path / "bus.asc"
    with can.Logger(str(path)) as log:
        for m in _traffic():
            log.on_message_received(m)
    again = tmp_path / "again.blf"
    assert cli.main(["monitor", "--log", str(path), "--op", "GAP,SAP", "-o", str(again)]) == 0
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert len(lines) == 2
    assert "id 1  GAP 1, 0  // ActualPosition  =>  100 ok, GAP value -5000 (ActualPosition " \
           "= -5000" in lines[0] and lines[0].endswith("0.50 ms")
    assert "SAP 4, 0, 1000  // MaxPositioningSpeed  =>  100 ok" in lines[1]
    assert "17 frames" in err and "statuses: 2 invalid command x1, 4 invalid value x1, " \
                                  "100 ok x5" in err
    assert "modules: @1 TMCM-1311 (1311V111)" in err and "shown: 2 lines" in err
    # -o kept every frame, filters notwithstanding, in a log python-can reads back
    assert len(list(can.LogReader(str(again)))) == len(_traffic())
    assert cli.main(["monitor", "--log", str(again), "--json", "--count", "3"]) == 0
    got = frames(objects(capsys.readouterr().out))
    assert [o["frame"] for o in got] == ["request", "reply", "request"]


def test_ids_are_learnt_from_frames_that_answer_each_other(tmp_path, capsys):
    path = tmp_path / "ids.log"
    with can.Logger(str(path)) as log:
        t = T0
        for arb_req, arb_rep in [(5, 6), (7, 8), (5, 6)]:
            log.on_message_received(msg(t, arb_req, instruction(6, 1)))
            log.on_message_received(msg(t + 0.001, arb_rep, answer(6, arb_req)))
            t += 0.01
    assert cli.main(["monitor", "--log", str(path), "--json"]) == 0
    got = frames(objects(capsys.readouterr().out))
    assert [(o["frame"], o["can_id"]) for o in got] == [
        ("request", 5), ("reply", 6), ("request", 7), ("reply", 8), ("request", 5),
        ("reply", 6)]
    assert [o["value"] for o in got if o["frame"] == "reply"] == [5, 7, 5]
    # given ids are taken as given: nothing is learnt
    assert cli.main(["monitor", "--log", str(path), "--json", "--can-id", "5",
                     "--reply-id", "6"]) == 0
    got = frames(objects(capsys.readouterr().out))
    assert [(o["frame"], o["can_id"]) for o in got] == [
        ("request", 5), ("reply", 6), ("other", 7), ("other", 8), ("request", 5),
        ("reply", 6)]


def test_a_file_python_can_cannot_read(tmp_path, capsys):
    bad = tmp_path / "bus.asc"
    bad.write_text("not a log\n")
    assert cli.main(["monitor", "--log", str(bad)]) == 1  # an .asc with no frames: said
    err = capsys.readouterr().err
    assert err == f"tmclsh: {bad}: no CAN frames in it (an empty log, or not the .asc its " \
        "name says)\n"
    other = tmp_path / "bus.xyz"
    other.write_text("hello\n")
    assert cli.main(["monitor", "--log", str(other)]) != 0
    err = capsys.readouterr().err
    assert "bus.xyz:1: not a line of a serial capture" in err and "Traceback" not in err


def test_what_the_command_line_refuses(run_tmclsh):
    r = run_tmclsh("monitor")
    assert r.returncode == 2 and "one of the arguments --can --log --port is required" in r.stderr
    r = run_tmclsh("monitor", "--log", "x.asc", "--op", "GAPP")
    assert r.returncode == 2 and "'GAPP' is no command" in r.stderr
    r = run_tmclsh("monitor", "--log", "x.asc", "--param", "ActualPositon")
    assert r.returncode == 2 and "'ActualPositon' is no parameter name" in r.stderr
    r = run_tmclsh("monitor", "--log", "x.asc", "--address", "5-2")
    assert r.returncode == 2 and "runs backwards" in r.stderr
    r = run_tmclsh("monitor", "--can", "nosuchiface:0")
    assert r.returncode == 3 and "Traceback" not in r.stderr
    r = run_tmclsh("monitor", "--log", "missing.asc")
    assert r.returncode == 1 and "missing.asc" in r.stderr and "Traceback" not in r.stderr


def test_a_reply_of_eight_data_bytes_reads_the_same_everywhere(tmp_path, capfd):
    # (capfd: the bridge describes in a process of its own, writing to the same stdout)
    """A TMCM-1260 answers with DLC 8 (its seven bytes and their sum): the client, the
    monitor (a log of it), the bridge (a serial master to the CAN module) and ``.decode``
    read the same reply: module 1, status 100, GAP, value 1000; nothing called unanswered."""
    import serial
    from responder import CanModule

    from tmclsh.client.connect import connect
    from tmclsh.shell.features.trace import decode_hex

    captured = bytes.fromhex("01 64 06 00 00 03 e8 56")  # 7 bytes, then their sum
    # .decode, of the candump line a user pastes
    (_, readings), = decode_hex("can0  002   [8]  01 64 06 00 00 03 E8 56", None)
    assert readings[0].plausible and "1000" in readings[0].text
    assert "status 100" in readings[0].text or "ok" in readings[0].text
    # the monitor, reading a log of the exchange
    path = tmp_path / "eight.asc"
    with can.Logger(str(path)) as log:
        log.on_message_received(msg(T0, 1, instruction(6, 4)))
        log.on_message_received(msg(T0 + 0.001, 2, captured))
    assert cli.main(["monitor", "--log", str(path), "--json"]) == 0
    objs = objects(capfd.readouterr().out)
    (req, rep) = frames(objs)
    assert (rep["frame"], rep["op"], rep["status"], rep["value"]) == ("reply", 6, 100, 1000)
    assert objs[-1]["summary"]["unanswered"] == 0 and objs[-1]["summary"]["other"] == 0
    # the client and the bridge, against a module that answers so
    channel = "eight-everywhere"
    bus = can.Bus(interface="virtual", channel=channel)
    module = CanModule(bus, version="1311V111", eighth="sum")
    module.values[(4, 0, False)] = 1000
    try:
        c = connect(can=f"virtual:{channel}", timeout=1)
        try:
            assert c.value("GAP 4, 0") == 1000
        finally:
            c.close()
        from test_bridge import _free_port, request

        port_no = _free_port()
        rc: list[int] = []
        thread = threading.Thread(target=lambda: rc.append(cli.main(
            ["bridge", "--tcp", f"127.0.0.1:{port_no}", "--can", f"virtual:{channel}",
             "--json", "--count", "2"])))
        thread.start()
        deadline = time.monotonic() + 10
        while True:
            try:
                port = serial.serial_for_url(f"socket://127.0.0.1:{port_no}", timeout=5)
                break
            except serial.SerialException:
                assert time.monotonic() < deadline
                time.sleep(0.05)
        with port:
            port.write(request(1, 6, 4))
            got = port.read(9)
        thread.join(20)
    finally:
        module.close()
        bus.shutdown()
    assert got == bytes([2, 1, 100, 6, 0, 0, 3, 0xE8]) + bytes([sum(got[:8]) & 0xFF])
    assert rc == [0]
    objs = objects("\n".join(line for line in capfd.readouterr().out.splitlines()
                             if line.startswith("{")))
    (req, rep) = frames(objs)
    assert (rep["frame"], rep["op"], rep["status"], rep["value"]) == ("reply", 6, 100, 1000)


def test_requests_sent_ahead_of_their_replies_are_paired_in_order():
    """Three requests to one id before the first reply: each reply answers its own; a
    request whose module answered a later one instead got no answer (and says so)."""
    from tmclsh.ops.monitor import CanReader, Exchange, Monitor

    reader = CanReader(Monitor())
    items = []
    for i, cmd in enumerate((6, 5, 6, 10)):
        items += reader.feed(T0 + i * 0.001, 1, instruction(cmd, 4, 0, i))
    for i, (cmd, value) in enumerate(((6, 7), (5, 1), (10, 9))):  # (the second GAP: none)
        items += reader.feed(T0 + 0.01 + i * 0.001, 2, answer(cmd, value))
    ex = [x for x in items if isinstance(x, Exchange)]
    assert [(x.request.instruction.value, x.reply.reply.value if x.reply else x.note)
            for x in ex] == [(0, 7), (1, 1),
                             (2, "no reply: a later request to this module was answered"),
                             (3, 9)]
    s = reader.monitor.summary
    assert (s.unanswered, s.late, s.unpaired) == (1, 0, 0)


# -- a log read at the reader's pace (issue 34) -------------------------------------------------

class _Writes:
    """A stream that counts the writes it is given."""

    def __init__(self) -> None:
        self.parts: list[str] = []

    def write(self, text: str) -> None:
        self.parts.append(text)

    def flush(self) -> None:
        pass


def _shown(path, *, batch: int | None, plain: bool) -> _Writes:
    from tmclsh.link.canlog import read_log
    from tmclsh.ops import listen
    from tmclsh.ops.filter import Filter
    from tmclsh.ops.monitor import CanReader, Monitor
    from tmclsh.shell.features.monitor import View, show_items

    monitor = Monitor()
    reader = CanReader(monitor)
    if plain:  # the general path alone, as before the common pair had its own
        reader._plain_reply = lambda *args: None
    stream = _Writes()
    view = View(monitor, json_mode=True, stream=stream)
    if batch is not None:
        view.batch = batch
    filt = Filter((), (), (), monitor)
    for items in listen.can_log(read_log(str(path)), reader):
        show_items(items, view, filt, monitor.summary, None)
    view.summary(monitor.summary)
    return stream


def test_a_log_is_written_in_batches_with_what_the_general_path_says(tmp_path):
    path = tmp_path / "bus.asc"
    with can.Logger(str(path)) as log:
        for i in range(300):
            for m in _traffic():
                m.timestamp += i
                log.on_message_received(m)
    batched = _shown(path, batch=None, plain=False)
    one_by_one = _shown(path, batch=1, plain=True)
    lines = "".join(one_by_one.parts).splitlines()
    assert len(lines) == 300 * 18 + 1
    assert "".join(batched.parts).splitlines() == lines  # the same lines, the same order
    assert len(batched.parts) < len(lines) / 100  # ... in a few writes, not one a line
