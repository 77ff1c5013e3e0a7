"""Killing the shell (SIGTERM, SIGHUP) never leaves the module in ASCII or download mode."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time

import pytest

from conftest import ROOT, patience, read_until, tmclsh_env
from tmclsh.tmcl.frames import Request, Reply
from tmclsh.sim import Simulator
from tmclsh.sim.serve import serve_pty


def start(path: str, *args: str, cache=None) -> subprocess.Popen:
    """tmclsh on ``path``; with ``cache`` (an empty folder) as its bytecode cache, the first
    run after an install: every module it imports is compiled from source."""
    env = tmclsh_env()
    if cache is not None:
        env["PYTHONPYCACHEPREFIX"] = str(cache)
    return subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", path, *args],
                            cwd=str(ROOT), env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def wait_for(pred, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + patience(timeout)
    while not pred():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.01)


@pytest.fixture
def served():
    sim = Simulator("TMCM-1311")
    server = serve_pty(sim)
    yield sim, server.path
    server.close()
    sim.close()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
@pytest.mark.parametrize("delay", [0.0, 0.5])  # during the mode switch, and while idle
def test_killed_in_ascii_mode_leaves_binary_mode(served, sig, delay, tmp_path):
    """Also on a first run, its modules compiled from source as they are imported: a signal
    that landed in the compiler was lost there (CI: the run slept its 30 s)."""
    sim, path = served
    p = start(path, "--ascii", "-c", ".sleep 30", cache=tmp_path)
    wait_for(lambda: sim.ascii_active)
    time.sleep(delay)
    p.send_signal(sig)
    assert p.wait(patience(10)) == 128 + sig
    assert not sim.ascii_active


def test_killed_during_upload_ends_download_mode(served, tmp_path):
    sim, path = served
    program = tmp_path / "long.tmc"
    program.write_text("Loop:\n" + "    WAIT TICKS, 0, 1\n" * 200 + "    JA Loop\n")
    sim.faults.delay = 0.01  # every reply 10 ms late: the upload takes a few seconds
    p = start(path, "-c", f".upload {program} --yes")

    def downloading() -> bool:
        return sim.param("global", 129, 0) == 1

    wait_for(downloading)
    p.send_signal(signal.SIGTERM)
    assert p.wait(patience(10)) == 128 + signal.SIGTERM
    sim.faults.delay = 0.0
    assert not downloading()
    # and the module still answers normally, on the same line
    import serial

    with serial.Serial(path, timeout=2) as port:
        port.reset_input_buffer()
        port.write(Request(1, 6, 1, 0, 0).to_bytes())
        assert Reply.from_bytes(port.read(9)).status == 100


@pytest.mark.parametrize("sig, words", [(signal.SIGTERM, "terminated (SIGTERM)"),
                                        (signal.SIGHUP, "hung up (SIGHUP)")])
@pytest.mark.parametrize("how", ["-c", "-f"])
def test_killed_with_a_motor_turning_stops_it_and_says_so(served, tmp_path, sig, words, how):
    """A CI job's timeout (SIGTERM) or a terminal that went away (SIGHUP) is treated as
    Ctrl-C: the motor is stopped and read back, it is said on stderr, and the exit status is
    the signal's (it exited silently with 143 and left the axis moving)."""
    sim, path = served
    lines = "ROR 0, 30000\n.sleep 30\n"
    if how == "-f":
        script = tmp_path / "turn.tmcl"
        script.write_text(lines)
        p = start(path, "-f", str(script))
    else:
        p = start(path, "-c", lines.replace("\n", "; ").strip("; "))
    wait_for(lambda: sim.param("axis", 3, 0) != 0)
    p.send_signal(sig)
    out, err = p.communicate(timeout=patience(20))
    assert p.returncode == 128 + sig, err
    assert f"{words}: stopped motor 0 (MST; speed reads 0)" in err, err
    assert sim.param("axis", 3, 0) == 0
    if how == "-f":  # how far the script got, as after Ctrl-C (it said nothing of it)
        # (at line 2, or still at line 1 when the signal beats the ROR's reply on a busy
        # machine: the ROR went out either way, and is counted)
        assert re.search(rf"turn\.tmcl: {re.escape(words)} at line [12] after 1 command "
                         "sent", out), out


