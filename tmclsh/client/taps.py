"""What the client tells those who watch it: frames to tracers, 138 events to listeners, and
notices of what it did on its own.

The client owns the only receive path (nothing else reads the transport), so whoever wants
to see the line subscribes here instead: the trace, a watch, the debugger, ``scan``, the
bridge. Kept apart from the request path so that the path stays a few attribute reads when
no one watches: the client holds the same lists this component fills (``_tracers``,
``_sent_tracers``) and the flags a framing asks before it builds a trace's words
(``_sent_wanted``, ``_tracing``), so the framings and the request path read them as plain
attributes of the client, never through this object.

Events are collected while a transaction holds the link and handed to the listeners once it
is released (or from the event poller's thread while the link is idle), so a listener may
itself send commands.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

from ..base.errors import TransportError
from ..base.logs import Logger
from ..tmcl.frames import Reply, Request

if TYPE_CHECKING:
    from .core import Client

log = Logger(__name__)  # (logging imported when it first logs)

Tracer = Callable[[str, bytes, object], None]
Listener = Callable[[Reply], None]

_ALL_OPCODES = frozenset(range(256))  # a sent-only tracer that watches every command


class Taps:
    """The client's observers: tracers, listeners, the event queue and its poller."""

    def __init__(self, client: Client):
        self._client = client
        self._stats = client.stats
        self.listeners: list[Listener] = []
        self.tracers: list[Tracer] = []
        self.sent_tracers: list[Tracer] = []  # add_tracer(sent_only=True)
        self._sent_filters: dict[Tracer, frozenset[int]] = {}  # each one's opcodes
        self.events: deque[tuple[Reply, float]] = deque()  # with when each arrived
        self._delivering = threading.RLock()  # held while events go to the listeners
        # when the event being delivered arrived (time.monotonic()), for listeners that
        # put a time on it
        self.event_time = 0.0
        self._poller: threading.Thread | None = None
        self._poller_stop = threading.Event()
        self._flags()

    def _flags(self) -> None:
        """Write what the framings ask of the client on every request: which commands some
        sent-only tracer wants (all when one asked for every one: a script's per-line check
        costs a set lookup, not a call, for the lines none wants), and whether anyone traces
        at all. Replaced whole, never changed in place: a request reading them meanwhile
        sees the old set or the new one."""
        c = self._client
        c._sent_wanted = frozenset().union(*self._sent_filters.values())
        c._tracing = bool(self.tracers or self.sent_tracers)

    # -- subscriptions ------------------------------------------------------------------
    def add_listener(self, fn: Listener) -> Callable[[], None]:
        """``Client.add_listener``."""
        listeners = self.listeners
        listeners.append(fn)
        return lambda: listeners.remove(fn) if fn in listeners else None

    def add_tracer(self, fn: Tracer, *, sent_only: bool = False,
                   opcodes: Iterable[int] | None = None) -> Callable[[], None]:
        """``Client.add_tracer``."""
        if opcodes is not None and not sent_only:
            raise ValueError("opcodes= filters a sent_only tracer")
        tracers = self.sent_tracers if sent_only else self.tracers
        tracers.append(fn)
        filters = self._sent_filters
        if sent_only:
            filters[fn] = frozenset(opcodes) if opcodes is not None else _ALL_OPCODES
        self._flags()

        def remove() -> None:
            if fn in tracers:
                tracers.remove(fn)
                if sent_only and fn not in tracers:
                    del filters[fn]
                self._flags()
        return remove

    # -- what the framing reports (tmclsh.link.framing.Owner, through the client) -------
    def trace(self, direction: str, raw: bytes, decoded: object, *,
              request: Request | None = None) -> None:
        """Report a frame to the tracers ("tx", "rx", "drop" or "note"). ``request``: the
        request a "tx" line carries (an ASCII line's decoded is its text), for the tracers
        that only watch what is sent (``add_tracer(sent_only=True)`` is told requests)."""
        if direction == "tx" and self.sent_tracers:
            sent = decoded if request is None else request
            if not isinstance(sent, Request) or sent.opcode in self._client._sent_wanted:
                tell(self.sent_tracers, "tx", raw, sent)
        if self.tracers:
            tell(self.tracers, direction, raw, decoded)

    def tell(self, direction: str, raw: bytes, decoded: object) -> None:
        """Report a frame to the full tracers (the framing's: it tells the sent-only
        tracers of a request itself, before it goes out)."""
        tell(self.tracers, direction, raw, decoded)

    def trace_sent(self, raw: bytes, req: Request) -> None:
        tell(self.sent_tracers, "tx", raw, req)

    def note(self, text: str) -> None:
        """A line of the trace about what the client did (a retry, a reconnect)."""
        if self.tracers:
            tell(self.tracers, "note", b"", text)

    def discard(self, raw: bytes, why: str) -> None:
        self._stats["discarded"] += len(raw)
        if self.tracers:
            tell(self.tracers, "drop", raw, why)

    def event(self, raw: bytes, reply: Reply) -> None:
        self._stats["events"] += 1
        if self.tracers:
            tell(self.tracers, "rx", raw, reply)
        self.events.append((reply, time.monotonic()))
        self._client.motion.reached(reply.value)  # (138: the motors whose position move ended)

    def notice(self, text: str) -> None:
        """Tell the user about something the client did on its own (``Client.on_notice``;
        with none set, it is logged)."""
        on_notice = self._client.on_notice
        if on_notice is not None:
            on_notice(text)
        else:
            log.warning("%s", text)

    # -- events to the listeners --------------------------------------------------------
    def deliver(self) -> None:
        # One deliverer at a time (the request's thread or the event poller's), so events
        # reach listeners in the order they came, each with its own event_time. The poller
        # leaves its events to a request's thread that is delivering; a request's thread
        # waits for the poller's turn to end (so the events that came before its reply are
        # out before its result), though never for long: a poller's listener may itself be
        # waiting for the link. A listener that sends a command delivers inline (re-entrant).
        poller = threading.current_thread() is self._poller
        events = self.events
        while events:
            if not self._delivering.acquire(blocking=not poller, timeout=-1 if poller else 1.0):
                return
            try:
                while True:
                    try:
                        reply, self.event_time = events.popleft()
                    except IndexError:
                        break
                    for fn in list(self.listeners):
                        try:
                            fn(reply)
                        except Exception as exc:
                            failed("a listener", exc)
            finally:
                self._delivering.release()

    def poll(self) -> None:
        """``Client.poll``: what waits on the line is taken in only when no transaction holds
        it (a transaction takes in what comes meanwhile itself)."""
        c = self._client
        lock = c._lock
        if not lock.acquire(blocking=False):
            return
        try:
            if not c._by_line and c.transport.is_open and c._framing.waiting():
                c._framing.absorb()
        except TransportError:
            c._down = True  # found here as a request would have found it
            raise
        finally:
            lock.release()
            if self.events:
                self.deliver()

    def start_poller(self, interval: float = 0.05) -> None:
        """``Client.start_event_poller``."""
        if self._poller is not None:
            return
        # each poller its own stop: one that outlived stop_poller's wait (a listener that
        # blocked) still ends, instead of running on beside the next one
        stop = self._poller_stop = threading.Event()
        poll = self._client.poll

        def run() -> None:
            while not stop.wait(interval):
                try:
                    poll()
                except TransportError:
                    pass  # the next command reports the lost link
                except Exception as exc:
                    failed("looking for events", exc)

        self._poller = threading.Thread(target=run, name="tmclsh-events", daemon=True)
        self._poller.start()

    def stop_poller(self) -> None:
        """``Client.stop_event_poller``."""
        self._poller_stop.set()
        if self._poller is not None:
            self._poller.join(1)
            self._poller = None


def tell(tracers: list[Tracer], direction: str, raw: bytes, decoded: object) -> None:
    """Each tracer told of a frame; one that fails is logged, never stops the link."""
    for fn in list(tracers):
        try:
            fn(direction, raw, decoded)
        except Exception as exc:  # a broken tracer must not break the link
            failed("a tracer", exc)


def failed(what: str, exc: Exception) -> None:
    """Something the client runs on the side failed: one line (with no logging set up,
    Python would print a logged exception's traceback to the user); the traceback is
    logged at debug level for whoever set logging up."""
    log.warning("%s failed: %s", what, exc)
    log.debug("%s failed", what, exc_info=exc)
