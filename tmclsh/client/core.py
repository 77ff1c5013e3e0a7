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
``add_tracer`` and ``add_listener``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Container, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

from ..tmcl import instructions as isa
from ..base.errors import (ChecksumError, DownloadModeError, StatusError, TmclTimeoutError, TransportError, ValidationError)
from ..tmcl.modules import Module, from_version_string, generic_for
from ..tmcl.modules import load as load_module
from ..tmcl.frames import (SERIAL_FRAME_LEN, VERSION_STRING_LEN, Control, Reply, ReplyKind, Request, Status, status_ok)
from ..link.base import CanTransport, StreamTransport, Transport

if TYPE_CHECKING:  # the assembler is imported when a line is first encoded
    from ..tmcl import asm

log = logging.getLogger(__name__)

Tracer = Callable[[str, bytes, object], None]
Listener = Callable[[Reply], None]

Op = isa.Opcode
_NORMAL, _VERSION, _MEMORY, _NONE = (ReplyKind.NORMAL, ReplyKind.VERSION_STRING,
                                     ReplyKind.MEMORY, ReplyKind.NONE)
_FRAME = SERIAL_FRAME_LEN
_FIRST_CONTROL = int(Control.STOP_APPLICATION)  # only control commands have other layouts
_EVENT, _OK = int(Status.EVENT), int(Status.OK)
_TARGET_REACHED = int(Control.TARGET_REACHED_EVENT)
_STATUSES = frozenset(int(s) for s in Status)
_REPLY_STATUSES = _STATUSES - {_EVENT}
_CAN_REPLY_LEN = 7
# After bytes that were no frame, how long a silent line is given to bring the rest of the
# reply before the client calls it corrupted (instead of waiting out the whole timeout).
_QUIET_AFTER_GARBAGE = 0.05
ENCODE_CACHE = 512  # checked lines kept per client (prepare)
# Download mode cannot use a marker: wait until the line has been quiet this long.
_DRAIN_QUIET = 0.03
_LOADED = int(Status.LOADED)
_WRONG_CHECKSUM = int(Status.WRONG_CHECKSUM)
_SEEN_REPLIES = 512  # distinct reply frames kept as Reply objects
_ALL_OPCODES = frozenset(range(256))  # a sent-only tracer that watches every command
# GP 129 "download mode" (all three manuals): read to find out whether the module executes
# commands; in download mode the read itself is stored (answered with status 101) instead
_GP_DOWNLOAD_MODE = 129
_START_DOWNLOAD = int(Control.START_DOWNLOAD)
_QUIT_DOWNLOAD = int(Control.QUIT_DOWNLOAD)

# Commands a retry may repeat without changing the outcome. Anything else (CALC, SAC, the
# user functions, CCO (it captures a position that moves on), run/step/download, raw numbers
# we do not know) is sent at most once.
_IDEMPOTENT = frozenset({
    Op.ROR, Op.ROL, Op.MST, Op.MVP, Op.SAP, Op.GAP, Op.STAP, Op.RSAP, Op.SGP, Op.GGP,
    Op.STGP, Op.RSGP, Op.RFS, Op.SIO, Op.GIO, Op.SCO, Op.GCO, Op.AAP, Op.AGP, Op.ACO,
    Op.CLE, Control.STOP_APPLICATION, Control.RESET_APPLICATION, Control.READ_MEMORY,
    Control.GET_STATUS, Control.GET_VERSION})
_MVP_REL = isa.by_mnemonic("MVP").types["REL"]  # type: ignore[union-attr]
_RFS_START = isa.by_mnemonic("RFS").types["START"]  # type: ignore[union-attr]


def idempotent(req: Request, downloading: bool = False) -> bool:
    """May ``req`` be sent again when its reply got lost? Never while downloading (every frame
    is stored), never for a relative move or a restarted reference search."""
    if downloading:
        return False
    op = req.opcode
    if op == Op.MVP:
        return req.type != _MVP_REL
    if op == Op.RFS:
        return req.type != _RFS_START
    return op in _IDEMPOTENT


@dataclass(frozen=True)
class Suspect:
    """A reply already returned that may have been another request's: a reply arrived later
    that no request was waiting for. ``seq`` is ``Client.replies`` when it was returned."""

    request: Request
    reply: Reply
    seq: int
    extra: bytes  # the reply that came when none was outstanding (b"": damaged bytes)


class Result(NamedTuple):
    """A typed line and what the module answered (reply is None for 137). A named tuple: a
    script makes one a line, and a frozen dataclass costs several times as much to make."""

    line: str
    encoded: asm.Encoded
    reply: Reply | None

    @property
    def request(self):
        return self.encoded.instruction

    @property
    def ok(self) -> bool:
        return self.reply is None or self.reply.ok

    @property
    def value(self) -> int | None:
        return None if self.reply is None else self.reply.value


# what the stream matcher did with the frame at the head of the buffer
_SKIPPED = object()  # a whole frame consumed: an event, a stale reply, another host's reply
_GARBAGE = object()  # one byte dropped: no frame starts here