def test_a_signal_wrapped_in_another_error_is_still_the_stop(monkeypatch, capsys):
    """A SIGTERM that lands while a command's module is first imported comes out wrapped
    (a dataclass being built raises RuntimeError from it; seen in CI: a traceback and exit 1
    with the motor turning). It is still the signal: the one stop, its exit status."""
    from tmclsh.cli.main import main
    from tmclsh.shell.lang import main as shell_main

    def killed_mid_import(args, client, settings):
        client.execute("ROR 0, 30000")
        try:
            raise shell_main.Terminated(signal.SIGTERM)
        except shell_main.Terminated as exc:
            raise RuntimeError("Error calling __set_name__ on 'Field' instance") from exc

    monkeypatch.setattr(shell_main, "run_connected", killed_mid_import)
    status = main(["--sim", "-c", "GAP 1, 0"])
    err = capsys.readouterr().err
    assert status == 128 + signal.SIGTERM, err
    assert "terminated (SIGTERM): stopped motor 0 (MST; speed reads 0)" in err
    assert "Traceback" not in err


_KILLED_IN_A_CALLBACK = """
import os, signal, sys, weakref
from tmclsh.shell.lang.session import Session

run_line = Session.run_line


class Thing:
    pass


def killed_in_a_callback(self, line, *args, **kwargs):
    done = run_line(self, line, *args, **kwargs)
    if line.startswith("ROR"):
        # SIGTERM whose handler runs inside a weak reference's callback (as in importlib's
        # module-lock cleanup): what the handler raises there is dropped by the interpreter
        def callback(_ref):
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(10_000):
                pass

        thing = Thing()
        ref = weakref.ref(thing, callback)
        del thing
    return done


Session.run_line = killed_in_a_callback
sys.argv = ["tmclsh", *sys.argv[1:]]
from tmclsh.cli.main import main

sys.exit(main())
"""


def test_a_signal_that_lands_in_a_callback_still_ends_the_run(served):
    """Seen in CI: a SIGTERM during the switch into ASCII mode landed in importlib's
    weak-reference callback, was dropped ("Exception ignored"), and the run slept on for 30 s.
    It is sent again and ends the run as any SIGTERM does: the one stop, exit 143, the module
    in binary mode."""
    sim, path = served
    p = subprocess.Popen([sys.executable, "-c", _KILLED_IN_A_CALLBACK, "--port", path,
                          "--ascii", "-c", "ROR 0, 30000; .sleep 30"], cwd=str(ROOT),
                         env=tmclsh_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    _, err = p.communicate(timeout=patience(20))
    assert p.returncode == 128 + signal.SIGTERM, err
    assert "Exception ignored" not in err
    assert "terminated (SIGTERM): stopped motor 0" in err, err
    assert not sim.ascii_active
    assert sim.param("axis", 3, 0) == 0


def test_a_run_started_ignoring_sighup_outlives_its_terminal(served, tmp_path):
    """``nohup tmclsh -f long.tmcl &``: a run meant to go on when the SSH session drops. It
    was ended by the hang-up all the same (tmclsh set its own handler over nohup's)."""
    sim, path = served
    script = tmp_path / "long.tmcl"
    script.write_text("ROR 0, 30000\n.sleep 1\nMST 0\nGAP 3, 0\n")

    def as_nohup() -> None:
        signal.signal(signal.SIGHUP, signal.SIG_IGN)

    p = subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", path, "-f", str(script)],
                         cwd=str(ROOT), env=tmclsh_env(), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, preexec_fn=as_nohup)
    wait_for(lambda: sim.param("axis", 3, 0) != 0)
    p.send_signal(signal.SIGHUP)
    out, err = p.communicate(timeout=patience(20))
    assert p.returncode == 0, err
    assert "long.tmcl: 3 commands sent" in out, out
    assert "hung up" not in err, err


