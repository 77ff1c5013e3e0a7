"""The per-module table of ``monitor`` and ``bridge`` (ops/tally.py), fed the items the
monitor's pairing returns for real bytes (frames made as tests/responder.py makes them), on
the test's own clock."""

from __future__ import annotations

import pytest

from responder import reply, version_reply
from tmclsh.ops.monitor import RX, TX, Monitor, SerialPair
from tmclsh.ops.tally import Tally
from tmclsh.tmcl.modules import load


def request(addr: int, cmd: int, typ: int = 0, motor: int = 0, value: int = 0) -> bytes:
    body = bytes([addr, cmd, typ, motor]) + (value & 0xFFFFFFFF).to_bytes(4, "big")
    return body + bytes([sum(body) & 0xFF])


class Line:
    """A bridge's two directions read by the monitor's pairing, every item given to a
    ``Tally``."""

    def __init__(self, module=None, timeout: float = 1.0):
        self.monitor = Monitor(module, timeout=timeout)
        self.pair = SerialPair(self.monitor)
        self.tally = Tally(self.monitor.module_for)

    def exchange(self, t: float, req: bytes, answer: bytes | None, took: float = 0.001):
        self.tally.take_all(self.pair.feed(TX, req, t))
        if answer is not None:
            self.tally.take_all(self.pair.feed(RX, answer, t + took))

    def expire(self, now: float) -> None:
        self.tally.take_all(self.monitor.expire(now))

    def row(self, now: float | None = None, where: str = "@1"):
        return next(r for r in self.tally.rows(now) if r.where == where)


def test_exchanges_errors_by_name_slowest_and_unanswered_per_module():
    line = Line()
    line.exchange(10.0, request(1, 6, 4), reply(6, 1000))
    line.exchange(10.1, request(1, 5, 4, 0, -5), reply(5, -5, 4))  # refused: invalid value
    line.exchange(10.2, request(1, 99), reply(99, 0, 2))  # invalid command
    line.exchange(10.3, request(1, 99), reply(99, 0, 2))
    line.exchange(10.4, request(1, 6, 1), reply(6, 7), took=0.25)  # the slowest
    line.exchange(10.8, request(3, 6, 4), reply(6, 5, module=3), took=0.002)
    line.exchange(11.0, request(1, 6, 0), None)  # never answered
    line.expire(13.0)
    one, three = line.row(), line.row(where="@3")
    assert one.exchanges == 6 and three.exchanges == 1
    assert one.errors == {"invalid value": 1, "invalid command": 2}
    assert three.errors == {}
    assert one.unanswered == 1 and three.unanswered == 0
    assert one.slowest.command == "GAP 1, 0" and one.slowest.latency == pytest.approx(0.25)
    assert three.slowest.latency == pytest.approx(0.002)
    assert [r.where for r in line.tally.rows()] == ["@1", "@3"]


def test_the_rate_is_taken_over_a_sliding_window_on_the_callers_clock():
    line = Line()
    for i in range(50):  # 10 a second for 5 s
        line.exchange(100.0 + i / 10, request(1, 6, 4), reply(6, 1))
    assert line.row(104.95).per_second == pytest.approx(10, rel=0.05)
    assert line.row(107.45).per_second == pytest.approx(5, rel=0.05)  # half the window
    assert line.row(200.0).per_second == 0  # the traffic stopped: the rate falls to 0
    assert line.row(200.0).exchanges == 50


def test_a_first_exchange_is_not_rated_a_thousand_a_second():
    line = Line()
    line.exchange(5.0, request(1, 6, 4), reply(6, 1))
    assert line.row(5.001).per_second == pytest.approx(1.0)


def test_last_value_per_parameter_by_the_module_files_names():
    """Reads give the reply's value, writes the module accepted the request's; a refused
    write leaves the value read before. Names appear once the module is learnt from 136."""
    line = Line()
    line.exchange(1.0, request(1, 6, 4), reply(6, 51200))  # GAP 4 before the module is known
    line.exchange(1.1, request(1, 15, 3, 2), reply(15, 1))  # GIO 3, 2
    assert {v.name: v.value for v in line.row().values} == {"GAP 4, 0": 51200, "GIO 3, 2": 1}
    line.exchange(1.2, request(1, 136), version_reply("1311V111"))
    line.exchange(1.3, request(1, 5, 4, 0, 1000), reply(5, 1000))  # SAP 4, 0, 1000
    line.exchange(1.4, request(1, 5, 4, 0, 9), reply(5, 9, 4))  # refused: stays 1000
    line.exchange(1.5, request(1, 9, 0, 2, -42), reply(9, -42))  # SGP 0, 2, -42
    values = {v.name: v.value for v in line.row().values}
    assert values["MaxPositioningSpeed"] == 1000
    assert values[f"{_bank2_name()} (bank 2)"] == -42
    assert line.row().module == "TMCM-1311"
    speed = next(v for v in line.row().values if v.name == "MaxPositioningSpeed")
    assert speed.param is not None and speed.param.unit


def _bank2_name() -> str:
    return load("TMCM-1311").glob(0, 2).name


def test_a_module_given_names_its_parameters_from_the_start_and_motors_on_several():
    line = Line(load("TMCM-351"))
    line.exchange(1.0, request(1, 6, 4, 2), reply(6, 300))
    assert [v.name for v in line.row().values] == ["MaxPositioningSpeed (motor 2)"]


def test_no_reply_by_design_is_no_unanswered_and_a_reply_without_its_request_is_counted():
    line = Line()
    line.exchange(1.0, request(1, 242), None)  # the bootloader's: no reply comes
    line.tally.take_all(line.pair.feed(RX, reply(6, 0, 2), 1.5))  # nobody asked
    row = line.row()
    assert (row.exchanges, row.unanswered, row.unpaired) == (1, 0, 1)
    assert row.errors == {"invalid command": 1}


def test_a_can_module_is_its_id():
    from tmclsh.ops.monitor import CanReader

    monitor = Monitor()
    reader = CanReader(monitor, [5], [2])
    tally = Tally(monitor.module_for)
    tally.take_all(reader.feed(1.0, 5, bytes([6, 4, 0, 0, 0, 0, 0])))
    tally.take_all(reader.feed(1.001, 2, bytes([5, 100, 6, 0, 0, 0x03, 0xe8])))
    (row,) = tally.rows()
    assert row.where == "id 5" and row.exchanges == 1
    assert [v.value for v in row.values] == [1000]
