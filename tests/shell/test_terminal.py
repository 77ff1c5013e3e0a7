"""The shell side of ASCII mode: the terminal's pure views on canned byte sequences, its
key translation and completion, ``.mode`` and ``.ascii-config`` through a Session, and the
terminal's line mode without a tty (in process and through the CLI)."""

from __future__ import annotations

import json

import pytest

from tmclsh.client.ascii import AsciiLink, Echo, LineKind, Mode
from tmclsh.client.text import LineClient
from tmclsh.base.errors import ValidationError
from tmclsh.tmcl.frames import Request
from tmclsh.shell.features import terminal as tm
from tmclsh.shell.features import termloops as tl
from tmclsh.shell.features import termview as tv
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Abort, Session
from tmclsh.sim import Simulator
from tmclsh.link.sim import SimTransport


def text(segments) -> str:
    return "".join(t for _, t in segments)


# -- what gets sent ---------------------------------------------------------------------------------

@pytest.mark.parametrize("typed, sent", [
    ("GAP 1, 0", "AGAP 1, 0"),
    ("gap 1, 0", "Agap 1, 0"),
    ("AGAP 1, 0", "AGAP 1, 0"),
    ("A GAP 1, 0", "A GAP 1, 0"),
    ("CMST 0", "CMST 0"),
    ("BIN", "ABIN"),
    ("RUN", "ARUN"),
    ("STOP", "ASTOP"),
    ("ASTOP", "ASTOP"),
    ("SAP 4, 0, 1", "ASAP 4, 0, 1"),  # SAP is a command, not S + AP
    ("CCO 1, 0", "ACCO 1, 0"),
    ("XYZ", "AXYZ"),
    ("  GAP 1, 0  ", "AGAP 1, 0"),
    ("17", "A17"),
])
def test_with_address(typed, sent):
    assert tv.with_address(typed, 1) == sent


def test_with_address_other_module():
    assert tv.with_address("GAP 1, 0", 3) == "CGAP 1, 0"


# -- the line view ------------------------------------------------------------------------------------

SENT = b"AGAP 1, 0\r"


@pytest.mark.parametrize("stream", [
    b"AGAP 1, 0\rBA 100 -5000\r",  # echo each character (CR echoed) / whole line
    b"AGAP 1, 0BA 100 -5000\r",  # echo each character, CR not echoed
    b"BA 100 -5000\r",  # no echo
    b"AGAP 1, 0\r\nBA 100 -5000\r\n",
])
def test_line_view_hides_echo_and_decodes(stream):
    view = tv.LineView()
    view.expect(SENT)
    shown = []
    for i in range(len(stream)):  # byte by byte: nothing may depend on chunking
        shown += view.feed(stream[i:i + 1])
    visible = [s for s in shown if s.kind != LineKind.ECHO]
    assert len(visible) == 1
    assert text(visible[0].segments) == "BA 100 -5000   ok, value -5000"


def test_line_view_other_lines_and_errors():
    view = tv.LineView()
    view.expect(b"AXYZ\r")
    shown = view.feed(b"AXYZ\rBA 2 0\rhello\r\x01junk")
    assert [s.kind for s in shown] == [LineKind.ECHO, LineKind.REPLY, LineKind.OTHER]
    assert text(shown[1].segments) == "BA 2 0   error 2: invalid command"
    assert text(shown[2].segments) == "hello"
    assert [text(s.segments) for s in view.flush()] == ["\\x01junk"]
    assert view.flush() == []


# -- the raw view -------------------------------------------------------------------------------------

def feed_all(view: tv.RawView, *chunks) -> str:
    out = []
    for chunk in chunks:
        if isinstance(chunk, tuple):
            view.user_enter(chunk[0])
        else:
            out += view.feed(chunk)
    return text(out)


def test_raw_view_backspace_echo():
    # char echo with a typo erased: the module's own \b \b passes through
    got = feed_all(tv.RawView(), b"AGAX", b"\b \b", b"P 1, 0", (b"AGAP 1, 0",), b"\rBA 100 -5000\r")
    assert got == "AGAX\b \bP 1, 0\r\nBA 100 -5000   ok, value -5000\r\n"


def test_raw_view_breaks_line_when_cr_not_echoed():
    view = tv.RawView()
    got = feed_all(view, b"A", (b"AGAP 1, 0",), b"GAP 1, 0", b"BA 100 7\r")
    assert got == "AGAP 1, 0\r\nBA 100 7   ok, value 7\r\n"
    # the Enter is known before the echo arrived (fast typing): still right
    got = feed_all(tv.RawView(), (b"AMST 0",), b"AMST 0BA 100 0\r")
    assert got == "AMST 0\r\nBA 100 0   ok, value 0\r\n"


