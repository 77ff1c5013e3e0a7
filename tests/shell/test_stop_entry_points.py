"""The safety stop is one stop (shell/features/stop.py over ops/stop.py): from every place a user can
ask for it, against a link that dropped under a turning motor, it brings the link back first,
stops the motor, and says so in the same words.

The entry points: Ctrl-C at the prompt, Ctrl-C while a command runs, ``.stopall``, the
watch's stop key and its Ctrl-C, the ASCII terminal's Ctrl-C, and Ctrl-C in ``-c``. The
module is the simulator on TCP; its server hangs up on the client (a cable pulled) and takes
the next connection (plugged back in).
"""

from __future__ import annotations

import ctypes
import subprocess
import sys
import threading
import time

import pytest

from conftest import ROOT, patience, tmclsh_env
from test_repl import CTRL_C, ENTER, Repl, Screen

from tmclsh.client.text import LineClient
from tmclsh.link import open_serial
from tmclsh.shell.features import watch
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session
from tmclsh.sim import Simulator
from tmclsh.sim.serve import serve_tcp

STOPPED = "stopped motor 0 (MST; speed reads 0)"


@pytest.fixture
def dropped():
    """(sim, session, url): motor 0 turning, then the cable pulled; the client found it out
    on its next request (the link is down)."""
    sim = Simulator("TMCM-1311")
    server = serve_tcp(sim, "127.0.0.1", 0)
    url = f"socket://127.0.0.1:{server.address[1]}"
    client = LineClient(open_serial(url), module="TMCM-1311", timeout=0.3)
    session = Session(client, Output())
    try:
        client.execute("ROR 0, 30000")
        server.drop_client()
        with pytest.raises(Exception):
            client.execute("GAP 1, 0")
        assert not client.connected and sim.param("axis", 3, 0) != 0
        yield sim, session, url
    finally:
        client.close()
        server.close()
        sim.close()


def _stopped_and_said(sim, said: str, url: str, why: str = "") -> None:
    assert f"reconnected to {url}" in said, said
    assert f"{why}: {STOPPED}" in said if why else STOPPED in said, said
    assert said.index(f"reconnected to {url}") < said.index(STOPPED)
    assert sim.param("axis", 3, 0) == 0  # the motor stands


def test_stopall(dropped, capsys):
    sim, session, url = dropped
    session.run_line(".stopall")
    _stopped_and_said(sim, capsys.readouterr().out, url)


def test_ctrl_c_at_the_prompt(dropped):
    from prompt_toolkit.input import create_pipe_input

    sim, session, url = dropped
    with create_pipe_input() as inp:
        repl = Repl(session, inp, Screen())
        repl.start()
        repl.type(CTRL_C)
        repl.expect(f"Ctrl-C: {STOPPED}")
        _stopped_and_said(sim, repl.screen.text(), url, "Ctrl-C")
        inp.send_text(".quit" + ENTER)
        repl.thread.join(5)


def test_ctrl_c_while_a_command_runs(dropped):
    from prompt_toolkit.input import create_pipe_input

    from tmclsh.shell.lang import commands

    sim, session, url = dropped
    started = threading.Event()

    @commands.command(".test-busy", ".test-busy", "runs until interrupted")
    def _busy(session, arg):
        started.set()
        for _ in range(3000):
            time.sleep(0.01)

    try:
        with create_pipe_input() as inp:
            repl = Repl(session, inp, Screen())
            repl.start()
            repl.type(".test-busy" + ENTER)
            assert started.wait(patience(5))
            ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(repl.thread.ident),
                                                       ctypes.py_object(KeyboardInterrupt))
            repl.expect(f"interrupted: {STOPPED}")
            _stopped_and_said(sim, repl.screen.text(), url, "interrupted")
            inp.send_text(".quit" + ENTER)
            repl.thread.join(5)
    finally:
        commands.REGISTRY.pop(".test-busy", None)
        commands.HANDLERS.pop(".test-busy", None)


class _Pressed:
    """The watch's keys: ``presses`` one after another, one per wait."""

    active = True

    def __init__(self, *presses: str):
        self.presses = list(presses)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None

    def wait(self, timeout: float) -> str:
        time.sleep(min(timeout, 0.02))
        return self.presses.pop(0) if self.presses else ""


@pytest.mark.parametrize("keys", [("s", "q"), ("\x03",)], ids=["stop key", "ctrl-c"])
def test_the_watch(dropped, capsys, keys):
    sim, session, url = dropped
    items = watch.parse_items(session, "v=GAP 3, 0")
    result = watch.run_watch(session, items, interval=0.05, live=False, keys=_Pressed(*keys),
                             emit=lambda obj: None)
    said = capsys.readouterr()
    assert result.stops and result.stops[0].stopped == [0]
    assert sim.param("axis", 3, 0) == 0
    assert f"reconnected to {url}" in said.out + said.err
    assert STOPPED in said.out + said.err


def test_the_ascii_terminal(dropped):
    from tmclsh.shell.features import terminal as tm
    from tmclsh.shell.features import termview as tv

    sim, session, url = dropped
    notes: list[str] = []
    term = tm.Terminal(session, None, tm.TerminalOptions(), notes.append,
                       tv.Painter(color=False))
    term.stop_motors()
    _stopped_and_said(sim, "\n".join(notes), url)


def test_ctrl_c_in_c(tmp_path):
    """The same in a run nobody watches: the link dropped under the run, Ctrl-C."""
    sim = Simulator("TMCM-1311")
    server = serve_tcp(sim, "127.0.0.1", 0)
    url = f"socket://127.0.0.1:{server.address[1]}"
    p = subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", url, "-m", "TMCM-1311",
                          "-c", "ROR 0, 30000; .sleep 30"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, env=tmclsh_env(), cwd=str(ROOT))
    try:
        deadline = time.monotonic() + patience(15)
        while sim.param("axis", 3, 0) == 0 and time.monotonic() < deadline:
            time.sleep(0.02)  # (the motor turns: the run is in its .sleep)
        server.drop_client()
        time.sleep(0.2)
        p.send_signal(2)
        _, err = p.communicate(timeout=patience(20))
        assert p.returncode == 130, err
        _stopped_and_said(sim, err, url, "interrupted")
    finally:
        if p.poll() is None:
            p.kill()
        server.close()
        sim.close()