class Client:
    """One module on one transport. Thread-safe: one transaction at a time.

    ``timeout`` is the reply timeout in seconds (per attempt), ``retries`` how often an
    idempotent request is repeated after a timeout or a corrupted reply.
    """

    def __init__(self, transport: Transport, *, address: int = 1, host_address: int = 2,
                 module: Module | str | None = None, timeout: float = 1.0, retries: int = 2,
                 can_id: int | None = None, reply_id: int | None = None):
        self.transport = transport
        self.address = address
        self.host_address = host_address
        self.timeout = timeout
        self.retries = retries
        self.can_id = can_id if can_id is not None else 1
        self.reply_id = reply_id if reply_id is not None else 2
        self.module: Module | None = load_module(module) if isinstance(module, str) else module
        self.version: str | None = None
        self.downloading = False  # set by tmclsh.ops.program between 132 and 133
        # a 132 was answered that no 133 has ended yet, outside tmclsh.ops.program (a line typed
        # or a script's): close() ends it, so the module is not left storing what it gets
        self.left_downloading = False
        self.ascii_link = None  # set by tmclsh.client.ascii when the module is driven in ASCII mode
        self._lock = threading.RLock()
        self._buf = bytearray()
        # how many normal-layout replies may still arrive, by (address, opcode);
        # _stale_versions: 136 type 0 version strings that may; _stale_opaque: a reply that
        # could look like anything (134) may, or something else used the line;
        # _drained: download mode only drained the line (no marker): send one after it
        self._stale: Counter[tuple[int, int]] = Counter()
        self._stale_versions = 0
        self._stale_opaque = False
        self._drained = False
        self._flushing = False  # _absorb runs for _flush_input (for the trace's words)
        self._noise = False  # _absorb met bytes that were no frame
        # bytes waiting on a byte stream (None on CAN: there every request takes in what is
        # queued, a non-blocking receive)
        self._bound: Transport | None = None
        self._pending: Callable[[], int] | None = None
        self._bind(transport)
        self._events: deque[tuple[Reply, float]] = deque()  # with when each arrived
        self._delivering = threading.RLock()  # held while events go to the listeners
        # when the event being delivered arrived (time.monotonic()), for listeners that
        # put a time on it
        self.event_time = 0.0
        # the last reply returned (its request, reply, raw bytes): what a reply that comes
        # when none is outstanding may have displaced
        self.replies = 0  # replies returned so far (Suspect.seq numbers them)
        self._last: tuple[Request, Reply] | None = None
        self._recent: deque[Reply] = deque(maxlen=4)  # replies taken lately, markers too
        self._seen_replies: dict[bytes, Reply] = {}  # frame -> Reply, see _exchange_stream
        # replies returned earlier that may have answered another request (take_suspects
        # empties it; a runner asks whether it is empty after every line)
        self.suspects: deque[Suspect] = deque(maxlen=64)
        # set by reconnect(): before the next command, check the module is not in download
        # mode (a link lost mid-upload leaves it there)
        self._check_download = False
        # set by reconnect() too: with that check, ask 136 (another module may have been
        # plugged into the same port meanwhile)
        self._check_module = False
        self._confirmed = -1  # Client.replies when confirm_last last watched the line
        # one-line notices about what the client did on its own (ended download mode); the
        # shell points it at its output, else they are logged
        self.on_notice: Callable[[str], None] | None = None
        # checked lines: line -> (Encoded, Request), for (module, binary mode); see prepare()
        self._encoded: dict[str, tuple[asm.Encoded, Request]] = {}
        self._encoded_for: tuple[Module | None, bool] = (None, False)
        # run by close() while the link is still open (the ASCII link restores the mode the
        # module was found in)
        self.close_hooks: list[Callable[[], None]] = []
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
                      "flushed": 0, "unsolicited": 0, "suspect": 0}

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

    def _trace(self, direction: str, raw: bytes, decoded: object) -> None:
        _tell(self._tracers, direction, raw, decoded)

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
                        reply, self.event_time = self._events.popleft()
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
        return "ascii" if self.ascii_link is not None else "binary"

    @property
    def is_can(self) -> bool:
        return isinstance(self.transport, CanTransport)

    @property
    def connected(self) -> bool:
        return self.transport.is_open

    def describe(self) -> str:
        return self.transport.describe()

    def __repr__(self) -> str:
        mod = self.module.name if self.module else "unknown module"
        return f"<Client {mod} at address {self.address} on {self.describe()}>"

    # -- the request path ---------------------------------------------------------------
    def send(self, opcode: int | str, type: int = 0, motor: int = 0, value: int = 0, *,
             timeout: float | None = None) -> Reply | None:
        """Send one raw command and return its reply (None for 137, which has none).

        ``opcode`` is a number or a mnemonic (``send("GAP", 1, 0)``); no module checks are
        made, the status is not checked (see :meth:`execute` for both).
        """
        if isinstance(opcode, str):
            spec = isa.by_mnemonic(opcode)
            if spec is None:
                raise ValidationError(f"unknown mnemonic {opcode!r}")
            opcode = spec.opcode
        return self.request(Request.make(self.address, opcode, type, motor, value), timeout=timeout)

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
        try:
            with self._lock:
                if self._check_download and not self.downloading and self.ascii_link is None:
                    self._after_reconnect(req)
                if self.ascii_link is not None:
                    reply = self.ascii_link.transact(req, timeout)
                else:
                    reply = self._request(req, timeout,
                                          self.retries if retries is None else retries)
            if req.opcode >= _FIRST_CONTROL and reply is not None:
                if req.opcode == _START_DOWNLOAD and reply.ok and not self.downloading:
                    self.left_downloading = True
                elif req.opcode == _QUIT_DOWNLOAD and reply.ok:
                    self.left_downloading = False
            if reply is not None and reply.status == _LOADED and not self.downloading:
                raise DownloadModeError(
                    _LOADED, reply,
                    f"the module is in download mode (it stores commands instead of executing "
                    f"them): {_name(req)} was stored in program memory, not executed; "
                    "the line 133 (quit download mode) ends it")
            return reply
        finally:
            if self._events:
                self._deliver_events()

    def _after_reconnect(self, req: Request) -> None:
        """Before the first command after a reconnect (or a 133 that may have been lost):
        end download mode if the module is in it; after a reconnect also ask 136, and if
        another module type answers now, take its data (a ``ValidationError`` for ``req``,
        not sent, when it is a command checked against the old module's data)."""
        self._check_download = False
        old = self.module
        try:
            self.leave_download_mode()
            changed = self._check_module and self._module_changed()
        except BaseException:
            self._check_download = True
            raise
        self._check_module = False
        if changed and old is not None and req.opcode < _FIRST_CONTROL:
            now = self.module.name if self.module is not None else "module of another type"
            raise ValidationError(
                f"{_name(req)} was not sent: it was checked against the {old.name}'s data "
                f"(the module at address {self.address} is a {now} now); give it again")

    def _module_changed(self) -> bool:
        """Ask 136: True (with a notice) if another module type answers than the one whose
        data the client uses, which it then takes (None if the type is not known)."""
        old = self.module
        if old is None:  # asked when needed
            return False
        reply = self.request(Request(self.address, Control.GET_VERSION, 0, 0, 0))
        version = reply.version if reply is not None else None
        before = self.version
        if version is None or version == before:
            return False
        self.version = version
        if old.generic and (before is None or from_version_string(before) is not None):
            if before is None:  # (numbers only, the type never asked)
                return False
            new: Module | None = generic_for(version)  # -m generic: numbers only, as asked
        else:
            new = from_version_string(version) or generic_for(version)
        if new is not None and new.name == old.name:
            return False
        self.module = new
        what = (f"a {new.name}" if new is not None else
                "a type tmclsh does not know (give it with .module or --module)")
        self.notice(f"another module answers at address {self.address} on {self.describe()} "
                    f"since the link came back: {what}, version {version} (it was a "
                    f"{old.name}); lines are checked against its data from now on")
        return True

    def notice(self, text: str) -> None:
        """Tell the user about something the client did on its own."""
        if self.on_notice is not None:
            self.on_notice(text)
        else:
            log.warning("%s", text)

    def leave_download_mode(self) -> bool:
        """Bring a module found in download mode out of it (133), with a notice.

        Asks GP 129 (download mode): a module in normal mode answers it, one in download mode
        stores it and answers status 101. True if the module was in download mode.
        """
        try:
            self.request(Request(self.address, Op.GGP, _GP_DOWNLOAD_MODE, 0, 0))
        except DownloadModeError:
            pass
        else:
            return False
        self.downloading = True  # until 133 is answered, whatever is sent is stored
        try:
            reply = self.request(Request(self.address, Control.QUIT_DOWNLOAD, 0, 0, 0))
        finally:
            self.downloading = False
        if reply is None or not reply.ok:
            status = reply.status if reply is not None else 0
            raise StatusError(status, reply, f"the module at address {self.address} is in "
                              "download mode (it stores commands instead of executing them) "
                              f"and refused to leave it (133): status {status}")
        self.notice(f"the module at address {self.address} was in download mode (an upload "
                    "was cut short?): ended it with 133; the program stored on it may be "
                    "incomplete")
        return True

    def check_download_next(self) -> None:
        """Download mode may not have ended (a 133 went unanswered, or was interrupted):
        before the next command, ask the module and end it if need be (as after a
        reconnect), so that command is executed, not stored."""
        self._check_download = True

    def _request(self, req: Request, timeout: float, retries: int) -> Reply | None:
        if not self.transport.is_open:
            raise TransportError(f"{self.transport.describe()} is not connected "
                                 "(the link was closed or lost; reconnect first)")
        kind = _NORMAL if req.opcode < _FIRST_CONTROL else req.reply_kind
        attempt = 0
        went = False  # req itself went out, in some attempt
        while True:
            attempt += 1
            sent = False  # a failed resynchronisation sends nothing (its marker is counted)
            try:
                if self._bound is not self.transport:  # (replaced by .connect)
                    self._bind(self.transport)
                pending = self._pending
                if pending is None or self._buf or pending():
                    self._flush_input()  # (one cheap check when nothing waits)
                synced = False
                if (self._stale or self._stale_versions or self._stale_opaque
                        or self._drained) and self._dirty:  # (the property, spelt out first)
                    synced = self._sync_before(req, kind, timeout)
                sent = went = True
                # (the line was found clear just now, unless a resynchronisation ran since)
                reply = (self._exchange(req, kind, timeout) if pending is None
                         else self._exchange_stream(req, kind, timeout, absorb=synced))
            except TmclTimeoutError as exc:
                self.stats["timeouts"] += 1
                failure: Exception = exc
            except ChecksumError as exc:
                self.stats["checksum_errors"] += 1
                failure = exc
            except BaseException:
                # Ctrl-C or a link error mid-transaction: the reply may still be on its way
                if sent:
                    self._mark_stale(req, kind)
                raise
            else:
                if (reply is not None and reply.status == _WRONG_CHECKSUM
                        and not self.downloading and attempt <= retries):
                    # the module got a damaged frame and executed nothing: safe to send again
                    self.stats["retries"] += 1
                    if self._tracers:
                        self._trace("note", b"", "module saw a bad checksum; sending again")
                    continue
                if reply is not None:
                    self.replies += 1
                    self._last = (req, reply)
                    self._recent.append(reply)
                return reply
            if sent:
                self._mark_stale(req, kind)
            # a failed line check sent nothing of ``req``: asking again is safe for any command
            tries = 1 + (retries if not sent or idempotent(req, self.downloading) else 0)
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
                self._trace("note", b"", f"retry {attempt} of {tries - 1}")

    @property
    def _dirty(self) -> bool:
        """Something may still arrive that is no answer to the next request."""
        return bool(self._stale or self._stale_versions or self._stale_opaque
                    or (self._drained and not self.downloading))

    @_dirty.setter
    def _dirty(self, value: bool) -> None:
        # for code that talks past the client (the ASCII mode probe): True means "the line
        # may carry anything", so the next request resynchronises with a marker
        self._stale_opaque = bool(value)
        if not value:
            self._stale.clear()
            self._stale_versions = 0
            self._drained = False

    def _mark_stale(self, req: Request, kind: ReplyKind) -> None:
        if kind == _NONE:
            return
        if kind == _VERSION:
            # 136 type 0 is answered with a string (every module in the database has it; a
            # refusal would be a normal frame with an error status, not counted here)
            self._stale_versions += 1
            return
        self._stale[(req.address, req.opcode)] += 1
        if kind != _NORMAL:
            self._stale_opaque = True

    def _late(self, address: int, opcode: int, extra: Reply | None = None) -> bool:
        """A late normal reply showed up: one fewer of its kind may still arrive. If none
        could (``extra``, the reply, is one that no request was waiting for), see
        :meth:`_unsolicited` and return False."""
        key = (address, opcode)
        n = self._stale.get(key, 0)
        if n > 1:
            self._stale[key] = n - 1
        elif n:
            del self._stale[key]
        elif extra is not None and not self._stale_opaque and not self.downloading:
            self._unsolicited(extra)
            return False
        return True

    def _unsolicited(self, extra: Reply | None) -> None:
        """A reply came when none was outstanding: a duplicate, or the real answer to the
        last request, which then took another one. The line is dirty (the next request
        resynchronises) and, unless ``extra`` is a copy of the last request's reply (the
        value shown is the one it carries anyway) or of a marker's, the last request's reply
        is suspect. A copy of an older request's reply proves nothing: it may as well be the
        last request's own answer, displaced by a late copy of the one before (GAP 3 of three
        motors: 5000, 0, then a copy of the 0 taken for the third while its 5000 comes late)."""
        self.stats["unsolicited"] += 1
        self._stale_opaque = True
        last = self._last
        if last is None or extra == last[1] or (
                extra is not None and extra.opcode == Control.GET_VERSION
                and extra in self._recent):
            return
        self._last = None  # reported once
        self.stats["suspect"] += 1
        raw = b"" if extra is None else extra.to_can() if self.is_can else extra.to_bytes()
        self.suspects.append(Suspect(last[0], last[1], self.replies, raw))
        if self._tracers:
            self._trace("note", b"", f"the reply to {_name(last[0])} may have been another "
                                     "request's: a reply came that nothing was waiting for")

    def last_may_be_a_copy(self) -> bool:
        """Whether the last reply taken could be a late copy of the one before it: only a
        reply with the same module address and command is taken for an answer. When it
        could not, no answer still to come can show it to be another request's (so there is
        nothing for one more exchange to find out)."""
        with self._lock:
            recent = self._recent
            return len(recent) >= 2 and (recent[-1].module, recent[-1].opcode) == (
                recent[-2].module, recent[-2].opcode)

    def suspect_seqs(self) -> set[int]:
        """The ``seq`` of every suspect not yet taken (``take_suspects`` still reports them)."""
        with self._lock:  # (the event poller may add one meanwhile)
            return {s.seq for s in self.suspects}

    def take_suspects(self, seqs: Container[int] | None = None) -> list[Suspect]:
        """Replies returned earlier that may have answered another request (oldest first);
        each is reported once. ``seqs``: only those (a caller that read again, or marked the
        values in doubt itself, takes its own; the rest stay to be reported)."""
        out = []
        if seqs is None:
            while self.suspects:
                out.append(self.suspects.popleft())
            return out
        with self._lock:  # (the event poller may add one meanwhile)
            keep = [s for s in self.suspects if s.seq not in seqs]
            out = [s for s in self.suspects if s.seq in seqs]
            self.suspects.clear()
            self.suspects.extend(keep)
        return out

    def _bind(self, transport: Transport) -> None:
        self._bound = transport
        self._pending = transport.pending if isinstance(transport, StreamTransport) else None

    def _flush_input(self) -> None:
        """Before a request: what is already waiting cannot be its answer. Take it in
        (events are kept), drop the rest, count it."""
        before = self.stats["discarded"]
        self._flushing = True
        try:
            self._absorb()
        finally:
            self._flushing = False
        self.stats["flushed"] += self.stats["discarded"] - before

    def _sync_before(self, req: Request, kind: ReplyKind, timeout: float) -> bool:
        """Resynchronise if a late reply could be taken for ``req``'s (True if it did)."""
        if (self._stale_opaque or kind != _NORMAL or (req.address, req.opcode) in self._stale
                or (self._drained and not self.downloading)):
            self._resync(req.address, timeout)
            return True
        return False

    def _marker(self, address: int) -> tuple[Request, ReplyKind] | None:
        """A harmless request whose reply cannot be taken for a late one: 136 type 1 (a
        normal frame) unless a reply like it may still arrive, else 136 type 0 (a string;
        neither a normal frame nor ASCII text is a host-addressed string)."""
        if (address, Control.GET_VERSION) not in self._stale:
            return Request(address, Control.GET_VERSION, 1, 0, 0), _NORMAL
        if not self._stale_versions:
            return Request(address, Control.GET_VERSION, 0, 0, 0), _VERSION
        return None

    def _resync(self, address: int, timeout: float) -> None:
        """Consume every late reply: drain, then a 136 marker whose reply comes last."""
        self.stats["resyncs"] += 1
        if self._tracers:
            self._trace("note", b"", "checking the line with 136 after an earlier failure")
        if self.downloading:
            # a marker would be stored as an instruction: wait for a quiet line instead;
            # stale replies are still dropped by opcode matching. That proves nothing, so a
            # marker follows once download mode is over.
            self._drain(max(0.2, timeout))
            self._stale.clear()
            self._stale_versions = 0
            self._stale_opaque = False
            self._drained = True
            return
        self._absorb()
        chosen = self._marker(address)
        if chosen is None:
            # both markers' replies may still be on their way: take in what comes (for at
            # most a timeout) until one of them has shown up or the line is quiet
            end = time.monotonic() + timeout
            while chosen is None and (left := end - time.monotonic()) > 0:
                if not self._absorb(left):
                    break
                chosen = self._marker(address)
        marker, kind = chosen or (Request(address, Control.GET_VERSION, 1, 0, 0), _NORMAL)
        try:
            got = self._exchange(marker, kind, timeout)
            if got is not None:
                self._recent.append(got)
        except (TmclTimeoutError, ChecksumError) as exc:
            self._mark_stale(marker, kind)
            raise type(exc)(f"address {address} stopped answering: after a reply that went "
                            "wrong, its version (136) was asked to be sure which reply is "
                            f"which, and this failed too: {exc}") from exc
        except BaseException:
            self._mark_stale(marker, kind)
            raise
        self._stale.clear()
        self._stale_versions = 0
        self._stale_opaque = False
        self._drained = False

    def _exchange(self, req: Request, kind: ReplyKind, timeout: float) -> Reply | None:
        if self.transport.kind == "stream":
            return self._exchange_stream(req, kind, timeout)
        return self._exchange_can(req, kind, timeout)

    # -- serial framing -----------------------------------------------------------------
    def _exchange_stream(self, req: Request, kind: ReplyKind, timeout: float,
                         absorb: bool = True) -> Reply | None:
        t: StreamTransport = self.transport  # type: ignore[assignment]
        if kind != _NORMAL and absorb:
            # these layouts take any well-formed frame: clear out what is already here
            self._absorb()
        raw = req.to_bytes()
        if self._sent_tracers and req.opcode in self._sent_wanted:
            _tell(self._sent_tracers, "tx", raw, req)
        buf = self._buf
        deadline = time.monotonic() + timeout
        if buf or kind == _NONE or self._tracers:
            t.write(raw)
            self.stats["sent"] += 1
            if self._tracers:
                self._trace("tx", raw, req)  # (when it goes: the trace shows the time)
            if kind == _NONE:
                return None
            # the first read uses the client's timeout, so a pyserial URL port is not
            # reconfigured
            head = b"" if buf else t.read(_FRAME, timeout)
        else:
            self.stats["sent"] += 1
            head = t.transact(raw, _FRAME, timeout)
        if not buf:
            # the common case first: nine bytes that are the reply. The same nine bytes are
            # the same (immutable) reply, and a script repeating its lines mostly gets
            # answers it has had before: one met before passed the checks that do not depend
            # on the request (the sum, the status) and is taken with the others.
            seen = self._seen_replies
            reply = seen.get(head) if kind == _NORMAL and head.__class__ is bytes else None
            if (reply is not None and reply.module == req.address
                    and reply.opcode == req.opcode and reply.host == self.host_address):
                if self._tracers:
                    self._trace("rx", head, reply)
                return reply
            if (len(head) == _FRAME and kind == _NORMAL and head[1] == req.address
                    and head[3] == req.opcode and head[0] == self.host_address
                    and sum(head[:8]) & 0xFF == head[8] and head[2] in _REPLY_STATUSES):
                reply = Reply.from_frame(head)
                if head.__class__ is bytes:
                    if len(seen) >= _SEEN_REPLIES:
                        seen.clear()
                    seen[head] = reply
                if self._tracers:
                    self._trace("rx", head, reply)
                return reply
            if (len(head) == _FRAME and kind == _MEMORY and head[0] == self.host_address
                    and sum(head[:8]) & 0xFF == head[8]
                    and not (head[2] == _EVENT and head[3] == _TARGET_REACHED)):
                # a 134 read-back (upload's verify), taken as _take takes it from a line that
                # was just absorbed
                reply = Reply.from_memory_frame(head, req.address, req.opcode)
                if self._tracers:
                    self._trace("rx", head, reply)
                return reply
            buf += head
            wait = deadline - time.monotonic()
        else:
            wait = timeout
        junk = bytearray()
        garbled = False  # bytes that were no frame came since the last whole frame
        while True:
            while len(buf) >= _FRAME:
                got = self._take(req, kind, buf, junk)
                if got is _GARBAGE:
                    garbled = True
                    continue
                garbled = False
                if junk:
                    self._drop(junk, "bytes that are no frame")
                if got is not _SKIPPED:
                    return got  # type: ignore[return-value]
            if wait <= 0:
                break
            # bytes that are no frame and then silence: a damaged reply, no need to wait any
            # longer (the answer may come behind it as well: an event, say). But an RS485
            # adapter's echo of the request, one byte damaged, says nothing about when the
            # reply comes: a module may wait up to 255 ms (GP 75) before it answers.
            damaged_reply = garbled and not _echo_of(raw, bytes(junk[:_FRAME] + buf))
            if damaged_reply:
                wait = min(wait, _QUIET_AFTER_GARBAGE)
            chunk = t.read(_FRAME - len(buf), wait)
            if chunk:
                buf += chunk
            elif damaged_reply:
                break
            wait = deadline - time.monotonic()
        # what is left can never complete a frame: the rest of a damaged or truncated reply
        junk += buf
        buf.clear()
        self._drop(junk, "incomplete frame")
        if garbled:
            raise ChecksumError(f"corrupted reply to {_name(req)} from address {req.address} "
                                "(bad checksum)")
        raise TmclTimeoutError(f"no reply to {_name(req)} from address {req.address} "
                               f"within {timeout:g} s")

    def _take(self, req: Request, kind: ReplyKind, buf: bytearray, junk: bytearray) -> object:
        """Look at the frame at the head of ``buf`` and consume it: return it if it answers
        ``req``; queue events; drop stale replies (_SKIPPED) and bytes that are no frame
        (one at a time, into ``junk``: _GARBAGE)."""
        head = bytes(buf[:_FRAME])
        host = self.host_address
        if kind == _VERSION and head[0] == host and _printable(head, 1):
            del buf[:_FRAME]
            reply = Reply.from_bytes(head, kind, module=req.address)
            if self._tracers:
                self._trace("rx", head, reply)
            return reply
        if sum(head[:8]) & 0xFF != head[8] or (
                head[0] == host and kind != _MEMORY and head[2] not in _STATUSES):
            if self._late_version(head) or self._version_copy(head):
                # (a copy is no damaged reply either: the answer may still come, after a
                # module's pause before replying)
                del buf[:_FRAME]
                return _SKIPPED
            # no frame starts here (the decoder's rule: a checksum, and a TMCL status byte
            # in a reply to us)
            junk.append(buf[0])
            del buf[0]
            return _GARBAGE
        if head[0] != host and junk:
            # reached by sliding through bytes that were no frame: noise that happens to
            # add up (1 in 256) is likelier than another host's frame, and taking it whole
            # would swallow the start of the reply behind it
            junk.append(buf[0])
            del buf[0]
            return _GARBAGE
        del buf[:_FRAME]
        if head[0] != host:
            # a frame for another host, or our own request echoed by an RS485 adapter
            self._discard(head, f"frame for address {head[0]}, not host {host}")
            return _SKIPPED
        status, opcode = head[2], head[3]
        if status == _EVENT and opcode == _TARGET_REACHED:
            # (a 134 read-back of a stored instruction could have this shape too, but only
            # one whose opcode equals the address, with type 128 and motor 138)
            self._rx_event(head, Reply.from_frame(head))
            return _SKIPPED
        if kind == _MEMORY:
            reply = Reply.from_memory_frame(head, req.address, req.opcode)
        elif (head[1] != req.address or opcode != req.opcode
              or (kind == _VERSION and status == _OK)):
            # (a normal frame answering 136 type 0 can only carry an error status)
            self._late(head[1], opcode, Reply.from_frame(head))
            self._discard(head, f"stale reply (op {opcode} from address {head[1]})")
            return _SKIPPED
        else:
            reply = Reply.from_frame(head)
        if self._tracers:
            self._trace("rx", head, reply)
        return reply

    def _late_version(self, head: bytes) -> bool:
        """Is ``head`` (no frame) the version string a stale 136 type 0 still had coming?"""
        if self._stale_versions and head[0] == self.host_address and _printable(head, 1):
            self._stale_versions -= 1
            self._discard(head, "stale version string")
            return True
        return False

    def _version_copy(self, head: bytes) -> bool:
        """Is ``head`` a copy of a version string taken lately (a duplicated 136 reply)?"""
        if head[0] != self.host_address or not _printable(head, 1):
            return False
        text = head[1:].decode("latin-1")
        if not any(r.version == text for r in self._recent):
            return False
        self.stats["unsolicited"] += 1
        self._stale_opaque = True
        self._discard(head, "copy of the version string")
        return True

    def _rx_event(self, raw: bytes, reply: Reply) -> None:
        self.stats["events"] += 1
        if self._tracers:
            self._trace("rx", raw, reply)
        self._events.append((reply, time.monotonic()))

    def _discard(self, raw: bytes, why: str) -> None:
        self.stats["discarded"] += len(raw)
        if self._tracers:
            self._trace("drop", raw, why)

    def _drop(self, junk: bytearray, why: str) -> None:
        if junk:
            self._discard(bytes(junk), why)
            junk.clear()

    def _absorb(self, timeout: float = 0.0) -> bool:
        """Take in whatever is pending now (or, if nothing is, what comes within ``timeout``):
        events are queued, anything else is stale. False if nothing came."""
        if isinstance(self.transport, CanTransport):
            return self._absorb_can(timeout)
        t: StreamTransport = self.transport  # type: ignore[assignment]
        buf = self._buf
        data = t.read_available()
        if not data and timeout:
            data = t.read(1, timeout) + t.read_available()
        buf += data
        junk = bytearray()
        while len(buf) >= _FRAME:
            head = bytes(buf[:_FRAME])
            if sum(head[:8]) & 0xFF != head[8] or (
                    head[0] == self.host_address and head[2] not in _STATUSES) or (
                    head[0] != self.host_address and junk):  # (see _take)
                if self._late_version(head) or self._version_copy(head):
                    self._noise = self._noise or bool(junk)
                    self._drop(junk, "bytes that are no frame")
                    del buf[:_FRAME]
                    continue
                junk.append(buf[0])
                del buf[0]
                continue
            self._noise = self._noise or bool(junk)
            self._drop(junk, "bytes that are no frame")
            del buf[:_FRAME]
            if head[0] == self.host_address and head[2] == Status.EVENT \
                    and head[3] == Control.TARGET_REACHED_EVENT:
                self._rx_event(head, Reply.from_frame(head))
            else:
                expected = head[0] != self.host_address or self._late(
                    head[1], head[3], Reply.from_frame(head))
                why = "late reply" if expected else "reply no request was waiting for"
                self._discard(head, f"discarded before the request: {why}"
                              if self._flushing else why)
        if junk:
            # sliding through noise: what is left only counts if it can start a reply to us
            # (as in _take, a frame for another host met this way is taken for noise)
            while buf and buf[0] != self.host_address:
                junk.append(buf[0])
                del buf[0]
        noise = bool(junk) or self._noise
        self._noise = False
        self._drop(junk, "bytes that are no frame")
        if noise and not self._dirty and not self.downloading:
            # bytes that are no frame while nothing was outstanding: a damaged reply,
            # possibly the real answer to the last request (which then took another)
            self._unsolicited(None)
        return bool(data)

    def _drain(self, hard_stop: float) -> None:
        """Read until the line has been quiet for a moment (at most ``hard_stop`` s); then
        drop everything that is not an event, including a partial frame."""
        if isinstance(self.transport, CanTransport):
            end = time.monotonic() + hard_stop
            while time.monotonic() < end and self._take_can_any(_DRAIN_QUIET):
                pass
            return
        t: StreamTransport = self.transport  # type: ignore[assignment]
        end = time.monotonic() + hard_stop
        while time.monotonic() < end:
            chunk = t.read(64, _DRAIN_QUIET)
            if not chunk:
                break
            self._buf += chunk
        self._absorb()
        if self._buf:
            self._discard(bytes(self._buf), "partial frame")
            self._buf.clear()

    # -- CAN framing --------------------------------------------------------------------
    def _exchange_can(self, req: Request, kind: ReplyKind, timeout: float) -> Reply | None:
        t: CanTransport = self.transport  # type: ignore[assignment]
        if kind != _NORMAL:
            self._absorb_can()
        data = req.to_can()
        if self._sent_tracers and req.opcode in self._sent_wanted:
            _tell(self._sent_tracers, "tx", data, req)
        t.send(self.can_id, data)
        self.stats["sent"] += 1
        if self._tracers:
            self._trace("tx", data, req)
        if kind == _NONE:
            return None
        deadline = time.monotonic() + timeout
        wait = timeout
        while True:
            msg = t.recv(wait)
            if msg is not None:
                reply = self._take_can(req, kind, msg[0], msg[1])
                if reply is not None:
                    return reply
            wait = deadline - time.monotonic()
            if wait <= 0:
                break
        raise TmclTimeoutError(f"no CAN reply to {_name(req)} on id {self.reply_id} "
                               f"(sent to id {self.can_id}) within {timeout:g} s")

    def _take_can(self, req: Request, kind: ReplyKind, arb: int, data: bytes) -> Reply | None:
        if arb != self.reply_id:
            return None  # other traffic on the bus
        host = self.host_address
        if kind == _VERSION and len(data) == VERSION_STRING_LEN and _printable(data, 0):
            reply = Reply.from_can(host, data, kind, module=req.address)
        elif len(data) != _CAN_REPLY_LEN:
            self._discard(data, f"not a TMCL reply ({len(data)} bytes)")
            return None
        elif data[1] == Status.EVENT and data[2] == Control.TARGET_REACHED_EVENT:
            self._rx_event(data, Reply.from_can(host, data))
            return None
        elif kind == _MEMORY:
            reply = Reply.from_can(host, data, kind, module=req.address)
        else:
            reply = Reply.from_can(host, data)
            if reply.opcode != req.opcode or (kind == _VERSION and reply.status == Status.OK):
                self._late(reply.module, reply.opcode, reply)
                self._discard(data, f"stale reply (op {reply.opcode})")
                return None
        if self._tracers:
            self._trace("rx", data, reply)
        return reply

    def _take_can_any(self, timeout: float) -> bool:
        """Receive one message: events are queued, anything else dropped. False if none."""
        msg = self.transport.recv(timeout)  # type: ignore[union-attr]
        if msg is None:
            return False
        arb, data = msg
        if arb == self.reply_id and len(data) == _CAN_REPLY_LEN and data[1] == Status.EVENT \
                and data[2] == Control.TARGET_REACHED_EVENT:
            self._rx_event(data, Reply.from_can(self.host_address, data))
        elif arb == self.reply_id:
            if len(data) == _CAN_REPLY_LEN:
                self._late(data[0], data[2], Reply.from_can(self.host_address, data))
            self._discard(data, "stale reply")
        return True

    def _absorb_can(self, timeout: float = 0.0) -> bool:
        got = False
        while self._take_can_any(0 if got else timeout):
            got = True
        return got

    # -- events while idle --------------------------------------------------------------
    def poll(self) -> None:
        """Deliver pending unsolicited replies without waiting (never blocks a transaction)."""
        if not self._lock.acquire(blocking=False):
            return
        try:
            t = self.transport
            if self.ascii_link is None and t.is_open:
                if isinstance(t, CanTransport) or self._buf or t.pending():
                    self._absorb()
        finally:
            self._lock.release()
            if self._events:
                self._deliver_events()

    def confirm_last(self) -> None:
        """At the end of a run: was the last reply the answer to its request? A late copy of
        the reply before it (same address and command) would have been taken for it; its
        real answer then comes right behind, when nothing waits for it, and makes the last
        reply a suspect (``take_suspects``). So the line is watched until it has been quiet
        for two frames' wire time (nothing is sent); otherwise, or on the simulator, what is
        already waiting is taken in."""
        with self._lock:
            t = self.transport
            if self.ascii_link is not None or not t.is_open:
                return
            recent = self._recent
            same = len(recent) >= 2 and (recent[-1].module, recent[-1].opcode) == (
                recent[-2].module, recent[-2].opcode)
            baud = getattr(t, "baudrate", None)
            if (not same or t.simulated or not isinstance(t, StreamTransport)
                    or self._confirmed == self.replies):  # (this reply was watched for already)
                quiet = 0.0
            else:
                frame = 10 * _FRAME / baud if isinstance(baud, (int, float)) and baud else 0.01
                quiet = 2 * frame + 0.005
            end = time.monotonic() + max(0.5, 10 * quiet)
            while self._absorb(quiet) and quiet and time.monotonic() < end:
                pass
            self._confirmed = self.replies
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
        self._poller_stop.set()
        if self._poller is not None:
            self._poller.join(1)
            self._poller = None

    # -- convenience --------------------------------------------------------------------
    def require_module(self) -> Module:
        if self.module is None:
            self.identify()
        assert self.module is not None
        return self.module

    def identify(self) -> Module:
        """Ask the module what it is (136 type 0) and load its database."""
        reply = self.request(Request(self.address, Control.GET_VERSION, 0, 0, 0))
        if reply is None or reply.version is None:
            status = reply.status if reply is not None else 0
            raise StatusError(status, reply, f"address {self.address} refused the version "
                              f"request (136): status {status}")
        self.version = reply.version
        mod = from_version_string(reply.version) or generic_for(reply.version)
        if mod is None:
            raise ValidationError(f"unknown module type in version string {reply.version!r}; "
                                  "give it with --module (or --module generic)")
        self.module = mod
        return mod

    def encode(self, line: str) -> asm.Encoded:
        """Parse and check one TMCL line against the module (nothing is sent)."""
        return self.prepare(line)[0]

    def prepare(self, line: str) -> tuple[asm.Encoded, Request]:
        """The checked instruction of one TMCL line and its request to this address.

        A script or a watch repeats its lines: the result of a line that passed the checks is
        kept (ENCODE_CACHE lines, the oldest dropped first) for the module and mode it was
        checked against; another module or mode starts the cache afresh. Lines that fail are
        checked again every time. ``${...}`` is expanded by the shell before it gets here."""
        mod = self.module if self.module is not None else self.require_module()
        ascii_mode = self.ascii_link is not None
        cache = self._encoded
        if mod is not self._encoded_for[0] or ascii_mode is not self._encoded_for[1]:
            cache.clear()
            self._encoded_for = (mod, ascii_mode)
        hit = cache.get(line)
        if hit is not None:
            enc, req = hit
            if req.address == self.address:
                return hit
        else:
            from ..tmcl import asm

            parsed = asm.parse_line(line)
            if parsed.mnemonic is None:
                raise ValidationError(f"no command in {line!r}")
            enc = asm.encode(parsed, mod, direct=True, ascii=ascii_mode)
            if len(cache) >= ENCODE_CACHE:
                del cache[next(iter(cache))]
        ins = enc.instruction
        hit = (enc, Request.make(self.address, ins.opcode, ins.type, ins.motor, ins.value))
        cache[line] = hit
        return hit

    def execute(self, line: str, *, check: bool = True, timeout: float | None = None) -> Result:
        """Parse, check, send one TMCL line (``"GAP 1, 0"``); StatusError on an error status."""
        enc, req = self.prepare(line)
        reply = self.request(req, timeout=timeout)
        if check and reply is not None and not status_ok(reply.status):
            raise StatusError(reply.status, reply)
        return Result(line, enc, reply)

    def value(self, line: str, *, timeout: float | None = None) -> int:
        """The reply value of one TMCL line: ``client.value("GAP ActualPosition, 0")``."""
        r = self.execute(line, timeout=timeout)
        if r.reply is None:
            raise ValidationError(f"{line!r} gets no reply, so it has no value")
        return r.reply.value

    def stop_all(self) -> list[int]:
        """MST on every motor; returns the motors that answered. (The shell's safety stop
        is ``program.stop_everything``: it also stops a running program and reads back.)"""
        mod = self.module
        motors = range(mod.motors) if mod else range(1)
        stopped = []
        for m in motors:
            try:
                self.send(Op.MST, 0, m, 0, timeout=min(self.timeout, 0.5))
                stopped.append(m)
            except (TmclTimeoutError, ChecksumError, TransportError):
                log.warning("MST %d failed", m)
        return stopped

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
            time.sleep(interval if deadline is None else min(interval, deadline - now))

    def reconnect(self, wait: float = 0.0) -> None:
        """Close and reopen the transport (after the port was lost, e.g. USB unplugged).

        ``wait``: keep trying for that many seconds while the port is not back yet. Raises
        ``TransportError`` if it cannot be opened. Before the next command the module is
        asked whether it is in download mode (ended if so) and what it is (136): another
        module type on the port is taken, with a notice (see ``_after_reconnect``).
        """
        with self._lock:
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
            self._buf.clear()
            self._dirty = False
            self._last = None  # whatever comes now says nothing about answers before
            self._check_download = True
            self._check_module = True
            self.stats["reconnects"] += 1
            if self._tracers:
                self._trace("note", b"", f"reconnected to {self.describe()}")

    # -- for peers that speak on the same line (the ASCII mode link) -------------------
    @property
    def lock(self):
        """Held for every exchange on the line; a peer that talks past ``request`` takes it."""
        return self._lock

    @property
    def tracing(self) -> bool:
        return bool(self._tracers or self._sent_tracers)

    def trace(self, direction: str, raw: bytes, decoded: object, *,
              request: Request | None = None) -> None:
        """Report a frame to the tracers ("tx", "rx", "drop" or "note"). ``request``: the
        request a "tx" line carries (an ASCII line's decoded is its text), for the tracers
        that only watch what is sent (``add_tracer(sent_only=True)`` is told requests)."""
        if direction == "tx" and self._sent_tracers:
            sent = decoded if request is None else request
            if not isinstance(sent, Request) or sent.opcode in self._sent_wanted:
                _tell(self._sent_tracers, "tx", raw, sent)
        if self._tracers:
            self._trace(direction, raw, decoded)

    def absorb(self) -> None:
        """Take in what is pending on a binary line: events are kept, all else is stale."""
        with self._lock:
            self._absorb()

    def clear_input(self) -> None:
        """Forget bytes buffered for the binary framing (the line was in another mode)."""
        with self._lock:
            self._buf.clear()

    def forget_stale(self) -> None:
        """The line was reset (its baud rate changed): nothing sent before can still arrive."""
        with self._lock:
            self._buf.clear()
            self._dirty = False

    def resync_next(self) -> None:
        """Something else used the line (the module's ASCII mode): whatever is left on it is
        stale, so the next binary request starts with the resynchronisation marker."""
        with self._lock:
            self._buf.clear()
            self._stale_opaque = True

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
        hooks, self.close_hooks = self.close_hooks, []
        for hook in hooks:
            try:
                hook()
            except Exception as exc:
                _failed("closing", exc)
        if self.left_downloading and self.transport.is_open:
            self._end_left_download()
        if self.ascii_link is not None:
            try:
                self.ascii_link.close()
            except Exception as exc:
                _failed("leaving ASCII mode", exc)

    def _end_left_download(self) -> None:
        """133 for a 132 that was sent and never ended (by a line, not an upload)."""
        self.left_downloading = False
        self.downloading = True  # (what 133 gets while the module stores commands)
        try:
            reply = self.request(Request(self.address, Control.QUIT_DOWNLOAD, 0, 0, 0))
        except Exception as exc:
            _failed("ending download mode (133)", exc)
            return
        finally:
            self.downloading = False
        if reply is not None and reply.ok:
            self.notice(f"the module at address {self.address} was still in download mode "
                        "(a 132 line with no 133 after it): ended it with 133; what was sent "
                        "after the 132 is stored as its program")
        else:
            self.notice(f"the module at address {self.address} is in download mode (a 132 "
                        "line) and did not leave it for 133 "
                        f"(status {reply.status if reply is not None else 'none'})")

    def switch_transport(self, transport: Transport, module: Module | str | None = None) -> None:
        """Go on on another link (the shell's ``.connect``): the old one is left as ``close``
        leaves it (the close hooks run, the module is left in the mode it was found in, the
        port is closed); nothing of it is carried over. The new link starts in binary mode
        with ``module`` (None: not known yet); listeners, tracers and the event poller stay.
        Bring the module up with ``connection.start`` (136, download mode, ASCII mode)."""
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
            self.reconnect()  # clears buffers and stale-reply bookkeeping, reopens the link
            self._check_download = self._check_module = False  # (what start does first)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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


def _echo_of(raw: bytes, seen: bytes) -> bool:
    """Are the first nine bytes of ``seen`` the request ``raw`` itself, one byte damaged at
    most (what an RS485 adapter that hears its own transmission gives back)?"""
    return len(seen) >= _FRAME and sum(a != b for a, b in zip(raw, seen)) <= 1


def _printable(data: bytes, start: int) -> bool:
    return all(32 <= b < 127 for b in data[start:])


def _name(req: Request) -> str:
    spec = isa.by_opcode(req.opcode)
    if spec is not None:
        return spec.mnemonic
    try:
        return f"{req.opcode} ({Control(req.opcode).name.lower().replace('_', ' ')})"
    except ValueError:
        return f"command {req.opcode}"
