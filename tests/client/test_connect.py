"""tmclsh never reports a state the module is not in (issue 11, points 1, 3, 5): no silent
simulator for runs nobody watches, several USB modules named rather than guessed, the module's
type and mode checked at connect, and a connect that finds nobody says so in the user's words.

The modules here are small responders written from the manuals' byte tables (TMCM-1311 manual
§4: a request is address, command, type, motor, value big-endian, checksum = sum of the eight
bytes; a reply is host, module, status, command, value, checksum; 136 type 0 is answered by
the host address and eight ASCII characters; §4.4 ASCII mode: ``<address char><command> CR``
answered by ``<host char><module char> <status> <value> CR``), served on a pty, independent
of the project's simulator: tests/responder.py's ``Responder``, each variation a subclass.
"""

from __future__ import annotations

import os
import termios
import threading
import time

import pytest
from serial.tools import list_ports
from serial.tools.list_ports_common import ListPortInfo

from tmclsh.cli import main as cli
from tmclsh.client.text import LineClient
from tmclsh.base.errors import DownloadModeError
from tmclsh.tmcl.frames import Request
from tmclsh.link import open_serial

from responder import DownloadModeModule, Responder
from tmux import needs_tmux

OK, INVALID_COMMAND = 100, 2
GET_VERSION, ENTER_ASCII, QUIT_DOWNLOAD, START_DOWNLOAD = 136, 139, 133, 132
GAP = 6
# the client's own machinery (a 136 sent to line the replies up again); "end marker" and the
# debugger's "->" marker are words the user knows
INTERNAL_WORDS = ("resynchron", "resync", "136 marker", "marker (136)", "marker request")


@pytest.fixture
def responders():
    made: list[Responder] = []

    def make(cls=Responder, **kw) -> Responder:
        made.append(cls(**kw))
        return made[-1]

    yield make
    for r in made:
        r.close()


