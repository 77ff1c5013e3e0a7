"""Shared fixtures: simulated modules behind real byte paths.

* ``sim``: an in-process ``Simulator`` (TMCM-1311, address 1), closed afterwards.
* ``pty_sim``: that simulator served on a pseudo-terminal: ``(sim, path)``; open ``path`` like
  a serial port. ``make_pty_sim(...)`` serves any ``Simulator``/``SimBus`` arguments.
* ``client``: ``tmclsh.connect(sim="TMCM-1311")``, in process, 0.5 s timeout; the simulator is
  ``client.transport.simulator``.
* ``fast_client``: a ``LineClient`` on an in-process TMCM-1311 whose module time runs 20x real
  time (moves and WAITs finish quickly), 0.5 s timeout, no retries.
* ``pty_client``: a ``LineClient`` on ``pty_sim`` through pyserial, 0.2 s timeout (fault tests);
  the simulator is ``pty_client.sim``.
* ``run_tmclsh(*args, timeout=...)``: ``python -m tmclsh ARGS`` in a subprocess with this
  checkout on the path; returns the ``CompletedProcess`` (text, stdout and stderr captured).
  Such a run is not interactive: without ``--sim``/``--port``/``--can`` it exits 3 (no
  module found), it never falls back to the simulator.
* ``terminal(**kw)``: a ``tmux.Terminal`` (tests/tmux.py), a real terminal on a private tmux
  server, killed afterwards.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


try:  # a property test's examples are not timed: a busy machine is not a slow strategy
    from hypothesis import HealthCheck, settings

    settings.register_profile("tmclsh", deadline=None,
                              suppress_health_check=[HealthCheck.too_slow])
    settings.load_profile("tmclsh")
except ImportError:  # pragma: no cover (hypothesis comes with the test extra)
    pass


def patience(seconds: float) -> float:
    """A bound on how long a test waits for something that should happen (a subprocess to
    end, a state to come up), which only a hang should reach: ``seconds`` on a quiet
    machine, stretched by how many runnable processes share each core now. It bounds a wait
    for a condition; it is never a time the test sleeps."""
    try:
        busy = os.getloadavg()[0] / (os.cpu_count() or 1)
    except OSError:  # (no load average on this platform)
        busy = 1.0
    return seconds * max(1.0, busy)


def delivered(pid: int, sig: int = signal.SIGINT, timeout: float = 30) -> None:
    """Wait until the kernel has handed ``sig`` to process ``pid`` (no longer pending: its
    handler has run, or runs now). On a busy machine a signalled process may not run for a
    while; a module model that holds its answer "while the signal lands" waits for this
    instead of a fixed time. Returns at once where /proc does not say."""
    bit = 1 << (sig - 1)
    deadline = time.monotonic() + patience(timeout)
    while time.monotonic() < deadline:
        try:
            with open(f"/proc/{pid}/status") as fh:
                fields = dict(line.split(":", 1) for line in fh if ":" in line)
        except OSError:  # (ended, or no /proc here)
            return
        if not any(int(fields.get(k, "0"), 16) & bit for k in ("SigPnd", "ShdPnd")):
            return
        time.sleep(0.005)
    raise AssertionError(f"signal {sig} still pending for process {pid}")


def read_until(proc: subprocess.Popen, done, timeout: float = 30) -> str:
    """Read ``proc``'s stdout (a pipe) until ``done(text so far)``: the process has shown
    it is where the test wants it (before a signal, say) instead of a guess at how long that
    takes. Returns the text read; ``communicate()`` afterwards returns only the rest."""
    import select

    fd, data = proc.stdout.fileno(), b""
    deadline = time.monotonic() + patience(timeout)
    while not done(data.decode(errors="replace")):
        left = deadline - time.monotonic()
        assert left > 0, f"not seen in time; stdout so far: {data!r}"
        if select.select([fd], [], [], min(left, 0.1))[0]:
            chunk = os.read(fd, 65536)
            assert chunk, f"the process ended first; stdout: {data!r}"
            data += chunk
    return data.decode(errors="replace")


def pytest_configure(config: pytest.Config) -> None:
    """Ctrl-C means KeyboardInterrupt here and in every tmclsh the tests start, whoever
    started the run. A run started in the background by a shell without job control
    (``stress.sh &``, a CI step) inherits SIGINT ignored; Python then installs no handler, the
    xdist workers and every subprocess they start inherit the ignoring, and each test that
    interrupts a tmclsh with SIGINT sees it run on to the end as if the signal were lost.
    The same for SIGHUP (a run under ``nohup``): tmclsh keeps a SIGHUP it starts ignoring
    ignored, as ``nohup`` asks, and the tests that hang it up need it not to."""
    for sig, handler in ((signal.SIGINT, signal.default_int_handler),
                         (signal.SIGHUP, signal.SIG_DFL)):
        if signal.getsignal(sig) is signal.SIG_IGN:
            try:
                signal.signal(sig, handler)
            except ValueError:  # not the main thread: nothing to restore from here
                pass


def tmclsh_env(**extra: str) -> dict[str, str]:
    """Environment for a ``python -m tmclsh`` subprocess: this checkout first on the path, no
    user config file, no attached-module detection surprises."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["TMCLSH_CONFIG"] = os.devnull
    for var in ("TMCLSH_PORT", "TMCLSH_CAN", "TMCLSH_PROFILE", "TMCLSH_MODULE", "TMCLSH_ADDRESS"):
        env.pop(var, None)
    env.update(extra)
    return env


