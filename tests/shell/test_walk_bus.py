"""One script walks a bus: ``.address`` takes an expression, commands that name a link or a
file take ``${...}``, and a text variable (a unit's ``${port}``) goes into lines as it is."""

from __future__ import annotations

import pytest

from tmclsh.sim import SimBus, Simulator


@pytest.fixture
def bus(make_pty_sim):
    """A TMCM-1311 at 1, a TMCM-351 at 2 and a TMCM-1640 at 3 on one pty-served line."""
    return make_pty_sim(target=SimBus([Simulator("TMCM-1311", 1), Simulator("TMCM-351", 2),
                                       Simulator("TMCM-1640", 3)]))


def test_a_script_walks_the_bus_by_expression(bus, run_tmclsh, tmp_path):
    _, path = bus
    script = tmp_path / "walk.tmcl"
    script.write_text(".let base = 1\n"
                      ".repeat 3 as i\n"
                      ".address base + i\n"
                      "GGP 66, 0\n"
                      ".end\n"
                      ".let a = 2\n"
                      ".address ${a}\n"
                      f".save {tmp_path}/at-${{a}}.tmcl --yes\n")
    p = run_tmclsh("--port", path, "-f", str(script))
    assert p.returncode == 0, p.stderr
    assert [line for line in p.stdout.splitlines() if line.startswith("address")] == [
        "address 1: TMCM-1311, firmware 1311V111", "address 2: TMCM-351, firmware 0351V103",
        "address 3: TMCM-1640, firmware 1640V210", "address 2: TMCM-351, firmware 0351V103"]
    assert [line.split(" = ")[1] for line in p.stdout.splitlines()
            if line.startswith("SerialAddress")] == ["1", "2", "3"]
    assert (tmp_path / "at-2.tmcl").read_text().count("TMCM-351") >= 1


def test_address_refuses_clearly(bus, run_tmclsh):
    _, path = bus
    p = run_tmclsh("--port", path, "-c", f".let n = 9; .address n * 100")
    assert p.returncode == 1
    assert "must be a whole number from 0 to 255, got 900" in p.stderr
    p = run_tmclsh("--port", path, "-c", ".address nowhere")
    assert p.returncode == 1 and "unknown variable 'nowhere'" in p.stderr


def test_a_text_variable_goes_into_lines_and_not_into_numbers(client):
    from tmclsh.base.errors import ValidationError
    from tmclsh.shell.render import Output
    from tmclsh.shell.lang.session import Session

    session = Session(client, Output(json_mode=True))
    session.variables["port"] = "/dev/ttyACM0"
    assert session.expand("echo ${port}") == "echo /dev/ttyACM0"
    with pytest.raises(ValidationError, match=r"port is text \('/dev/ttyACM0'\).*\$\{port\}"):
        session.run_line(".let x = port + 1")
