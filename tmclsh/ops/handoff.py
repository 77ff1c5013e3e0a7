"""What a bridge forwarded, handed to whatever describes it in a process of its own.

Why another process: a bridge's forwarding threads and anything that describes what they
forward (reading frames, pairing, wording lines, a live table, a file) share one interpreter
lock when they share a process, and the forwarding then waits for it at every turn: measured,
a p99 of several hundred microseconds added to each exchange, against about 25 when the
describing runs in another process. So the bridge's process only forwards, and hands each
chunk as a few bytes to a pipe that never makes it wait (``Pipe.put``): what a full pipe
cannot take (the describer behind) waits beside it in order, and beyond ``BEHIND`` bytes is
not handed over and is counted (``dropped``); it was forwarded all the same.

While traffic flows, the describer reads the pipe in a rhythm (``RHYTHM``) rather than
waiting on it, so a put wakes no process (measured per exchange: the forwarding's CPU
46-59 -> 36-49 us, the describer's 52-68 -> 30-35 us), and it gives way between the things
it describes (``give_way``), so a batch described at once never holds a core the
forwarding needs.

Each record is at most ``PIPE_BUF`` bytes, which a pipe writes whole or not at all, so
two forwarding threads (the master's and the module's, where the module's port is read by a
thread of its own: ops/bridge.py) can put at once without a lock and their records keep the
order they were put in: the wire's order (ops/bridge.py ``_Bridge`` says how).

The same pipe carries the few words the two sides say to each other (``START``, ``END``,
``FINISH``, ``DONE``, ``LEFT``), each a record too. Where a process cannot be forked
(Windows), the describer runs on a thread of the bridge's own process (``Describer``), its pipe
an in-process one with the same records (``LocalPipe``): the same code, without the gain.

Nothing here prints.
"""

from __future__ import annotations

import json
import logging
import os
import select
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from ..base.interrupts import interrupted, unwind_on
from ..link.base import CanFrame
from .monitor import RX, TX

# what the forwarding tells: (TX | RX | NOISE, bytes, time) for a serial chunk or the
# master's bytes that are no frame; (CAN_TX | CAN_RX, CanFrame); (LOST, why)
CAN_TX, CAN_RX, NOISE, LOST = "can-tx", "can-rx", "noise", "lost"
# what the two sides say to each other: START (the endpoint is out: the describer may draw),
# END (forwarding has stopped: say what the traffic left), FINISH (untold: the end),
# DONE (from the describer: a limit was reached), LEFT (its answer to END: a dict),
# CAPTURE (a frame for the -o file only: what the closing stop sent and got)
START, END, FINISH, DONE, LEFT, CAPTURE = "start", "end", "finish", "done", "left", "capture"

PIPE_BUF = getattr(select, "PIPE_BUF", 512)  # bytes a pipe writes whole or not at all
PIPE_SIZE = 1 << 20  # bytes asked of the kernel for the pipe (Linux; else its default)
_READ = 1 << 16  # bytes a read asks for
BEHIND = 4 << 20  # bytes that may wait for room in the pipe before the newest are dropped
RHYTHM = 0.02  # s between the describer's reads while traffic flows (as often as the bridge
# writes its lines: reading sooner would show nothing sooner)
QUIET = 0.1  # s without traffic after which it waits on the pipe again (a master polling
# less often than that wakes it with each request)

_HEAD = struct.Struct("<HBd")  # bytes after the head, kind, time
_CAN = struct.Struct("<IB")  # arbitration id, flags
_EXTENDED, _ERROR, _REMOTE = 1, 2, 4
_KINDS = (TX, RX, NOISE, CAN_TX, CAN_RX, LOST, START, END, FINISH, DONE, LEFT)
_CODE = {k: i for i, k in enumerate(_KINDS)}
_CAPTURED = 0x80  # the kind's code with this bit: CAPTURE, around the frame it names
_CHUNK = PIPE_BUF - _HEAD.size  # bytes of a serial chunk a record carries
_head = _HEAD.pack
_SERIAL = {TX: _CODE[TX], RX: _CODE[RX]}


