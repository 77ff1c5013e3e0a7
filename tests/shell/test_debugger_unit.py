"""The debugger's shell commands where nothing reaches a module: locations, refusals, options.

The client sits on pyserial's ``loop://``; every test checks that nothing was sent.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tmclsh.tmcl import asm
from tmclsh.client.text import LineClient
from tmclsh.base.errors import AsmError, ValidationError
from tmclsh.shell.features import debugger, upload
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Abort, Session
from tmclsh.link import open_serial

from responder import AsciiModeModule

DEMO = Path(__file__).resolve().parents[2] / "scripts" / "programs" / "demo" / "demo-counter.tmc"


@pytest.fixture
def session():
    c = LineClient(open_serial("loop://"), module="TMCM-1311", timeout=0.05, retries=0)
    s = Session(c, Output())
    yield s
    assert c.stats["sent"] == 0, "nothing may be sent by these commands"
    c.close()


@pytest.fixture
def mapped(session):
    debugger.state(session).program = asm.assemble_file(DEMO, session.module)
    return session


def test_commands_registered() -> None:
    from tmclsh.shell.lang import commands

    commands.load_all()
    for name in (".upload", ".dump", ".disasm", ".run", ".stop", ".reset", ".status", ".step",
                 ".break", ".delete", ".continue", ".list", ".where", ".display", ".vars",
                 ".source-map", ".undisplay"):
        cmd = commands.find(name)
        assert cmd is not None, name
        assert cmd.help and cmd.syntax.startswith(cmd.name)
    assert "no breakpoint command" in commands.find(".continue").details


def test_resolve_with_source(mapped) -> None:
    r = lambda t, lines=True: debugger.resolve(mapped, t, line_numbers=lines)  # noqa: E731
    assert r("Loop") == (2, "Loop")
    assert r("twice") == (12, "Twice")  # labels are case-insensitive
    assert r("@7") == (7, "@7")
    # line 18 is "Loop:" (no instruction): the next instruction's line is taken
    addr, where = r("18")
    assert addr == 2 and where.endswith("demo-counter.tmc:19")
    assert r("demo-counter.tmc:31")[0] == 12
    assert r("demo-counter.tmc:29")[0] == 12  # a blank line: the next instruction
    assert r("7", lines=False) == (7, "@7")  # .run ADDR: a number is an address
    assert r("L0012") == (12, "L0012")
    with pytest.raises(ValidationError, match="unknown label 'Nope'.*Loop, Twice"):
        r("Nope")
    with pytest.raises(ValidationError, match="no instruction at or after line 99"):
        r("99")
    with pytest.raises(ValidationError, match="other.tmc is not part of the program"):
        r("other.tmc:3")
    with pytest.raises(ValidationError, match="outside program memory 0..2047"):
        r("@2048")


def test_resolve_without_source(session) -> None:
    assert debugger.resolve(session, "12", line_numbers=True) == (12, "@12")
    assert debugger.resolve(session, "$10", line_numbers=True) == (16, "@16")
    assert debugger.resolve(session, "L0003", line_numbers=True) == (3, "L0003")
    with pytest.raises(ValidationError, match="no source file is known.*@ADDRESS"):
        debugger.resolve(session, "Loop", line_numbers=True)


def test_where_in_source_terms(mapped) -> None:
    w = debugger.where(mapped, 12)
    assert (w.line, w.text, w.label) == (31, "GGP Count, 2", "Twice")
    assert w.place.endswith("demo-counter.tmc:31")
    assert w.to_json()["line"] == 31


def test_breakpoints_and_delete(mapped, capsys) -> None:
    mapped.run_line(".break Twice")
    mapped.run_line(".break 23")
    mapped.run_line(".break @5")
    mapped.run_line(".break Twice")  # already there: not added twice
    dbg = debugger.state(mapped)
    assert sorted(bp.address for bp in dbg.breakpoints.values()) == [5, 6, 12]
    out = capsys.readouterr().out
    assert "breakpoint 1 at @12" in out and "GGP Count, 2" in out
    assert "already at 12" in out
    mapped.run_line(".break")
    assert "breakpoints" in capsys.readouterr().out
    mapped.run_line(".delete 2")
    assert sorted(dbg.breakpoints) == [1, 3]
    with pytest.raises(ValidationError, match=r"no breakpoint 2 \(breakpoints: 1, 3\)"):
        mapped.run_line(".delete 2")
    mapped.run_line(".delete")
    assert not dbg.breakpoints


def test_display_refuses_commands_that_change_things(session) -> None:
    # with the scripting engine's evaluator (installed by the session) ...
    with pytest.raises(ValidationError):
        session.run_line(".display SAP 4, 0, 100")
    # ... and without it, where one TMCL read line is accepted
    session.state.take("evaluate")
    with pytest.raises(ValidationError, match="does not read a value"):
        session.run_line(".display SAP 4, 0, 100")
    with pytest.raises(AsmError):
        session.run_line(".display FOO 1")
    assert not debugger.state(session).displays


def test_upload_asks_first(session, tmp_path) -> None:
    with pytest.raises(Abort, match="overwrite the TMCM-1311's program memory at 0..15 with "
                                    "16 instructions from demo-counter.tmc"):
        session.run_line(f".upload {DEMO}")


def test_upload_refuses_too_large_before_asking(session, tmp_path) -> None:
    big = tmp_path / "big.tmc"
    big.write_text("    STOP\n" * 20)
    with pytest.raises(AsmError, match="program needs 20 instructions from address 2040"):
        session.run_line(f".upload {big} --at 2040 --yes")
    with pytest.raises(ValidationError, match="usage: .upload FILE"):
        session.run_line(".upload")
    with pytest.raises(ValidationError, match=r"unknown option --force \(options: --at, --yes"):
        session.run_line(f".upload {big} --force")


def test_upload_reports_source_errors_with_location(session, tmp_path) -> None:
    bad = tmp_path / "bad.tmc"
    bad.write_text("    STOP\n    FOO 1, 2\n")
    with pytest.raises(AsmError) as err:
        session.run_line(f".upload {bad} --yes")
    assert (err.value.file, err.value.line) == (str(bad), 2)


def test_step_argument_checked(session) -> None:
    with pytest.raises(ValidationError, match=r"\.step N: must be a whole number from 1 to"):
        session.run_line(".step x")
    with pytest.raises(ValidationError, match="from 1 to 1000000, got '0'"):
        session.run_line(".step 0")
    with pytest.raises(ValidationError, match="from 1 to 1000000"):
        session.run_line(".step " + "9" * 5000)


def test_vars_range_checked(session) -> None:
    with pytest.raises(ValidationError, match="user variable 300 does not exist.*0..255"):
        session.run_line(".vars 300")
    with pytest.raises(ValidationError, match="empty range"):
        session.run_line(".vars 5..2")


def test_ascii_mode_errors_are_clear() -> None:
    """A module in its ASCII mode (a module written from the manual): what it does not know
    is refused with a clear line, and nothing reaches it."""
    from tmclsh.client.ascii import AsciiLink

    module = AsciiModeModule()
    c = LineClient(open_serial(module.path), module="TMCM-1311", timeout=1.0, retries=0)
    try:
        AsciiLink.attach(c)
        s = Session(c, Output())
        heard = list(module.log)
        for line in (".step", ".reset", f".upload {DEMO} --yes", ".dump"):
            with pytest.raises(ValidationError, match="binary mode"):
                s.run_line(line)
        assert module.log == heard
    finally:
        c.close()
        module.close()


def test_source_map_show_and_off(mapped, capsys) -> None:
    mapped.run_line(".source-map")
    assert "16 instructions at 0..15" in capsys.readouterr().out
    mapped.run_line(".source-map --off")
    assert debugger.state(mapped).program is None


def test_completion(mapped, tmp_path, monkeypatch) -> None:
    assert ("Loop", "@2") in debugger.complete_location(mapped, "")
    (tmp_path / "a.tmc").write_text("STOP\n")
    (tmp_path / "b.bin").write_bytes(b"")
    (tmp_path / "sub").mkdir()
    monkeypatch.chdir(tmp_path)
    got = upload.complete_file(mapped, "")
    assert "a.tmc" in got and "sub/" in got and "b.bin" not in got
