"""Several modules at once from Python, without a shell (tmclsh/ops/units.py): each unit's
result as data, units on one line in turn, and the stop reaching every unit, on the simulator
through ``tmclsh.connect`` and on modules written from the manual (tests/responder.py)."""

from __future__ import annotations

import threading
import time

import pytest
from responder import Module, SharedLine

from tmclsh.base.errors import ConnectError, ValidationError
from tmclsh.ops import units

ROR, MST, SAP = 1, 3, 5
PATIENCE = 30.0  # s: generous bounds for a busy machine


def test_a_run_on_two_simulated_modules_gives_each_units_result(capsys):
    plan = [units.Unit(1, "sim", "TMCM-1311"), units.Unit(2, "sim", "TMCM-1640")]

    def fn(client):
        client.execute("SAP 4, 0, 1234")
        return client.module.name, client.value("GAP 4, 0")

    results = units.run(plan, fn)
    assert [(r.unit.number, r.value, r.error, r.ok) for r in results] == [
        (1, ("TMCM-1311", 1234), None, True), (2, ("TMCM-1640", 1234), None, True)]
    assert capsys.readouterr() == ("", "")


def test_units_on_one_line_take_turns_and_each_addresses_its_own_module():
    bus = SharedLine()
    one, five = Module(address=1, line=bus), Module(address=5, line=bus)
    try:
        plan = [units.Unit(1, "port", bus.path, 1), units.Unit(2, "port", bus.path, 5)]
        running, most = [], []
        lock = threading.Lock()

        def fn(client):
            with lock:
                running.append(client.address)
                most.append(len(running))
            try:
                client.execute(f"SAP 4, 0, {100 + client.address}")
                time.sleep(0.2)
                return client.value("GAP 4, 0")
            finally:
                with lock:
                    running.remove(client.address)

        results = units.run(plan, fn)
        assert [r.value for r in results] == [101, 105]
        assert max(most) == 1  # never two units on the line at once
        assert [g for g in one.got if g[0] == SAP] == [(SAP, 4, 0, 101)]
        assert [g for g in five.got if g[0] == SAP] == [(SAP, 4, 0, 105)]
    finally:
        bus.close()


def test_a_unit_without_a_module_fails_alone():
    m = Module(version="1311V111")
    try:
        plan = [units.Unit(1, "port", m.path, 1), units.Unit(2, "port", m.path, 7)]
        results = units.run(plan, lambda c: c.value("GAP 4, 0"))
        assert results[0].ok and results[0].value == 0
        assert isinstance(results[1].error, ConnectError) and not results[1].connected
    finally:
        m.close()


def test_ctrl_c_stops_every_units_motor_and_starts_no_other():
    modules = [Module(version="1311V111"), Module(version="1311V111")]
    bus = SharedLine()
    third, fourth = Module(address=1, line=bus), Module(address=3, line=bus)
    try:
        plan = [units.Unit(1, "port", modules[0].path, 1),
                units.Unit(2, "port", modules[1].path, 1),
                units.Unit(3, "port", bus.path, 1), units.Unit(4, "port", bus.path, 3)]

        def fn(client):
            client.execute("ROR 0, 1000")
            while True:
                time.sleep(0.05)

        main = threading.main_thread()

        def press_ctrl_c():
            deadline = time.monotonic() + PATIENCE
            while not all(ROR in m.commands() for m in (*modules, third)):
                assert time.monotonic() < deadline
                time.sleep(0.05)
            units._raise_in(main, KeyboardInterrupt)

        helper = threading.Thread(target=press_ctrl_c, daemon=True)
        helper.start()
        results = units.run(plan, fn)
        helper.join(PATIENCE)
        assert [r.stopped for r in results[:3]] == [True, True, True]
        assert not results[3].ran and results[3].why_not == "interrupted"
        for m in (*modules, third):
            heard = m.commands()
            assert MST in heard[heard.index(ROR):]  # stopped after it was set turning
        assert fourth.commands() == []  # never started: nothing sent to it
    finally:
        bus.close()
        for m in modules:
            m.close()


def test_the_shell_and_python_share_the_unit():
    """The shell plans its units as ops.units.Unit: one kind of unit, one runner."""
    from tmclsh.shell.features import units as shell_units

    assert shell_units.Unit is units.Unit
    assert units.Unit(3, "sim", "TMCM-1311").label == "3 sim TMCM-1311"


def test_ctrl_c_stops_a_unit_whose_function_waits_in_c_at_once():
    # time.sleep, Event.wait: a thread blocked in C takes the stop raised in it only when
    # the wait returns; its motor must not turn until then
    m = Module(version="1311V111")
    started, released = threading.Event(), threading.Event()
    stopped_in_time: list[bool] = []
    try:
        def fn(client):
            client.execute("ROR 0, 1000")
            started.set()
            released.wait(PATIENCE)  # (blocked in C until the test lets it go)

        main = threading.main_thread()

        def press_ctrl_c():
            try:
                assert started.wait(PATIENCE)
                units._raise_in(main, KeyboardInterrupt)
                deadline = time.monotonic() + PATIENCE / 2
                while MST not in m.commands() and time.monotonic() < deadline:
                    time.sleep(0.05)
                stopped_in_time.append(MST in m.commands())
            finally:
                released.set()

        helper = threading.Thread(target=press_ctrl_c, daemon=True)
        helper.start()
        (result,) = units.run([units.Unit(1, "port", m.path, 1)], fn)
        helper.join(PATIENCE)
        assert stopped_in_time == [True]  # stopped while its function still waited
        assert result.stopped and not result.ok
        heard = m.commands()
        assert heard[heard.index(ROR):].count(MST) == 1  # stopped once, not again on waking
    finally:
        m.close()


def test_a_unit_of_no_known_kind_is_refused_when_the_plan_is_made():
    # it was a TypeError from connect() inside the run, as that unit's error
    with pytest.raises(ValidationError, match="kind 'usb' is not one of port, can, sim"):
        units.Unit(1, "usb", "/dev/ttyUSB0")