def pack(event: tuple) -> list[bytes]:
    """The records of one event (a long serial chunk takes several, each whole)."""
    kind = event[0]
    flag = 0
    if kind == CAPTURE:
        flag, event = _CAPTURED, event[1]
        kind = event[0]
    code = _CODE[kind] | flag
    if kind in (TX, RX, NOISE):
        data, t = event[1], event[2]
        if len(data) <= _CHUNK:
            return [_HEAD.pack(len(data), code, t) + data]
        return [_HEAD.pack(len(part), code, t) + part
                for part in (data[i:i + _CHUNK] for i in range(0, len(data), _CHUNK))]
    if kind in (CAN_TX, CAN_RX):
        f: CanFrame = event[1]
        flags = (_EXTENDED if f.extended else 0) | (_ERROR if f.error else 0) \
            | (_REMOTE if f.remote else 0)
        body = _CAN.pack(f.arbitration_id, flags) + bytes(f.data)
        return [_HEAD.pack(len(body), code, f.t) + body]
    if kind == FINISH:
        body = str(event[1]).encode()
    elif kind in (LOST, LEFT):
        body = json.dumps(event[1]).encode()[:_CHUNK]
    else:
        body = b""
    return [_HEAD.pack(len(body), code, 0.0) + body]


class Unpacker:
    """Records back into events, whatever pieces the pipe's reads cut them into."""

    def __init__(self) -> None:
        self._rest = b""

    def feed(self, data: bytes) -> list[tuple]:
        buf = self._rest + data if self._rest else data
        events: list[tuple] = []
        at, end, head = 0, len(buf), _HEAD.size
        unpack = _HEAD.unpack_from
        while end - at >= head:
            size, code, t = unpack(buf, at)
            if end - at - head < size:
                break
            body = buf[at + head:at + head + size]
            at += head + size
            kind = _KINDS[code & ~_CAPTURED]
            if kind in (TX, RX, NOISE):
                event: tuple = (kind, body, t)
            elif kind in (CAN_TX, CAN_RX):
                arb, flags = _CAN.unpack_from(body)
                event = (kind, CanFrame(t, arb, body[_CAN.size:], bool(flags & _EXTENDED),
                                        bool(flags & _ERROR), bool(flags & _REMOTE)))
            elif kind == FINISH:
                event = (kind, int(body))
            elif kind in (LOST, LEFT):
                event = (kind, json.loads(body))
            else:
                event = (kind,)
            events.append((CAPTURE, event) if code & _CAPTURED else event)
        self._rest = buf[at:]
        return events


