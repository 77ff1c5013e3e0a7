"""What a technician reads and how lines are cut (issue 16, "What users read" and "Lines"),
through the in-process simulator and the real command line."""

from __future__ import annotations

import json
import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tmclsh.client.connect import connect
from tmclsh.base.errors import TmclError
from tmclsh.shell.lang.lines import split_line, strip_comment
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session

from responder import Responder, reply, version_reply


@pytest.fixture(autouse=True)
def wide_console(monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")


def make_session(module="TMCM-1311", json_mode=False, **kw):
    client = connect(sim=module, timeout=0.3, retries=0)
    return Session(client, Output(json_mode=json_mode), **kw)


@pytest.fixture
def s351():
    s = make_session("TMCM-351")
    yield s
    s.client.close()


# -- what users read ---------------------------------------------------------------------

def test_help_140_on_the_351_shows_user_text_only(s351, capsys):
    s351.run_line("help 140")
    out = capsys.readouterr().out
    assert "0..6" in out and "note" in out and "AP 211" in out
    assert "\u011e" not in out and "decoded" not in out and "printed" not in out
    assert "source" not in out


def test_param_source_shows_how_the_entry_was_read(s351, capsys):
    s351.run_line(".param --source 140")
    out = capsys.readouterr().out
    assert "source" in out and "decoded 0…6" in out
    s351.run_line(".param --source MaxPositioningSpeed")  # no source: says it is as printed
    assert "as the manual prints it" in capsys.readouterr().out


def test_no_default_shown_where_no_manual_gives_one(capsys):
    s = make_session("TMCM-1640")
    try:
        s.run_line("help gp 66")
        out = capsys.readouterr().out
        assert "SerialAddress" in out and "default" not in out
        s.run_line("help gp 65")  # the manual: 0 = 9600 baud "Default"
        assert "default" in capsys.readouterr().out
        # the simulated module still answers at the factory address
        s.run_line("GGP SerialAddress, 0")
        assert "= 1" in capsys.readouterr().out
    finally:
        s.client.close()


def test_param_json_has_the_note_and_source_only_on_request(capsys):
    s = make_session("TMCM-351", json_mode=True)
    try:
        s.run_line(".param 140")
        obj = json.loads(capsys.readouterr().out.splitlines()[0])
        assert obj["note"].startswith("Full and half step") and "source" not in obj
        s.run_line(".param --source 140")
        obj = json.loads(capsys.readouterr().out.splitlines()[0])
        assert "decoded" in obj["source"]
    finally:
        s.client.close()


def _value(session: Session, line: str) -> int:
    result = session.run_tmcl(line, show=False)
    assert result.reply is not None
    return result.reply.value


def test_1311_encoder_mode_takes_bit_combinations_and_ap198_sets_bit_2():
    s = make_session("TMCM-1311")
    try:
        s.run_tmcl("SAP 201, 0, 20", show=False)  # bit 4 (polarity) + bit 2 (clear on next)
        assert _value(s, "GAP 201, 0") == 20
        s.run_tmcl("SAP 198, 0, 0", show=False)  # "Delete bit 2 of axis parameter 201"
        assert _value(s, "GAP 201, 0") == 16
        assert _value(s, "GAP 198, 0") == 0
        s.run_tmcl("SAP 198, 0, 1", show=False)  # "set bit 2 of axis parameter 201"
        assert _value(s, "GAP 201, 0") == 20
        s.run_tmcl("SAP 201, 0, 0", show=False)  # what AP 198 can leave behind is legal
        assert _value(s, "GAP 198, 0") == 0
        sent = s.stats.commands
        with pytest.raises(TmclError, match="out of range"):
            s.run_tmcl("SAP 201, 0, 5", show=False)  # bit 0 is not documented
        assert s.stats.commands == sent
    finally:
        s.client.close()


# -- .version against a responder written from the TMCM-1311 manual's byte tables ---------------

class _Versioned(Responder):
    """A TCP module (tests/responder.py): 136 type 0 answers '1311V111' (host address + 8
    characters, no checksum), 136 type 1 answers ``binary``; anything else status 100,
    value 0 ("please use the normal reply format": host 2, module 1)."""

    def __init__(self, binary: int):
        self.binary = binary
        super().__init__(tcp=True)

    def answer(self, raw: bytes) -> bytes | None:
        if raw[1] == 136 and raw[2] == 0:
            return version_reply("1311V111")
        return reply(raw[1], self.binary if raw[1] == 136 else 0)


@pytest.mark.parametrize("binary, agrees", [(0x051F6F00, True), (0x051F7000, False)])
def test_version_shows_the_binary_bytes_and_checks_them_against_the_string(
        run_tmclsh, binary, agrees):
    module = _Versioned(binary)
    try:
        out = run_tmclsh("--port", module.url, "-m", "TMCM-1311", "-c", ".version", timeout=30)
    finally:
        module.close()
    text = out.stdout + out.stderr
    lines = [line for line in text.splitlines() if line.strip()]
    first = next(line for line in lines if line.startswith("firmware"))
    binary_line = next(line for line in lines if "136 type 1" in line)
    assert first.startswith("firmware 1311V111") and "136 type 1" not in first
    raw = " ".join(f"{b:02X}" for b in binary.to_bytes(4, "big"))
    assert raw in binary_line and "module type 1311 (05 1F)" in binary_line
    version = (binary >> 8) & 0xFF
    assert f"version {version} ({version:02X} 00, low byte first)" in binary_line
    if agrees:
        assert "the same as the string" in binary_line
    else:
        assert "does not match the string" in binary_line
        assert "111" not in binary_line.split(":", 1)[1]  # never both versions on one line


# -- lines -------------------------------------------------------------------------------

def test_semicolon_separates_commands_that_cannot_contain_one(capsys):
    s = make_session("TMCM-1311")
    try:
        assert s.split('help 4; help 5') == ["help 4", "help 5"]
        assert s.split('.param 4; .params axis Max') == [".param 4", ".params axis Max"]
        assert s.split('.echo "a;b"; .echo x') == ['.echo "a;b"', ".echo x"]
        assert s.split(".echo don't; GAP 1, 0") == [".echo don't", "GAP 1, 0"]
        # a command that owns its line takes the rest of it
        assert s.split(".watch a=GAP 1, 0; b=GIO 0, 0") == [".watch a=GAP 1, 0; b=GIO 0, 0"]
        assert s.split(".decode 01;06;01;00") == [".decode 01;06;01;00"]
        for line in s.split("help 4; help 5"):
            s.run_line(line)
        out = capsys.readouterr().out
        assert "AP 4  MaxPositioningSpeed" in out and "AP 5  MaxAcceleration" in out
    finally:
        s.client.close()


def test_every_command_says_whether_it_owns_its_line():
    from tmclsh.shell.lang import commands

    commands.load_all()
    owners = {c.name for c in commands.all_commands() if c.owns_line}
    assert ".watch" in owners and ".decode" in owners
    assert not owners & {".help", ".param", ".params", ".echo", ".let", ".expect"}


def test_watch_error_caused_by_a_semicolon_shows_how_to_split(run_tmclsh):
    out = run_tmclsh("--sim", "TMCM-1311", "-c", ".watch GAP 1, 0; MST 0")
    assert out.returncode == 2  # (checked before anything is sent, as a script's lines)
    assert "after ';'" in out.stderr and ".watch takes the rest of its line" in out.stderr
    assert "  .watch GAP 1, 0\n" in out.stderr and "  MST 0" in out.stderr


@pytest.mark.parametrize("options", ["--count 2", "--count 2 --csv {csv}"])
def test_semicolon_after_the_watch_options_shows_how_to_split(run_tmclsh, tmp_path, options):
    """Was "--count: must be a whole number ..., got '2;'", or a CSV file named 'x.csv;'
    and 'GAP 3, 0' taken into the watched expression."""
    csv = tmp_path / "x.csv"
    opts = options.format(csv=csv)
    out = run_tmclsh("--sim", "TMCM-1311", "-c", f".watch pos=GAP 1, 0 {opts}; GAP 3, 0")
    assert out.returncode == 2
    assert "'GAP 3, 0' after ';' follows the watch's options" in out.stderr
    assert f"  .watch pos=GAP 1, 0 {opts}\n  GAP 3, 0" in out.stderr
    assert out.stdout == "" and [p for p in tmp_path.iterdir() if p.name != "cache"] == []  # nothing watched or written


@pytest.mark.parametrize("how", ["-c", "-f"])
def test_hash_comment_ends_a_line_like_slashes(run_tmclsh, tmp_path, how):
    text = "GAP 1, 0 # where it is; not a command\n.let a = 3 # three\n.echo ${a} // done\n" \
           '.echo "a # b"\n.echo issue#5\n'
    if how == "-c":
        out = run_tmclsh("--sim", "TMCM-1311", "-c", text)
    else:
        path = tmp_path / "c.tmcl"
        path.write_text(text)
        out = run_tmclsh("--sim", "TMCM-1311", "-f", str(path))
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[:4] == ["ActualPosition = 0 µsteps", "3", "a # b", "issue#5"]


def test_hash_keeps_its_meaning_in_assembler_source_and_the_lexer(tmp_path):
    """``#include`` in a program and ``$1F`` hex are untouched by ``#`` comments."""
    from pygments.token import Comment

    from tmclsh.tmcl import asm, modules
    from tmclsh.shell.repl.lexer import TmclLexer

    (tmp_path / "inc.tmcl").write_text("Speed = 1000\n")
    main = tmp_path / "main.tmcl"
    main.write_text('#include "inc.tmcl"\nSAP 4, 0, Speed\nSAP 5, 0, $1F\nSTOP\n')
    program = asm.assemble_file(main, modules.load("TMCM-1311"))
    values = [i.value for i in program.instructions][:2]
    assert values == [1000, 0x1F]
    tokens = list(TmclLexer().get_tokens_unprocessed("GAP 1, 0 # where\n"))
    assert (9, Comment.Single, "# where") in tokens
    assert list(TmclLexer().get_tokens_unprocessed("#include x.tmcl\n"))[0][1] is Comment.Preproc
    hex_tokens = list(TmclLexer().get_tokens_unprocessed("SAP 4, 0, $1F\n"))
    assert not any(tok is Comment.Single for _, tok, _ in hex_tokens)


def test_question_mark_and_bare_help_are_help(run_tmclsh):
    for line in ("?", "help", "? 140"):
        out = run_tmclsh("--sim", "TMCM-1311", "-c", line)
        assert out.returncode == 0, (line, out.stderr)
    assert "MicrostepResolution" in run_tmclsh("--sim", "TMCM-1311", "-c", "? 140").stdout
    assert ".help" in run_tmclsh("--sim", "TMCM-1311", "-c", "?").stdout


# -- script errors and counts ---------------------------------------------------------------

def _script(run_tmclsh, tmp_path, body: str, *args: str):
    path = tmp_path / "s.tmcl"
    path.write_text(body)
    return run_tmclsh("--sim", "TMCM-1311", *args, "-f", str(path))


def test_a_value_out_of_range_is_a_range_error_not_a_syntax_error(run_tmclsh, tmp_path):
    out = _script(run_tmclsh, tmp_path, "GAP 1, 0\nSAP 140, 0, 99\n")
    assert out.returncode == 2
    assert "s.tmcl:2: 99 is out of range" in out.stderr
    assert "not run (a value out of range; nothing was sent)" in out.stdout
    assert "syntax" not in out.stdout + out.stderr


def test_a_missing_file_is_no_such_file(run_tmclsh, tmp_path):
    out = run_tmclsh("--sim", "TMCM-1311", "-f", str(tmp_path / "nowhere.tmcl"))
    assert out.returncode == 2 and "no such file" in out.stderr
    assert "not run (no such file" in out.stdout and "syntax" not in out.stdout
    out = _script(run_tmclsh, tmp_path, ".source nowhere.tmcl\n")
    assert "s.tmcl:1: no such file" in out.stderr and "not run (no such file" in out.stdout


def test_a_real_syntax_error_is_still_called_one(run_tmclsh, tmp_path):
    out = _script(run_tmclsh, tmp_path, "GAP 1, 0\nSAP 4, 0\n")
    assert out.returncode == 2 and "not run (syntax error; nothing was sent)" in out.stdout


def test_summary_counts_add_up(run_tmclsh, tmp_path):
    out = _script(run_tmclsh, tmp_path, "GAP 1, 0\n.expect 1 == 2\nGAP 1, 0\n", "--keep-going")
    assert out.returncode == 1
    assert "2 commands sent, 0 checks passed, 1 failed, 0 errors" in out.stdout
    # every GAP .params sends is a command sent: one per readable parameter
    from tmclsh.tmcl import modules

    mod = modules.load("TMCM-1311")
    readable = sum(1 for p in mod.axis_params if p.readable)
    out = _script(run_tmclsh, tmp_path, ".params axis\n")
    assert f"{readable} commands sent" in out.stdout, out.stdout


# -- lists as prose ---------------------------------------------------------------------------

_REPR = re.compile(r"\[\s*(-?\d+[,\]]|'|\"|\()|\(\d+, \d+\)|\{'|\bNone\b|\bTrue\b|\bFalse\b")


def test_interrupted_run_names_the_stopped_motors_in_prose(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    from conftest import patience, tmclsh_env

    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "--sim", "TMCM-351", "-c",
                             "ROR 0, 100; .sleep 20"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=tmclsh_env())
    try:
        deadline = time.monotonic() + patience(20)
        line = proc.stdout.readline()  # the ROR's result: the shell is in .sleep now
        assert "0" in line and time.monotonic() < deadline
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=patience(20))
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130
    assert "interrupted: stopped motors 0, 1, 2 (MST; speed reads 0)" in err, err
    assert not _REPR.search(err), err


