"""The real REPL, driven through prompt_toolkit's pipe input as a person would type.

The prompt runs in a worker thread with a plain-text output (what a user would see, minus
colours); the test types into the pipe and waits for what should appear on the screen.
"""

from __future__ import annotations

import io
import threading
import time

import pytest
from prompt_toolkit.application import create_app_session
from prompt_toolkit.history import InMemoryHistory
from prompt_toolkit.input import create_pipe_input
from prompt_toolkit.output.plain_text import PlainTextOutput

from tmclsh.client.connect import connect
from tmclsh.shell.repl import app
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session
from conftest import patience

TAB, ENTER, CTRL_C, CTRL_D = "\t", "\r", "\x03", "\x04"


class Screen(io.StringIO):
    """The terminal: everything the prompt and the shell wrote."""

    def __init__(self):
        super().__init__()
        self.lock = threading.Lock()

    def write(self, s):
        with self.lock:
            return super().write(s)

    def text(self) -> str:
        with self.lock:
            return self.getvalue()


class Repl:
    def __init__(self, session: Session, inp, screen: Screen):
        self.session, self.inp, self.screen = session, inp, screen
        self.mark = 0
        self.result: list[object] = []
        self.file_history = False  # True: the history file in XDG_STATE_HOME, as a user's
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        try:
            with create_app_session(input=self.inp, output=PlainTextOutput(self.screen)):
                kw = {} if self.file_history else {"history": InMemoryHistory()}
                self.ps = app.build_prompt_session(self.session, **kw)
                self.result.append(app.run_repl(self.session, self.ps))
        except BaseException as exc:  # surfaced by the test
            self.result.append(exc)

    def start(self) -> None:
        """Start the prompt. Done inside the test (not the fixture): pytest resets
        sys.stdout between setup and call, which would undo ``patch_stdout``."""
        if not self.thread.is_alive() and not self.result:
            self.thread.start()
            self.expect("TMCM-1311:1> ")

    def type(self, text: str) -> None:
        self.start()
        self.inp.send_text(text)

    def expect(self, text: str, timeout: float = 5.0) -> str:
        """Wait until ``text`` appears in what was written since the last expect()."""
        if not self.thread.is_alive() and not self.result:
            self.start()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            out = self.screen.text()
            idx = out.find(text, self.mark)
            if idx >= 0:
                seen = out[self.mark:idx + len(text)]
                self.mark = idx + len(text)
                return seen
            time.sleep(0.01)
        raise AssertionError(f"{text!r} did not appear; screen since last check:\n"
                             f"{self.screen.text()[self.mark:]}")

    def line(self, text: str, expect: str) -> str:
        self.type(text + ENTER)
        return self.expect(expect)

    def wait_prompt(self):
        """Wait until the prompt is back and idle (the previous line has finished)."""
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            ps = getattr(self, "ps", None)
            if ps is not None and ps.app.is_running and not ps.default_buffer.text:
                return
            time.sleep(0.01)
        raise AssertionError("the prompt did not come back")

    def quit(self) -> int:
        self.start()
        self.wait_prompt()
        self.type(CTRL_D)
        self.thread.join(10)
        assert not self.thread.is_alive(), "the REPL did not end on Ctrl-D"
        (rc,) = self.result
        if isinstance(rc, BaseException):
            raise rc
        return rc


@pytest.fixture
def repl(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))  # no user config file
    monkeypatch.delenv("TMCLSH_CONFIG", raising=False)
    client = connect(sim="TMCM-1311", timeout=0.3, retries=0)
    session = Session(client, Output())
    screen = Screen()
    with create_pipe_input() as inp:
        r = Repl(session, inp, screen)
        try:
            yield r
        finally:
            if r.thread.is_alive():
                inp.send_text(CTRL_D)
                r.thread.join(10)
            client.close()


class Frames:
    def __init__(self, client):
        self.tx = []
        client.add_tracer(lambda d, raw, dec: self.tx.append(dec) if d == "tx" else None)


def at_rest(client) -> None:
    """The motor comes to a standstill (the simulator ramps down after MST)."""
    client.wait_until(lambda: client.value("GAP ActualSpeed, 0") == 0, timeout=5)


