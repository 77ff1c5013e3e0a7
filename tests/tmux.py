"""A real terminal for the tests: a command in a detached tmux session on a private server,
typed at with send-keys, read back with capture-pane.

``Terminal(tmp_path, ...)`` owns one tmux server (``-L`` socket under ``tmp_path``); ``kill()``
ends it. The ``terminal`` fixture (conftest.py) makes them and always kills them. Test modules
set ``pytestmark = needs_tmux``.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path
from typing import Callable

import pytest

ROOT = Path(__file__).resolve().parent.parent

needs_tmux = pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")


class Terminal:
    """``env`` is added to the default environment of ``start`` (XDG dirs under ``tmp_path``,
    this checkout on PYTHONPATH, TERM=xterm-256color); ``unset`` names variables to remove
    besides COLUMNS and LINES (the pane's size must win). ``history`` lines of scrollback are
    part of ``screen()``. ``timeout`` is the default of the waits."""

    NAME = "tmclsh"

    def __init__(self, tmp_path: Path, *, env: dict[str, str] | None = None,
                 unset: tuple[str, ...] = (), cwd: Path = ROOT, width: int = 120,
                 height: int = 36, history: int = 0, timeout: float = 15.0):
        self.env = {"XDG_STATE_HOME": str(tmp_path / "state"),
                    "XDG_CONFIG_HOME": str(tmp_path / "config"),
                    "XDG_CACHE_HOME": str(tmp_path / "cache"),
                    "PYTHONPATH": str(ROOT), "TERM": "xterm-256color", **(env or {})}
        self.unset = ("COLUMNS", "LINES", *unset)
        self.cwd, self.width, self.height = cwd, width, height
        self.history, self.timeout = history, timeout
        # the server's socket is $TMUX_TMPDIR/tmux-UID/<socket>; unix socket paths are short
        self.socket = f"tmclsh-{uuid.uuid4().hex[:8]}"
        self._own_dir = None
        if len(str(tmp_path)) > 80:
            self._own_dir = tempfile.mkdtemp(prefix="tmux")
        self._tmux_env = {**os.environ, "TMUX_TMPDIR": self._own_dir or str(tmp_path)}

    def tmux(self, *args: str, check: bool = True) -> str:
        proc = subprocess.run(["tmux", "-L", self.socket, *args], capture_output=True, text=True,
                              timeout=20, env=self._tmux_env)
        if check and proc.returncode:
            raise AssertionError(f"tmux {' '.join(args)}: {proc.stderr}")
        return proc.stdout

    def shell(self, command: str) -> None:
        """Run the shell ``command`` as it is in the pane."""
        self.tmux("-f", "/dev/null", "new-session", "-d", "-s", self.NAME,
                  "-x", str(self.width), "-y", str(self.height), command)

    def start(self, *argv: str) -> None:
        """``python -m tmclsh ARGV`` in ``cwd`` with ``env``; ``EXIT=<status>`` is printed
        after it and the pane stays open."""
        env = " ".join(f"{k}={shlex.quote(v)}" for k, v in self.env.items())
        unset = " ".join(f"-u {k}" for k in self.unset)
        args = " ".join(shlex.quote(a) for a in (sys.executable, "-m", "tmclsh", *argv))
        self.shell(f"cd {shlex.quote(str(self.cwd))} && env {unset} {env} {args}; "
                   "echo EXIT=$?; sleep 60")

    def keys(self, *keys: str) -> None:
        """Keys by tmux name (``Enter``, ``C-c``, ``Tab``); other words are typed."""
        self.tmux("send-keys", "-t", self.NAME, *keys)

    def hex(self, *codes: str) -> None:
        """Raw bytes in hex, e.g. ``hex("1d")`` for Ctrl-]."""
        self.tmux("send-keys", "-t", self.NAME, "-H", *codes)

    def type(self, text: str) -> None:
        """``text`` literally, no key names."""
        self.tmux("send-keys", "-t", self.NAME, "-l", text)

    def line(self, text: str) -> None:
        self.type(text)
        self.keys("Enter")

    def screen(self) -> str:
        history = ("-S", f"-{self.history}") if self.history else ()
        return self.tmux("capture-pane", "-p", "-t", self.NAME, *history)

    def wait_for(self, predicate: Callable[[str], object] | re.Pattern,
                 timeout: float | None = None, what: str = "condition not met") -> str:
        """Wait until ``predicate(screen)`` (or the regex is found); the screen."""
        if isinstance(predicate, re.Pattern):
            predicate, what = predicate.search, f"{predicate.pattern!r} not on the screen"
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while True:
            screen = self.screen()
            if predicate(screen):
                return screen
            if time.monotonic() > deadline:
                raise AssertionError(f"{what}:\n{screen}")
            time.sleep(0.05)

    def wait(self, text: str, timeout: float | None = None, more_than: int = 0) -> str:
        """Wait until ``text`` is on the screen more than ``more_than`` times."""
        return self.wait_for(lambda screen: screen.count(text) > more_than, timeout,
                             f"{text!r} not on the screen")

    def run(self, line: str, *expect: str, timeout: float | None = None) -> str:
        """Type ``line`` and wait for a new occurrence of each of ``expect``."""
        before = self.screen()
        self.line(line)
        screen = before
        for text in expect:
            screen = self.wait(text, timeout, before.count(text))
        return screen

    def quit(self, keys: tuple[str, ...] = ("C-d",)) -> None:
        """Leave and see ``EXIT=0``. A key typed while the shell is between two prompts (the
        terminal briefly in cooked mode) can be eaten by the tty, as it would be for a person;
        then the key is typed again."""
        for _ in range(3):
            self.keys(*keys)
            try:
                self.wait("EXIT=0", timeout=3)
                return
            except AssertionError:
                continue
        raise AssertionError(f"the shell did not exit:\n{self.screen()}")

    def kill(self) -> None:
        self.tmux("kill-server", check=False)
        if self._own_dir:
            shutil.rmtree(self._own_dir, ignore_errors=True)
