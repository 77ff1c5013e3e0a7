"""Issue 33's done-when line for ``replay``, end to end as a technician meets it: a master
tmclsh did not write (raw pyserial) talks to a module written from the manual
(tests/responder.py) through ``tmclsh bridge --pty -o``, the monitor's capture of a live
serial line; ``tmclsh replay`` sends that capture to the same module: no difference; then
values and statuses are changed in the module and every exchange they touch is named, no
other. A varied mix: GAP, SAP, GGP, GIO, 136, reads answered with errors (status 4 for a
refused parameter, status 2 for commands the module does not know).

The small session runs in the main suite; the 50,000-exchange one is ``slow`` (.ci/run runs
it after the main suite). Nothing here is timed: every wait is for a condition, bounded by
``patience``."""

from __future__ import annotations

import json
import random
import signal
import struct
import subprocess
import sys
import threading

import pytest
import serial

from conftest import ROOT, patience, tmclsh_env
from responder import OK, PtyModule

GAP, SAP, GGP, GIO, GCO, GAS, VERSION = 6, 5, 10, 15, 31, 135, 136
REFUSED = (GAP, 222, 0)  # answered status 4 (invalid value) while the capture is made
SCRATCH = (5, 7, 140, 153, 154)  # axis parameters the master writes before it reads them


def frame(addr: int, cmd: int, typ: int = 0, motor: int = 0, value: int = 0) -> bytes:
    body = struct.pack(">BBBBi", addr, cmd, typ, motor, value)
    return body + bytes([sum(body) & 0xFF])


class LineModule(PtyModule):
    """The responder's module, with inputs GIO reads (``io[(port, bank)]``): a module on a
    pty that knows nothing of tmclsh."""

    def __init__(self, **kw):
        super().__init__(version="1161V130", **kw)
        self.io: dict[tuple[int, int], int] = {}

    def respond(self, command, type_, motor, value):
        if command == GIO and (command, type_, motor) not in self.refuse:
            self.got.append((command, type_, motor, value))
            return OK, self.io.get((type_, motor), 0)
        return super().respond(command, type_, motor, value)


def session(n: int, seed: int = 33) -> list[tuple[int, int, int, int]]:
    """``n`` requests (command, type, motor/bank, value) of a master polling and setting a
    module: many parameters, inputs, its version, a refused read, unknown commands; each
    scratch parameter written before it is first read (a replay starts from the module
    as the capture left it)."""
    rnd = random.Random(seed)
    axis = list(range(0, 60)) + [140, 153, 154, 194, 204, 209, REFUSED[1]]
    glob = [(t, 0) for t in range(64, 90)] + [(t, 2) for t in range(0, 16)]
    written: set[int] = set()
    out = []
    for _ in range(n):
        r = rnd.random()
        if r < 0.40:
            typ = rnd.choice(axis)
            if typ in SCRATCH and typ not in written:
                typ = 4
            out.append((GAP, typ, rnd.choice((0, 0, 0, 1)) if typ != REFUSED[1] else 0, 0))
        elif r < 0.50:
            typ = rnd.choice(SCRATCH)
            written.add(typ)
            out.append((SAP, typ, 0, rnd.randrange(-2**31, 2**31)))
        elif r < 0.70:
            typ, bank = rnd.choice(glob)
            out.append((GGP, typ, bank, 0))
        elif r < 0.90:
            out.append((GIO, rnd.randrange(8), rnd.choice((0, 1)), 0))
        elif r < 0.95:
            out.append((VERSION, rnd.choice((0, 1)), 0, 0))
        else:
            out.append((rnd.choice((GCO, GAS)), rnd.randrange(4), 0, 0))
    return out


def fill(m: LineModule, seed: int = 7) -> None:
    """What the module holds: a value for every parameter and input the session reads."""
    rnd = random.Random(seed)
    for typ in range(0, 256):
        for motor in (0, 1):
            m.values[(typ, motor, False)] = rnd.randrange(-2**31, 2**31)
        for bank in (0, 2):
            m.values[(typ, bank, True)] = rnd.randrange(-2**31, 2**31)
    for port in range(8):
        m.io[(port, 0)] = rnd.randrange(2)
        m.io[(port, 1)] = rnd.randrange(4096)
    m.refuse.add(REFUSED)