class _Terminal:
    """tmclsh's prompt on a pty of its own, as in a window, but not its controlling terminal
    (as under ``setsid``): when the window goes (``close``), no SIGHUP comes, and only the
    prompt's reads and writes can tell."""

    def __init__(self, path: str):
        import os
        import pty

        self.main, tty = pty.openpty()
        self.p = subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", path],
                                  cwd=str(ROOT), env={**tmclsh_env(), "TERM": "xterm"},
                                  stdin=tty, stdout=tty, stderr=subprocess.PIPE,
                                  start_new_session=True)  # (no SIGHUP)
        os.close(tty)
        self.seen = bytearray()

    def shows(self, text: bytes) -> bool:
        """Whether ``text`` has been drawn (since the last ``forget``)."""
        import os
        import select

        while select.select([self.main], [], [], 0.05)[0]:
            self.seen.extend(os.read(self.main, 4096))
        return text in self.seen

    def type(self, line: str) -> None:
        import os

        os.write(self.main, line.encode() + b"\r")

    def forget(self) -> None:
        del self.seen[:]

    def close(self) -> None:
        """The window goes away."""
        import os

        os.close(self.main)


def test_the_prompts_terminal_gone_without_a_signal_stops_the_motors(served):
    """The window closed or the SSH session dropped, and no SIGHUP came (tmclsh was not the
    terminal's controlling process, or it ignores the signal): the prompt's reads fail. It
    said "[Errno 5] Input/output error" and left the motor turning; now the hang-up's stop."""
    sim, path = served
    term = _Terminal(path)
    try:
        wait_for(lambda: term.shows(b"TMCM-1311:1>"), 20)
        term.type("ROR 0, 30000")
        wait_for(lambda: sim.param("axis", 3, 0) != 0)
    finally:
        term.close()  # the terminal goes away
    p = term.p
    err = p.communicate(timeout=patience(20))[1].decode()
    assert p.returncode == 128 + signal.SIGHUP, err
    assert "hung up (the terminal went away): stopped motor 0 (MST; speed reads 0)" in err, err
    assert sim.param("axis", 3, 0) == 0


@pytest.mark.parametrize("moves", [True, False])
def test_a_run_whose_reader_went_away_stops_what_it_set_moving(served, tmp_path, moves):
    """``tmclsh -f turn.tmcl | head -1``: the run is cut short where ``head`` stopped
    reading, before the line that would have stopped the motor; it left the motor turning.
    A run that moved nothing sends nothing more."""
    sim, path = served
    script = tmp_path / "turn.tmcl"
    first = "ROR 0, 30000\n" if moves else ""
    script.write_text(first + "GAP 1, 0\n.sleep 0.3\nGAP 1, 0\n.sleep 0.3\nMST 0\n")
    p = subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", path, "-f", str(script)],
                         cwd=str(ROOT), env=tmclsh_env(), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE)
    p.stdout.readline()
    p.stdout.close()  # the reader goes away after one line
    err = p.stderr.read().decode()
    assert p.wait(patience(20)) == 1, err
    assert "Traceback" not in err, err
    if moves:
        assert ("the output's reader went away: stopped motor 0 (MST; speed reads 0)"
                in err), err
        assert sim.param("axis", 3, 0) == 0
    else:
        assert "stopped" not in err, err


@pytest.mark.parametrize("how", ["-c", "-f"])
def test_ctrl_c_in_a_watch_ends_an_unattended_run(served, tmp_path, how):
    """Ctrl-C during ``.watch`` in ``-c``/``-f`` stopped the motor and ended the watch, and
    the run went on: the next line set the motor turning again, and the run ended 0 with it
    turning. In a run nobody types at, Ctrl-C ends the run, as on any other line."""
    sim, path = served
    lines = "ROR 0, 30000\n.watch GAP 3, 0\nROR 0, 10000\n.sleep 1\n"
    if how == "-f":
        script = tmp_path / "watch.tmcl"
        script.write_text(lines)
        p = start(path, "-f", str(script))
    else:
        p = start(path, "-c", lines)
    read_until(p, lambda text: '"GAP 3, 0"' in text)  # the watch shows samples
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=patience(20))
    assert p.returncode == 130, err
    assert "Traceback" not in err, err
    assert "10000" not in out, out  # the line after the watch was not run
    assert sim.param("axis", 3, 0) == 0
    if how == "-f":
        assert "watch.tmcl: interrupted (Ctrl-C) at line 2" in out, out


