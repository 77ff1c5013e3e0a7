"""Leaving the shell after the link was lost and came back with a module that does not
answer (yet): the prompt keeps the module's name, and Ctrl-D says what it waits for."""

from __future__ import annotations

from tmclsh.client.connect import connect
from tmclsh.shell.repl import app
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session


def test_a_silent_module_after_a_reconnect_keeps_its_name_and_leaving_says_why_it_waits(
        capsys):
    from responder import PtyModule

    module = PtyModule(version="1311V111")
    client = connect(module.path, timeout=0.3, retries=0)
    try:
        session = Session(client, Output())
        asked: list[str] = []
        session.choose = lambda question, options: asked.append(question) or "leave"
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
    finally:
        client.close()
        module.close()


def test_leaving_with_the_link_down_names_the_motor_tmclsh_left_turning(capsys):
    """A motor set turning, then the link lost (the USB cable pulled from a powered module):
    Ctrl-D cannot ask the module or stop it, and says so, naming what it last told the motor
    (was: it left without a word)."""
    from tmclsh.base.errors import TmclError
    from responder import PtyModule

    module = PtyModule(version="1311V111")
    client = connect(module.path, timeout=0.3, retries=0)
    try:
        session = Session(client, Output())
        asked: list[str] = []
        session.choose = lambda question, options: asked.append(question) or "leave"
        app.run_one(session, "ROR 0, 3000")
        module.close()  # pulled: the port is gone
        try:
            client.execute("GAP 3, 0")
        except (TmclError, OSError):
            pass
        assert not client.connected
        capsys.readouterr()
        assert app.may_leave(session)
        said = capsys.readouterr()
        text = said.out + said.err
        assert "link down" in text and "motor 0: ROR 0, 3000" in text, text
    finally:
        client.close()


def test_a_line_typed_after_the_link_went_unnoticed_says_it_is_down_not_still_down(capsys):
    """The link went while nobody typed (only the toolbar showed it): the next line says the
    link is down and did not come back; "still disconnected" referred to nothing said."""
    from tmclsh.base.errors import TmclError
    from responder import PtyModule

    module = PtyModule(version="1311V111")
    client = connect(module.path, timeout=0.3, retries=0)
    try:
        session = Session(client, Output())
        module.close()  # pulled
        try:
            client.execute("GAP 3, 0")  # (the toolbar's poll, say, finds it gone)
        except (TmclError, OSError):
            pass
        assert not client.connected
        capsys.readouterr()
        sent = client.stats["sent"]
        app.run_one(session, "GAP 1, 0")
        said = capsys.readouterr()
        text = said.out + said.err
        assert "the link is down and did not come back" in text and "still" not in text, text
        assert "nothing was sent" in text and client.stats["sent"] == sent
    finally:
        client.close()
