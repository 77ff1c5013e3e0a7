"""A pty between a host and a module in ASCII mode that delays, duplicates and changes reply
lines, on schedule or at random: what a slow repeater, an RS485 echo that lags or a noisy
line does to the module's ASCII replies, which carry no checksum.

Written from the manuals' ASCII reply format (``<host char><module char> <status> <value>``
and CR, TMCM-1311 manual §4.4), like tests/responder.py it imports nothing of tmclsh: what
it does to the line cannot follow tmclsh's idea of it. Only lines that look like replies are
touched; the module's echo and everything the host sends pass as they are.

Faults, per reply line (``schedule`` first: a list of kinds for the reply lines in order,
None for none; then ``rates``, drawn from ``rng``):

* ``delay``: the line and everything behind it held back ``DELAY`` seconds (order kept, as a
  slow link keeps it);
* ``dup``: the line sent twice, back to back;
* ``dup-late``: a copy of the line sent just before the next reply line (after that line's
  echo: the copy is taken for the next command's reply unless it is found out);
* ``flip``: one digit of the value changed to another digit (a valid reply, a wrong value).

``armed`` (an Event) is clear until the host sends a line containing ``arm_on``: the bring-up
of a session passes untouched, the faults begin with the first line of the run measured.
"""

from __future__ import annotations

import os
import random
import re
import select
import threading
import time
import tty

REPLY = re.compile(rb"^([\x40-\xff][\x40-\xff] *[0-9]{1,3} +[-+]?)([0-9]{1,10}) *$")
KINDS = ("delay", "dup", "dup-late", "flip")
DELAY = (0.4, 1.2)  # s a delayed reply is held back (the host's timeout is shorter)


class AsciiProxy:
    """``AsciiProxy(upstream_path)``: ``path`` is the pty the host opens."""

    def __init__(self, upstream: str, *, schedule: list[str | None] | None = None,
                 rates: dict[str, float] | None = None, seed: int = 0,
                 arm_on: bytes | None = None):
        self.schedule = list(schedule or [])
        self.rates = dict(rates or {})
        self.rng = random.Random(seed)
        self.counts = dict.fromkeys(KINDS, 0)
        self.replies = 0  # reply lines seen
        self.armed = threading.Event()
        self.arm_on = arm_on
        if arm_on is None:
            self.armed.set()
        self._up = os.open(upstream, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self._up)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        self._out: list[tuple[float, bytes]] = []  # (due, bytes) to the host, in order
        self._late: list[bytes] = []  # dup-late copies waiting for the next reply line
        self._line = bytearray()  # from the module, the current line
        self._host_line = bytearray()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ascii-proxy", daemon=True)
        self._thread.start()

    # -- what happens to one reply line -------------------------------------------------------
    def _fault(self) -> str | None:
        if not self.armed.is_set():
            return None
        if self.schedule:
            return self.schedule.pop(0)
        for kind in KINDS:
            p = self.rates.get(kind, 0.0)
            if p and self.rng.random() < p:
                return kind
        return None

    def _flip(self, line: bytes) -> bytes:
        m = REPLY.match(line.rstrip(b"\r\n"))
        if m is None:
            return line
        digits = bytearray(m.group(2))
        i = self.rng.randrange(len(digits))
        old = digits[i]
        digits[i] = self.rng.choice([d for d in b"0123456789" if d != old])
        return m.group(1) + bytes(digits) + line[len(line.rstrip(b"\r\n")):]

    def _from_module(self, line: bytes) -> None:
        now = time.monotonic()
        last = self._out[-1][0] if self._out else now
        due = max(now, last)
        if not REPLY.match(line.rstrip(b"\r\n")):
            self._out.append((due, line))
            return
        self.replies += 1
        kind = self._fault()
        if kind is not None:
            self.counts[kind] += 1
        for copy in self._late:
            self._out.append((due, copy))
        self._late.clear()
        if kind == "delay":
            due += self.rng.uniform(*DELAY)
        elif kind == "flip":
            line = self._flip(line)
        self._out.append((due, line))
        if kind == "dup":
            self._out.append((due, line))
        elif kind == "dup-late":
            self._late.append(line)

    def _from_host(self, data: bytes) -> None:
        os.write(self._up, data)
        if self.arm_on is None or self.armed.is_set():
            return
        self._host_line += data
        while (end := self._host_line.find(b"\r")) >= 0:
            if self.arm_on in self._host_line[:end]:
                self.armed.set()
            del self._host_line[:end + 1]

    # -- the relay -----------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            wait = 0.05
            if self._out:
                wait = max(0.0, min(wait, self._out[0][0] - time.monotonic()))
            try:
                ready, _, _ = select.select([self._up, self._master], [], [], wait)
            except (OSError, ValueError):
                return
            try:
                if self._master in ready:
                    self._from_host(os.read(self._master, 4096))
                if self._up in ready:
                    for b in os.read(self._up, 4096):
                        self._line.append(b)
                        if b in (0x0D, 0x0A):
                            self._from_module(bytes(self._line))
                            self._line.clear()
                    if self._line and (self._line[0] < 0x40
                                       or len(self._line) > 1 and self._line[1] < 0x40):
                        # a partial line that cannot become a reply (echo, binary frames)
                        self._from_module(bytes(self._line))
                        self._line.clear()
                now = time.monotonic()
                while self._out and self._out[0][0] <= now:
                    os.write(self._master, self._out.pop(0)[1])
            except OSError:
                return

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        for fd in (self._master, self._slave, self._up):
            try:
                os.close(fd)
            except OSError:
                pass
