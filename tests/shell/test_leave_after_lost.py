"""Leaving the shell after the link was lost and came back with a module that does not
answer (yet): the prompt keeps the module's name, and Ctrl-D says what it waits for."""

from __future__ import annotations

import pytest

from tmclsh.base.errors import TmclError
from tmclsh.client.connect import connect
from tmclsh.shell.repl import app
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session


@pytest.fixture
def shell():
    """(module, client, session): the shell on a module written from the manual, whose
    Ctrl-D menu records its question and answers "leave"."""
    from responder import PtyModule

    module = PtyModule(version="1311V111")
    client = connect(module.path, timeout=0.3, retries=0)
    session = Session(client, Output())
    session.asked = []
    session.choose = lambda question, options: session.asked.append(question) or "leave"
    yield module, client, session
    client.close()
    if not getattr(module, "pulled", False):
        module.close()


def _pull(module, client) -> None:
    """The module's port goes (a USB cable pulled), and the client finds it gone (the
    toolbar's poll, say)."""
    module.close()
    module.pulled = True
    try:
        client.execute("GAP 3, 0")
    except (TmclError, OSError):
        pass
    assert not client.connected


def test_a_silent_module_after_a_reconnect_keeps_its_name_and_leaving_says_why_it_waits(
        shell, capsys):
    module, client, session = shell
    prompt = app.prompt_message(session)
    assert "TMCM-1311:1" in "".join(text for _, text in prompt())
    module.address = 99  # it answers nothing at address 1 from now on
    client.reconnect()  # the link came back (a cable put back)
    app.run_one(session, "GAP 1, 0")  # the bring-up finds no answer
    capsys.readouterr()
    assert "TMCM-1311:1" in "".join(text for _, text in prompt())
    assert app.may_leave(session)  # nothing known to turn: it leaves
    said = capsys.readouterr()
    assert "has not answered since the link came back" in said.out + said.err


def test_leaving_with_the_link_down_names_the_motor_tmclsh_left_turning(shell, capsys):
    """A motor set turning, then the link lost (the USB cable pulled from a powered module):
    Ctrl-D cannot ask the module or stop it, and says so, naming what it last told the motor
    (was: it left without a word)."""
    module, client, session = shell
    app.run_one(session, "ROR 0, 3000")
    _pull(module, client)
    capsys.readouterr()
    assert app.may_leave(session)
    said = capsys.readouterr()
    text = said.out + said.err
    assert "link down" in text and "motor 0: ROR 0, 3000" in text, text


def test_a_line_typed_after_the_link_went_unnoticed_says_it_is_down_not_still_down(shell,
                                                                                 capsys):
    """The link went while nobody typed (only the toolbar showed it): the next line says the
    link is down and did not come back; "still disconnected" referred to nothing said."""
    module, client, session = shell
    _pull(module, client)
    capsys.readouterr()
    sent = client.stats["sent"]
    app.run_one(session, "GAP 1, 0")
    said = capsys.readouterr()
    text = said.out + said.err
    assert "the link is down and did not come back" in text and "still" not in text, text
    assert "nothing was sent" in text and client.stats["sent"] == sent
