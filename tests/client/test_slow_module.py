"""A module that answers later than the timeout is there: its answers come after tmclsh has
given them up. What tmclsh says must be that (and that a longer timeout helps), not 'no module
answered' or 'stopped answering', which send a technician to the cable, the baud rate or
the address. Against a module written from the manual (tests/responder.py)."""

from __future__ import annotations

import pytest

from tmclsh.base.errors import NoAnswerError, TmclTimeoutError
from tmclsh.client.connect import connect
from tmclsh.client.text import LineClient
from tmclsh.link import open_serial

from responder import PtyModule


@pytest.fixture
def module():
    m = PtyModule(version="1311V111")
    yield m
    m.close()


def test_connect_to_a_module_slower_than_the_timeout_says_it_answered_late(module):
    module.delay = 0.5
    with pytest.raises(NoAnswerError) as err:
        connect(module.path, timeout=0.3)
    said = str(err.value)
    assert "no module answered" not in said
    assert "answered too late" in said
    # the cause it names first is the one that helps, in the words of connect()'s caller
    assert said.splitlines()[1] == "  - a slow link: timeout=2"


def test_the_command_line_is_told_its_option(module):
    """The same module from the command line: the advice names the option to give."""
    import subprocess
    import sys

    from conftest import ROOT, tmclsh_env

    module.delay = 0.5
    run = subprocess.run([sys.executable, "-m", "tmclsh", "--port", module.path, "--timeout",
                          "0.3", "-c", "GAP 1, 0"], cwd=str(ROOT), env=tmclsh_env(),
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 3, run.stderr
    assert "  - a slow link: --timeout 2" in run.stderr.splitlines(), run.stderr
    assert "timeout=" not in run.stderr


def test_a_module_that_became_slow_is_not_said_to_have_stopped_answering(module):
    module.values[(4, 0, False)] = 1234
    c = LineClient(open_serial(module.path), module="TMCM-1311", timeout=0.3, retries=0)
    try:
        assert c.value("GAP 4, 0") == 1234
        module.delay = 0.5  # from now on every answer comes after the timeout
        said = []
        for _ in range(4):
            with pytest.raises(TmclTimeoutError) as err:
                c.value("GAP 4, 0")
            said.append(str(err.value))
        assert not any("stopped answering" in s for s in said), said
        assert "answers too late" in said[-1] and "more time: timeout=2" in said[-1]
    finally:
        c.close()


def test_no_module_at_another_address_names_the_address_first_not_the_baud_rate(module):
    """.address 3 on a line where the module at address 1 answers: the baud rate and the
    port are proven right, so the message does not send anyone to change them."""
    from tmclsh.client.bringup import switch_address

    c = LineClient(open_serial(module.path), module="TMCM-1311", timeout=0.2, retries=1)
    try:
        c.identify()
        with pytest.raises(NoAnswerError) as err:
            switch_address(c, 3)
        said = str(err.value)
        assert said.startswith("no module answered at address 3")
        assert "where the module at address 1 answers" in said
        assert "baud" not in said
        assert said.splitlines()[1].startswith("  - address: no module has address 3")
        assert c.address == 1 and c.value("GAP 4, 0") == 0
    finally:
        c.close()