def capture(port: str, path: str, requests: list[tuple[int, int, int, int]]) -> None:
    """The master's session through ``tmclsh bridge --pty --port PORT -o PATH``, ended
    with Ctrl-C as a user ends it (the bridge tells and writes everything it forwarded
    before it exits)."""
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "bridge", "--pty", "--port",
                             port, "-o", path], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=tmclsh_env(),
                            cwd=str(ROOT))
    lines: list[str] = []
    try:
        endpoint = proc.stdout.readline().strip()
        assert endpoint, proc.stderr.read()
        # (its lines read as a terminal would: a pipe left full would only drop them)
        reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
        reader.start()
        with serial.Serial(endpoint, 9600, timeout=patience(10)) as master:
            for cmd, typ, motor, value in requests:
                master.write(frame(1, cmd, typ, motor, value))
                got = master.read(9)
                assert len(got) == 9, (cmd, typ, motor, got)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=patience(120))
        reader.join(patience(30))
        err = proc.stderr.read()
        assert proc.returncode == 0, err
        assert "not written" not in err and "not told" not in err, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def replay(*args: str) -> tuple[int, str, str]:
    proc = subprocess.run([sys.executable, "-m", "tmclsh", "replay", *args],
                          capture_output=True, text=True, env=tmclsh_env(), cwd=str(ROOT),
                          timeout=patience(600))
    return proc.returncode, proc.stdout, proc.stderr


def objects(text: str) -> list[dict]:
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def planted(m: LineModule, requests: list[tuple[int, int, int, int]]) -> dict[int, str]:
    """Change what the module holds and answers, as someone might have since the capture;
    returns each exchange (numbered from 1) that must now differ, with the difference that
    names it."""
    axis = (GAP, 6, 0)
    glob = (GGP, 75, 0)
    io = (GIO, 3, 1)
    refused_now = (GAP, 13, 0)  # read fine in the capture, now status 4
    old = {axis: m.values[(6, 0, False)], glob: m.values[(75, 0, True)],
           io: m.io[(3, 1)]}
    m.values[(6, 0, False)] = old[axis] + 1
    m.values[(75, 0, True)] = old[glob] - 1
    m.io[(3, 1)] = old[io] ^ 1
    m.refuse.add(refused_now)
    m.refuse.discard(REFUSED)  # refused in the capture, answered now
    expect = {}
    for i, (cmd, typ, motor, _) in enumerate(requests, 1):
        key = (cmd, typ, motor)
        if key in old:
            now = old[key] + (1 if key == axis else -1) if key != io else old[key] ^ 1
            expect[i] = f"value {old[key]} -> {now}"
        elif key == refused_now:
            expect[i] = f"status {OK} -> 4"
        elif key == REFUSED:
            expect[i] = f"status 4 -> {OK}"
    return expect