class _TurningModule:
    """A TMCM-1311 from the manual (tests/responder.py), which turns its motor on ROR/ROL
    and stops it on MST (GAP 3 reads the speed), its stored program stopped (135 reads 0).
    ``on_stop``: called when it hears the stop's first request (135), before it answers."""

    @staticmethod
    def make(on_stop):
        from responder import OK, PtyModule

        class Turning(PtyModule):
            turning = 0  # (``speed`` is the responder's baud rate)
            stop_seen = False

            def respond(self, command, type_, motor, value):
                if command == 135 and not self.stop_seen and self.turning:
                    self.stop_seen = True
                    on_stop(self)
                if command in (1, 2):
                    self.turning = value if command == 1 else -value
                elif command == 3:
                    self.turning = 0
                elif command == 6 and type_ == 3:
                    self.got.append((command, type_, motor, value))
                    return OK, self.turning
                elif command in (128, 135):
                    self.got.append((command, type_, motor, value))
                    return OK, 0
                return super().respond(command, type_, motor, value)

        return Turning(version="1311V111")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_second_signal_during_the_stop_does_not_cut_it_short(sig):
    """Ctrl-C pressed twice, or a second SIGTERM (a supervisor's), landing while the stop
    asks whether the stored program runs: the stop was abandoned before MST (Ctrl-C said
    "the motors may still turn"; SIGTERM and SIGHUP said nothing at all) and the motor
    went on turning. The stop's commands go out first; the second signal cuts short only
    the reading back, and is said."""
    from conftest import delivered

    proc: list[subprocess.Popen] = []

    def second_signal(module) -> None:
        proc[0].send_signal(sig)
        delivered(proc[0].pid, sig)

    module = _TurningModule.make(second_signal)
    try:
        p = start(module.path, "-c", "ROR 0, 30000; .sleep 30")
        proc.append(p)
        wait_for(lambda: module.turning != 0)
        p.send_signal(sig)
        out, err = p.communicate(timeout=patience(20))
        assert module.stop_seen, err
        assert p.returncode == 128 + sig, err
        assert "Traceback" not in err, err
        assert module.turning == 0, err  # MST went out
        assert "again" in err, err  # the second signal is said
    finally:
        module.close()


@pytest.mark.skipif(__import__("shutil").which("tmux") is None, reason="tmux is not installed")
@pytest.mark.parametrize("where", [".watch GAP 3, 0", ".ascii"])
def test_the_terminal_gone_mid_command_ends_without_a_traceback(served, terminal, tmp_path,
                                                                 where):
    """The window closed while a watch draws or the ASCII terminal runs: the motor was
    stopped and the module left ASCII mode, but a thread writing to the terminal (the
    prompt's output proxy) met the dead terminal first and printed its traceback."""
    import os
    import shlex

    sim, path = served
    term = terminal()
    err = tmp_path / "err"
    env = " ".join(f"{k}={shlex.quote(v)}" for k, v in term.env.items())
    term.shell(f"cd {shlex.quote(str(ROOT))} && env {env} {shlex.quote(sys.executable)} -m "
               f"tmclsh --port {path} 2>{err}; sleep 60")
    term.wait("TMCM-1311:1>", patience(20))
    term.line("ROR 0, 30000")
    wait_for(lambda: sim.param("axis", 3, 0) != 0)
    term.line(where)
    if where == ".ascii":
        wait_for(lambda: sim.ascii_active)
        term.wait("ascii A>", patience(20))
    else:
        term.wait("GAP 3, 0", patience(20), more_than=1)  # the watch's table is drawn
    pid = int(subprocess.run(["pgrep", "-f", f"^{sys.executable} -m tmclsh --port {path}"],
                             capture_output=True, text=True).stdout.split()[0])
    term.kill()  # the terminal goes away

    def ended() -> bool:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        return False

    wait_for(ended, 20)
    text = err.read_text()
    assert "Traceback" not in text, text
    assert "stopped motor 0 (MST; speed reads 0)" in text, text
    assert sim.param("axis", 3, 0) == 0
    assert not sim.ascii_active