@pytest.mark.parametrize("module", ["TMCM-1311", "TMCM-351", "TMCM-1640"])
def test_user_facing_output_has_no_python_reprs(module, capsys):
    s = make_session(module)
    lines = [".help", ".params", ".module", ".version", ".status", ".vars all", ".stopall",
             ".mode", "help SAP", "help 140", "help 66", ".param 0", "GIO 0, 0", "136 1",
             "MVP ABS, 0, 100", ".history", ".decode 01 06 01 00 00 00 00 00 08"]
    try:
        for line in lines:
            try:
                s.run_line(line)
            except TmclError as exc:  # an error's message is output too
                print(exc)
        out = capsys.readouterr()
        text = out.out + out.err
        assert not _REPR.search(text), _REPR.search(text).group()
    finally:
        s.client.close()


# -- the splitter itself ----------------------------------------------------------------------

_SEGMENT = st.text(st.sampled_from("GAP 1,0$xF.abc_=+-()"), max_size=12)


@given(st.lists(_SEGMENT, max_size=6))
def test_semicolons_cut_exactly_the_segments(segments):
    line = ";".join(segments)
    assert split_line(line, lambda text: False) == [s.strip() for s in segments if s.strip()]


@given(st.lists(_SEGMENT, min_size=1, max_size=6))
def test_a_line_owner_takes_everything_after_it(segments):
    line = ".watch " + ";".join(segments)
    assert split_line(line, lambda text: text.startswith(".watch")) == [line.strip()]


@pytest.mark.parametrize("text, kept", [
    ("GAP 1, 0 # where", "GAP 1, 0"),
    ("GAP 1, 0 // where", "GAP 1, 0"),
    ("# all of it", ""),
    ('.echo "a # b" # c', '.echo "a # b"'),
    (".echo issue#5", ".echo issue#5"),
    ("SAP 4, 0, $1F", "SAP 4, 0, $1F"),
    (".echo don't # c", ".echo don't"),
    (".let x = (1 + 2) # three", ".let x = (1 + 2)"),
])
def test_comments(text, kept):
    assert strip_comment(text) == kept


@pytest.mark.parametrize("text, kept", [
    (".connect socket://127.0.0.1:4001", ".connect socket://127.0.0.1:4001"),
    (".connect rfc2217://10.0.0.5:2217 // bench", ".connect rfc2217://10.0.0.5:2217"),
    (".connect loop://", ".connect loop://"),
    ("GAP 1, 0// where", "GAP 1, 0"),
    ("GAP 1, 0 ://x", "GAP 1, 0 :"),  # no scheme before it
    (".echo a:b//c", ".echo a:b"),
])
def test_a_url_scheme_is_no_comment(text, kept):
    assert strip_comment(text) == kept