def test_banner_names_module_address_and_simulator(repl, capsys):
    repl.start()
    banner = capsys.readouterr().out
    assert "TMCM-1311 at address 1" in banner and "SIMULATED" in banner
    assert repl.quit() == 0


def test_set_get_and_the_toolbar(repl):
    seen = repl.line("SAP 4, 0, 1000", "ok: MaxPositioningSpeed set to 1000 pps")
    assert "TMCM-1311:1> SAP 4, 0, 1000" in seen
    repl.line("GAP 4, 0", "MaxPositioningSpeed = 1000 pps")
    screen = repl.screen.text()
    assert "SIMULATED" in screen and "TMCM-1311 @1" in screen and "binary" in screen
    assert "trace off" in screen
    assert repl.quit() == 0


def test_tab_completes_maxpos_and_shows_both_candidates(repl):
    repl.type("GAP MaxPos")
    repl.type(TAB)
    menu = repl.expect("MaxPossibleCurrent")
    assert "MaxPositioningSpeed" in menu
    assert "AP 4 · 0..327679999 pps" in menu  # the meta a user sees beside the name
    assert repl.ps.default_buffer.text == "GAP MaxPositioningSpeed"  # the first Tab took the best
    repl.type(", 0" + ENTER)
    repl.expect("MaxPositioningSpeed = ")
    assert repl.quit() == 0


def test_help_140(repl):
    out = repl.line("help 140", "now")
    assert "AP 140" in out and "MicrostepResolution" in out and "8 = 256 microsteps" in out
    assert repl.quit() == 0


def test_bad_input_shows_one_error_line_and_sends_nothing(repl, capsys):
    frames = Frames(repl.session.client)
    repl.line("SAP 140, 0, 99",
              "error: 99 is out of range for AP 140 MicrostepResolution: allowed 0..8\n")
    repl.wait_prompt()
    repl.line("GAP 4, 7", "error: TMCM-1311 has no motor 7: only motor 0\n")
    repl.wait_prompt()
    assert frames.tx == []
    assert repl.quit() == 0


def test_ctrl_c_at_the_prompt_stops_the_motor_and_clears_the_line(repl):
    frames = Frames(repl.session.client)
    repl.line("ROR 0, 2000", "rotating right at 2000 pps")
    repl.wait_prompt()
    repl.type("GAP 1, 0")  # a half-typed line
    repl.type(CTRL_C)
    repl.expect("Ctrl-C: stopped motor 0 (MST; speed reads 0)")
    repl.wait_prompt()
    assert repl.ps.default_buffer.text == ""
    # ROR; then the stop: 135 (no program runs), MST, the speed read back (GAP 3), and a
    # 136 type 1 that lets a displaced speed reading show: the typed GAP 1 never ran
    assert [(f.opcode, f.type) for f in frames.tx][:4] == [(1, 0), (135, 0), (3, 0), (6, 3)]
    assert all((f.opcode, f.type) in ((6, 3), (136, 1)) for f in frames.tx[4:])
    at_rest(repl.session.client)
    assert repl.quit() == 0


@pytest.fixture
def slow_command():
    """A command that runs until interrupted (like a long .watch)."""
    from tmclsh.shell.lang import commands

    started = threading.Event()

    @commands.command(".test-slow", ".test-slow", "runs until interrupted")
    def _slow(session, arg):
        started.set()
        for _ in range(3000):
            time.sleep(0.01)

    yield started
    commands.REGISTRY.pop(".test-slow", None)
    commands.HANDLERS.pop(".test-slow", None)


def test_ctrl_c_while_a_command_runs(repl, slow_command):
    import ctypes

    repl.line("ROR 0, 500", "rotating right")
    repl.wait_prompt()
    repl.type(".test-slow" + ENTER)
    assert slow_command.wait(patience(5))
    # what SIGINT does to the main thread, done to the REPL's thread
    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(repl.thread.ident),
                                               ctypes.py_object(KeyboardInterrupt))
    repl.expect("interrupted: stopped motor 0 (MST; speed reads 0)")
    at_rest(repl.session.client)
    repl.line("GAP 4, 0", "MaxPositioningSpeed = ")  # the shell is still fine
    assert repl.quit() == 0


