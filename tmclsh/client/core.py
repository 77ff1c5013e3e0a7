"""One module on one transport: send a request, get *its* reply.

TMCL replies carry no sequence number, so the client keeps the link honest itself:

* a reply is taken only if its host address, module address and opcode match the request
  (on CAN: the reply id and the opcode);
* 138 target-reached events (status 128) are collected whenever they arrive (before, during
  or between transactions), never taken for a reply, and handed to listeners once the link is
  released, so a listener may itself send commands;
* bytes that are no frame (line noise, a lost byte) are skipped one at a time until a frame
  with a valid checksum lines up again;
* a request that timed out or got a corrupted reply is remembered as *stale*: its reply may
  still arrive (they are counted, and a late reply that shows up is crossed off). Before a
  request whose reply could be confused with a stale one (same address and opcode, or a reply
  layout that does not name its opcode: 136 type 0, 134) the client sends a 136 as a marker
  and discards everything up to the marker's reply. The module answers in order, so a late
  reply is consumed before it could be taken for a newer one. The marker's own reply must not
  be confusable either: it is a 136 type 1 (a normal frame) unless such a reply may still
  arrive (an earlier marker went unanswered), else a 136 type 0 (the version string); if
  both may, the client first lets the line go quiet. In download mode (132 ... 133) a marker
  would be stored in program memory, so the client only drains the line there, and sends a
  marker once download mode is over;
* before each request, whatever is already waiting on the line is taken in and dropped (an
  event is kept): nothing that arrived before a request can be its answer. A reply that
  arrives when none is outstanding (a duplicate, or the real answer to a request that took
  another reply) marks the line dirty, so the next request resynchronises; unless it is a
  byte-for-byte copy of the reply the last request took (then the value shown was the one
  it carries either way), that last reply is reported as *suspect* (``take_suspects``).
  Bytes that are no frame arriving then count the same (the real answer, damaged); a real
  answer that is lost altogether leaves no trace for any client;
* only idempotent requests are retried on a timeout or corrupted reply (a retried ``MVP REL``
  would move twice); a reply with status 1 (the module saw a bad checksum and executed
  nothing) is retried for every request.

The client owns the only receive path: trace, watch and the debugger subscribe with
``add_tracer`` and ``add_listener``. How frames are read off the wire is the framing's
(tmclsh.link.framing, one per wire shape; tmclsh.link.ascii for the module's ASCII command
line, swapped in by ``ascii_link``); what may still arrive and which answers are in
doubt is the ledger's (ledger.py); bringing a module up, at connect and after a reconnect,
is bringup.py's; TMCL lines as text are text.py's, on top of this.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Container, Iterable, Mapping
from typing import TYPE_CHECKING, TypeVar

from ..base import clock
from ..base.canspec import LINK_DEFAULTS
from ..base.logs import Logger
from ..base.errors import (ChecksumError, DownloadModeError, TmclTimeoutError, TransportError,
                           ValidationError)
from ..link.base import Transport
from ..link.framing import name_of
from ..tmcl import instructions as isa
from ..tmcl.frames import Control, Reply, ReplyKind, Request, Status
from ..tmcl.modules import Module
from ..tmcl.modules import load as load_module
from .ledger import CONFIRM_ROUNDS, Ledger, Suspect
from .motion import MotionRecord, watched_opcodes

if TYPE_CHECKING:
    from ..link.ascii import AsciiFraming
    from ..link.framing import CanFraming, SerialFraming
    from ..tmcl.asm import Encoded, Line

log = Logger(__name__)  # (logging imported when it first logs)

Tracer = Callable[[str, bytes, object], None]
Listener = Callable[[Reply], None]
K = TypeVar("K")

_NORMAL, _VERSION, _MEMORY, _NONE = (ReplyKind.NORMAL, ReplyKind.VERSION_STRING,
                                     ReplyKind.MEMORY, ReplyKind.NONE)
_FIRST_CONTROL = int(Control.STOP_APPLICATION)  # only control commands have other layouts
_LOADED = int(Status.LOADED)
_WRONG_CHECKSUM = int(Status.WRONG_CHECKSUM)
_ALL_OPCODES = frozenset(range(256))  # a sent-only tracer that watches every command
_QUIT_DOWNLOAD = isa.download_command("leave")
_GET_VERSION = int(Control.GET_VERSION)
_MOTION = watched_opcodes()  # what may start or stop a motor (client/motion.py)

__all__ = ["Client", "Suspect", "CONFIRM_ROUNDS", "idempotent", "shared_text"]


def idempotent(req: Request, downloading: bool = False) -> bool:
    """May ``req`` be sent again when its reply got lost? Only what the instruction set says
    may (``idempotent``, not one of its ``once_types``: a retried ``MVP REL`` would move
    twice as far); never while downloading (every frame is stored)."""
    return not downloading and isa.repeatable(req.opcode, req.type)


class Client:
    """One module on one transport. Thread-safe: one transaction at a time.

    ``timeout`` is the reply timeout in seconds (per attempt), ``retries`` how often an
    idempotent request is repeated after a timeout or a corrupted reply.
    """

    def __init__(self, transport: Transport, *, address: int = 1, host_address: int = 2,
                 module: Module | str | None = None, timeout: float = 1.0, retries: int = 2,
                 can_id: int | None = None, reply_id: int | None = None):
        self.transport = transport
        """The link (serial port, CAN bus, simulator); ``transport.simulated`` is true on
        the built-in simulator."""
        self.address = address
        """The module address requests go to (0..255); set it to talk to another module on
        the same bus (the shell's ``.address`` also brings that one up)."""
        self.host_address = host_address
        """The host address replies are sent to (the module's GP 76)."""
        self.timeout = timeout
        """Seconds to wait for each reply (per attempt)."""
        self.retries = retries
        """How often a request that may be repeated is sent again after no or a garbled
        answer."""
        self.can_id = can_id if can_id is not None else LINK_DEFAULTS["can_id"]
        """The CAN id requests go out on (on a CAN link)."""
        self.reply_id = reply_id if reply_id is not None else LINK_DEFAULTS["reply_id"]
        """The CAN id the module's replies come on (on a CAN link)."""
        # CAN ids besides reply_id whose messages are replies too (a bootloader's 0x7FF)
        self._other_reply_ids: frozenset[int] = frozenset()
        self.module: Module | None = load_module(module) if isinstance(module, str) else module
        """The module's data (name, motors, parameters), as 136 named it; None before it
        answered, or in generic mode, numbers only."""
        self.version: str | None = None
        """The version string the module answered to 136 (``1311V111``)."""
        self._downloading = False  # set by tmclsh.ops.program between 132 and 133
        # a 132 was answered that no 133 has ended yet, outside tmclsh.ops.program (a line
        # typed or a script's): close() ends it, so the module is not left storing what it gets
        self._left_downloading = False
        self._ascii_link = None  # (the ascii_link property)
        # while a write moves the module (client/reach.py): its answer may come from the new
        # module address, go to the new host address, or come on the new CAN reply id
        self._also_from: int | None = None
        self._also_host: int | None = None
        self._also_reply_id: int | None = None
        self._lock = threading.RLock()
        self._ledger = Ledger()
        # what tmclsh set each motor doing and has not stopped (motion.py): the leave-checks
        # read it, as a motor that reads speed 0 may still be meant to turn
        self.motion = MotionRecord()
        """What tmclsh told each motor to do and has not stopped (a turning target, a
        position move): a motor whose speed reads 0 may still be meant to turn."""
        self._events: deque[tuple[Reply, float]] = deque()  # with when each arrived
        self._delivering = threading.RLock()  # held while events go to the listeners
        # when the event being delivered arrived (time.monotonic()), for listeners that
        # put a time on it
        self._event_time = 0.0
        # set by reconnect(): before the next command, the module is brought up again as at
        # connect (tmclsh.client.bringup: what answers, its mode, download mode)
        self._bring_up_next = False
        # a request met a link failure (TransportError): the link counts as down, whether or
        # not the transport closed itself, until it is reopened (reconnect, .connect)
        self._down = False
        # set when a 133 may not have been answered: before the next command, download mode
        # is checked (and ended)
        self._check_download = False
        self._judging = False  # an answer that may be a copy is being judged (_judge)
        self._answered_at = 0.0  # when the last answer was taken (time.monotonic())
        # one-line notices about what the client did on its own (ended download mode); the
        # shell points it at its output, else they are logged
        self.on_notice: Callable[[str], None] | None = None
        """Called with each one-line notice of what the client did on its own (the module
        answers at a new address, download mode ended); None: they are logged."""
        self._checks_lost = 0  # line checks in a row that got no good answer (lost_check)
        # called when a request finds the link down, to bring it back before the request
        # goes (a --keep-going script waits for a cable plugged back in); it raises
        # TransportError if the link stays down. None: the request fails at once.
        self._on_link_lost: Callable[[], None] | None = None
        # run by close() while the link is still open (the ASCII link restores the mode the
        # module was found in)
        self._close_hooks: list[Callable[[], None]] = []
        self._listeners: list[Listener] = []
        self._tracers: list[Tracer] = []
        self._sent_tracers: list[Tracer] = []  # add_tracer(sent_only=True)
        # the commands some sent-only tracer asked for (all when one asked for every one): a
        # script's per-line check costs a set lookup, not a call, for the lines none wants
        self._sent_wanted: frozenset[int] = frozenset()
        self._sent_filters: dict[Tracer, frozenset[int]] = {}  # each one's opcodes
        self._poller: threading.Thread | None = None
        self._poller_stop = threading.Event()
        self.stats = {"sent": 0, "timeouts": 0, "checksum_errors": 0, "resyncs": 0,
                      "discarded": 0, "events": 0, "retries": 0, "reconnects": 0,
                      "flushed": 0, "unsolicited": 0, "suspect": 0,
                      "judged": 0}
        """Counters of what happened on the link since it was opened: requests sent,
        timeouts, checksum errors, resynchronisations, retries, events, ..."""
        # the transport's framing, and the one requests go through: the ASCII link's while
        # the module is driven in its ASCII mode (the ascii_link property swaps them)
        self._binary_framing: SerialFraming | CanFraming = transport.framing(self)
        self._framing: SerialFraming | CanFraming | AsciiFraming = self._binary_framing
        self._by_line = False  # the framing is the ASCII link's (set with ascii_link)

    # -- subscriptions ------------------------------------------------------------------
    def add_listener(self, fn: Listener) -> Callable[[], None]:
        """Call ``fn(reply)`` for every unsolicited reply (138 events). Returns an unsubscribe.

        Listeners run after the transaction that received the event has released the link
        (or on the event poller's thread), so they may send commands themselves.
        """
        self._listeners.append(fn)
        return lambda: self._listeners.remove(fn) if fn in self._listeners else None

    def add_tracer(self, fn: Tracer, *, sent_only: bool = False,
                   opcodes: Iterable[int] | None = None) -> Callable[[], None]:
        """Call ``fn(direction, raw, decoded)`` for every frame: "tx", "rx", "drop" or "note".

        Tracers run inside the transaction: they must be quick and must not use the client.
        ``sent_only``: only "tx", each request just before it goes out; a tracer that only
        watches what is sent then leaves the receive path as fast as with no tracer at all.
        ``opcodes`` (with ``sent_only``): only requests of these command numbers are needed,
        so the others skip the call (the tracer may still be told of others: it checks).
        """
        if opcodes is not None and not sent_only:
            raise ValueError("opcodes= filters a sent_only tracer")
        tracers = self._sent_tracers if sent_only else self._tracers
        tracers.append(fn)
        filters = self._sent_filters
        if sent_only:
            filters[fn] = frozenset(opcodes) if opcodes is not None else _ALL_OPCODES
            self._sent_wanted = frozenset().union(*filters.values())

        def remove() -> None:
            if fn in tracers:
                tracers.remove(fn)
                if sent_only and fn not in tracers:
                    del filters[fn]
                    self._sent_wanted = frozenset().union(*filters.values())
        return remove

    # -- what the framing reports (tmclsh.link.framing.Owner) ---------------------------
    def _trace(self, direction: str, raw: bytes, decoded: object, *,
              request: Request | None = None) -> None:
        """Report a frame to the tracers ("tx", "rx", "drop" or "note"). ``request``: the
        request a "tx" line carries (an ASCII line's decoded is its text), for the tracers
        that only watch what is sent (``add_tracer(sent_only=True)`` is told requests)."""
        if direction == "tx" and self._sent_tracers:
            sent = decoded if request is None else request
            if not isinstance(sent, Request) or sent.opcode in self._sent_wanted:
                _tell(self._sent_tracers, "tx", raw, sent)
        if self._tracers:
            _tell(self._tracers, direction, raw, decoded)

    def _tell(self, direction: str, raw: bytes, decoded: object) -> None:
        """Report a frame to the full tracers (the framing's: it tells the sent-only
        tracers of a request itself, before it goes out)."""
        _tell(self._tracers, direction, raw, decoded)

    def _trace_sent(self, raw: bytes, req: Request) -> None:
        _tell(self._sent_tracers, "tx", raw, req)

    def _discard(self, raw: bytes, why: str) -> None:
        self.stats["discarded"] += len(raw)
        if self._tracers:
            _tell(self._tracers, "drop", raw, why)

    def _event(self, raw: bytes, reply: Reply) -> None:
        self.stats["events"] += 1
        if self._tracers:
            _tell(self._tracers, "rx", raw, reply)
        self._events.append((reply, time.monotonic()))
        self.motion.reached(reply.value)  # (138: the motors whose position move ended)

    def _late(self, address: int, opcode: int, reply: Reply | None) -> bool:
        """A reply arrived that no request waits for: True if one like it was expected
        (``Ledger.late``), or the line may carry anything; else it is unsolicited."""
        ledger = self._ledger
        if ledger.late(address, opcode, reply):
            return True
        if ledger.opaque or self._downloading:
            # (no doubt cast, but a reply all the same: a second module answers here too)
            self._second(ledger.doubles.extra(address, reply))
            return True
        self._unsolicited(reply)
        return False

    def _noise_unsolicited(self) -> None:
        """Bytes that were no frame came while nothing was outstanding and nothing was
        expected: a damaged reply, possibly the real answer to the last request."""
        if not self._ledger.dirty(self._downloading) and not self._downloading:
            self._unsolicited(None)

    def _accept_version(self, window: bytes) -> bool:
        """Nine bytes that are no frame: a version string the ledger expects (a stale 136
        type 0's) or one taken lately (a duplicated 136 reply)? Then they are read whole."""
        if window[0] != self.host_address or not all(32 <= b < 127 for b in window[1:9]):
            return False
        raw = bytes(window[:9])
        ledger = self._ledger
        if ledger.late_version():
            self._discard(raw, "stale version string")
            return True
        if ledger.is_version_copy(raw[1:].decode("latin-1")):
            # (a copy is no damaged reply either: the answer may still come, after a
            # module's pause before replying)
            self.stats["unsolicited"] += 1
            ledger.mark_dirty()
            self._discard(raw, "copy of the version string")
            self._second(ledger.doubles.extra_version())
            return True
        if ledger.doubles.asks_version() and not ledger.opaque:
            # another version string right behind the one asked for: a second module
            # answered the same 136 (nothing else sends a host-addressed string)
            self.stats["unsolicited"] += 1
            ledger.mark_dirty()
            self._discard(raw, "a second version string (another module at this address?)")
            self._second(ledger.doubles.extra_version())
            return True
        return False

    def _second(self, found: int | None) -> None:
        """A reply was counted (``ledger.Doubles``): ``found``, the address found shared
        just now (the trace says so where it happened)."""
        if found is not None and self._tracers:
            _tell(self._tracers, "note", b"", shared_text(found))

    @property
    def shared(self) -> frozenset[int]:
        """The addresses two modules were found to answer at (``ledger.Doubles``): every
        request to one reaches both, and which answer is taken is chance."""
        return frozenset(self._ledger.doubles.shared)

    def answered_twice(self, address: int, *, lately: bool = False) -> bool:
        """Did the last answer from ``address`` come twice (``lately``: any of the last
        few)? Not yet a finding (a line may copy a reply): asked again, two modules answer
        twice every time (``shared``)."""
        with self._lock:
            return self._ledger.doubles.seconded(address, lately=lately)

    @property
    def shared_news(self) -> bool:
        """Was an address found shared that ``take_shared`` has not told yet?"""
        return bool(self._ledger.doubles.new)

    def take_shared(self) -> list[int]:
        """The addresses found shared since last asked (each told once: the shell warns)."""
        with self._lock:
            return self._ledger.doubles.take()

    def _unsolicited(self, extra: Reply | None) -> None:
        self.stats["unsolicited"] += 1
        if extra is not None:
            self._second(self._ledger.doubles.extra(extra.module, extra))
        raw = b"" if extra is None else extra.to_can() if self.is_can else extra.to_bytes()
        for suspect in self._ledger.unsolicited(extra, raw):
            self.stats["suspect"] += 1
            if self._tracers:
                _tell(self._tracers, "note", b"", f"the reply to {name_of(suspect.request)} may "
                      "have been another request's: a reply came that nothing was waiting for")

    def _deliver_events(self) -> None:
        # One deliverer at a time (the request's thread or the event poller's), so events
        # reach listeners in the order they came, each with its own event_time. The poller
        # leaves its events to a request's thread that is delivering; a request's thread
        # waits for the poller's turn to end (so the events that came before its reply are
        # out before its result), though never for long: a poller's listener may itself be
        # waiting for the link. A listener that sends a command delivers inline (re-entrant).
        poller = threading.current_thread() is self._poller
        while self._events:
            if not self._delivering.acquire(blocking=not poller, timeout=-1 if poller else 1.0):
                return
            try:
                while True:
                    try:
                        reply, self._event_time = self._events.popleft()
                    except IndexError:
                        break
                    for fn in list(self._listeners):
                        try:
                            fn(reply)
                        except Exception as exc:
                            _failed("a listener", exc)
            finally:
                self._delivering.release()

    # -- properties ---------------------------------------------------------------------
    @property
    def timeout(self) -> float:
        """Seconds to wait for each reply (per attempt). A request/reply link never waits
        forever: a lost reply would hang it."""
        return self._timeout

    @timeout.setter
    def timeout(self, value: float) -> None:
        if not (isinstance(value, (int, float)) and value > 0):
            raise ValueError(f"timeout must be a positive number of seconds, got {value!r}")
        self._timeout = float(value)

    @property
    def mode(self) -> str:
        """How the module is talked to now: ``"binary"`` (TMCL frames) or ``"ascii"`` (its
        ASCII mode), the framing's ``tmclsh.link.modes.LinkMode``, a ``str`` that carries
        what differs between the two (front ends read those facts, not the name)."""
        return self._framing.mode

    @property
    def ascii_link(self):
        """The module's ASCII mode while the client drives it (tmclsh.client.ascii.AsciiLink),
        else None. Setting it swaps the framing: the link's ``framing`` (command lines), or
        back to the transport's, whose leftovers from before are stale."""
        return self._ascii_link

    @ascii_link.setter
    def ascii_link(self, link) -> None:
        with self._lock:
            self._ascii_link = link
            lines = getattr(link, "framing", None)
            if lines is not None:
                self._framing = lines
            elif self._framing is not self._binary_framing:
                self._binary_framing.clear()
                self._framing = self._binary_framing
            # requests go as ASCII command lines (one attribute read on the request path)
            self._by_line = self._framing is not self._binary_framing

    def refusal(self, req: Request) -> str | None:
        """Why ``req`` cannot be sent on the link as it is now (None: it can): the module's
        ASCII mode knows only some commands (the instruction set says which). Asked by an
        operation before it sends the first of several requests, so it sends none."""
        return self._framing.refusal(req)


    @property
    def is_can(self) -> bool:
        """The link is a CAN bus (addresses are CAN ids there)."""
        return self.transport.kind == "can"

    def check(self, line: Line, module: Module | None = None, *,
              as_typed: bool = False) -> Encoded:
        """A parsed line checked as this client would send it (nothing is sent): against
        ``module`` (default: the client's), and against what the link carries (the module's
        ASCII mode accepts only some commands)."""
        from ..tmcl import asm

        mod = module if module is not None else self.require_module()
        return asm.encode(line, mod, direct=True, ascii=self.ascii_link is not None,
                          as_typed=as_typed)

    def cut_by(self, breaks: str | None) -> bool:
        """Whether writing a parameter whose ``breaks`` (module data: any, can, serial,
        ascii) is that may cut the link in use with nothing to follow: a CAN bit rate on
        CAN, the ASCII echo while the module is driven in its ASCII mode. A CAN id written
        over a serial line cuts nothing here."""
        return (breaks == "any" or (breaks == "can" and self.is_can)
                or (breaks == "serial" and not self.is_can)
                or (breaks == "ascii" and self.ascii_link is not None))

    @property
    def judges_as_read(self) -> bool:
        """Are answers judged as they are read, so a reader need not confirm them again
        (``in_doubt``)? On the module's ASCII line: every reading of a setting is read
        twice, the replies are lines in order."""
        return self.ascii_link is not None

    @property
    def connected(self) -> bool:
        """The link is up: open, and no request met a failure of it since it was opened.
        The one answer to "is the link down" (the shell, the stop, a watch ask it)."""
        return self.transport.is_open and not self._down

    @property
    def _replies(self) -> int:
        """Replies returned so far (numbers them: ``Suspect.seq``, ``in_doubt``)."""
        return self._ledger.replies

    @property
    def _suspects(self):
        return self._ledger.suspects

    def describe(self) -> str:
        """Where the module is, in words (``/dev/ttyACM0 @ 9600``, ``SIMULATED TMCM-1311``)."""
        return self.transport.describe()

    def __repr__(self) -> str:
        mod = self.module.name if self.module else "unknown module"
        return f"<Client {mod} at address {self.address} on {self.describe()}>"

    # -- the request path ---------------------------------------------------------------
    def send(self, opcode: int | str, type: int = 0, motor: int = 0, value: int = 0, *,
             timeout: float | None = None) -> Reply | None:
        """Send one raw command and return its reply (None for 137, which has none).

        ``opcode`` is a number or a mnemonic (``send("GAP", 1, 0)``); no module checks are
        made, the status is not checked.
        """
        if isinstance(opcode, str):
            spec = isa.by_mnemonic(opcode)
            if spec is None:
                raise ValidationError(f"unknown mnemonic {opcode!r}")
            opcode = spec.opcode
        return self.request(Request.make(self.address, opcode, type, motor, value),
                            timeout=timeout)

    def request(self, req: Request, *, timeout: float | None = None,
                retries: int | None = None) -> Reply | None:
        """Send ``req`` and return its reply (None when the command has none, i.e. 137).

        ``timeout`` (seconds per attempt) and ``retries`` default to the client's. Raises
        ``TmclTimeoutError``, ``ChecksumError`` (corrupted reply, after retries) or
        ``TransportError`` (link lost). The reply's status is returned, not checked.
        """
        if timeout is None:
            timeout = self._timeout
        elif not (isinstance(timeout, (int, float)) and timeout > 0):
            raise ValueError(f"timeout must be a positive number of seconds, got {timeout!r}")
        if self._on_link_lost is not None and not self.connected:
            self._on_link_lost()
        try:
            with self._lock:
                if (self._bring_up_next or self._check_download) and not self._downloading:
                    self._before_next(req)
                try:
                    if self._by_line:
                        reply = self._line_request(req, timeout)
                    else:
                        reply = self._request(req, timeout,
                                              self.retries if retries is None else retries)
                except TransportError:
                    self._down = True
                    raise
            if req.opcode in _MOTION and reply is not None and not self._downloading:
                self.motion.take(self.module, req, reply.status)
            op = req.opcode
            if op >= _FIRST_CONTROL and reply is not None and (
                    op == _QUIT_DOWNLOAD or op == isa.download_command("enter")) and reply.ok:
                # (a typed 132 with no 133 after it; asked of 132 and 133 alone: an upload's
                # verify sends thousands of 134)
                if op == _QUIT_DOWNLOAD:
                    self._left_downloading = False
                elif not self._downloading:
                    self._left_downloading = True
            if reply is not None and reply.status == _LOADED and not self._downloading:
                raise DownloadModeError(
                    _LOADED, reply,
                    f"the module is in download mode (it stores commands instead of executing "
                    f"them): {name_of(req)} was stored in program memory, not executed; "
                    "the line 133 (quit download mode) ends it")
            return reply
        finally:
            if self._events:
                self._deliver_events()

    def _before_next(self, req: Request) -> None:
        """The first command after a reconnect brings the module up again, exactly as at
        connect (tmclsh.client.bringup); one after a 133 that may have been lost checks
        download mode."""
        from . import bringup

        if self._bring_up_next:
            self._bring_up_next = self._check_download = False
            try:
                refused = bringup.again(self, req)
            except BaseException:
                self._bring_up_next = True
                raise
            if refused is not None:
                raise refused
        else:
            self._check_download = False
            try:
                bringup.leave_download_mode(self)
            except BaseException:
                self._check_download = True
                raise

    def _notice(self, text: str) -> None:
        """Tell the user about something the client did on its own."""
        if self.on_notice is not None:
            self.on_notice(text)
        else:
            log.warning("%s", text)

    def _check_download_next(self) -> None:
        """Download mode may not have ended (a 133 went unanswered, or was interrupted):
        before the next command, ask the module and end it if need be, so that command is
        executed, not stored."""
        self._check_download = True

    def _request(self, req: Request, timeout: float, retries: int) -> Reply | None:
        if not self.transport.is_open:
            raise TransportError(f"{self.transport.describe()} is not connected "
                                 "(the link was closed or lost; reconnect first)")
        kind = _NORMAL if req.opcode < _FIRST_CONTROL else isa.reply_kind(req.opcode, req.type)
        framing = self._framing
        ledger = self._ledger
        attempt = 0
        went = False  # req itself went out, in some attempt
        while True:
            attempt += 1
            sent = False  # a failed resynchronisation sends nothing (its marker is counted)
            try:
                if framing.waiting():
                    self._flush_input()
                synced = False
                if ledger.dirty(self._downloading):
                    if ledger.needs_sync(req, kind, self._downloading):
                        self._resync(req.address, timeout)
                        synced = True
                elif ledger.run and time.monotonic() - self._answered_at >= timeout:
                    # quiet for a whole timeout, nothing expected: an answer displaced
                    # before now would have come (it counts as lost after a timeout)
                    ledger.in_step()
                sent = went = True
                # (the line was found clear just now, unless a resynchronisation ran since)
                reply = framing.exchange(req, kind, timeout, absorb=synced)
            except TmclTimeoutError as exc:
                self.stats["timeouts"] += 1
                failure: Exception = exc
            except ChecksumError as exc:
                self.stats["checksum_errors"] += 1
                failure = exc
            except BaseException:
                # Ctrl-C or a link error mid-transaction: the reply may still be on its way
                if sent:
                    ledger.expect_late(req, kind)
                raise
            else:
                if (reply is not None and reply.status == _WRONG_CHECKSUM
                        and not self._downloading and attempt <= retries):
                    # the module got a damaged frame and executed nothing: safe to send again
                    self.stats["retries"] += 1
                    if self._tracers:
                        _tell(self._tracers, "note", b"",
                              "module saw a bad checksum; sending again")
                    continue
                if reply is None:
                    return None
                copy = ledger.took(req, reply, copy=None, downloading=self._downloading)
                found = ledger.doubles.answered(req, reply)
                if found is not None:
                    self._second(found)
                self._answered_at = time.monotonic()
                if copy and not self._judging:
                    return self._judge(req, reply, timeout, retries)
                return reply
            if sent:
                ledger.expect_late(req, kind)
            # a failed line check sent nothing of ``req``: asking again is safe for any command
            tries = 1 + (retries if not sent or idempotent(req, self._downloading) else 0)
            if attempt >= tries:
                if tries > 1:
                    again = type(failure)(f"{failure} (after {tries} attempts)")
                    again.__cause__ = failure  # (raise ... from failure)
                    failure = again
                # whether the module may have got it (the shell says so of a command it
                # does not repeat by itself: MVP REL, ...)
                failure.sent = went  # type: ignore[attr-defined]
                raise failure
            self.stats["retries"] += 1
            if self._tracers:
                _tell(self._tracers, "note", b"", f"retry {attempt} of {tries - 1}")

    def _line_request(self, req: Request, timeout: float) -> Reply:
        """``req`` as an ASCII command line (the framing is the ASCII link's), its answer
        judged by the one rule (``_judge``) before anyone sees it: an answer that may be a
        copy of the one before, and every reading of a setting (an ASCII reply carries no
        checksum: a digit changed on the line is found out only by a second read)."""
        reply = self._line_once(req, timeout)
        if self._judging:  # (a judge's own exchange)
            return reply
        module = self.module
        if self._framing.copy or (module is not None and module.reads_setting(
                isa.by_opcode(req.opcode), req.type, req.motor)):
            return self._judge(req, reply, timeout, self.retries)
        return reply

    def _line_once(self, req: Request, timeout: float) -> Reply:
        """One answer to ``req`` on the ASCII line, retried on a timeout as the binary path
        retries (only a command the instruction set calls idempotent)."""
        tries = 1 + (self.retries if idempotent(req) else 0)
        last: TmclTimeoutError | None = None
        for attempt in range(tries):
            try:
                return self._framing.exchange(req, _NORMAL, timeout)
            except TmclTimeoutError as exc:
                last = exc
                if attempt + 1 < tries:
                    self._trace("note", b"", f"retry {attempt + 1} of {tries - 1}")
        assert last is not None
        if tries > 1:
            raise TmclTimeoutError(f"{last} (after {tries} attempts)")
        raise last

    def _flush_input(self) -> None:
        """Before a request: what is already waiting cannot be its answer. Take it in
        (events are kept), drop the rest, count it."""
        before = self.stats["discarded"]
        self._framing.absorb(flushing=True)
        self.stats["flushed"] += self.stats["discarded"] - before

    def _resync(self, address: int, timeout: float) -> None:
        """Consume every late reply: drain, then a 136 marker whose reply comes last."""
        ledger = self._ledger
        framing = self._framing
        self.stats["resyncs"] += 1
        if self._tracers:
            _tell(self._tracers, "note", b"",
                  "checking the line with 136 after an earlier failure")
        if self._downloading:
            # a marker would be stored as an instruction: wait for a quiet line instead;
            # stale replies are still dropped by opcode matching. That proves nothing, so a
            # marker follows once download mode is over.
            framing.drain(max(0.2, timeout))
            ledger.forget()
            ledger.drained = True
            return
        framing.absorb()
        # Replies come in the order of their requests, so a marker's own reply comes after
        # every late one: then nothing sent before can still arrive. When both kinds of
        # marker reply may themselves still be on their way (earlier markers went
        # unanswered), one more reply of a marker is taken than earlier ones may come:
        # that last one is then certainly from a marker sent now, after everything stale.
        extra = 0  # markers sent now whose replies may still come (the earlier ones came)
        while True:
            chosen = ledger.marker(address)
            if chosen is None:
                # take in what comes (for at most a timeout) until one has shown up
                end = time.monotonic() + timeout
                while chosen is None and (left := end - time.monotonic()) > 0:
                    if not framing.absorb(left):
                        break
                    chosen = ledger.marker(address)
            marker, kind = chosen or (Request(address, _GET_VERSION, 1, 0, 0), _NORMAL)
            try:
                got = framing.exchange(marker, kind, timeout)
            except (TmclTimeoutError, ChecksumError) as exc:
                ledger.expect_late(marker, kind)
                raise type(exc)(lost_check(self, address, "after a reply that went wrong, its "
                                           "version (136) was asked to be sure which reply "
                                           f"is which, and this failed too: {exc}")) from exc
            except BaseException:
                ledger.expect_late(marker, kind)
                raise
            if chosen is None:
                ledger.late(address, _GET_VERSION, got)  # (an earlier marker's, or this one's)
                extra += 1
                continue
            if got is not None:
                ledger.took_marker(marker, got)
                self._second(ledger.doubles.answered(marker, got))
            self._checks_lost = 0
            ledger.forget()
            for _ in range(extra):  # (crossed off when they come)
                ledger.expect_late(Request(address, _GET_VERSION, 1, 0, 0), _NORMAL)
            return

    def _judge(self, req: Request, reply: Reply, timeout: float, retries: int) -> Reply:
        """``reply`` is byte for byte one taken lately for another request: it may be a copy
        of that reply (a line that repeats replies, late), taken for ``req``'s own answer,
        which then comes behind it. So it is judged before anyone sees it. A reading is
        asked again until two answers agree (``CONFIRM_ROUNDS`` more at most; else the last
        one is returned as a suspect): that also holds when the answer behind the copy was
        lost. Any other command (not sent twice) is followed by a marker, 136, whose reply
        comes after the displaced answer, which then makes this one a suspect.

        On a clean line this costs one exchange where two requests of one command in a row
        get the same answer (two parameters holding 0), and only there; nothing cheaper is
        sure: a copy whose own answer was lost leaves nothing else to see, and waiting for
        the line to go quiet takes longer than the exchange.

        On the module's ASCII line the same rule holds, through the ASCII link's exchanges
        (``_line_once``, ``AsciiFraming.mark``); there every reading of a setting is judged,
        copy or not: an ASCII reply has no checksum, and a digit changed on the line is
        found out only by a second read that disagrees."""
        ledger = self._ledger
        by_line = self._by_line
        first = ledger.replies
        self.stats["judged"] += 1
        self._judging = True
        try:
            if not isa.reading(req.opcode, req.type):
                marker = Request(req.address, _GET_VERSION, 1, 0, 0)
                noise = self.stats["discarded"]
                if by_line:
                    got = self._framing.mark(timeout)
                else:
                    try:
                        got = self._framing.exchange(marker, _NORMAL, timeout)
                    except (TmclTimeoutError, ChecksumError):
                        ledger.expect_late(marker, _NORMAL)
                        got = None
                    else:
                        if got is not None:
                            ledger.took_marker(marker, got)
                            self._second(ledger.doubles.answered(marker, got))
                # not judged (no answer to the marker), or bytes that were no frame came
                # before it (the displaced answer, damaged?): in doubt, unless found already
                if (got is None or self.stats["discarded"] > noise) and not any(
                        s.seq == first for s in ledger.suspects):
                    ledger.doubt(req, reply, first)
                return reply
            for _ in range(CONFIRM_ROUNDS):
                found = ledger.found
                again = (self._line_once(req, timeout) if by_line
                         else self._request(req, timeout, retries))
                if again is None:
                    break
                if (again == reply and ledger.found == found
                        and not ledger.took_a_copy()):
                    # two answers agree, nothing that came meanwhile speaks against them (a
                    # line that brings the same copy first every time would agree with
                    # itself), and the second may not be a copy itself (on the ASCII line, of
                    # a line check's answer: two such copies agree with each other): the
                    # doubts cast on this request's answers are met
                    ledger.clear_suspects(first, ledger.replies)
                    ledger.in_step()
                    return again
                reply = again
            ledger.clear_suspects(first, ledger.replies)
            ledger.doubt(req, reply, ledger.replies)
            return reply
        finally:
            self._judging = False

    # -- answers in doubt ---------------------------------------------------------------
    def _last_may_be_a_copy(self) -> bool:
        """Whether the last reply taken could be a late copy of the one before it."""
        with self._lock:
            return self._ledger.last_may_be_a_copy()

    def _suspect_seqs(self) -> set[int]:
        """The ``seq`` of every suspect not yet taken (``take_suspects`` still reports them)."""
        with self._lock:  # (the event poller may add one meanwhile)
            return self._ledger.suspect_seqs()

    def _take_suspects(self, seqs: Container[int] | None = None) -> list[Suspect]:
        """Replies returned earlier that may have answered another request (oldest first);
        each is reported once. ``seqs``: only those (a caller that read again, or marked the
        values in doubt itself, takes its own; the rest stay to be reported)."""
        with self._lock:  # (the event poller may add one meanwhile)
            return self._ledger.take_suspects(seqs)

    def doubt_on_last(self, *, take: bool = True) -> bool:
        """Was the answer just returned left in doubt (its judge could not settle it, or a
        reply that came while it was judged spoke against it)? ``take``: it is said with the
        answer by whoever shows it, so it is not reported again (``take_suspects``)."""
        ledger = self._ledger
        if not ledger.suspects:  # (the common case, without the lock: a script's every line)
            return False
        with self._lock:
            seq = ledger.replies
            if ledger.suspects and ledger.suspects[-1].seq == seq:
                if take:
                    ledger.take_suspects((seq,))
                return True
            return False

    def in_doubt(self, answered: Mapping[int, K], *, confirm: bool = True) -> set[K]:
        """The one check of answers in doubt: of the reads ``answered`` (``replies`` right
        after each -> what the reader calls it), those whose answer may have been another
        request's. A late copy of the reply before it, taken for it, is found out when the
        real answer comes while nothing waits for it; ``confirm`` gives it that chance:
        what waits is taken in, and one more exchange made (136 type 1) when the last answer
        may be such a copy (the module answers in order). Readers read those again
        (``CONFIRM_ROUNDS`` times at most) or say they are in doubt, then ``settle`` them.
        In ASCII mode what waits is taken in (AsciiFraming.absorb); its readings of settings
        were judged as they were read."""
        if not answered:
            return set()
        if confirm and self._by_line:
            with self._lock:
                self._framing.absorb()
        elif confirm:
            self.poll()  # what waits already is taken in (nothing is sent, nothing awaited)
            # the exchange only if the last answer may be the reply before it, taken again;
            # not on the simulator in process (whatever follows an answer waits already)
            if not self.transport.simulated and self._last_may_be_a_copy():
                try:
                    self.request(Request(self.address, _GET_VERSION, 1, 0, 0))
                except (TmclTimeoutError, ChecksumError, DownloadModeError):
                    pass  # what it could find is found by the next request's flush as well
        found = self._suspect_seqs()
        return {key for seq, key in answered.items() if seq in found}

    def _settle(self, answered: Mapping[int, object]) -> None:
        """The suspects among ``answered`` were dealt with by their reader (read again, or
        said to be in doubt): they are not reported again."""
        if answered:
            self._take_suspects(answered.keys())

    # -- events while idle --------------------------------------------------------------
    def poll(self) -> None:
        """Deliver pending unsolicited replies without waiting (never blocks a transaction)."""
        if not self._lock.acquire(blocking=False):
            return
        try:
            if not self._by_line and self.transport.is_open and self._framing.waiting():
                self._framing.absorb()
        except TransportError:
            self._down = True  # found here as a request would have found it
            raise
        finally:
            self._lock.release()
            if self._events:
                self._deliver_events()

    def _confirm_last(self) -> None:
        """At the end of a run: was the last reply the answer to its request? A late copy of
        the reply before it (same address and command) would have been taken for it; its
        real answer then comes right behind, when nothing waits for it, and makes the last
        reply a suspect (``take_suspects``). So the line is watched until it has been quiet
        for two frames' wire time (nothing is sent); otherwise, or on the simulator, what is
        already waiting is taken in."""
        with self._lock:
            if not self.transport.is_open:
                return
            if self._by_line:
                self._framing.absorb(watch=True)
                return
            ledger = self._ledger
            quiet = self._framing.quiet_time()
            if not ledger.last_may_be_a_copy() or ledger.confirmed == ledger.replies:
                quiet = 0.0  # (this reply was watched for already)
            end = time.monotonic() + max(0.5, 10 * quiet)
            while self._framing.absorb(quiet) and quiet and time.monotonic() < end:
                pass
            ledger.confirmed = ledger.replies
        if self._events:
            self._deliver_events()

    def start_event_poller(self, interval: float = 0.05) -> None:
        """Deliver 138 events while no command is running, from a background thread."""
        if self._poller is not None:
            return
        # each poller its own stop: one that outlived stop_event_poller's wait (a listener
        # that blocked) still ends, instead of running on beside the next one
        stop = self._poller_stop = threading.Event()

        def run() -> None:
            while not stop.wait(interval):
                try:
                    self.poll()
                except TransportError:
                    pass  # the next command reports the lost link
                except Exception as exc:
                    _failed("looking for events", exc)

        self._poller = threading.Thread(target=run, name="tmclsh-events", daemon=True)
        self._poller.start()

    def stop_event_poller(self) -> None:
        """Stop delivering events in the background (``start_event_poller``)."""
        self._poller_stop.set()
        if self._poller is not None:
            self._poller.join(1)
            self._poller = None

    # -- the module ---------------------------------------------------------------------
    def require_module(self) -> Module:
        """The module's data, asked for (136) if not known yet."""
        if self.module is None:
            self.identify()
        assert self.module is not None
        return self.module

    def identify(self) -> Module:
        """Ask the module what it is (136) and take its data (bringup.identify)."""
        from .bringup import identify

        return identify(self)

    def _leave_download_mode(self) -> bool:
        """End download mode if the module is in it (bringup.leave_download_mode)."""
        from .bringup import leave_download_mode

        return leave_download_mode(self)

    def wait_until(self, predicate: Callable[[], bool], timeout: float | None,
                   interval: float = 0.05) -> None:
        """Call ``predicate`` every ``interval`` s until it is true; TmclTimeoutError after
        ``timeout`` s (None: wait forever)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not predicate():
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                raise TmclTimeoutError(f"condition not met within {timeout:g} s")
            # a long interval never sleeps past the deadline
            clock.sleep(interval if deadline is None else min(interval, deadline - now))

    # -- the link -----------------------------------------------------------------------
    def reconnect(self, wait: float = 0.0, *, bring_up: bool = True) -> None:
        """Close and reopen the transport (after the port was lost, e.g. USB unplugged).

        ``wait``: keep trying for that many seconds while the port is not back yet. Raises
        ``TransportError`` if it cannot be opened. Before the next command the module is
        brought up again as at connect (tmclsh.client.bringup): what answers now (another
        module type is taken, with a notice), in which mode, whether in download mode;
        unless ``bring_up`` is false (a firmware update, which expects the module to have
        restarted into its bootloader and asks it itself).
        """
        with self._lock:
            self._reopen(wait)
            self._bring_up_next = bring_up
            self.stats["reconnects"] += 1
            if self._tracers:
                _tell(self._tracers, "note", b"", f"reconnected to {self.describe()}")

    def _reopen(self, wait: float = 0.0) -> None:
        self.transport.close()
        deadline = time.monotonic() + wait
        while True:
            try:
                self.transport.open()
                break
            except TransportError:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(min(0.1, max(0.0, deadline - time.monotonic())))
        self._down = False
        # (a module driven in ASCII mode is found again in whichever mode it is in now:
        # bringup.again)
        self._framing = self._binary_framing = self.transport.framing(self)
        self._by_line = False
        self._ledger.reset()  # (an answer still to come may come on the new link too)

    def _lost_check(self, address: int, why: str) -> str:
        """``lost_check`` for the framings (the ASCII link's line check)."""
        return lost_check(self, address, why)

    @property
    def bring_up_pending(self) -> bool:
        """The link came back but the module has not been brought up since (it did not
        answer yet): the next exchange waits for its bring-up first."""
        return self._bring_up_next

    @property
    def lock(self):
        """Held for every exchange on the line; a peer that talks past ``request`` takes it."""
        return self._lock

    @property
    def _tracing(self) -> bool:
        return bool(self._tracers or self._sent_tracers)

    def _absorb(self) -> None:
        """Take in what is pending on the line (the framing's rules): events are kept, all
        else is stale; a reply among it is a late one."""
        with self._lock:
            self._framing.absorb()

    def _clear_input(self) -> None:
        """Forget bytes buffered for the binary framing (the line was in another mode)."""
        with self._lock:
            self._framing.clear()

    def _forget_stale(self) -> None:
        """The line was reset (its baud rate changed): nothing sent before can still arrive."""
        with self._lock:
            self._framing.clear()
            self._ledger.forget()

    def _resync_next(self) -> None:
        """Something else used the line (the module's ASCII mode): whatever is left on it is
        stale, so the next binary request starts with the resynchronisation marker."""
        with self._lock:
            self._framing.clear()
            self._ledger.mark_dirty()

    def close(self) -> None:
        """Stop the event poller, run the close hooks, leave ASCII mode if entered, close the
        transport. Safe to call more than once."""
        self.stop_event_poller()
        with self._lock:
            self._leave_link()
            self.transport.close()

    def _leave_link(self) -> None:
        """Run the close hooks, leave ASCII mode if entered: the module is left as it was
        found, while the link is still open."""
        hooks, self._close_hooks = self._close_hooks, []
        for hook in hooks:
            try:
                hook()
            except Exception as exc:
                _failed("closing", exc)
        if self._left_downloading and self.transport.is_open:
            self._end_left_download()
        if self.ascii_link is not None:
            try:
                self.ascii_link.close()
            except Exception as exc:
                _failed("leaving ASCII mode", exc)

    def _end_left_download(self) -> None:
        """133 for a 132 that was sent and never ended (by a line, not an upload)."""
        self._left_downloading = False
        self._downloading = True  # (what 133 gets while the module stores commands)
        try:
            reply = self.request(Request(self.address, _QUIT_DOWNLOAD, 0, 0, 0))
        except Exception as exc:
            _failed("ending download mode (133)", exc)
            return
        finally:
            self._downloading = False
        if reply is not None and reply.ok:
            self._notice(f"the module at address {self.address} was still in download mode "
                        "(a 132 line with no 133 after it): ended it with 133; what was sent "
                        "after the 132 is stored as its program")
        else:
            self._notice(f"the module at address {self.address} is in download mode (a 132 "
                        "line) and did not leave it for 133 "
                        f"(status {reply.status if reply is not None else 'none'})")

    def _switch_transport(self, transport: Transport, module: Module | str | None = None) -> None:
        """Go on on another link (the shell's ``.connect``): the old one is left as ``close``
        leaves it (the close hooks run, the module is left in the mode it was found in, the
        port is closed); nothing of it is carried over. The new link starts in binary mode
        with ``module`` (None: not known yet); listeners, tracers and the event poller stay.
        Bring the module up with ``bringup.bring_up`` (136, download mode, ASCII mode)."""
        mod = load_module(module) if isinstance(module, str) else module
        with self._lock:
            self._leave_link()
            try:
                self.transport.close()
            except Exception:  # the old link may already be gone; that is why we switch
                pass
            self.ascii_link = None
            self.transport = transport
            self.module = mod
            self.version = None
            self.motion.forget()  # (another module, or one that was told nothing yet)
            self._reopen()  # clears buffers and stale-reply bookkeeping, reopens the link
            self._bring_up_next = self._check_download = False  # (what bring_up does)
            self.stats["reconnects"] += 1
            if self._tracers:
                _tell(self._tracers, "note", b"", f"reconnected to {self.describe()}")

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def shared_text(address: int) -> str:
    """What a shared address means, in words for users (the one wording)."""
    return (f"two modules answer at address {address}: every reply came twice, so every "
            "command reaches both and which answer is shown is chance; give one of them "
            "another address while the other is disconnected")


def lost_check(client: Client, address: int, why: str) -> str:
    """The words for a line check (after a failure) that got no good answer: the first is a
    lost reply, as a line that loses one now and then does; only a second in a row, with
    no good answer between, is a module that stopped answering."""
    client._checks_lost += 1
    if client._checks_lost == 1:
        return (f"a reply from address {address} was lost ({why}); the next command checks "
                "the line again")
    return f"address {address} stopped answering: {why}"


def _tell(tracers: list[Tracer], direction: str, raw: bytes, decoded: object) -> None:
    for fn in list(tracers):
        try:
            fn(direction, raw, decoded)
        except Exception as exc:  # a broken tracer must not break the link
            _failed("a tracer", exc)


def _failed(what: str, exc: Exception) -> None:
    """Something the client runs on the side failed: one line (with no logging set up,
    Python would print a logged exception's traceback to the user); the traceback is
    logged at debug level for whoever set logging up."""
    log.warning("%s failed: %s", what, exc)
    log.debug("%s failed", what, exc_info=exc)
