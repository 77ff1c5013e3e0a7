"""What the prompt, the toolbar, the banner, ``.mode`` and ``.version`` show of the mode, read
from the mode's facts (``client.mode``, ``tmclsh.link.modes``), against a module written from
the manual's ASCII interface (tests/responder.py, nothing of tmclsh): found in its ASCII mode,
switched to binary with ``.mode binary`` and put back at exit."""

from __future__ import annotations

import pytest

from tmclsh.base.errors import ValidationError
from tmclsh.client.ascii import AsciiLink
from tmclsh.client.text import LineClient
from tmclsh.link import open_serial
from tmclsh.shell.lang.session import Session
from tmclsh.shell.render import Output
from tmclsh.shell.repl.app import banner, prompt_message
from tmclsh.shell.repl.toolbar import toolbar_fragments

from responder import AsciiModeModule


@pytest.fixture
def found_in_ascii():
    module = AsciiModeModule()
    c = LineClient(open_serial(module.path), module="TMCM-1311", timeout=1.0, retries=0)
    try:
        AsciiLink.attach(c)
        yield Session(c, Output()), module
    finally:
        c.close()
        module.close()


def prompt(session: Session) -> str:
    return "".join(text for _, text in prompt_message(session)())


def toolbar(session: Session, columns: int = 120) -> list[tuple[str, str]]:
    return toolbar_fragments(session, columns)


def completions(session: Session, text: str) -> list[str]:
    from prompt_toolkit.completion import CompleteEvent
    from prompt_toolkit.document import Document

    from tmclsh.shell.repl.completer import TmclCompleter

    c = TmclCompleter(session=session, module=session.client.module)
    return [x.text for x in c.get_completions(Document(text),
                                              CompleteEvent(completion_requested=True))]


def words(fragments: list[tuple[str, str]]) -> str:
    return "".join(text for _, text in fragments)


def test_ascii_mode_is_shown_everywhere_and_binary_goes_unsaid(found_in_ascii, capsys):
    s, module = found_in_ascii
    assert s.client.mode == "ascii" and str(s.client.mode) == "ascii"
    assert prompt(s) == "TMCM-1311:1 ascii> "
    assert ("class:bottom-toolbar.on", "ASCII") in toolbar(s)
    # just wide enough for the connection, the module and the mode: ASCII is kept
    where = toolbar(s)[0][1]
    narrow = len(f"{where} | TMCM-1311 @1 | ASCII")
    assert words(toolbar(s, narrow)) == f"{where} | TMCM-1311 @1 | ASCII"
    assert " · ASCII mode" in "".join(text for _, text in banner(s))
    assert {"GAP", "SAP", "MVP"} <= set(completions(s, ""))  # (none of them is sent)
    s.run_line(".mode")
    said = capsys.readouterr().out
    assert "mode: ASCII mode" in said and "found in ascii mode" in said

    s.run_line(".mode binary")  # BIN, and 136 type 1 answered in binary frames
    assert module.modes == ["ascii", "binary"] and s.client.mode == "binary"
    assert prompt(s) == "TMCM-1311:1> "
    assert ("class:bottom-toolbar", "binary") in toolbar(s)
    # the usual mode goes before the connection is shortened
    assert words(toolbar(s, narrow)) == f"{where} | TMCM-1311 @1"
    assert "ASCII" not in "".join(text for _, text in banner(s))
    said = capsys.readouterr().out
    assert "mode: binary (module was found in ASCII mode: 139 is sent at exit)" in said
    s.client.close()
    assert module.modes == ["ascii", "binary", "ascii"]  # left as it was found


def test_mode_as_json_names_the_mode_and_the_link(found_in_ascii, capsys):
    s, _ = found_in_ascii
    s.out.json = True
    s.run_line(".mode")
    line = capsys.readouterr().out.strip()
    assert line == ('{"mode": "ascii", "echo": "none", "found": "ascii", '
                    '"on_exit": "ascii"}')


def test_version_in_ascii_mode_sends_nothing_and_says_how(found_in_ascii):
    """136 has no line in the module's ASCII mode (the link refuses it): nothing is sent,
    and with no version read at connect the error says how to read one."""
    s, module = found_in_ascii
    heard = list(module.log)
    with pytest.raises(ValidationError,
                       match=r"cannot be read in ASCII mode.*\.mode binary, \.version, "
                             r"\.mode ascii reads it again"):
        s.run_line(".version")
    assert module.log == heard


def test_what_ascii_mode_refuses_names_the_shell_commands_for_its_own_lines(found_in_ascii):
    """136 refused in ASCII mode listed BIN, RUN and STOP among what the module accepts; typed
    at the prompt, each was refused in turn ('unknown command', 'did you mean .run?', 'only
    inside a stored program'). The refusal says which shell command sends each, and BIN
    typed is pointed to .mode binary; nothing is sent."""
    s, module = found_in_ascii
    heard = list(module.log)
    with pytest.raises(ValidationError) as exc:
        s.run_line("136")
    said = str(exc.value)
    assert "BIN, RUN and STOP, which .mode binary, .run and .stop send" in said, said
    with pytest.raises(ValidationError, match=r"'BIN'.*\.mode binary"):
        s.run_line("BIN")
    assert module.log == heard