def test_empty_line_repeats_what_the_debugger_asks_for(repl):
    repl.line("SAP 4, 0, 777", "set to 777")
    repl.wait_prompt()
    repl.type(ENTER)  # nothing set: an empty line does nothing
    repl.wait_prompt()
    repl.session.state.repeat_on_empty = "GAP 4, 0"
    repl.type(ENTER)
    repl.expect("MaxPositioningSpeed = 777 pps")
    assert repl.quit() == 0


def test_target_reached_event_appears_above_the_prompt(repl):
    repl.line("SAP 4, 0, 200000", "set to")
    repl.line("MVP ABS, 0, 2000", "moving to 2000")
    repl.wait_prompt()
    repl.line("138 0, 0, 0", "TMCM-1311:1> ")
    repl.expect("event: target position reached (motor 0)")
    assert repl.quit() == 0


def test_eeprom_write_asks_and_no_sends_nothing(repl):
    frames = Frames(repl.session.client)
    repl.type("STAP MaxPositioningSpeed, 0" + ENTER)
    repl.expect("EEPROM")
    repl.type("n" + ENTER)
    repl.expect("cancelled; nothing was sent")
    assert frames.tx == []
    repl.wait_prompt()
    repl.type("STAP MaxPositioningSpeed, 0" + ENTER)
    repl.expect("EEPROM")
    repl.type("y" + ENTER)
    repl.expect("stored in EEPROM")
    assert [f.opcode for f in frames.tx] == [7]
    assert repl.quit() == 0


def test_quit_and_semicolons(repl):
    repl.line("SAP 4, 0, 10; GAP 4, 0", "MaxPositioningSpeed = 10 pps")
    repl.wait_prompt()
    repl.type("quit" + ENTER)
    repl.thread.join(10)
    assert repl.result == [0]


def test_a_lost_link_is_reported_and_reconnected_on_the_next_command(repl):
    from tmclsh.base.errors import TransportError

    client = repl.session.client
    t = client.transport
    real = t.write

    def pulled(data):  # the cable is pulled while the command goes out
        t.write = real
        t.close()
        raise TransportError("lost the port (write failed); the port is gone")

    t.write = pulled
    repl.type("GAP 4, 0" + ENTER)
    repl.expect("error: lost the port")
    repl.expect("the next command tries to reconnect")
    repl.wait_prompt()
    assert "DISCONNECTED" in repl.screen.text()[-2000:] or not client.connected
    repl.line("GAP 4, 0", "reconnected to")  # ... and it is back
    repl.expect("MaxPositioningSpeed = ")
    assert repl.quit() == 0


def test_the_first_command_after_the_link_went_down_reconnects(repl):
    """As after a .watch that met the lost link: no failed command first."""
    client = repl.session.client
    client.transport.close()
    repl.line("GAP 4, 0", "reconnected to")
    repl.expect("MaxPositioningSpeed = ")
    assert client.connected
    assert repl.quit() == 0


def test_history_file_lives_in_the_xdg_state_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    hist = app.make_history()
    hist.append_string("GAP 4, 0")
    assert (tmp_path / "tmclsh" / "history").read_text().strip().endswith("+GAP 4, 0")


def test_missing_and_corrupted_replies_leave_the_shell_alive(repl):
    sim = repl.session.client.transport.simulator
    sim.faults.drop_next = 1
    repl.line("GAP 4, 0", "error: no reply to GAP")
    repl.wait_prompt()
    sim.faults.corrupt_next = 1
    repl.line("GAP 1, 0", "error:")
    repl.wait_prompt()
    repl.line("GAP 4, 0", "MaxPositioningSpeed = ")  # and then it works again
    assert repl.quit() == 0


