"""The shell's own commands (help, .param, .params, .trace, .decode, .connect, ...) and the
checks before sending, against the in-process simulator."""

from __future__ import annotations

import json

import pytest

from tmclsh.client.connect import connect
from tmclsh.base.errors import StatusError, TmclError, TmclTimeoutError, ValidationError
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Abort, QuitShell, Session


class Frames:
    """Every frame the client puts on the wire (a tracer, like --trace)."""

    def __init__(self, client):
        self.tx: list[object] = []
        client.add_tracer(self)

    def __call__(self, direction, raw, decoded):
        if direction == "tx":
            self.tx.append(decoded)


@pytest.fixture(autouse=True)
def wide_console(monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")  # tables unwrapped, so lines can be asserted


def make_session(module="TMCM-1311", json_mode=False, **kw):
    client = connect(sim=module, timeout=0.3, retries=0)
    return Session(client, Output(json_mode=json_mode), **kw)


@pytest.fixture
def session():
    s = make_session()
    yield s
    s.client.close()


@pytest.fixture
def s351():
    s = make_session("TMCM-351")
    yield s
    s.client.close()


def run(s: Session, *lines: str) -> None:
    for line in lines:
        s.run_line(line)


# -- help --------------------------------------------------------------------------------

def test_help_lists_every_registered_command_by_category(session, capsys):
    from tmclsh.shell.lang.commands import all_commands

    run(session, ".help")
    out = capsys.readouterr().out
    for cmd in all_commands():
        assert cmd.name in out
    for title in ("General", "Parameters", "Connection and module", "Protocol", "Keys"):
        assert title in out
    assert "Ctrl-C stops all motors" in " ".join(out.split())


def test_bare_help_explains_an_instruction(session, capsys):
    run(session, "help SAP")
    out = capsys.readouterr().out
    assert "SAP  (command 5)  Set axis parameter" in out
    assert "SAP <parameter>, <motor>, <value>" in out
    assert "axis parameter: number or name" in out
    assert "TMCM-1311, TMCM-1640, TMCM-351" in out


def test_help_shows_symbolic_types_of_this_module(session, capsys):
    run(session, "help mvp")
    out = capsys.readouterr().out
    assert "ABS = 0, REL = 1, COORD = 2" in out


def test_help_number_is_the_parameter(session, capsys):
    run(session, "help 140")
    out = capsys.readouterr().out
    assert "AP 140" in out and "MicrostepResolution" in out and "Microstep resolution" in out
    assert "8 = 256 microsteps" in out
    assert "now" in out and "8 (256 microsteps)" in out  # read from the module


def test_instruction_help_shows_the_note_and_keeps_the_source_for_source(session, capsys):
    """`help ROL` says what a technician needs; how the manuals were read shows only with
    --source (before or after the mnemonic), as for `.param --source`."""
    run(session, "help ROL")
    out = capsys.readouterr().out
    assert "The actual position decreases while ROL turns the motor." in out
    assert "§" not in out and "copied from ROR" not in out and "source" not in out
    run(session, "help --source ROL", "help RFS --source")
    out = " ".join(capsys.readouterr().out.split())
    assert "source TMCM-1311 manual §5.7.2 says 'positive direction' (copied from ROR)" in out
    assert "tmclsh follows the TMCM-351 wording" in out
    # the note as well: on this TMCM-1311, what the value means here (issue 27)
    assert "On the TMCM-1311, RFS STATUS answers 0 when no reference search is running" in out
    run(session, "help --source ROR")  # nothing to say: as for parameters
    assert "source as the manuals describe it" in " ".join(capsys.readouterr().out.split())


def test_instruction_help_json_has_the_source_only_when_asked(capsys):
    s = make_session(json_mode=True)
    run(s, "help CALC", "help --source CALC")
    plain, asked = (json.loads(line) for line in capsys.readouterr().out.splitlines())
    assert "source" not in plain and "nine different" not in plain["note"]
    assert plain["note"].startswith("The accumulator belongs to the stored program")
    assert "'nine different arithmetic functions'" in asked["source"]
    assert asked["note"] == plain["note"]


def test_help_number_takes_source_like_param(session, capsys):
    run(session, "help 140")
    assert "source" not in capsys.readouterr().out
    run(session, "help 140 --source")
    assert "source   as the manual prints it" in capsys.readouterr().out


def test_help_number_shows_axis_and_global_parameter(session, capsys):
    run(session, "help 0")
    out = capsys.readouterr().out
    assert "AP 0" in out and "TargetPosition" in out
    assert "GP 0 (bank 3)" in out and "Timer0Period" in out
    assert "UserVariable" not in out  # ranges of user variables are left out


def test_help_for_a_command_and_a_bare_word(session, capsys):
    run(session, "help .param", "help quit")
    out = capsys.readouterr().out
    assert ".param [--source] QUERY" in out
    assert ".quit" in out and "leave the shell" in out


def test_help_unknown(session):
    with pytest.raises(ValidationError, match="no help topic or parameter matches 'xyzzy'"):
        run(session, "help xyzzy")


def test_quit_and_exit(session):
    for line in (".quit", "quit", "exit", ".exit"):
        with pytest.raises(QuitShell):
            session.run_line(line)


# -- .param / .params --------------------------------------------------------------------

def test_param_by_name_shows_description_range_and_live_value(session, capsys):
    run(session, "SAP 4, 0, 1234")
    capsys.readouterr()
    run(session, ".param MaxPositioningSpeed")
    out = capsys.readouterr().out
    assert "AP 4" in out and "Maximum positioning speed" in out
    assert "0..327679999 pps" in out and "RWE (read, write, store in EEPROM)" in out
    assert "1234 pps" in out


def test_param_fuzzy_single_and_several(session, capsys):
    run(session, ".param microstep")
    assert "AP 140" in capsys.readouterr().out
    run(session, ".param maxpos")
    out = capsys.readouterr().out
    assert "match 'maxpos'" in out
    assert "MaxPositioningSpeed" in out and "MaxPossibleCurrent" in out


def test_param_kind_prefix_and_unknown(session, capsys):
    run(session, ".param gp 66")
    out = capsys.readouterr().out
    assert "GP 66" in out and "SerialAddress" in out and "now" in out
    with pytest.raises(ValidationError, match="has no axis parameter 66"):
        run(session, ".param ap 66")
    with pytest.raises(ValidationError, match="no parameter matches"):
        run(session, ".param qqqqqq")


def test_param_write_only(session, capsys):
    run(session, ".param ClearI2tExceededFlag")
    assert "write-only" in capsys.readouterr().out


def test_params_reads_each_readable_parameter_once(session, capsys):
    frames = Frames(session.client)
    run(session, ".params axis")
    out = capsys.readouterr().out
    mod = session.module
    readable = [p for p in mod.axis_params if p.readable]
    # (and once more where an answer was the one before it, byte for byte: Client._judge)
    assert len(frames.tx) == len(readable) + session.client.stats["judged"]
    assert {f.type for f in frames.tx} == {p.number for p in readable}
    assert all(f.opcode == 6 for f in frames.tx)
    assert "MaxPositioningSpeed" in out and "(write-only)" in out


def test_params_filter_and_one_column_per_motor(s351, capsys):
    run(s351, ".params axis position")
    out = capsys.readouterr().out
    assert "Motor 0" in out and "Motor 1" in out and "Motor 2" in out
    assert "ActualPosition" in out
    with pytest.raises(ValidationError, match="matches"):
        run(s351, ".params global nothingmatchesthis")


def test_params_json(capsys):
    s = make_session(json_mode=True)
    try:
        run(s, ".params global serial")
    finally:
        s.client.close()
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    addr = next(r for r in rows if r["name"] == "SerialAddress")
    assert addr["value"] == 1 and addr["number"] == 66 and addr["kind"] == "global"


# -- trace and decode --------------------------------------------------------------------

def test_trace_on_shows_frames_on_stderr_and_off_stops(session, capsys):
    run(session, ".trace on", "GAP 4, 0")
    cap = capsys.readouterr()
    assert "tx> 01 06 04 00 00 00 00 00 0b  GAP 4, 0  // MaxPositioningSpeed" in cap.err
    assert "<rx 02 01 64 06" in cap.err and "100 ok" in cap.err
    assert "tx>" not in cap.out
    run(session, ".trace off", "GAP 4, 0")
    assert "tx>" not in capsys.readouterr().err
    run(session, ".trace")  # toggles
    assert "trace on" in capsys.readouterr().out


def test_decode_request_reply_and_bad_checksum(session, capsys):
    run(session, ".decode 01 06 04 00 00 00 00 00 0b")
    out = capsys.readouterr().out
    assert "request: to address 1: GAP 4, 0" in out and "checksum ok" in out
    run(session, ".decode $02 $01 $64 $06 $00 $00 $03 $E8 $59")
    out = capsys.readouterr().out
    assert "reply: from address 1 to host 2: 100 ok, GAP value 1000" in out
    assert "WRONG: 0x59, should be 0x58" in out
    run(session, ".decode 0231333131563131 31")
    assert "'1311V111'" in capsys.readouterr().out
    run(session, ".decode memory 02 04 00 00 00 01 5f 90 f6")
    assert "stored MVP ABS, 0, 90000" in capsys.readouterr().out
    with pytest.raises(TmclError, match="5 bytes"):
        run(session, ".decode 01 02 03 04 05")


# -- connection and module ---------------------------------------------------------------

def test_version(session, capsys):
    run(session, ".version")
    out = capsys.readouterr().out
    assert "1311V111" in out and "TMCM-1311" in out and "module type 1311" in out


def test_module_show_and_override(session, capsys):
    run(session, ".module")
    out = capsys.readouterr().out
    assert "TMCM-1311" in out and "SIMULATED" in out
    run(session, ".module TMCM-351")
    assert session.client.module.name == "TMCM-351"
    with pytest.raises(ValidationError, match="unknown module"):
        run(session, ".module TMCM-9999")


def test_address_without_a_module_there_keeps_the_old_one(session):
    with pytest.raises(TmclTimeoutError, match="no module answered at address 7"):
        run(session, ".address 7")
    assert session.client.address == 1
    run(session, "GAP 4, 0")  # still talking to address 1


def test_connect_switches_to_another_simulated_module(session, capsys):
    frames = Frames(session.client)
    run(session, ".connect sim TMCM-351")
    assert "connected: TMCM-351" in capsys.readouterr().out
    assert session.client.module.name == "TMCM-351"
    run(session, "GAP 1, 2")  # motor 2 exists now
    assert frames.tx  # tracers stay attached across the switch
    run(session, ".connect")
    assert "reconnected" in capsys.readouterr().out
    run(session, "GAP 1, 2")


def test_stopall_stops_every_motor(s351, capsys):
    frames = Frames(s351.client)
    run(s351, "ROR 1, 500", ".stopall")
    assert "stopped motors 0, 1, 2 (MST; speed reads 0)" in capsys.readouterr().out
    assert [f.motor for f in frames.tx if f.opcode == 3] == [0, 1, 2]
    c = s351.client
    c.wait_until(lambda: c.value("GAP 3, 1") == 0, timeout=5)  # ramps down to a standstill


# -- checks before sending ---------------------------------------------------------------

@pytest.mark.parametrize("line, message", [
    ("SAP 140, 0, 99", "99 is out of range for AP 140 MicrostepResolution: allowed 0..8"),
    ("GAP 4, 5", "TMCM-1311 has no motor 5"),
    ("SAP MaxPossibleCurrent, 0, 1", "is read-only"),
    ("FOO 1, 2", "unknown command 'FOO'"),
    ("GAP Bogus, 0", "unknown axis parameter 'Bogus'"),
    ("MVP SIDEWAYS, 0, 1", "MVP has no type 'SIDEWAYS'"),
    ("JA 5", "only works inside a stored program"),
    ("SIO 0, 0, 1", "is an input"),
])
def test_bad_input_is_one_clear_error_and_nothing_is_sent(session, line, message):
    frames = Frames(session.client)
    with pytest.raises(TmclError) as info:
        session.run_line(line)
    assert message in str(info.value)
    assert "\n" not in str(info.value)
    assert frames.tx == []


def test_eeprom_writes_are_refused_in_scripts_without_yes(session):
    frames = Frames(session.client)
    for line in ("STAP 4, 0", "STGP SerialAddress, 0", "SGP 66, 0, 1", "137 0, 0, 1234"):
        with pytest.raises(Abort, match="--yes") as info:
            session.run_line(line)
        # said as what was not done: no question that nobody can answer
        assert str(info.value).startswith("not done without confirmation: ")
        assert "?" not in str(info.value) and "continue" not in str(info.value)
    assert frames.tx == []


def test_eeprom_writes_ask_in_the_repl():
    s = make_session(interactive=True)
    asked = []
    s.ask = lambda q: asked.append(q) or False
    frames = Frames(s.client)
    try:
        with pytest.raises(Abort, match="cancelled"):
            s.run_line("STAP MaxPositioningSpeed, 0")
        assert "MaxPositioningSpeed" in asked[0] and "EEPROM" in asked[0]
        assert frames.tx == []
        s.ask = lambda q: True
        s.run_line("STAP MaxPositioningSpeed, 0")
        assert [f.opcode for f in frames.tx] == [7]
    finally:
        s.client.close()


def test_module_refusal_is_shown_with_status_in_words(session, capsys):
    with pytest.raises(StatusError):
        session.run_line("6 250, 0, 0")  # raw GAP of a parameter the module does not have
    out = capsys.readouterr().out
    assert "wrong type" in out or "invalid" in out


# -- mistyped shell commands -------------------------------------------------------------

@pytest.mark.parametrize("typed, near", [
    (".halp", ".help"), (".wach", ".watch"), (".stpo", ".stop"), (".PARMS", ".params")])
def test_mistyped_shell_command_names_the_close_ones_and_sends_nothing(session, typed, near):
    frames = Frames(session.client)
    with pytest.raises(ValidationError, match=rf"unknown shell command '{typed}'; did you mean "
                                              rf"[^?]*{near}\b"):
        session.run_line(typed)
    assert frames.tx == []


def test_shell_command_far_from_any_gets_no_guess(session):
    with pytest.raises(ValidationError) as err:
        session.run_line(".xyzzy")
    assert "did you mean" not in str(err.value) and ".help" in str(err.value)


@pytest.mark.parametrize("line", [".param nonsense", ".params nonsense", ".params axis nonsense"])
def test_a_near_miss_is_offered_not_shown_as_the_match(session, line):
    """difflib finds Vsense for 'nonsense'; a table titled "matching 'nonsense'" or Vsense's
    help as the answer would mislead. Nothing is read from the module either."""
    frames = Frames(session.client)
    with pytest.raises(ValidationError, match=r"no parameter matches 'nonsense' on the "
                                              r"TMCM-1311; did you mean Vsense\?"):
        session.run_line(line)
    assert frames.tx == []


def test_params_filter_that_is_part_of_names_still_lists_them(session, capsys):
    session.run_line(".params axis speed")
    out = capsys.readouterr().out
    assert "matching 'speed'" in out and "MaxPositioningSpeed" in out and "Vsense" not in out


def test_help_for_a_number_nothing_answers_to_is_an_error():
    """`help 140` on the TMCM-1640 (no AP 140, no command 140) printed a note and passed."""
    s = make_session("TMCM-1640")
    try:
        with pytest.raises(ValidationError, match=r"^the TMCM-1640 has no parameter 140, and no "
                                                  r"command has that number"):
            s.run_line("help 140")
        s.run_line("help 136")  # no parameter, but a command: explained, not an error
    finally:
        s.client.close()


def _takes_nothing():
    from tmclsh.shell.lang import commands

    return [c.name for c in commands.REGISTRY.values() if c.syntax == c.name]


@pytest.mark.parametrize("name", _takes_nothing())
def test_words_after_a_command_that_takes_none_are_a_usage_error(session, name):
    """`.stopall extra words` (and `.reset now`, `.quit please`) was run with the words
    ignored: now one line says so and nothing is sent."""
    frames = Frames(session.client)
    with pytest.raises(ValidationError) as err:
        session.run_line(f"{name} extra words")
    assert str(err.value) == f"{name} takes no arguments (got 'extra words')"
    assert frames.tx == []


def test_stopall_with_words_is_one_line_and_sends_nothing(run_tmclsh):
    p = run_tmclsh("--sim", "TMCM-1311", "-c", ".stopall extra words")
    assert p.returncode == 1 and p.stdout == ""
    assert p.stderr == "error: .stopall takes no arguments (got 'extra words')\n"


def test_suggestions_are_near_in_spelling_and_kind(session, run_tmclsh):
    """Issue 35: `help SAPP` suggested CurrentScaleUpperErrorLimit, `clear` suggested CLE."""
    for word in ("SAPP", "sapp"):
        with pytest.raises(ValidationError) as exc:
            session.run_line(f"help {word}")
        assert "did you mean SAP" in str(exc.value) and "Limit" not in str(exc.value)
    with pytest.raises(ValidationError) as exc:  # a long name misspelt: still parameters
        session.run_line("help MaxSpeeed")
    assert "Speed" in str(exc.value)
    sent = session.client.stats["sent"]
    with pytest.raises(TmclError) as exc:
        session.run_line("clear")
    assert "did you mean .clear?" in str(exc.value) and "Ctrl-L" in str(exc.value)
    assert "CLE" not in str(exc.value) and session.client.stats["sent"] == sent
    with pytest.raises(TmclError, match="did you mean SGP, SAP"):  # a mnemonic misspelt
        session.run_line("SPA 4, 0, 1")
    session.run_line(".clear")  # not a terminal: nothing written, nothing sent
    assert session.client.stats["sent"] == sent
    p = run_tmclsh("--sim", "-c", "clear")  # checked ahead: the same pointer
    assert p.returncode == 2 and "did you mean .clear?" in p.stderr


def test_version_in_ascii_mode_says_what_connect_read_and_how_to_read_it(session, capsys):
    """Issue 35: `.version` in ASCII mode was refused without a word on how to get it."""
    session.run_line(".mode ascii")
    capsys.readouterr()
    sent = session.client.stats["sent"]
    session.run_line(".version")
    out = capsys.readouterr()
    said = " ".join((out.out + out.err).split())
    assert "firmware 1311V111 (TMCM-1311)" in said and "as read at connect" in said
    assert ".mode binary, .version, .mode ascii" in said
    assert session.client.stats["sent"] == sent  # 136 has no ASCII form: nothing sent
    session.run_line(".mode binary")


def test_version_read_in_the_other_byte_order_is_explained_not_a_fault(capsys):
    """Issue 35: a TMCM-1640 whose 136 type 1 bytes come type first (as the TMCM-1311
    manual prints them, not as the 1640's does) got "does not match the string"."""
    from tmclsh.tmcl.version import TYPE_FIRST, encode_type1

    for json_mode in (False, True):
        s = make_session("TMCM-1640", json_mode=json_mode)
        try:
            s.client.transport.simulator._version_binary = (
                lambda: encode_type1(1640, 210, TYPE_FIRST))
            capsys.readouterr()
            s.run_line(".version")
            out = capsys.readouterr()
        finally:
            s.client.close()
        if json_mode:
            obj = json.loads(out.out)
            assert obj["agrees"] is True and obj["layout"] == "type_first", obj
            assert (obj["binary_type"], obj["binary_version"]) == (1640, 210)
        else:
            said = " ".join((out.out + out.err).split())
            assert "does not match" not in said and "module type 1640 (06 68)" in said
            assert "the same as the string, read type first" in said
            assert "TMCM-1640 data says version first" in said
            assert not out.err  # a statement, not a warning


def test_help_of_a_parameter_command_with_its_parameter_explains_the_parameter(session,
                                                                              capsys):
    """`help GGP 67` is about GP 67 (the 67 was ignored: GGP's own help was shown), and the
    whole line typed after help names the same parameter."""
    for line in ("help GGP 67", "help GGP 67, 0", "help SGP ASCIIMode, 0, 1"):
        session.run_line(line)
        out = capsys.readouterr().out
        assert out.startswith("GP 67  ASCIIMode"), (line, out[:80])
    session.run_line("help SAP MaxCurrent, 0, 100")
    assert capsys.readouterr().out.startswith("AP 6  MaxCurrent")
    session.run_line("help GGP")  # the command itself, as before
    assert capsys.readouterr().out.startswith("GGP  (command 10)")
    session.run_line("help MVP ABS")  # not a parameter command: its own help
    assert capsys.readouterr().out.startswith("MVP  (command 4)")