def test_raw_view_line_and_no_echo():
    assert feed_all(tv.RawView(), (b"AGAP 1, 0",), b"AGAP 1, 0\rBA 4 0\r") == \
        "AGAP 1, 0\r\nBA 4 0   error 4: invalid value\r\n"
    assert feed_all(tv.RawView(), (b"AGAP 1, 0",), b"BA 100 0\r\n") == \
        "BA 100 0   ok, value 0\r\n"


def test_raw_view_non_printable_and_local_echo():
    view = tv.RawView()
    assert text(view.feed(b"\x01x\r")) == "\\x01x\r\n"
    assert text(view.local(b"AG\x7f")) == "AG\b \b"
    assert text(view.local(b"\r")) == "\r\n"


def test_translate_keys():
    assert tl.translate_keys(b"AG\x7fP\r") == [b"A", b"G", b"\x08", b"P", b"\r"]
    assert tl.translate_keys(b"\x1b[A\x1b[1;5Cx\x1bOPy") == [b"x", b"y"]  # arrows, F1 dropped
    assert tl.translate_keys(b"a\x03\x1d\n") == [b"a", tl.CTRL_C, tl.ESCAPE_KEY, b"\r"]


def test_parse_options():
    o = tm.parse_options("--raw --bin --echo")
    assert (o.raw, o.send_bin, o.local_echo) == (True, True, True)
    assert tm.parse_options("--no-bin").send_bin is False
    assert tm.parse_options("").send_bin is None
    with pytest.raises(ValidationError, match="--raw"):
        tm.parse_options("--fast")


def test_painter_plain_and_colour():
    segs = [("tmcl.ok", "ok"), ("", " x")]
    assert tv.Painter(color=False)(segs) == "ok x"
    coloured = tv.Painter(color=True)(segs)
    assert coloured.endswith(" x") and "\x1b[" in coloured and "ok" in coloured


# -- with a simulated module -------------------------------------------------------------------------

@pytest.fixture
def session(capsys):
    made = []

    def factory(yes: bool = True, json_mode: bool = False, **kw) -> tuple[Simulator, Session]:
        sim = Simulator("TMCM-1311", 1, **kw)
        client = LineClient(SimTransport("TMCM-1311", 1, simulator=sim), module="TMCM-1311",
                        timeout=0.25, retries=0)
        made.append((sim, client))
        return sim, Session(client, Output(json_mode=json_mode), yes=yes)

    yield factory
    for sim, client in made:
        client.close()
        sim.close()


def test_completions(session):
    sim, s = session()

    def texts(line):
        return [c.text for c in tl.ascii_completions(s, line)]

    first = texts("")
    assert {"GAP", "SAP", "MVP", "BIN", "RUN", "STOP"} <= set(first)
    assert "CALC" not in first and "JA" not in first and ".mode" not in first
    assert texts("GAP act")[0] == "1"  # names find numbers: the module knows no names
    assert texts("AGAP act")[0] == "1"  # after a typed address character
    assert texts("A GAP maxpos")[0] == "4"
    assert texts("MVP ")[:3] == ["ABS", "REL", "COORD"]
    assert texts("B")[:1] == ["BIN"]
    assert texts("GGP 67, ")[:1] == ["0"]


def test_mode_command(session, capsys):
    sim, s = session()
    s.run_line(".mode")
    assert capsys.readouterr().out.strip() == "mode: binary"
    s.run_line(".mode ascii")
    assert sim.ascii_active and s.client.mode == "ascii"
    assert "BIN at exit" in capsys.readouterr().out
    s.run_line("SAP 1, 0, 42")
    s.run_line("GAP 1, 0")
    assert "ActualPosition = 42" in capsys.readouterr().out
    s.run_line(".mode binary")
    assert not sim.ascii_active and s.client.mode == "binary"
    s.run_line(".mode ascii --keep")
    assert AsciiLink.for_client(s.client).on_exit == Mode.ASCII
    with pytest.raises(ValidationError):
        s.run_line(".mode serial")
    s.client.close()
    assert sim.ascii_active  # --keep: left in ASCII mode


def test_mode_json(session, capsys):
    sim, s = session(json_mode=True, ascii_startup=True)
    s.run_line(".mode ascii")
    obj = json.loads(capsys.readouterr().out)
    assert obj == {"mode": "ascii", "echo": "char", "found": "ascii", "on_exit": "ascii",
                   "simulated": True}