def test_a_thread_that_meets_the_terminal_gone_ends_quietly(monkeypatch):
    """The same, where it happens: a thread's write fails with EIO as the terminal goes.
    What else fails in a thread still reaches the hook there was (which prints it)."""
    import errno
    import threading

    from tmclsh.shell.repl import app

    reached: list[BaseException] = []
    monkeypatch.setattr(threading, "excepthook", lambda args: reached.append(args.exc_value))
    monkeypatch.setattr(app, "terminal_gone", lambda fd: True)  # (the terminal has gone)
    app._quiet_when_the_terminal_goes()

    def fails(exc: BaseException) -> None:
        def run() -> None:
            raise exc
        t = threading.Thread(target=run, name="patch-stdout-flush-thread")
        t.start()
        t.join()

    fails(OSError(errno.EIO, "Input/output error"))
    assert reached == []
    other = ValueError("something else")
    fails(other)
    assert reached == [other]


@pytest.mark.parametrize("where, shown", [(".watch GAP 3, 0", b"stop all"),  # (its keys)
                                          (".watch GAP 3, 0", None),  # (gone as it starts)
                                          (".ascii", b"ascii A>")])
def test_the_terminal_gone_without_a_signal_mid_command_stops_the_motors(served, where, shown):
    """As at the prompt, with a watch or the ASCII terminal running: no SIGHUP came (tmclsh
    under ``setsid``), the terminal's reads end. The watch took that for no key pressed and
    sampled on, the motor turning, until killed."""
    sim, path = served
    term = _Terminal(path)
    try:
        wait_for(lambda: term.shows(b"TMCM-1311:1>"), 20)
        term.type("ROR 0, 30000")
        wait_for(lambda: sim.param("axis", 3, 0) != 0)
        term.forget()
        term.type(where)
        if shown is not None:
            wait_for(lambda: term.shows(shown), 20)
    finally:
        term.close()  # the terminal goes away
    p = term.p
    try:
        err = p.communicate(timeout=patience(20))[1].decode()
    except subprocess.TimeoutExpired:
        p.kill()
        raise AssertionError("tmclsh went on after its terminal went away") from None
    assert p.returncode == 128 + signal.SIGHUP, err
    assert "Traceback" not in err, err
    assert "hung up (the terminal went away): stopped motor 0 (MST; speed reads 0)" in err, err
    assert sim.param("axis", 3, 0) == 0
    assert not sim.ascii_active


def test_a_watch_whose_reader_went_away_stops_what_the_run_set_moving(served):
    """``tmclsh -c "ROR 0, 30000; .watch GAP 3, 0" | head -1``: the watch ended at the
    broken pipe as if its count were reached, and the run ended there as finished: exit 0,
    the motor turning. It is the run's reader gone, as on any other line."""
    sim, path = served
    p = subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", path, "-c",
                          "ROR 0, 30000\n.watch GAP 3, 0"], cwd=str(ROOT),
                         env=tmclsh_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.readline()
    p.stdout.close()  # the reader goes away after one line
    err = p.stderr.read().decode()
    assert p.wait(patience(20)) == 1, err
    assert "Traceback" not in err, err
    assert "the output's reader went away: stopped motor 0 (MST; speed reads 0)" in err, err
    assert sim.param("axis", 3, 0) == 0


