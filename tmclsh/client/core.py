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
``add_tracer`` and ``add_listener``. What is here is the request path and the client's
settings; the rest is done by components the client owns, each with one job: who watches
the line, events and their delivery (taps.py), replies nobody waited for and the answers
they put in doubt (doubt.py, on the ledger's bookkeeping, ledger.py), addresses two modules
answer at (shared.py), and the link reopened, reset, switched or closed (lifecycle.py). How
frames are read off the wire is the framing's (tmclsh.link.framing, one per wire shape;
tmclsh.link.ascii for the module's ASCII command line, swapped in by ``ascii_link``);
bringing a module up, at connect and after a reconnect, is bringup.py's; TMCL lines as text
are text.py's, on top of this.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import TYPE_CHECKING, TypeVar

from ..base import clock
from ..base.canspec import LINK_DEFAULTS
from ..base.errors import ChecksumError, TmclTimeoutError, TransportError, ValidationError
from ..link.base import Transport
from ..tmcl import instructions as isa
from ..tmcl.frames import Control, Reply, ReplyKind, Request, Status
from ..tmcl.modules import Module
from ..tmcl.modules import load as load_module
from .doubt import Doubts
from .ledger import CONFIRM_ROUNDS, Ledger, Suspect
from .lifecycle import Lifecycle, lost_check
from .motion import MotionRecord
from .shared import SharedAddresses
from .advice import KEYWORDS
from .steps import after_answer, clear_line, reply_kind, take_answer
from .steps import run as run_requests
from .taps import Listener, Taps, Tracer
from .taps import tell as _tell

if TYPE_CHECKING:
    from ..link.ascii import AsciiFraming
    from ..link.framing import CanFraming, SerialFraming
    from ..tmcl.asm import Encoded, Line

K = TypeVar("K")

_NORMAL, _VERSION, _MEMORY, _NONE = (ReplyKind.NORMAL, ReplyKind.VERSION_STRING,
                                     ReplyKind.MEMORY, ReplyKind.NONE)
_WRONG_CHECKSUM = int(Status.WRONG_CHECKSUM)
_GET_VERSION = int(Control.GET_VERSION)

__all__ = ["Client", "Suspect", "CONFIRM_ROUNDS", "idempotent"]


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
        self._ascii_asked = False  # connected with ascii=True (--ascii): .address carries it
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
        self._motion_left: dict[int, MotionRecord] = {}
        """The same for the modules ``.address`` switched away from (by address or CAN
        id) while a motor there was still told to move: the stop after a signal goes
        there too."""
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
        self.advice = KEYWORDS
        """How advice in messages names a setting (client/advice.py): ``connect``'s keywords
        (``baud=115200``), the command line's options (``--baud 115200``) when it opened the
        client, or the shell's commands where it has one (``.address 5``) while the prompt
        or a script talks through it."""
        self._checks_lost = 0  # line checks in a row that got no good answer (lost_check)
        # replies from each address that came after tmclsh had stopped waiting for them
        # (Doubts.late): a module slower than the timeout is no module that stopped
        # answering (lost_check), nor one that does not answer (no_answer_message)
        self._late_from: dict[int, int] = {}
        self._late_seen = 0  # _late_from of the address at a row's first lost check
        self._late_base = 0  # _late_from of the address when a bring-up began
        self._replies_base = 0  # the ledger's replies when a bring-up began
        # called when a request finds the link down, to bring it back before the request
        # goes (a --keep-going script waits for a cable plugged back in); it raises
        # TransportError if the link stays down. None: the request fails at once.
        self._on_link_lost: Callable[[], None] | None = None
        self.stats = {"sent": 0, "timeouts": 0, "checksum_errors": 0, "resyncs": 0,
                      "discarded": 0, "events": 0, "retries": 0, "reconnects": 0,
                      "flushed": 0, "unsolicited": 0, "suspect": 0,
                      "judged": 0}
        """Counters of what happened on the link since it was opened: requests sent,
        timeouts, checksum errors, resynchronisations, retries, events, ..."""
        # the components the client's jobs beside the request path are done by (taps.py,
        # shared.py, doubt.py, lifecycle.py)
        self._taps = taps = Taps(self)
        self._tracers = taps.tracers  # (the same lists: the request path reads them here)
        self._sent_tracers = taps.sent_tracers  # (_sent_wanted and _tracing: Taps writes)
        self._events = taps.events
        self._sharing = sharing = SharedAddresses(self)
        self._doubts = doubts = Doubts(self, taps, sharing)
        self._lifecycle = life = Lifecycle(self, taps)
        # what the request path and the framings call (tmclsh.link.framing.Owner), bound
        # here to the component that does it: one attribute read, as a method's would be
        self._trace = taps.trace
        self._tell = taps.tell
        self._trace_sent = taps.trace_sent
        self._discard = taps.discard
        self._event = taps.event
        self._deliver_events = taps.deliver
        self._second = sharing.second
        self._late = doubts.late
        self._noise_unsolicited = doubts.noise_unsolicited
        self._accept_version = doubts.accept_version
        self._lost_check = life.lost_check
        # the suspects not yet reported (the ledger's own queue): a script's every line asks
        # whether it is empty before it asks for the suspects
        self._suspects = self._ledger.suspects
        # the transport's framing, and the one requests go through: the ASCII link's while
        # the module is driven in its ASCII mode (the ascii_link property swaps them)
        self._binary_framing: SerialFraming | CanFraming = transport.framing(self)
        self._framing: SerialFraming | CanFraming | AsciiFraming = self._binary_framing
        self._by_line = False  # the framing is the ASCII link's (set with ascii_link)

    # -- subscriptions (taps.py) --------------------------------------------------------
    def add_listener(self, fn: Listener) -> Callable[[], None]:
        """Call ``fn(reply)`` for every unsolicited reply (138 events). Returns an unsubscribe.

        Listeners run after the transaction that received the event has released the link
        (or on the event poller's thread), so they may send commands themselves.
        """
        return self._taps.add_listener(fn)

    def add_tracer(self, fn: Tracer, *, sent_only: bool = False,
                   opcodes: Iterable[int] | None = None) -> Callable[[], None]:
        """Call ``fn(direction, raw, decoded)`` for every frame: "tx", "rx", "drop" or "note".

        Tracers run inside the transaction: they must be quick and must not use the client.
        ``sent_only``: only "tx", each request just before it goes out; a tracer that only
        watches what is sent then leaves the receive path as fast as with no tracer at all.
        ``opcodes`` (with ``sent_only``): only requests of these command numbers are needed,
        so the others skip the call (the tracer may still be told of others: it checks).
        """
        return self._taps.add_tracer(fn, sent_only=sent_only, opcodes=opcodes)

    # -- addresses two modules answer at (shared.py) ------------------------------------
    @property
    def shared(self) -> frozenset[int]:
        """The addresses two modules were found to answer at (``ledger.Doubles``): every
        request to one reaches both, and which answer is taken is chance."""
        return self._sharing.shared

    def answered_twice(self, address: int, *, lately: bool = False) -> bool:
        """Did the last answer from ``address`` come twice (``lately``: any of the last
        few)? Not yet a finding (a line may copy a reply): asked again, two modules answer
        twice every time (``shared``)."""
        return self._sharing.answered_twice(address, lately=lately)

    @property
    def shared_news(self) -> bool:
        """Was an address found shared that ``take_shared`` has not told yet?"""
        return self._sharing.news

    def take_shared(self) -> list[int]:
        """The addresses found shared since last asked (each told once: the shell warns)."""
        return self._sharing.take()

    # -- properties ---------------------------------------------------------------------
    @property
    def timeout(self) -> float:
        """Seconds to wait for each reply (per attempt). A request/reply link never waits
        forever: a lost reply would hang it."""
        return self._timeout

    @timeout.setter
    def timeout(self, value: float) -> None:
        if not (isinstance(value, (int, float)) and value > 0):
            raise ValidationError(f"timeout must be a positive number of seconds, got {value!r}")
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
            raise ValidationError(f"timeout must be a positive number of seconds, got {timeout!r}")
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
            after_answer(self, req, reply)
            return reply
        finally:
            if self._events:
                self._deliver_events()

    def requests(self, reqs: Iterable[Request], *, timeout: float | None = None,
                 retries: int | None = None) -> Iterator[Reply | None]:
        """``request`` for each of ``reqs`` in turn: each reply is yielded before the next
        request is sent, so the caller stops the run by leaving its loop (nothing more is
        sent). Each request takes the steps ``request`` takes, with the same checks
        (client/steps.py); what a run does not change is looked up once, so thousands at
        the line's pace (an upload's frames, their read-back) cost little more between a
        reply and the next request than the checks. ``reqs`` is read as each goes out (a
        list made before costs the line least). ``timeout`` and ``retries`` as
        ``request``'s, checked before anything is sent."""
        if timeout is None:
            timeout = self._timeout
        elif not (isinstance(timeout, (int, float)) and timeout > 0):
            raise ValidationError(f"timeout must be a positive number of seconds, got {timeout!r}")
        return run_requests(self, reqs, timeout, self.retries if retries is None else retries)

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

    def _request(self, req: Request, timeout: float, retries: int,
                 first: tuple[bool, object] | None = None) -> Reply | None:
        """``req``'s answer (steps.py), attempted again where that is safe. ``first``: an
        attempt a run made already (``steps.run``): whether ``req`` went out, and its reply
        or what it raised, taken on from there as an attempt of this loop's own."""
        if first is None and not self.transport.is_open:
            raise TransportError(f"{self.transport.describe()} is not connected "
                                 "(the link was closed or lost; reconnect first)")
        kind = reply_kind(req)
        framing = self._framing
        ledger = self._ledger
        attempt = 0
        went = False  # req itself went out, in some attempt
        while True:
            attempt += 1
            sent = False  # a failed resynchronisation sends nothing (its marker is counted)
            try:
                if first is None:
                    synced = clear_line(self, req, kind, timeout)
                    sent = went = True
                    # (the line was found clear just now, unless a resynchronisation ran since)
                    reply = framing.exchange(req, kind, timeout, absorb=synced)
                else:
                    sent, outcome = first
                    went = sent
                    first = None
                    if isinstance(outcome, BaseException):
                        raise outcome
                    reply = outcome  # type: ignore[assignment]
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
                return take_answer(self, req, reply, timeout, retries)
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
        why = ledger.why_dirty()
        if self._tracers:
            _tell(self._tracers, "note", b"", f"checking the line with 136 {why}")
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
                raise type(exc)(lost_check(self, address, f"{why}, its version (136) was "
                                           "asked to be sure which reply is which, and this "
                                           f"failed too: {exc}")) from exc
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

    # -- answers in doubt (doubt.py) ----------------------------------------------------
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
        (``CONFIRM_ROUNDS`` times at most) or say they are in doubt, then settle them
        (``Doubts.settle``). In ASCII mode what waits is taken in (AsciiFraming.absorb); its
        readings of settings were judged as they were read."""
        return self._doubts.in_doubt(answered, confirm=confirm)

    # -- events while idle (taps.py) ----------------------------------------------------
    def poll(self) -> None:
        """Deliver pending unsolicited replies without waiting (never blocks a transaction)."""
        self._taps.poll()

    def start_event_poller(self, interval: float = 0.05) -> None:
        """Deliver 138 events while no command is running, from a background thread."""
        self._taps.start_poller(interval)

    def stop_event_poller(self) -> None:
        """Stop delivering events in the background (``start_event_poller``)."""
        self._taps.stop_poller()

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

    # -- the link (lifecycle.py) --------------------------------------------------------
    def reconnect(self, wait: float = 0.0, *, bring_up: bool = True) -> None:
        """Close and reopen the transport (after the port was lost, e.g. USB unplugged).

        ``wait``: keep trying for that many seconds while the port is not back yet. Raises
        ``TransportError`` if it cannot be opened. Before the next command the module is
        brought up again as at connect (tmclsh.client.bringup): what answers now (another
        module type is taken, with a notice), in which mode, whether in download mode;
        unless ``bring_up`` is false (a firmware update, which expects the module to have
        restarted into its bootloader and asks it itself).
        """
        self._lifecycle.reconnect(wait, bring_up=bring_up)

    @property
    def bring_up_pending(self) -> bool:
        """The link came back but the module has not been brought up since (it did not
        answer yet): the next exchange waits for its bring-up first."""
        return self._bring_up_next

    @property
    def lock(self):
        """Held for every exchange on the line; a peer that talks past ``request`` takes it."""
        return self._lock

    def close(self) -> None:
        """Stop the event poller, run the close hooks, leave ASCII mode if entered, close the
        transport. Safe to call more than once."""
        self._lifecycle.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