def test_ascii_config(session, capsys):
    sim, s = session()
    s.run_line(".ascii-config")
    out = capsys.readouterr().out
    assert "GP 67 ASCIIMode = 0" in out and "start up in binary mode" in out
    s.run_line(".ascii-config startup=ascii echo=line")
    out = capsys.readouterr().out
    assert "= 17" in out and "was 0" in out and "bit  4 1" in out
    assert s.client.value("GGP 67, 0") == 17
    s.run_line(".mode ascii")
    link = s.client.ascii_link
    assert link.echo == Echo.LINE
    s.run_line(".ascii-config echo=none")  # over the ASCII link: the echo mode follows
    assert link.echo == Echo.NONE and s.client.value("GGP 67, 0") == 33
    s.run_line(".ascii-config echo=none")
    assert "unchanged" in capsys.readouterr().out
    sim.reset()  # power cycle: SGP 67 went to EEPROM, bit 0 makes it start in ASCII
    assert sim.ascii_active


def test_ascii_config_asks_and_validates(session):
    sim, s = session(yes=False)
    with pytest.raises(Abort, match="--yes"):
        s.run_line(".ascii-config echo=line")
    assert s.client.value("GGP 67, 0") == 0  # nothing written
    for bad in ("echo=loud", "startup=maybe", "speed=1", "echo"):
        with pytest.raises(ValidationError):
            s.run_line(f".ascii-config {bad}")


def test_ascii_config_json(session, capsys):
    sim, s = session(json_mode=True)
    s.run_line(".ascii-config echo=none")
    obj = json.loads(capsys.readouterr().out)
    assert obj == {"gp67": 32, "startup": "binary", "echo": "none", "note": "was 0",
                   "simulated": True}


def test_terminal_line_mode_in_process(session):
    sim, s = session()
    s.client.request(Request(1, 5, 1, 0, -5000))
    link = AsciiLink.attach(s.client)
    out: list[str] = []
    term = tm.Terminal(s, link, tm.TerminalOptions(), out.append, tv.Painter(color=False))
    tl.run_plain_lines(term, ["GAP 1, 0", "XYZ", "", "AGGP 67, 0", "CGAP 1, 0"])
    lines = "".join(out).splitlines()
    assert lines == ["BA 100 -5000   ok, value -5000", "BA 2 0   error 2: invalid command",
                     "BA 100 0   ok, value 0"]  # nothing answers address C


def test_terminal_through_the_cli_without_a_tty(run_tmclsh):
    res = run_tmclsh("--sim", "-c", ".ascii --bin\nGAP 1, 0", input="SAP 1, 0, 77\nGAP 1, 0\n")
    assert res.returncode == 0, res.stderr
    out, notes = res.stdout.splitlines(), res.stderr.splitlines()
    assert out == ["BA 100 77   ok, value 77", "BA 100 77   ok, value 77",
                   "ActualPosition = 77 µsteps"]  # the last in binary mode, after the terminal
    assert "--- module entered ASCII mode (command 139)" in notes  # status lines: stderr
    assert "--- BIN sent: module in binary mode" in notes


def test_the_terminal_says_nothing_of_reading_twice_until_the_shell_reads_in_ascii(
        run_tmclsh):
    """The terminal passes lines through and reads nothing twice: the note that the shell
    reads every setting twice in ASCII mode comes only when the shell goes on in it."""
    res = run_tmclsh("--sim", "-c", ".ascii --bin", input="GAP 1, 0\n")
    assert res.returncode == 0, res.stderr
    assert "no checksum" not in res.stderr
    res = run_tmclsh("--sim", "-c", ".ascii --no-bin\nGAP 1, 0", input="GAP 1, 0\n")
    assert res.returncode == 0, res.stderr
    notes = res.stderr
    assert notes.count("no checksum") == 1
    assert notes.index("module stays in ASCII mode") < notes.index("no checksum")


def test_terminal_raw_needs_a_tty(run_tmclsh):
    res = run_tmclsh("--sim", "-c", ".ascii --raw")
    assert res.returncode != 0 and "needs a terminal" in res.stderr


def test_bin_sent_from_the_terminal_returns_to_the_binary_link(run_tmclsh):
    res = run_tmclsh("--sim", "-c", ".ascii\nGAP 1, 0",
                     input="SAP 1, 0, 77\nBIN\nGAP 1, 0\n")
    assert res.returncode == 0, res.stderr
    out, notes = res.stdout.splitlines(), res.stderr.splitlines()
    # the line after BIN is not sent in ASCII: the terminal has ended; the -c line after
    # .ascii runs on binary frames
    assert out == ["BA 100 77   ok, value 77", "BA 100 0   ok, value 0",
                   "ActualPosition = 77 µsteps"]
    assert "--- module left ASCII mode (BIN): back to the shell on the binary link" in notes
    assert not any("send BIN" in n for n in notes)


def test_quit_in_the_terminal_without_a_tty(run_tmclsh):
    res = run_tmclsh("--sim", "-c", ".ascii --bin\nGAP 1, 0", input="SAP 1, 0, 5\n.quit\nGAP 1, 0\n")
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines() == ["BA 100 5   ok, value 5", "ActualPosition = 5 µsteps"]