@pytest.mark.parametrize("second", [signal.SIGINT, signal.SIGTERM])
def test_a_second_signal_before_the_stop_begins_does_not_skip_it(monkeypatch, capsys, second):
    """Ctrl-C pressed twice (or a SIGTERM after it) with the second landing as the run
    turns to its stop, before the stop's first request (the stop's modules are imported
    then): the second escaped, the run ended 130 without a word, the motor turning (found
    on a shared line with a module model: the motor at 30000 after the run). It is part of
    the same end: the stop runs."""
    import os

    from tmclsh.cli.main import main
    from tmclsh.shell.lang import main as shell_main

    seen = {}

    def ctrl_c_mid_run(args, client, settings):
        seen["sim"] = client.transport.simulator
        client.execute("ROR 0, 30000")
        raise KeyboardInterrupt

    behind = shell_main._signal_behind

    def second_signal_lands(exc):
        os.kill(os.getpid(), second)  # (to this thread: its handler runs in the loop)
        for _ in range(20):
            time.sleep(0.001)
        return behind(exc)

    monkeypatch.setattr(shell_main, "run_connected", ctrl_c_mid_run)
    monkeypatch.setattr(shell_main, "_signal_behind", second_signal_lands)
    previous = signal.getsignal(signal.SIGTERM)
    try:
        status = main(["--sim", "-c", "GAP 1, 0"])
    finally:
        signal.signal(signal.SIGTERM, previous)
    err = capsys.readouterr().err
    assert status == 130, err
    assert "interrupted: stopped motor 0 (MST; speed reads 0)" in err, err
    assert seen["sim"].param("axis", 3, 0) == 0


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("ascii", [False, True])
def test_a_motor_set_turning_at_an_address_left_is_stopped_too(make_pty_sim, sig, ascii):
    """``ROR 0, 20000; .address 2; ROR 0, 30000`` then Ctrl-C or SIGTERM: the stop went to
    address 2 only; the motor at address 1, which this run set turning, went on. The run's
    stop visits each address it left a motor moving at (and leaves the others alone)."""
    from tmclsh.sim import SimBus, Simulator

    sims = [Simulator("TMCM-1311", a) for a in (1, 2, 3)]
    bus, path = make_pty_sim(target=SimBus(sims))
    extra = ("--ascii",) if ascii else ()
    p = start(path, *extra, "-c", "ROR 0, 20000; .address 2; ROR 0, 30000; .sleep 30")
    wait_for(lambda: sims[1].param("axis", 3, 0) != 0)
    p.send_signal(sig)
    out, err = p.communicate(timeout=patience(30))
    assert p.returncode == 128 + sig, err
    assert "Traceback" not in err, err
    assert [s.param("axis", 3, 0) for s in sims[:2]] == [0, 0], err
    assert "address 1: stopped motor 0 (MST; speed reads 0)" in err, err
    assert not any(s.ascii_active for s in sims), err


def test_an_address_left_that_no_longer_answers_is_named(make_pty_sim):
    """The module left turning does not answer when the stop comes back for it: said,
    with the motor, in one line; the run still ends with the signal's status."""
    from tmclsh.sim import SimBus, Simulator

    sims = [Simulator("TMCM-1311", a) for a in (1, 2)]
    bus, path = make_pty_sim(target=SimBus(sims))
    p = start(path, "--timeout", "0.2", "-c",
              "ROR 0, 20000; .address 2; ROR 0, 30000; .sleep 30")
    wait_for(lambda: sims[1].param("axis", 3, 0) != 0)
    sims[0].faults.lose_next = 10_000  # (address 1 hears nothing from now on)
    p.send_signal(signal.SIGTERM)
    out, err = p.communicate(timeout=patience(60))
    assert p.returncode == 143, err
    assert "Traceback" not in err, err
    assert "terminated (SIGTERM): stopped motor 0 (MST; speed reads 0)" in err, err
    assert "terminated (SIGTERM): address 1: motor 0 may still turn: " in err, err
    assert sims[1].param("axis", 3, 0) == 0


def test_a_command_cut_short_after_it_went_out_is_counted(served, tmp_path):
    """SIGTERM while the ROR's reply is still on its way: the module got the ROR (its motor
    turns), so the summary counts it; it said "after 0 commands sent", above the stop of
    the motor that command had set turning."""
    sim, path = served
    script = tmp_path / "turn.tmcl"
    script.write_text("ROR 0, 30000\n.sleep 30\n")
    sim.faults.delay = 1.0  # every reply a second late: the signal lands before the ROR's
    p = start(path, "-f", str(script), "--timeout", "5")
    wait_for(lambda: sim.param("axis", 3, 0) != 0)
    p.send_signal(signal.SIGTERM)
    out, err = p.communicate(timeout=patience(30))
    sim.faults.delay = 0.0
    assert p.returncode == 128 + signal.SIGTERM, err
    assert "turn.tmcl: terminated (SIGTERM) at line 1 after 1 command sent" in out, out
