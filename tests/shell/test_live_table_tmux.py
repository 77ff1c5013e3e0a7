"""The live table of ``bridge`` and ``monitor`` in a real terminal (tmux), read as a person
reads it: one row per module at the bottom, its counts, the error statuses by name and the
parameters' last values, the lines scrolling above; the last state left on the screen at
Ctrl-C. The module is tests/responder.py's (written from the manuals, not the simulator)."""

from __future__ import annotations

import re
import struct

import serial

from conftest import patience
from responder import PtyModule, reply, version_reply
from tmux import needs_tmux

pytestmark = needs_tmux


def request(addr: int, cmd: int, typ: int = 0, motor: int = 0, value: int = 0) -> bytes:
    body = struct.pack(">BBBBi", addr, cmd, typ, motor, value)
    return body + bytes([sum(body) & 0xFF])


def _row(screen: str, where: str) -> list[str]:
    """The table's lines of the module's row (its first line and those that continue it)."""
    lines = screen.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(f"│{where} "))
    row = [lines[start]]
    for line in lines[start + 1:]:
        if not line.startswith("│ "):
            break
        row.append(line)
    return row


def test_the_bridge_shows_a_row_per_module_with_errors_by_name_and_last_values(terminal):
    module = PtyModule(version="1311V111")
    module.refuse.add((5, 4, 0))  # SAP 4, 0, ...: invalid value
    term = terminal(width=150, height=40, timeout=patience(20))
    try:
        term.start("bridge", "--pty", "--port", module.path)
        endpoint = re.search(r"^(/dev/\S+)$", term.wait_for(re.compile(r"(?m)^/dev/\S+$")),
                             re.M).group(1)
        with serial.Serial(endpoint, timeout=patience(10)) as port:
            for req in (request(1, 136), request(1, 9, 0, 2, -42), request(1, 5, 4, 0, 77),
                        request(1, 99), request(1, 6, 1), request(1, 15, 3, 2)):
                port.write(req)
                assert len(port.read(9)) >= 9
        screen = term.wait_for(lambda s: "│@1 TMCM-1311" in s and "│         6 │" in s,
                               what="the module's row with 6 exchanges")
        row = "\n".join(_row(screen, "@1"))
        assert "invalid value x1" in row and "invalid command x1" in row
        assert "UserVariable (bank 2) = -42" in row  # (SGP's value, named by the module file)
        assert "ActualPosition = 0" in row and "OUT_3 (bank 2) = 0" in row
        assert "module" in screen and "exchanges" in screen and "per s" in screen
        lines = screen.splitlines()
        header = next(i for i, line in enumerate(lines) if "exchanges" in line)
        above = "\n".join(lines[:header])
        assert "SGP 0, 2, -42" in above and "4 invalid value" in above  # the line stream
        term.keys("C-c")
        screen = term.wait("EXIT=0")
        assert "│@1 TMCM-1311" in screen and "invalid value x1" in screen  # left as it ended
        assert "Ctrl-C ends" not in screen.split("exchanges", 1)[1]
        assert "6 requests, 6 replies" in screen
    finally:
        module.close()


def _capture(path) -> None:
    """A serial capture (as ``bridge -o`` writes it) of two modules: @1 answers a GAP and
    refuses a command, @3 answers a GGP; one request to @1 gets no answer."""
    t = 1718000000.0
    lines = ["# tmclsh capture of a serial line: time (s since the epoch), tx/rx where the "
             "link tells, bytes in hex"]
    frames = [("tx", request(1, 136)), ("rx", version_reply("1311V111")),
              ("tx", request(1, 6, 4)), ("rx", reply(6, 2000)),
              ("tx", request(1, 6, 200)), ("rx", reply(6, 0, 3)),  # wrong type
              ("tx", request(3, 10, 0, 2)), ("rx", reply(10, 17, module=3)),
              ("tx", request(1, 6, 1))]  # never answered
    for i, (way, raw) in enumerate(frames):
        lines.append(f"{t + i * 0.01:.6f} {way} {raw.hex(' ')}")
    path.write_text("\n".join(lines) + "\n")


def test_monitor_reading_a_log_leaves_the_table_of_what_it_read(terminal, tmp_path):
    log = tmp_path / "session.txt"
    _capture(log)
    term = terminal(width=150, height=40, timeout=patience(20))
    term.start("monitor", "--log", str(log))
    screen = term.wait("EXIT=0")
    one = "\n".join(_row(screen, "@1"))
    three = "\n".join(_row(screen, "@3"))
    assert "TMCM-1311" in one and "│         4 │" in one
    assert "wrong type x1" in one and "unanswered x1" in one
    assert "MaxPositioningSpeed = 2000 pps" in one
    assert "│         1 │" in three and "GGP 0, 2 = 17" in three  # (@3's type is not known)


def test_no_table_on_a_terminal_is_the_lines_alone(terminal, tmp_path):
    log = tmp_path / "session.txt"
    _capture(log)
    term = terminal(width=150, height=40, timeout=patience(20))
    term.start("monitor", "--log", str(log), "--no-table")
    screen = term.wait("EXIT=0")
    assert "GAP 4, 0" in screen and "exchanges" not in screen and "│" not in screen


def test_the_table_is_refused_with_json(run_tmclsh, tmp_path):
    log = tmp_path / "session.txt"
    _capture(log)
    proc = run_tmclsh("monitor", "--log", str(log), "--json", "--table")
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip().splitlines() == [
        "tmclsh: --table is drawn for people: not with --json"]