def test_history_is_trimmed_to_history_size(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    hist = app.make_history()
    for n in range(10):
        hist.store_string(f"GAP {n}, 0")
    kept = list(app.make_history(size=3).load_history_strings())
    assert kept == ["GAP 9, 0", "GAP 8, 0", "GAP 7, 0"]
    assert isinstance(app.make_history(size=0), InMemoryHistory)  # history_size = 0


def _history_file(tmp_path, monkeypatch, data: bytes):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    path = tmp_path / "state" / "tmclsh" / "history"
    path.parent.mkdir(parents=True)
    path.write_bytes(data)
    return path


MIB = 1024 * 1024


@pytest.mark.parametrize("kind", ["20 MB of entries", "20 MB of NUL bytes", "one 20 MB entry"])
def test_the_repl_starts_whatever_the_history_file_holds(repl, tmp_path, monkeypatch, kind):
    """prompt_toolkit's FileHistory read the whole file, twice (trim, then load), and kept
    any entry however long; now the newest 4 MiB are read and the file is cut down."""
    entry = b"\n# 2026-12-01 10:00:00\n+GAP 1, 0\n"
    data = {"20 MB of entries": entry * (20 * MIB // len(entry)) + b"\n# last\n+GAP 4, 0\n",
            "20 MB of NUL bytes": bytes(20 * MIB),
            "one 20 MB entry": b"+" + b"x" * (20 * MIB) + b"\n"}[kind]
    path = _history_file(tmp_path, monkeypatch, data)
    repl.file_history = True
    repl.start()
    assert list(repl.ps.history.load_history_strings())[:1] == (
        ["GAP 4, 0"] if kind.endswith("entries") else [])
    repl.line("GAP 4, 0", "MaxPositioningSpeed = ")
    assert repl.quit() == 0
    assert path.stat().st_size < 100_000  # trimmed to history_size (1000) entries
    assert path.read_text().endswith("+GAP 4, 0\n")


def test_a_history_that_is_no_regular_file_is_kept_in_memory(tmp_path, monkeypatch, caplog):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    (tmp_path / "tmclsh").mkdir()
    (tmp_path / "tmclsh" / "history").symlink_to("/dev/zero")  # endless: never read
    assert isinstance(app.make_history(size=1000), InMemoryHistory)
    assert "history is not a regular file" in caplog.text


def test_history_entries_of_a_cut_file_start_at_a_whole_entry(tmp_path, monkeypatch):
    """Only the file's last HISTORY_BYTES are read: a line cut there is dropped, an entry
    longer than a script line is dropped, bytes that are not UTF-8 are replaced."""
    monkeypatch.setattr(app, "HISTORY_BYTES", 40)
    path = tmp_path / "history"
    path.write_bytes(b"+" + b"y" * 30 + b"\n+GAP 1, 0\n\n# t\n+SAP 4, 0, \xff\n")
    assert app.history_entries(path) == ["SAP 4, 0, \ufffd", "GAP 1, 0"]
    monkeypatch.setattr(app, "HISTORY_BYTES", 1000)
    path.write_bytes(b"+" + b"z" * 70_000 + b"\n\n+GAP 1, 0\n")
    assert app.history_entries(path) == ["GAP 1, 0"]


def test_vi_mode_from_the_config_file(tmp_path, monkeypatch):
    from prompt_toolkit.enums import EditingMode

    (tmp_path / "tmclsh").mkdir()
    (tmp_path / "tmclsh" / "config.toml").write_text('[settings]\nediting_mode = "vi"\n')
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    monkeypatch.delenv("TMCLSH_CONFIG", raising=False)
    client = connect(sim="TMCM-1311")
    try:
        with create_pipe_input() as inp:
            with create_app_session(input=inp, output=PlainTextOutput(io.StringIO())):
                ps = app.build_prompt_session(Session(client, Output()))
                assert ps.editing_mode == EditingMode.VI
    finally:
        client.close()


@pytest.mark.parametrize("comment", ["", "  // to the bench module"])
def test_connect_takes_a_url_typed_at_the_prompt(repl, comment):
    """``socket://`` was cut at its ``//`` as a comment: ``.connect socket:`` failed.
    Against a module written from the manuals (tests/responder.py), not the simulator."""
    from responder import TcpModule

    m = TcpModule(version="1311V111")
    try:
        repl.line(f".connect {m.url}{comment}", "connected: TMCM-1311 at address 1 on ")
        repl.wait_prompt()
        assert 136 in m.commands()  # it was this module that answered
        repl.line("GAP 4, 0", "MaxPositioningSpeed = ")
        assert m.commands()[-1] == 6
        assert repl.quit() == 0
    finally:
        repl.session.client.close()
        m.close()
