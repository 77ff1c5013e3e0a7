"""The bottom toolbar in narrow terminals: what it shows at 120, 80 and 60 columns, built for
a session on the simulator and on a serial link (a pty, the way a technician's port is)."""

from __future__ import annotations

import re

import pytest

from tmclsh.shell.lang.session import Session
from tmclsh.shell.repl.toolbar import toolbar_fragments
from tmclsh.shell.features.trace import enable_trace


def text(session: Session, columns: int) -> str:
    return "".join(t for _, t in toolbar_fragments(session, columns))


@pytest.fixture
def sim_session(client):
    return Session(client)


@pytest.fixture
def port_session(pty_client):
    return Session(pty_client)


# every form an item takes, whole
FORMS = {"SIMULATED", "TMCM-1311 @1", "binary", "ASCII", "trace off", "trace on",
         "Tab complete  ^C stop motors  ^D quit", "^C stop motors  ^D quit", "^C stop motors",
         "^C stop", "program run @12", "run @12"}


def whole_words_only(line: str) -> None:
    """The toolbar is whole items joined by `` | ``: none is cut."""
    for part in line.split(" | "):
        assert part.strip() in FORMS, f"{part!r} is not a whole item: {line!r}"


@pytest.mark.parametrize("columns", [60, 80, 120])
@pytest.mark.parametrize("state", [None, {"state": "run", "pc": 12}])
@pytest.mark.parametrize("trace", [False, True])
def test_it_fits_and_keeps_connection_and_module(sim_session, columns, state, trace):
    if state:
        sim_session.state.program_state = state
    if trace:
        enable_trace(sim_session)
    line = text(sim_session, columns)
    assert len(line) <= columns
    assert "SIMULATED" in line and "TMCM-1311 @1" in line
    whole_words_only(line)
    assert not line.rstrip().endswith("|")
    if state:  # a running program is never dropped for a hint
        assert re.search(r"(program )?run @12", line)


def test_the_least_useful_go_first(sim_session):
    wide = text(sim_session, 120)
    assert wide.endswith("Tab complete  ^C stop motors  ^D quit")
    assert "binary" in wide and "trace off" in wide
    at80 = text(sim_session, 80)
    assert "trace off" in at80 and "^C stop motors" in at80
    sim_session.state.program_state = {"state": "step", "pc": 4}
    at60 = text(sim_session, 60)
    assert "step @4" in at60 and "^C stop" in at60
    assert "trace off" not in at60  # an idle trace is worth less than the program state
    assert len(at60) <= 60


def test_a_serial_link_shortens_to_the_port(port_session):
    path = port_session.client.transport.url
    full = text(port_session, 200)
    assert f"{path} @ 9600" in full
    narrow = text(port_session, 20 + len(path))
    assert path in narrow and "TMCM-1311 @1" in narrow and len(narrow) <= 20 + len(path)


def test_disconnected_says_so_first(port_session):
    port_session.client.close()
    line = text(port_session, 60)
    assert line.startswith(" DISCONNECTED") and len(line) <= 60
    assert "TMCM-1311 @1" in line