def check_session(tmp_path, n: int) -> None:
    m = LineModule()
    try:
        fill(m)
        requests = session(n)
        cap = str(tmp_path / "session.txt")
        capture(m.path, cap, requests)
        from tmclsh.ops.replay import read_capture

        exchanges = read_capture(cap).exchanges
        assert [(c.instruction.opcode, c.instruction.type, c.instruction.motor,
                 c.instruction.signed_value) for c in exchanges] == requests
        assert all(c.reply is not None for c in exchanges)
        statuses = {c.reply.status for c in exchanges}
        assert {OK, 4, 2} <= statuses, statuses  # (error answers are in the capture too)

        # the same module: nothing differs
        code, out, err = replay(cap, "--port", m.path, "--yes", "--json")
        assert code == 0, err
        end = objects(out)[-1]
        assert (end["replayed"], end["exchanges"], end["differences"]) == (n, n, 0), end

        # what was planted: every exchange it touches named, no other
        expect = planted(m, requests)
        assert len(expect) >= 5
        code, out, err = replay(cap, "--port", m.path, "--yes", "--json")
        assert code == 1, err
        objs = objects(out)
        diffs = {o["index"]: o for o in objs if o.get("differs")}
        assert sorted(diffs) == sorted(expect)
        for index, words in expect.items():
            d = diffs[index]
            assert words in d["differences"], (index, d)
            assert (d["op"], d["type"], d["motor"]) == requests[index - 1][:3]
        assert objs[-1]["differences"] == len(expect) and objs[-1]["exit"] == 1

        # the table: exchange number, command, what was captured and what answers now
        code, out, err = replay(cap, "--port", m.path, "--yes")
        assert code == 1, err
        rows = {int(line.split("│")[1]): line for line in out.splitlines()
                if line.count("│") > 4 and line.split("│")[1].strip().isdigit()}
        assert sorted(rows) == sorted(expect)
        first_axis = next(i for i, r in enumerate(requests, 1) if r[:3] == (GAP, 6, 0))
        row = rows[first_axis]
        was = m.values[(6, 0, False)] - 1
        assert "GAP" in row and f"{OK} {was}" in row and f"{OK} {was + 1}" in row, row
        assert f"{len(expect)} differences" in out.splitlines()[-1]
    finally:
        m.close()


def test_a_bridge_capture_of_a_varied_session_replays_and_plants_are_named(tmp_path):
    check_session(tmp_path, 2_000)


@pytest.mark.slow
def test_fifty_thousand_exchanges_captured_by_the_monitor_replay(tmp_path):
    check_session(tmp_path, 50_000)


# -- CAN: candump's screen lines in the shape of the vendor library's tracker ---------------------

def candump_line(can_id: int, data: bytes) -> str:
    return f"  can0  {can_id:03X}   [{len(data)}]  {data.hex(' ').upper()}\n"


def test_a_candump_with_eight_byte_frames_and_doubled_replies_replays(tmp_path, capsys):
    """The shape of the candump pasted in the vendor library's issue tracker (PyTrinamic
    over socketcan, a TMCM-1260): every request eight data bytes (the serial checksum, the
    address counted, after the seven), every reply eight (a 0 after the seven), and each
    reply twice (two modules answering one id). Replayed to a module answering in eight
    bytes: no difference; a value changed in it since: that exchange named."""
    import can

    from tmclsh.cli import main as cli
    from responder import CanModule

    values = {4: 2000000000, 5: 200000, 6: 128, 1: -20000}
    session = [(SAP, 5, 0, values[5]), (GAP, 4, 0, 0), (GAP, 6, 0, 0), (SAP, 4, 0, values[4]),
               (GAP, 1, 0, 0), (GAP, 5, 0, 0), (GGP, 66, 0, 0)]
    lines = []
    for cmd, typ, motor, value in session:
        seven = struct.pack(">BBBi", cmd, typ, motor, value)
        lines.append(candump_line(1, seven + bytes([(1 + sum(seven)) & 0xFF])))
        answer = values.get(typ, 0) if cmd == GAP else (0 if cmd == GGP else value)
        data = struct.pack(">BBBi", 1, OK, cmd, answer) + b"\x00"
        lines += [candump_line(2, data)] * 2
    dump = tmp_path / "candump.txt"
    dump.write_text("".join(lines))
    channel = "replay-vendor-dump"
    m = CanModule(can.Bus(interface="virtual", channel=channel), version="1260V115",
                  eighth="zero")
    try:
        m.values.update({(t, 0, False): v for t, v in values.items()})
        args = ["replay", str(dump), "--can", f"virtual:{channel}", "--yes", "--json"]
        assert cli.main(args) == 0
        end = objects(capsys.readouterr().out)[-1]
        assert (end["replayed"], end["differences"], end["link"]) == (7, 0, "can"), end
        m.values[(1, 0, False)] = 12345  # the motor moved since
        assert cli.main(args) == 1
        diffs = [o for o in objects(capsys.readouterr().out) if o.get("differs")]
        assert [(d["index"], d["op"], d["type"], d["differences"]) for d in diffs] == [
            (5, GAP, 1, ["value -20000 -> 12345"])]
    finally:
        m.close()
