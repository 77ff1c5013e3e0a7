"""A hand-off that never makes its giver wait: things put here are taken by a worker thread
of their own, and when the worker falls behind by more than ``bound`` of them, the newest are
dropped and counted instead of blocking.

A bridge forwards frames on threads that must never wait for a person's terminal, a pager
someone paused, a pipe nobody reads or a slow disk: whatever describes the traffic sits
behind one of these, so a reader that stops reading costs lines of output (counted and said),
never a frame on the wire or time in forwarding it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

log = logging.getLogger(__name__)


class Spill:
    """``put`` hands ``thing`` to ``take`` on the worker thread, in order; beyond ``bound``
    things waiting, ``put`` drops it and counts it in ``dropped``. ``take`` failing is
    logged and the worker goes on (what describes traffic must not end it).

    ``poll``: the worker looks for new things this often (seconds) instead of being woken
    for each: ``put`` is then a bare append, no system call and no thread woken on the
    giver's path, and the worker takes what came meanwhile in one go."""

    def __init__(self, take: Callable[[Any], None], bound: int, name: str = "spill",
                 poll: float | None = None):
        self.take = take
        self.bound = bound
        self.poll = poll
        self.dropped = 0
        self._taking = False
        self._items: deque[Any] = deque()
        self._ready = threading.Condition(threading.Lock())
        self._closing = False
        self._thread = threading.Thread(target=self._work, name=name, daemon=True)
        self._thread.start()

    def put(self, thing: Any) -> bool:
        """False (and counted) when dropped."""
        items = self._items
        if len(items) >= self.bound or self._closing:
            with self._ready:
                self.dropped += 1
            return False
        items.append(thing)  # (atomic: several givers may put at once)
        if self.poll is None:
            with self._ready:
                self._ready.notify()
        return True

    @property
    def waiting(self) -> int:
        return len(self._items)

    def _work(self) -> None:
        items, ready, take = self._items, self._ready, self.take
        while True:
            if not items:
                with ready:
                    while not items and not self._closing:
                        ready.wait(self.poll)
                if not items:
                    return
            self._taking = True
            while items:
                thing = items.popleft()
                try:
                    take(thing)
                except Exception:
                    log.exception("taking what was handed over failed")
            self._taking = False

    def drain(self, timeout: float) -> bool:
        """Wait until what was put has been taken (at most ``timeout`` seconds): before
        another process writes where ``take`` writes. False: it had not."""
        deadline = time.monotonic() + timeout
        while self._items or self._taking:
            if time.monotonic() >= deadline:
                return False
            with self._ready:
                self._ready.notify()
            time.sleep(0.002)
        return True

    def close(self, timeout: float | None = None) -> int:
        """Take nothing more; the worker takes what waits (for at most ``timeout`` seconds,
        None: as long as it needs); what it could not take is counted as dropped. Returns
        ``dropped``."""
        with self._ready:
            self._closing = True
            self._ready.notify()
        self._thread.join(timeout)
        if self._thread.is_alive():
            with self._ready:
                self.dropped += len(self._items)
                self._items.clear()
        return self.dropped



class SpillWriter:
    """A text stream whose ``write`` never blocks: what is written goes to ``stream`` on a
    thread of its own; when ``bound`` writes wait there (the reader of ``stream`` stopped
    reading), further writes are dropped and counted (``dropped``: one per write, so one
    per line for a writer of lines). ``close`` waits for what was taken to be written.
    ``poll``: as ``Spill``'s (lines written in batches, one flush each, the writing thread
    woken that often rather than for every line)."""

    def __init__(self, stream: Any, bound: int = 2000, poll: float | None = None):
        self.stream = stream
        self.gone = False  # the reader went away (a broken pipe: ``| head`` has ended)
        self._spill = Spill(self._write, bound, name="output", poll=poll)

    @property
    def dropped(self) -> int:
        return self._spill.dropped

    @property
    def waiting(self) -> int:
        """Writes taken and not yet written (a live view skips a redraw while there are)."""
        return self._spill.waiting

    def write(self, text: str) -> int:
        self._spill.put(text)
        return len(text)

    def _write(self, text: str) -> None:
        if self.gone:
            return
        try:
            self.stream.write(text)
            if not self._spill.waiting:
                self.stream.flush()
        except BrokenPipeError:  # (the reader went away: nothing more to show; a run that
            self.gone = True     # only shows, as a monitor, ends on it)
        except (OSError, ValueError):
            pass

    def flush(self) -> None:
        """Nothing to do here: the writing thread flushes whenever it catches up."""

    def drain(self, timeout: float) -> bool:
        """Wait (at most ``timeout`` seconds) until what was written has reached ``stream``:
        before another process writes to the same terminal."""
        return self._spill.drain(timeout)

    def isatty(self) -> bool:
        try:
            return self.stream.isatty()
        except (AttributeError, ValueError):
            return False

    def fileno(self) -> int:
        return self.stream.fileno()

    @property
    def encoding(self) -> str:
        return getattr(self.stream, "encoding", "utf-8")

    def close(self, timeout: float | None = None) -> int:
        """Stop taking writes and let what was taken reach the stream (``timeout``: at most
        so long; None: until its reader has read it); the writes dropped, in all."""
        return self._spill.close(timeout)