@pytest.fixture
def run_tmclsh():
    def run(*args: str, timeout: float = 30, input: str | None = None,
            env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "tmclsh", *args], capture_output=True,
                              text=True, timeout=timeout, input=input,
                              env=env or tmclsh_env(), cwd=str(ROOT))
    return run


@pytest.fixture
def fast_client():
    from tmclsh.client.text import LineClient
    from tmclsh.link import open_sim

    client = LineClient(open_sim("TMCM-1311", 1, speed=20), module="TMCM-1311", timeout=0.5,
                    retries=0)
    yield client
    client.close()


@pytest.fixture
def sim():
    from tmclsh.sim import Simulator

    s = Simulator("TMCM-1311")
    yield s
    s.close()


@pytest.fixture
def make_pty_sim():
    """``make_pty_sim(module="TMCM-1311", address=1, **kw)`` -> (sim, path); or
    ``make_pty_sim(target=SimBus([...]))`` -> (bus, path). All are closed afterwards."""
    from tmclsh.sim import Simulator
    from tmclsh.sim.serve import serve_pty

    opened = []

    def make(module: str = "TMCM-1311", address: int = 1, *, target=None, **kw):
        if target is None:
            target = Simulator(module, address, **kw)
        server = serve_pty(target)
        opened.append((server, target))
        return target, server.path

    yield make
    for server, target in reversed(opened):
        server.close()
        target.close()


@pytest.fixture
def pty_sim(make_pty_sim):
    return make_pty_sim()


@pytest.fixture
def client():
    import tmclsh

    c = tmclsh.connect(sim="TMCM-1311", timeout=0.5)
    yield c
    c.close()


@pytest.fixture
def pty_client(pty_sim):
    from tmclsh.client.text import LineClient
    from tmclsh.link import open_serial

    sim, path = pty_sim
    c = LineClient(open_serial(path), module="TMCM-1311", timeout=0.2, retries=2)
    c.sim = sim  # type: ignore[attr-defined]  # the tests' handle on the module
    yield c
    c.close()


@pytest.fixture(autouse=True)
def _own_cache_dir(tmp_path, monkeypatch):
    """Each test its own user cache directory (uploads keep their source maps there)."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


@pytest.fixture
def terminal(tmp_path):
    """``terminal(**kw)`` -> a ``tmux.Terminal`` on its own tmux server (see tests/tmux.py),
    killed afterwards whatever happens."""
    from tmux import Terminal

    made: list[Terminal] = []

    def make(**kw) -> Terminal:
        made.append(Terminal(tmp_path, **kw))
        return made[-1]

    try:
        yield make
    finally:
        for t in reversed(made):
            t.kill()