def one_line(stderr: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    return lines[0]


def likely_causes(err: str) -> tuple[str, list[str], list[str]]:
    """A "nobody answered" message: its first line, the names of the likely causes, their lines."""
    first, *causes = err.strip().splitlines()
    return first, [c.split(":")[0].strip() for c in causes], causes


# -- 1. no silent simulation -------------------------------------------------------------------

@pytest.mark.parametrize("args, stdin", [
    (["-c", "SAP 4, 0, 1000"], None),
    (["--json", "-c", "GAP 1, 0"], None),
    (["-f", "-"], "GAP 1, 0\n"),
    ([], "GAP 1, 0\n"),  # stdin not a terminal
    (["scan"], None),
])
def test_runs_nobody_watches_never_fall_back_to_the_simulator(run_tmclsh, args, stdin):
    p = run_tmclsh(*args, input=stdin)
    # (under --json the failure is a record on stdout as well: issue 23)
    assert p.returncode == 3 and p.stdout == ("" if "--json" not in args else p.stdout)
    line = one_line(p.stderr)
    assert line.startswith("tmclsh: no module found: no --port, --can or --sim given")
    assert "no Trinamic USB module attached" in line and "--sim to simulate" in line


def test_with_sim_or_a_variable_naming_the_port_they_run(run_tmclsh, responders):
    p = run_tmclsh("--sim", "-c", "GAP 1, 0")
    assert p.returncode == 0 and "ActualPosition = 0" in p.stdout
    module = responders()
    from conftest import tmclsh_env

    p = run_tmclsh("-c", "GAP 1, 0", env=tmclsh_env(TMCLSH_PORT=module.path))
    assert p.returncode == 0, p.stderr
    assert any(raw[1] == GAP for raw in module.log)  # it went to the module, not a simulator


def _usb(device: str, serial: str) -> ListPortInfo:
    p = ListPortInfo(device)
    p.vid, p.pid, p.description, p.serial_number = 0x2A3C, 0x0100, "TMCM-1311", serial
    return p


@pytest.mark.parametrize("args, tty_in", [(["-c", "GAP 1, 0"], False), ([], True),
                                          (["scan"], False)])
def test_two_usb_modules_exit_3_naming_them_in_every_mode(monkeypatch, capsys, args, tty_in):
    monkeypatch.setattr(list_ports, "comports",
                        lambda *a, **k: [_usb("/dev/ttyACM1", "B"), _usb("/dev/ttyACM0", "A")])
    monkeypatch.setenv("TMCLSH_CONFIG", os.devnull)
    for var in ("TMCLSH_PORT", "TMCLSH_CAN", "TMCLSH_PROFILE"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setattr("sys.stdin.isatty", lambda: tty_in)
    assert cli.main(args) == 3
    err = capsys.readouterr().err
    assert one_line(err) == ("tmclsh: 2 Trinamic USB modules attached: /dev/ttyACM0 (TMCM-1311, "
                             "serial A), /dev/ttyACM1 (TMCM-1311, serial B); pick one with --port "
                             "(-c and -f: --all runs on every one)")


@needs_tmux
def test_a_person_at_the_prompt_still_gets_the_simulator_labelled(terminal):
    term = terminal()
    term.start()  # no connection, no module attached, a terminal: the README's first command
    screen = term.wait("trace off")
    assert "SIMULATED" in screen and "TMCM-1311:1>" in screen
    term.keys("GAP 1, 0", "Enter")
    assert "ActualPosition = 0" in term.wait("ActualPosition")


# -- 3. mode and type checked ------------------------------------------------------------------

def test_a_module_left_in_download_mode_is_brought_out_at_connect(run_tmclsh, responders):
    module = responders(DownloadModeModule)
    p = run_tmclsh("--port", module.path, "-c", "GAP 1, 0")
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "ActualPosition = -5000 µsteps"
    assert one_line(p.stderr) == (
        "tmclsh: the module at address 1 was in download mode (an upload was cut short?): "
        "ended it with 133; the program stored on it may be incomplete")
    cmds = [raw[1] for raw in module.log]
    assert cmds.index(QUIT_DOWNLOAD) < cmds.index(GAP)  # ended before the line was sent


def test_status_101_outside_an_upload_is_an_error_not_a_value(run_tmclsh, responders):
    module = responders(DownloadModeModule)
    module.downloading = False
    p = run_tmclsh("--port", module.path, "-c", "132 0, 0, 0; GAP 1, 0")
    assert p.returncode == 1
    assert "ActualPosition" not in p.stdout
    assert ("error: the module is in download mode (it stores commands instead of executing "
            "them): GAP was stored in program memory, not executed") in p.stderr
    p = run_tmclsh("--port", module.path, "--json", "-c", "GAP 1, 0")  # brought out again
    assert p.returncode == 0 and '"reply": -5000' in p.stdout


def test_a_132_line_left_unended_is_ended_when_tmclsh_exits(run_tmclsh, responders):
    """A 132 typed (or in a script) with no 133 after it left the module storing every
    command it got after tmclsh had gone (the next tmclsh ended it; another program would
    not): the exit ends it, and says so."""
    module = responders(DownloadModeModule)
    module.downloading = False
    p = run_tmclsh("--port", module.path, "-c", "132")
    assert p.returncode == 0, p.stderr
    assert not module.downloading and module.log[-1][1] == QUIT_DOWNLOAD
    assert ("still in download mode (a 132 line with no 133 after it): ended it with 133"
            in p.stderr)
    before = len(module.log)
    p = run_tmclsh("--port", module.path, "-c", "132\n133")  # ended by its own line
    assert p.returncode == 0 and "download mode" not in p.stderr, p.stderr
    assert [raw[1] for raw in module.log[before:]].count(QUIT_DOWNLOAD) == 1


def test_the_first_command_after_a_reconnect_ends_download_mode(responders):
    module = responders(DownloadModeModule)
    module.downloading = False
    client = LineClient(open_serial(module.path), module="TMCM-1311", timeout=0.5)
    notices: list[str] = []
    client.on_notice = notices.append
    try:
        assert client.value("GAP 1, 0") == -5000
        module.downloading = True  # the link dropped mid-upload
        with pytest.raises(DownloadModeError):
            client.value("GAP 1, 0")
        client.reconnect()
        assert client.value("GAP 1, 0") == -5000
        assert len(notices) == 1 and "ended it with 133" in notices[0]
        client.reconnect()  # in normal mode: one GGP 129 read, no 133, no notice
        assert client.value("GAP 1, 0") == -5000 and len(notices) == 1
        assert [raw[1] for raw in module.log].count(QUIT_DOWNLOAD) == 1
    finally:
        client.close()


class Tmcm351(Responder):
    version = "0351V103"


def test_a_contradicting_module_option_is_an_error_naming_both(run_tmclsh, responders):
    module = responders(Tmcm351)
    p = run_tmclsh("--port", module.path, "-m", "TMCM-1311", "-c", "GAP 1, 0")
    assert p.returncode == 3 and p.stdout == ""
    assert one_line(p.stderr) == (
        "tmclsh: -m TMCM-1311 does not match the module: address 1 says it is a TMCM-351 "
        "(version 0351V103); leave -m out to use what the module says, or give -m TMCM-351")
    assert not any(raw[1] == GAP for raw in module.log)  # nothing validated for the wrong one
    p = run_tmclsh("--port", module.path, "-c", "GAP 1, 0")  # without -m, 136 decides
    assert p.returncode == 0 and "TMCM-351" not in p.stderr


def test_a_bare_sim_simulates_the_module_m_names(run_tmclsh):
    """``-m TMCM-351 --sim``: the simulator is of the module asked for, not the default one
    and then an error that they differ; ``--sim`` alone is still a TMCM-1311."""
    for args in (["-m", "TMCM-351", "--sim"], ["--sim", "-m", "tmcm351"]):
        p = run_tmclsh(*args, "-c", ".version")
        assert p.returncode == 0 and "0351V103" in p.stdout, (args, p.stderr)
    assert "1311V111" in run_tmclsh("--sim", "-c", ".version").stdout
    assert "1311V111" in run_tmclsh("-m", "generic", "--sim", "-c", ".version").stdout
    p = run_tmclsh("-m", "TMCM-1311", "--sim", "TMCM-351", "-c", ".version")  # both named
    assert p.returncode == 3 and "--sim TMCM-1311 simulates a TMCM-1311" in p.stderr


class FlippedVersionOnce(Responder):
    """A bit flipped on the line in the first version string (it has no checksum)."""

    flipped = "1711V111"  # '3' (0x33) with bit 2 flipped is '7'
    lost_first = False  # the first string lost as well (the mode probe, then 136 again)

    def answer(self, raw: bytes) -> bytes | None:
        if raw[1] == GET_VERSION and raw[2] == 0 and self.lost_first:
            self.lost_first = False
            return None
        if raw[1] == GET_VERSION and raw[2] == 0 and self.flipped:
            got = self.version
            self.version, self.flipped = self.flipped, ""
            try:
                return super().answer(raw)
            finally:
                self.version = got
        return super().answer(raw)


@pytest.mark.parametrize("flipped, lost_first", [("1711V111", False), ("1311v111", False),
                                                 ("13!1V111", True)])
def test_a_version_string_damaged_on_the_line_is_asked_again(run_tmclsh, responders, flipped,
                                                             lost_first):
    """136 type 0 has no checksum: a string naming no known module is checked against the
    checksummed 136 type 1 and asked again (was: TMCM-1711 in generic mode, or 'unknown
    module type ... give it with --module', exit 3)."""
    module = responders(FlippedVersionOnce)
    module.flipped, module.lost_first = flipped, lost_first
    p = run_tmclsh("--port", module.path, "-c", "GAP ActualPosition, 0")
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "ActualPosition = 0 µsteps" and p.stderr == ""


def test_a_module_without_data_keeps_its_string(run_tmclsh, responders):
    class Tmcm1161(Responder):
        version = "1161V130"

    module = responders(Tmcm1161)
    p = run_tmclsh("--port", module.path, "-c", "GAP 1, 0")
    assert p.returncode == 0 and "TMCM-1161" in p.stderr  # generic mode, said so
    assert [raw[2] for raw in module.log if raw[1] == GET_VERSION][:2] == [0, 1]


class AsciiStartupModule(Responder):
    """GP 67 = 0x21: starts in ASCII mode (bit 0), no echo (bits 5/4 = 10). Binary frames are
    just characters of a line here. BIN switches to binary mode, 139 back."""

    gp67 = 0x21

    def line(self, text: str) -> str | None:
        if not text.startswith("A"):
            return None  # another address, or the rest of binary bytes
        cmd = text[1:].strip().upper()
        if cmd == "BIN":
            self.ascii = False
            return None
        if cmd.replace(" ", "") == "GGP67,0":
            return f"BA {OK} {self.gp67}"
        if cmd.startswith("GAP"):
            return f"BA {OK} 1234"
        return f"BA {INVALID_COMMAND} 0"

    def answer(self, raw: bytes) -> bytes | None:
        if raw[1] == ENTER_ASCII:
            self.ascii = True
            return None
        return super().answer(raw)


def test_a_module_in_ascii_mode_is_recognised_and_used_with_a_notice(run_tmclsh, responders):
    module = responders(AsciiStartupModule, ascii=True)
    p = run_tmclsh("--port", module.path, "--timeout", "0.3", "--retries", "0",
                   "-c", "GAP 1, 0")
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "ActualPosition = 1234 µsteps"
    checksum, note = p.stderr.strip().splitlines()  # (said once, where ASCII mode is taken)
    assert checksum.startswith("tmclsh: ASCII replies carry no checksum")
    assert note.startswith("tmclsh: the module at address 1 is in its ASCII mode")
    assert "'.mode binary --keep' switches it back to binary for good" in note
    assert "did not answer" not in note
    assert module.ascii  # left in the mode it was found in
    # (spaces after the address character keep binary modules' framing in step)
    assert b"AGAP 1, 0" in [t[:1] + t[1:].lstrip(b" ") for t in module.log]


# -- 5. nothing answers --------------------------------------------------------------------------

class Silent(Responder):
    def answer(self, raw: bytes) -> bytes | None:
        return None


def test_nothing_answering_says_what_was_tried_and_what_to_try(run_tmclsh, responders):
    module = responders(Silent)
    p = run_tmclsh("--port", module.path, "--timeout", "0.1", "-c", "GAP 1, 0")
    assert p.returncode == 3 and p.stdout == ""
    err = p.stderr
    first, names, causes = likely_causes(err)
    assert first == (f"tmclsh: no module answered at address 1 on {module.path} @ 9600: asked "
                     "for its version (136) 3 times and tried its ASCII mode, waiting up to "
                     "0.1 s each. Likely causes, most likely first:")
    # 1 + --retries (default 2) times, as said; the mode probe's 136 is one of them
    assert [raw[1] for raw in module.log if raw[:1] == b"\x01"].count(136) == 3
    assert names == [
        "- baud rate", "- address", "- a slow link", "- the port"]
    assert ("GP 65 allows 14400, 19200, 28800, 38400, 57600, 76800, 115200, 230400, 250000, "
            "500000, 1000000") in causes[0]
    assert f"'tmclsh scan --port {module.path}'" in causes[1]
    assert not any(word in err.lower() for word in INTERNAL_WORDS)
    assert not any(raw[1] == GAP for raw in module.log)


def test_no_internal_words_in_messages():
    """Every message text in the package is for users: no resynchronisation, no marker."""
    import ast
    from pathlib import Path

    import tmclsh

    bad = []
    for path in Path(tmclsh.__file__).parent.rglob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, (ast.Raise, ast.Call)):
                for sub in ast.walk(node):
                    if isinstance(sub, ast.Constant) and isinstance(sub.value, str) and any(
                            w in sub.value.lower() for w in INTERNAL_WORDS):
                        bad.append(f"{path.name}:{sub.lineno}: {sub.value!r}")
    assert not bad, bad


def test_a_request_after_an_earlier_failure_speaks_plainly(responders):
    module = responders(Silent)
    client = LineClient(open_serial(module.path), module="TMCM-1311", timeout=0.05, retries=0)
    try:
        for _ in range(2):
            with pytest.raises(TimeoutError) as exc:
                client.request(Request(1, GET_VERSION, 0, 0, 0))
        assert not any(w in str(exc.value).lower() for w in INTERNAL_WORDS), exc.value
    finally:
        client.close()


# -- scan ----------------------------------------------------------------------------------------

class Bus(Responder):
    """Modules at 3 and 200; the one at 7 answers late (after the first pass gave up on it),
    the one at 9 garbles its first answer."""

    addresses = frozenset({3, 7, 9, 200})

    def __init__(self, **kw):
        super().__init__(**kw)
        self.garbled = False

    def answer(self, raw: bytes) -> bytes | None:
        reply = super().answer(raw)
        if reply is None:
            return None
        if raw[0] == 7 and raw[1] == GET_VERSION and raw[2] == 1:
            # slow to answer, on its own time (the others answer meanwhile)
            threading.Timer(0.04, self.write, (reply,)).start()
            return None
        if raw[0] == 9 and not self.garbled:
            self.garbled = True
            return reply[:-1] + bytes([(reply[-1] + 1) & 0xFF])
        return reply


def test_scan_finds_late_and_garbled_answers_on_a_second_pass(run_tmclsh, responders):
    bus = responders(Bus)
    p = run_tmclsh("scan", "--port", bus.path, "--baud", "115200", "--json")
    assert p.returncode == 0, p.stderr
    import json

    rows = sorted((json.loads(line) for line in p.stdout.splitlines()),
                  key=lambda r: r["address"])  # (the second pass's come last)
    assert rows == [{"address": a, "module": "TMCM-1311", "version": "1311V111"}
                    for a in (3, 7, 9, 200)]
    assert p.stderr.splitlines()[-1] == "4 modules found at 3, 7, 9, 200"
    from collections import Counter

    probes = Counter(raw[0] for raw in bus.log if raw[1] == GET_VERSION and raw[2] == 1)
    # each silent address was asked once (no second look); 7 and 9 again, on the slower pass
    assert {a for a, n in probes.items() if n == 1} == set(range(1, 256)) - {3, 7, 9, 200}
    assert probes[7] >= 2 and probes[9] >= 2


def test_scan_baud_auto_tries_each_rate_gp65_allows(run_tmclsh, responders):
    module = responders(speed=termios.B57600)
    module.addresses = frozenset({3})
    p = run_tmclsh("scan", "--port", module.path, "--baud", "auto", "--to", "4")
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines() == [
        "address   3  TMCM-1311   firmware 1311V111  57600 baud"]
    tried = [ln.rsplit("@ ", 1)[1] for ln in p.stderr.splitlines() if ln.startswith("scanning")]
    assert tried == ["9600", "14400", "19200", "28800", "38400", "57600", "76800", "115200",
                     "230400", "250000", "500000", "1000000"]
    assert p.stderr.splitlines()[-1] == "1 module found at 3 (57600 baud)"


def test_scan_of_a_silent_line_says_what_it_tried(run_tmclsh, responders):
    module = responders(Silent)
    p = run_tmclsh("scan", "--port", module.path, "--baud", "115200", "--to", "9")
    assert p.returncode == 3 and p.stdout == ""
    assert p.stderr.splitlines()[-1] == (
        f"nothing answered; tried addresses 1..9 on {module.path} @ 115200 (6 ms each), in "
        "binary and in ASCII mode; other baud rates: --baud auto")


def test_scan_bad_baud_is_a_usage_error(run_tmclsh):
    p = run_tmclsh("scan", "--sim", "--baud", "fast")
    assert p.returncode == 2 and "--baud" in p.stderr and "got 'fast'" in p.stderr
    # a link without a baud rate is scanned once (each module reported once), saying why
    p = run_tmclsh("scan", "--sim", "--baud", "auto", "--to", "2")
    assert p.returncode == 0 and p.stdout.count("address") == 1, p.stderr
    assert "the baud rate has no effect on" in p.stderr and "one pass" in p.stderr


@needs_tmux
def test_scan_shows_progress_on_a_terminal_and_a_summary(terminal, responders):
    bus = responders(Bus)
    term = terminal()
    term.start("scan", "--port", bus.path, "--baud", "9600")
    screen = term.wait("EXIT=", timeout=30)
    assert "EXIT=0" in screen
    assert "4 modules found at 3, 7, 9, 200" in screen
    assert "address   3  TMCM-1311" in screen and "address 200  TMCM-1311" in screen
    assert "scanning addresses 1..255" not in screen  # the bar replaced the plain line


class Garbling(Responder):
    """Answers, but every reply's checksum is off (what a wrong baud rate often looks like)."""

    def answer(self, raw: bytes) -> bytes | None:
        reply = super().answer(raw)
        return None if reply is None else reply[:4] + bytes([reply[4] ^ 0x81]) + reply[5:]


def test_garbled_replies_at_connect_point_at_the_baud_rate(run_tmclsh, responders):
    module = responders(Garbling)
    p = run_tmclsh("--port", module.path, "--timeout", "0.1", "-c", "GAP 1, 0")
    assert p.returncode == 3 and p.stdout == ""
    first, cause = p.stderr.splitlines()[:2]
    assert first.startswith(f"tmclsh: replies came from {module.path} @ 9600 but were garbled "
                            "(bad checksums)")
    assert cause.startswith("  - baud rate:")


class AnswersOnly136(Responder):
    def answer(self, raw: bytes) -> bytes | None:
        return super().answer(raw) if raw[1] == 136 else None


def test_a_module_that_answers_136_and_then_nothing_is_not_blamed_on_baud_or_address(
        run_tmclsh, responders):
    """Its version string came readable at this rate and address: baud rate, address and
    ASCII mode are no likely cause; the line is."""
    module = responders(AnswersOnly136)
    p = run_tmclsh("--port", module.path, "--timeout", "0.05", "-c", "GAP 1, 0")
    assert p.returncode == 3
    first, names, _ = likely_causes(p.stderr)
    assert first.startswith(f"tmclsh: the module at address 1 on {module.path} @ 9600 answered "
                            "only in part: it answered 136 (version 1311V111), but not GGP 129")
    assert names == ["- the line", "- a slow link"]


@pytest.mark.parametrize("retries, asked, said", [("0", 2, "twice"), ("4", 5, "5 times")])
def test_connect_asks_as_often_as_retries_says(run_tmclsh, responders, retries, asked, said):
    module = responders(Silent)
    p = run_tmclsh("--port", module.path, "--timeout", "0.05", "--retries", retries,
                   "-c", "GAP 1, 0")
    assert p.returncode == 3
    assert f"asked for its version (136) {said} and tried its ASCII mode" in p.stderr
    assert [raw[1] for raw in module.log if raw[:1] == b"\x01"].count(136) == asked


def test_nothing_answering_on_can_names_bit_rate_and_ids(monkeypatch, capsys):
    import uuid

    monkeypatch.setenv("TMCLSH_CONFIG", os.devnull)
    channel = f"nobody-{uuid.uuid4().hex[:8]}"
    rc = cli.main(["--can", f"virtual:{channel}", "--timeout", "0.05", "--retries", "1",
                   "-c", "GAP 1, 0"])
    err = capsys.readouterr().err
    assert rc == 3
    first, names, _ = likely_causes(err)
    assert first == (f"tmclsh: no module answered on CAN virtual:{channel}: asked for its version "
                     "(136) on CAN id 1, listening on reply id 2, twice, 0.05 s each. Likely "
                     "causes, most likely first:")
    assert names == [
        "- bit rate", "- CAN ids", "- a slow bus", "- wiring"]


def test_a_port_that_cannot_be_opened_is_exit_3_for_scan_too(run_tmclsh, tmp_path):
    for args in (["-c", "GAP 1, 0"], ["scan"]):
        p = run_tmclsh(*args, "--port", str(tmp_path / "ttyACM9"))
        assert p.returncode == 3 and "no such port" in p.stderr


def test_killed_mid_upload_the_next_run_brings_the_module_out(run_tmclsh, make_pty_sim, tmp_path):
    """SIGKILL leaves no chance to send 133: the module (the project's simulator, on a pty)
    stays in download mode; the next tmclsh finds it so and ends it before anything else."""
    import signal
    import subprocess
    import sys

    from conftest import ROOT, tmclsh_env

    sim, path = make_pty_sim()
    src = tmp_path / "long.tmc"
    src.write_text("loop:\n" + "SAP 4, 0, 1000\n" * 1500 + "JA loop\n")
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", path, "--baud", "9600",
                             "-c", f".upload {src} --yes"], env=tmclsh_env(), cwd=str(ROOT),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 20
        while not (sim.vm.download and sim.vm.download_addr > 50):
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.005)
        proc.send_signal(signal.SIGKILL)
        proc.wait(5)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert sim.vm.download  # left in download mode
    p = run_tmclsh("--port", path, "-c", "SAP 4, 0, 777; GAP 4, 0")
    assert p.returncode == 0, p.stderr
    assert "ended it with 133" in p.stderr and not sim.vm.download
    assert p.stdout.splitlines()[-1] == "MaxPositioningSpeed = 777 pps"