class Pipe:
    """One way between two processes: ``put`` never waits; ``send`` waits for room (the
    words the two sides say, once the forwarding has stopped or from the describer);
    ``take`` reads what came within ``timeout`` seconds (None: the other side has closed its
    end).

    ``rhythm``: while traffic flows, ``take`` sleeps that long and reads what came
    meanwhile, instead of waiting on the pipe: a put to a pipe its reader waits on wakes the
    reader, and the putter pays for that wake-up (the forwarding, twice an exchange). Once
    ``quiet`` seconds brought nothing, ``take`` waits on the pipe again; a reader behind
    reads on without a pause.

    What a full pipe cannot take (the describer behind: a busy machine) waits in this
    process, in order, up to ``BEHIND`` bytes, and goes into the pipe ahead of anything
    put after it, at the next ``put``, ``catch_up`` or ``send``; beyond that, events are
    not handed over and are counted in ``dropped``. Only a put that finds records waiting
    takes a lock: the common one is a single write."""

    def __init__(self, rhythm: float = 0.0, quiet: float = QUIET) -> None:
        self._r, self._w = os.pipe()
        os.set_blocking(self._w, False)
        os.set_blocking(self._r, False)
        self.rhythm, self.quiet = rhythm, quiet
        self._flowing = self._full = False
        self._heard = 0.0  # (when a read last found something, while flowing)
        try:
            import fcntl

            fcntl.fcntl(self._w, getattr(fcntl, "F_SETPIPE_SZ", 1031), PIPE_SIZE)
        except (ImportError, OSError):
            pass  # (not Linux, or a limit on pipe sizes: the default size)
        self.dropped = 0
        self._behind: deque[bytes] = deque()
        self._behind_size = 0
        self._lock = threading.Lock()
        self._unpacker = Unpacker()

    def put(self, event: tuple) -> bool:
        kind = event[0]
        if not self._behind and (kind is TX or kind is RX):  # (the forwarding's own chunks)
            data = event[1]
            if len(data) <= _CHUNK:
                try:
                    os.write(self._w, _head(len(data), _SERIAL[kind], event[2]) + data)
                    return True
                except BlockingIOError:
                    pass
                except (OSError, TypeError):  # (the describer has gone, or this end closed)
                    self.dropped += 1
                    return False
        with self._lock:
            if not self._write_behind():
                self.dropped += 1
                return False
            records = pack(event)
            behind = self._behind
            if behind:
                return self._wait(records)
            for i, record in enumerate(records):
                try:
                    os.write(self._w, record)
                except BlockingIOError:
                    return self._wait(records[i:])
                except (OSError, TypeError):
                    self.dropped += 1
                    return False
            return True

    def _wait(self, records: list[bytes], bounded: bool = True) -> bool:
        """(Under the lock.) ``records`` wait behind the others, if there is room (or
        whatever the room: ``bounded`` False, the two sides' words)."""
        size = sum(map(len, records))
        if bounded and self._behind_size + size > BEHIND:
            self.dropped += 1
            return False
        self._behind.extend(records)
        self._behind_size += size
        return True

    def catch_up(self) -> None:
        """Put what waits in this process into the pipe, as far as it takes it now."""
        if self._behind:
            with self._lock:
                self._write_behind()

    def _write_behind(self) -> bool:
        """(Under the lock.) False: the other side has gone (what waited is counted)."""
        behind = self._behind
        while behind:
            try:
                os.write(self._w, behind[0])
            except BlockingIOError:
                return True
            except (OSError, TypeError):
                self.dropped += len(behind)
                behind.clear()
                self._behind_size = 0
                return False
            self._behind_size -= len(behind.popleft())
        return True

    def send(self, event: tuple, timeout: float = 5.0) -> bool:
        """Put ``event`` after what waits, waiting up to ``timeout`` seconds for room;
        False: no room came or the other side has gone."""
        deadline = time.monotonic() + timeout
        with self._lock:
            self._wait(pack(event), bounded=False)
            while self._behind:
                if not self._write_behind():
                    return False
                if not self._behind:
                    break
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                try:
                    select.select([], [self._w], [], min(left, 0.1))
                except (OSError, ValueError, TypeError):
                    return False
        return True

    @property
    def waiting(self) -> int:
        """Records waiting in this process for room in the pipe."""
        return len(self._behind)

    def take(self, timeout: float | None) -> list[tuple] | None:
        if self._r is None:  # (this end closed)
            return None
        if self._flowing:
            # (traffic flows: what came is read in the rhythm, and meanwhile nothing waits
            # on the pipe, so a put wakes nobody: a wake-up a chunk costs the forwarding)
            if not self._full:
                time.sleep(self.rhythm if timeout is None else min(self.rhythm, timeout))
        else:
            ready, _, _ = select.select([self._r], [], [], timeout)
            if not ready:
                return []
        data = self._read()
        if data is None:
            return None
        if data:
            if self.rhythm > 0:
                self._flowing, self._heard = True, time.monotonic()
            return self._unpacker.feed(data)
        if self._flowing and time.monotonic() - self._heard >= self.quiet:
            self._flowing = False  # (traffic has stopped: the next put wakes it)
        return []

    def _read(self) -> bytes | None:
        """What the pipe holds now, up to its size (b"": nothing; None: the other side has
        closed its end)."""
        parts: list[bytes] = []
        for _ in range(PIPE_SIZE // _READ):
            try:
                data = os.read(self._r, _READ)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                return None
            if not data:
                if not parts:
                    return None
                break
            parts.append(data)
            if len(data) < _READ:
                break
        data = b"".join(parts)
        self._full = len(data) >= _READ  # (far more than a rhythm of any wire: behind)
        return data

    def giving(self) -> None:
        """This process only puts (after the fork): its reading end closed."""
        self._close("_r")

    def taking(self) -> None:
        """This process only takes: its writing end closed, so it sees the other's end."""
        self._close("_w")

    def close(self) -> None:
        self._close("_r")
        self._close("_w")

    def _close(self, end: str) -> None:
        fd = getattr(self, end)
        if fd is not None:
            setattr(self, end, None)
            try:
                os.close(fd)
            except OSError:
                pass


class LocalPipe:
    """``Pipe``'s records between two threads of one process (where no process can be
    forked): bounded as a pipe is, by bytes waiting."""

    def __init__(self, bound: int = PIPE_SIZE) -> None:
        self.bound = bound
        self.dropped = 0
        self._records: deque[bytes] = deque()
        self._size = 0
        self._ready = threading.Condition()
        self._closed = False
        self._unpacker = Unpacker()

    def put(self, event: tuple) -> bool:
        records = pack(event)
        with self._ready:
            if self._closed or self._size + sum(map(len, records)) > self.bound:
                self.dropped += 1
                return False
            self._records.extend(records)
            self._size += sum(map(len, records))
            self._ready.notify()
        return True

    def send(self, event: tuple, timeout: float = 5.0) -> bool:
        with self._ready:
            if self._closed:
                return False
            records = pack(event)
            self._records.extend(records)
            self._size += sum(map(len, records))
            self._ready.notify()
        return True

    def take(self, timeout: float | None) -> list[tuple] | None:
        with self._ready:
            if not self._records and not self._closed:
                self._ready.wait(timeout)
            if not self._records:
                return None if self._closed else []
            data = b"".join(self._records)
            self._records.clear()
            self._size = 0
        return self._unpacker.feed(data)

    def catch_up(self) -> None:
        """(Nothing waits outside it.)"""

    def giving(self) -> None:
        """(One process: both ends stay.)"""

    def taking(self) -> None:
        """(One process: both ends stay.)"""

    def close(self) -> None:
        with self._ready:
            self._closed = True
            self._ready.notify_all()


def give_way() -> None:
    """Between two things the describer describes: whatever woke meanwhile on its core (the
    forwarding, the programs on either side of it) runs first. A describer that reads in a
    rhythm describes a batch at a time, and the scheduler lets a running task finish a
    slice before a task it has woken takes the core: measured side by side, the bridge's
    added p99 was 3.5x a forwarder's without this (median of 8 runs), 1.7x with it (of 17;
    2.0x with a describer woken at each chunk).

    What wakes for an exchange runs for microseconds; a yield that took longer than
    ``HOGGED`` gave the core to work that does not end (a busy machine), and yielding on
    would leave the describer a sliver of its share, far behind the wire: it stops giving
    way for ``HOGGED_FOR`` seconds, then tries again."""
    global _resume
    now = _clock()
    if now < _resume:
        return
    _yield()
    if _clock() - now > HOGGED:
        _resume = now + HOGGED_FOR


HOGGED = 0.001  # s a yield takes when the core went to work that does not end
HOGGED_FOR = 0.1  # s the describer then describes without giving way
_yield = getattr(os, "sched_yield", lambda: None)
_clock = time.monotonic
_resume = 0.0  # (the describer gives way again from then)

NICE = 10  # the describer's lower priority: measured, the bridge adds a fifth less time at
# the median than at the same priority (the forwarding wakes onto a core it would share);
# what it falls behind by on a busy machine waits beside the pipe (BEHIND)


class Describer:
    """``run(notes, back)`` on the other side: in a forked process where there is
    ``os.fork``, else on a thread. ``notes`` carries what was forwarded to it, ``back`` its
    words to the bridge.

    In the forked process Ctrl-C and SIGTERM are ignored: the bridge's process ends it
    (``END``, ``FINISH``), or the end of ``notes`` does when that process has gone however
    it went, so the describer always gets to say what the traffic left and to write its
    summary. ``interrupt`` (SIGUSR1) raises KeyboardInterrupt there, to give up on a reader
    that does not take its last lines. Forked with ``os.fork`` itself: ``multiprocessing``
    would also join the process at the bridge's exit, for as long as it takes.
    """

    def __init__(self, run: Callable[[Any, Any], None], *, name: str = "describer",
                 fork: bool | None = None, rhythm: float = RHYTHM):
        self.forked = hasattr(os, "fork") if fork is None else fork
        if self.forked:
            self.notes, self.back = Pipe(rhythm), Pipe()
        else:
            self.notes, self.back = LocalPipe(), LocalPipe()
        self._run = run
        self._pid: int | None = None
        self._thread: threading.Thread | None = None
        self.status: int | None = None  # once it has ended: 0, or what went wrong (not 0)
        if not self.forked:
            self._thread = threading.Thread(target=self._on_thread, name=name, daemon=True)

    def start(self) -> None:
        """Start it; fork before the caller has any thread of its own (a thread's locks
        would be copied into the describer as they stood)."""
        if self._thread is not None:
            self._thread.start()
            return
        import sys

        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError, AttributeError):
                pass
        pid = os.fork()
        if pid == 0:  # pragma: no cover - (the describer's process: measured by its tests)
            os._exit(self._in_child())
        self._pid = pid
        self.notes.giving()
        self.back.taking()

    def _in_child(self) -> int:
        import signal
        import sys

        try:
            # (a hang-up reaches both processes: the bridge's ends the run, this one must
            # live to say what the traffic left)
            for name in ("SIGINT", "SIGTERM", "SIGHUP"):
                sig = getattr(signal, name, None)
                if sig is not None:
                    signal.signal(sig, signal.SIG_IGN)
            unwind_on(("SIGUSR1",), interrupted)  # (the bridge's process: "stop now")
            try:
                os.nice(NICE)
            except OSError:
                pass
            self.notes.taking()
            self.back.giving()
            return self._described()
        finally:
            for stream in (sys.stdout, sys.stderr):
                try:
                    stream.flush()
                except (OSError, ValueError, AttributeError):
                    pass

    def _on_thread(self) -> None:
        try:
            failed = self._described()
            if failed:
                self.status = failed  # (else 0, set when it is joined)
        finally:
            self.back.close()

    def _described(self) -> int:
        """``run``, and how it ended: 0, or 1 when it failed (its reader gone, ``| head``:
        quietly, as tmclsh ends then; anything else: logged)."""
        try:
            self._run(self.notes, self.back)
        except KeyboardInterrupt:
            pass
        except BrokenPipeError:
            return 1
        except BaseException:
            logging.getLogger(__name__).exception("describing the bridge's traffic failed")
            return 1
        return 0

    def wait_for(self, kind: str, timeout: float) -> tuple | None:
        """The first word of ``kind`` that comes back within ``timeout`` seconds (None: the
        describer ended or did not say it); words of other kinds are passed over."""
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            got = self.back.take(left)
            if got is None:
                return None
            for event in got:
                if event[0] == kind:
                    return event
        return None

    @property
    def alive(self) -> bool:
        """Whether it still runs (a forked one that was killed has not)."""
        if self._thread is not None:
            return self._thread.is_alive()
        if self._pid is None:
            return False
        try:
            pid, status = os.waitpid(self._pid, os.WNOHANG)
        except ChildProcessError:
            return False
        if pid:
            self._pid, self.status = None, os.waitstatus_to_exitcode(status)
            return False
        return True

    def gone(self, within: float) -> bool:
        """Whether it has ended, or does within ``within`` seconds (a process killed closes
        its pipes a moment before it can be waited for)."""
        deadline = time.monotonic() + within
        while self.alive:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        return True

    def interrupt(self) -> None:
        """Give up on what the describer is waiting for (its reader, in a forked process)."""
        self._signal("SIGUSR1")

    def kill(self) -> None:
        self._signal("SIGKILL")

    def _signal(self, name: str) -> None:
        if self._pid is None:
            return
        import signal

        try:
            os.kill(self._pid, getattr(signal, name))
        except OSError:
            pass

    def join(self, timeout: float) -> bool:
        """Wait for the describer to end; False: it did not within ``timeout``."""
        deadline = time.monotonic() + timeout
        if self._thread is not None:
            self._thread.join(timeout)
            ended = not self._thread.is_alive()
            if ended and self.status is None:
                self.status = 0
        else:
            ended = self._pid is None
            while not ended:
                try:
                    pid, status = os.waitpid(self._pid, os.WNOHANG)
                except ChildProcessError:
                    pid, status = self._pid, 1 << 8
                if pid:
                    self._pid, ended = None, True
                    self.status = os.waitstatus_to_exitcode(status)
                elif time.monotonic() >= deadline:
                    break
                else:
                    time.sleep(0.01)
        if ended:
            self.notes.close()
            self.back.close()
        return ended
