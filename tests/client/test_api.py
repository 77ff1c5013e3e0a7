"""The Python API: ``tmclsh.connect(...)`` and what ``import tmclsh`` costs."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

import tmclsh
from tmclsh.base.errors import (ConnectError, StatusError, TmclError, TmclTimeoutError,
                                ValidationError)
from tmclsh.tmcl.frames import Status

from conftest import ROOT, tmclsh_env

HEAVY = ("prompt_toolkit", "rich", "can")


def test_connect_to_a_port_send_and_execute(pty_sim):
    sim, path = pty_sim
    with tmclsh.connect(port=path, timeout=0.5) as c:
        assert c.module.name == "TMCM-1311"  # asked with 136
        r = c.send(5, 1, 0, 90000)  # SAP 1, 0, 90000
        assert r.status == Status.OK and r.opcode == 5
        assert c.send(6, 1, 0).value == 90000
        res = c.execute("GAP 1, 0")
        assert res.ok and res.value == 90000 and res.reply.opcode == 6
        assert c.value("GAP ActualPosition, 0") == 90000
        assert sim.param("axis", 1, 0) == 90000
    assert not c.connected


def _attached(monkeypatch, *devices: str) -> None:
    """What pyserial lists: these devices, each a Trinamic USB module (vendor 0x2A3C)."""
    from serial.tools import list_ports
    from serial.tools.list_ports_common import ListPortInfo

    ports = []
    for device in devices:
        p = ListPortInfo(device)
        p.vid, p.pid = 0x2A3C, 0x0100
        ports.append(p)
    monkeypatch.setattr(list_ports, "comports", lambda *a, **k: list(ports))


def test_connect_opens_the_one_usb_module_never_the_simulator_by_itself(monkeypatch, pty_sim):
    """As the command line does: a jig written in Python must not pass on a simulator with
    its cable unplugged (it did: connect() opened the simulator)."""
    from tmclsh.base.errors import ConnectError

    _attached(monkeypatch)
    with pytest.raises(ConnectError, match='sim="TMCM-1311" for the simulator'):
        tmclsh.connect()
    _attached(monkeypatch, "/dev/ttyACM7", "/dev/ttyACM8")
    with pytest.raises(ConnectError, match="2 Trinamic USB modules attached"):
        tmclsh.connect()
    sim, path = pty_sim
    _attached(monkeypatch, path)
    with tmclsh.connect() as c:
        assert not c.transport.simulated and c.describe().startswith(path)
        assert c.execute("GAP 1, 0").ok
    with tmclsh.connect(sim="TMCM-1311") as c:
        assert c.transport.simulated and c.module.name == "TMCM-1311"
    with pytest.raises(ValidationError, match="only one"):
        tmclsh.connect(port="loop://", sim="TMCM-1311")


@pytest.mark.parametrize("kw, message", [
    ({"timeout": float("nan")}, "timeout: must be a number of seconds from 0.001 to 60, got nan"),
    ({"timeout": float("inf")}, "timeout: must be a number of seconds from 0.001 to 60, got inf"),
    ({"retries": -1}, "retries: must be a whole number from 0 to 10, got -1"),
    ({"address": 256}, "address: must be a whole number from 0 to 255, got 256"),
    ({"baud": 12345}, "baud: must be one of 9600, "),
    ({"port": "loop://", "can_id": 4096}, "can_id: must be a whole number from 0 to 2047"),
])
def test_connect_refuses_a_setting_as_the_command_line_does(kw, message):
    """Was a bare ValueError from the client (nan), or no error at all (inf: a wait forever)."""
    from tmclsh.base.limits import SettingError

    with pytest.raises(SettingError) as exc:
        tmclsh.connect(**kw)
    assert str(exc.value).startswith(message)
    assert isinstance(exc.value, ValidationError) and isinstance(exc.value, ValueError)


def test_connect_checks_the_module_given(pty_sim):
    sim, path = pty_sim
    with tmclsh.connect(port=path, module="TMCM-1311", timeout=0.5) as c:
        assert c.version == "1311V111"  # asked (136), not assumed
    with pytest.raises(ConnectError, match="-m TMCM-351 does not match.*is a TMCM-1311"):
        tmclsh.connect(port=path, module="TMCM-351", timeout=0.5)


def test_connect_to_nothing_fails_cleanly(tmp_path):
    with pytest.raises(TmclError, match="no such port"):
        tmclsh.connect(port=str(tmp_path / "ttyACM7"))
    with pytest.raises(TmclTimeoutError, match="no module answered at address 1"):
        tmclsh.connect(port="loop://", timeout=0.05, retries=0)  # nobody answers 136


def test_errors_are_the_builtins_a_caller_expects(client):
    client.address = 77  # nobody there
    with pytest.raises(TimeoutError):
        client.send(6, 1, 0, timeout=0.05)
    client.address = 1
    with pytest.raises(ValueError):
        client.send(6, 1, 300)  # motor out of 0..255: refused before sending
    client.execute("SGP 73, 0, 1234")  # lock the configuration EEPROM
    with pytest.raises(StatusError) as exc:
        client.execute("STAP 4, 0")
    assert exc.value.status == Status.EEPROM_LOCKED and exc.value.reply.status == 5


@pytest.mark.parametrize("call", [
    lambda c: c.send(6, 1, 300),  # motor/bank out of 0..255
    lambda c: c.send(6, 256, 0),  # type
    lambda c: c.send(6, 1, 0, 2**40),  # value beyond 32 bits
    lambda c: c.send(6, 1, 0, 1.5),  # not an integer
    lambda c: c.send(6, 1, 0, timeout=0),  # no time to answer
    lambda c: c.value("GAP 1, 0", timeout=-1),
])
def test_a_raw_field_the_frame_cannot_carry_is_a_tmcl_error_and_nothing_is_sent(call):
    """A script that catches ``TmclError`` (README: every error is one) catches these too;
    they were plain ValueErrors."""
    from responder import Module

    m = Module(version="1311V111")
    try:
        with tmclsh.connect(port=m.path, timeout=1.0) as c:
            heard = len(m.got)
            with pytest.raises(ValidationError) as exc:
                call(c)
            assert isinstance(exc.value, TmclError) and isinstance(exc.value, ValueError)
            assert "\n" not in str(exc.value)  # one line
            assert len(m.got) == heard  # nothing sent
    finally:
        m.close()


@pytest.mark.parametrize("line", [123, None, b"GAP 1, 0"])
def test_a_line_that_is_not_text_is_a_type_error(client, line):
    with pytest.raises(TypeError, match="a TMCL line is a str"):
        client.execute(line)


def _modules_after(code: str) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", code + "\nimport sys, json\n"
         "print(json.dumps(sorted(m for m in sys.modules)))"],
        capture_output=True, text=True, env=tmclsh_env(), cwd=str(ROOT), timeout=30)
    assert out.returncode == 0, out.stderr
    return set(json.loads(out.stdout.splitlines()[-1]))


@pytest.mark.parametrize("code", [
    "import tmclsh",
    "import tmclsh.cli.main",
    "import tmclsh; c = tmclsh.connect(sim='TMCM-1311'); c.execute('GAP 1, 0'); c.close()",
])
def test_import_and_connect_stay_light(code):
    loaded = _modules_after(code)
    heavy = sorted(m for m in loaded if m.split(".")[0] in HEAVY)
    assert heavy == [], f"{code!r} imported {heavy}"
    if code == "import tmclsh":
        assert not any(m.startswith(("tmclsh.", "serial")) for m in loaded)


def test_the_cli_imports_only_the_parser_and_the_standard_library():
    """What ``import tmclsh.cli.main`` costs, said without a clock (a timed bound failed on a
    busy machine; speed is measured in scripts/bench.py): it loads no package from outside
    the standard library, and of tmclsh only what the argument parser stands on (base and
    cli), never the protocol, the links, the client, the shell or the simulator."""
    baseline = _modules_after("pass")
    loaded = _modules_after("import tmclsh.cli.main") - baseline
    assert "tmclsh.cli.main" in loaded
    outside = sorted(m for m in loaded
                     if m.split(".")[0] not in (*sys.stdlib_module_names, "tmclsh"))
    assert outside == [], outside
    ours = sorted(m for m in loaded if m.startswith("tmclsh."))
    assert all(m.split(".")[1] in ("base", "cli") for m in ours), ours