def test_ascii_asked_for_a_module_left_in_download_mode(run_tmclsh, make_pty_sim):
    """--ascii needs 139, which a module in download mode refuses: download mode is ended
    first (the project's simulator on a pty, put in download mode with a raw 132)."""
    import serial

    sim, path = make_pty_sim()
    with serial.Serial(path, 9600, timeout=1) as port:
        port.write(Request(1, START_DOWNLOAD, 0, 0, 0).to_bytes())
        assert port.read(9)[2] == OK
    assert sim.vm.download
    p = run_tmclsh("--port", path, "--ascii", "-c", "SAP 4, 0, 555; GAP 4, 0")
    assert p.returncode == 0, p.stderr
    assert "ended it with 133" in p.stderr and not sim.vm.download
    assert p.stdout.splitlines()[-1] == "MaxPositioningSpeed = 555 pps"


def test_the_missing_checksum_is_said_once_a_session_not_at_every_connect(run_tmclsh,
                                                                           responders):
    module = responders(AsciiStartupModule, ascii=True)
    p = run_tmclsh("--port", module.path, "--timeout", "0.3", "--retries", "0",
                   "-c", "GAP 1, 0; .connect; GAP 1, 0")
    assert p.returncode == 0, p.stderr
    assert p.stdout.count("ActualPosition = 1234") == 2
    assert p.stderr.count("carry no checksum") == 1, p.stderr
