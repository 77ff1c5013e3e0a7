"""One module on one transport: send a request, get *its* reply.

TMCL replies carry no sequence number, so the client keeps the link honest itself:

* a reply is taken only if its host address, module address and opcode match the request;
* 138 target-reached events (status 128) are handed to listeners whenever they arrive, before,
  during or between transactions, and never taken for a reply;
* after a timeout or a corrupted reply the link is *dirty*: before the next request the client
  drains the line and sends a 136 type 1 (binary version) as a marker, discarding everything up
  to the marker's reply. Anything that arrives late is thereby consumed before it could be
  mistaken for the answer to a later request;
* only idempotent requests are retried (a retried ``MVP REL`` would move twice).

The client owns the only receive path: trace, watch and the debugger subscribe as listeners.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from . import asm
from .errors import ChecksumError, StatusError, TmclTimeoutError, TransportError, ValidationError
from .modules import Module, from_version_string
from .modules import load as load_module
from .protocol import (SERIAL_FRAME_LEN, Control, Reply, ReplyKind, Request, Status,
                       decode_reply, status_ok)
from .transport.base import CanTransport, StreamTransport, Transport

log = logging.getLogger(__name__)

Tracer = Callable[[str, bytes, object], None]
Listener = Callable[[Reply], None]

# requests that must never be sent twice by a retry
_NOT_IDEMPOTENT = {Control.RUN_APPLICATION, Control.STEP_APPLICATION, Control.RESET_APPLICATION,
                   Control.START_DOWNLOAD, Control.QUIT_DOWNLOAD, Control.FACTORY_DEFAULT,
                   Control.TARGET_REACHED_EVENT, Control.ENTER_ASCII}
_MVP, _MVP_REL = 4, 1


def idempotent(req: Request, downloading: bool = False) -> bool:
    if downloading or req.opcode in _NOT_IDEMPOTENT:
        return False
    if req.opcode == _MVP and req.type == _MVP_REL:
        return False
    return req.opcode not in (19, 33, 34, 35, 39)  # CALC/CALCX/AAP/AGP/ACO change state


@dataclass(frozen=True)
class Result:
    """A typed line and what the module answered (reply is None for 137)."""

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


class Client:
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
        self.downloading = False
        self.ascii_link = None  # set by tmclsh.ascii when the module is driven in ASCII mode
        self._lock = threading.RLock()
        self._buf = bytearray()
        self._dirty = False
        self._listeners: list[Listener] = []
        self._tracers: list[Tracer] = []
        self._poller: threading.Thread | None = None
        self._poller_stop = threading.Event()
        self.stats = {"sent": 0, "timeouts": 0, "checksum_errors": 0, "resyncs": 0,
                      "discarded": 0, "events": 0}

    # -- subscriptions ------------------------------------------------------------------
    def add_listener(self, fn: Listener) -> Callable[[], None]:
        """Call ``fn(reply)`` for every unsolicited reply (138 events). Returns an unsubscribe."""
        self._listeners.append(fn)
        return lambda: self._listeners.remove(fn) if fn in self._listeners else None

    def add_tracer(self, fn: Tracer) -> Callable[[], None]:
        """Call ``fn(direction, raw, decoded)`` for every frame: "tx", "rx", "drop" or "note"."""
        self._tracers.append(fn)
        return lambda: self._tracers.remove(fn) if fn in self._tracers else None

    def _trace(self, direction: str, raw: bytes, decoded: object) -> None:
        for fn in list(self._tracers):
            try:
                fn(direction, raw, decoded)
            except Exception:  # a broken tracer must not break the link
                log.exception("tracer failed")

    def _event(self, reply: Reply) -> None:
        self.stats["events"] += 1
        for fn in list(self._listeners):
            try:
                fn(reply)
            except Exception:
                log.exception("listener failed")

    # -- properties ---------------------------------------------------------------------
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

    # -- the request path ---------------------------------------------------------------
    def send(self, opcode: int, type: int = 0, motor: int = 0, value: int = 0, *,
             timeout: float | None = None) -> Reply | None:
        """Send one raw command and return its reply (None for 137, which has none)."""
        return self.request(Request(self.address, opcode, type, motor, value), timeout=timeout)

    def request(self, req: Request, *, timeout: float | None = None,
                retries: int | None = None) -> Reply | None:
        timeout = self.timeout if timeout is None else timeout
        with self._lock:
            if self.ascii_link is not None:
                return self.ascii_link.transact(req, timeout)
            if not self.transport.is_open:
                raise TransportError(f"{self.transport.describe()} is not connected (use .connect)")
            tries = 1 + ((self.retries if retries is None else retries)
                         if idempotent(req, self.downloading) else 0)
            last: Exception | None = None
            for attempt in range(tries):
                if self._dirty:
                    self._resync(timeout)
                try:
                    return self._transact(req, timeout)
                except TmclTimeoutError as exc:
                    self.stats["timeouts"] += 1
                    last = exc
                except ChecksumError as exc:
                    self.stats["checksum_errors"] += 1
                    last = exc
                self._dirty = True
                if attempt + 1 < tries:
                    self._trace("note", b"", f"retry {attempt + 1} of {tries - 1}")
            assert last is not None
            if tries > 1:
                raise type(last)(f"{last} (after {tries} attempts)")
            raise last

    def _transact(self, req: Request, timeout: float) -> Reply | None:
        if self.is_can:
            return self._transact_can(req, timeout)
        t = self.transport
        assert isinstance(t, StreamTransport)
        if self._buf or t.pending():
            self._absorb(timeout=0)
        raw = req.to_bytes()
        t.write(raw)
        self.stats["sent"] += 1
        if self._tracers:
            self._trace("tx", raw, req)
        kind = req.reply_kind
        if kind == ReplyKind.NONE:
            return None
        return self._await_stream(req, kind, timeout)

    def _await_stream(self, req: Request, kind: ReplyKind, timeout: float) -> Reply:
        t = self.transport
        assert isinstance(t, StreamTransport)
        buf = self._buf
        deadline = time.monotonic() + timeout
        corrupted = False
        while True:
            while len(buf) >= SERIAL_FRAME_LEN:
                reply = self._match(req, kind, buf)
                if reply is not None:
                    return reply
                if reply is None and self._last_bad:
                    corrupted = True
            left = deadline - time.monotonic()
            if left <= 0:
                break
            chunk = t.read(SERIAL_FRAME_LEN - len(buf) if len(buf) < SERIAL_FRAME_LEN else 1,
                           min(left, 0.05) if corrupted else left)
            if chunk:
                buf += chunk
            elif corrupted:
                break  # a corrupted reply and then silence: no need to wait out the deadline
        if corrupted:
            raise ChecksumError(f"corrupted reply to {_name(req)} (bad checksum); link resynchronised")
        if buf:
            self._trace("drop", bytes(buf), "incomplete frame")
            buf.clear()
        raise TmclTimeoutError(f"no reply to {_name(req)} from address {req.address} "
                               f"within {timeout:g} s")

    _last_bad = False

    def _match(self, req: Request, kind: ReplyKind, buf: bytearray) -> Reply | None:
        """Look at the frame at the head of ``buf``: consume it and return it if it answers
        ``req``; dispatch events; drop stale replies and bytes that are no frame."""
        self._last_bad = False
        head = bytes(buf[:SERIAL_FRAME_LEN])
        if kind == ReplyKind.VERSION_STRING and head[0] == self.host_address \
                and all(32 <= b < 127 for b in head[1:]):
            del buf[:SERIAL_FRAME_LEN]
            reply = Reply.from_bytes(head, kind, module=req.address)
            if self._tracers:
                self._trace("rx", head, reply)
            return reply
        used, reply = decode_reply(buf, ReplyKind.NORMAL)
        if reply is None:
            self._last_bad = True
            self.stats["discarded"] += used
            if self._tracers:
                self._trace("drop", bytes(buf[:used]), "not a frame (bad checksum)")
            del buf[:used]
            return None
        del buf[:used]
        if reply.host != self.host_address:
            self._discard(head, f"reply for host {reply.host}")
            return None
        if kind == ReplyKind.MEMORY:
            if reply.status == Status.EVENT and reply.opcode == Control.TARGET_REACHED_EVENT \
                    and reply.module == req.address:
                self._rx_event(head, reply)
                return None
            mem = Reply.from_bytes(head, kind, module=req.address, opcode=req.opcode)
            if self._tracers:
                self._trace("rx", head, mem)
            return mem
        if reply.status == Status.EVENT:
            self._rx_event(head, reply)
            return None
        if reply.module != req.address or reply.opcode != req.opcode:
            self._discard(head, f"stale reply (op {reply.opcode} from address {reply.module})")
            return None
        if self._tracers:
            self._trace("rx", head, reply)
        return reply

    def _rx_event(self, raw: bytes, reply: Reply) -> None:
        if self._tracers:
            self._trace("rx", raw, reply)
        self._event(reply)

    def _discard(self, raw: bytes, why: str) -> None:
        self.stats["discarded"] += len(raw)
        if self._tracers:
            self._trace("drop", raw, why)

    def _absorb(self, timeout: float = 0.0) -> None:
        """Take in whatever is pending: events go to listeners, anything else is stale."""
        t = self.transport
        assert isinstance(t, StreamTransport)
        data = t.read_available()
        if not data and timeout:
            data = t.read(1, timeout)
        self._buf += data
        buf = self._buf
        while len(buf) >= SERIAL_FRAME_LEN:
            used, reply = decode_reply(buf, ReplyKind.NORMAL)
            head = bytes(buf[:used])
            del buf[:used]
            if reply is None:
                self._discard(head, "not a frame")
            elif reply.status == Status.EVENT and reply.host == self.host_address:
                self._rx_event(head, reply)
            else:
                self._discard(head, "stale reply")

    def _resync(self, timeout: float) -> None:
        """Drain the line, then use a 136 type 1 reply as a marker: all before it is stale."""
        self.stats["resyncs"] += 1
        self._trace("note", b"", "resynchronising")
        if self.is_can:
            while self.transport.recv(0.02) is not None:  # type: ignore[union-attr]
                pass
            self._dirty = False
            return
        t = self.transport
        assert isinstance(t, StreamTransport)
        quiet_until = time.monotonic() + 0.03
        hard_stop = time.monotonic() + max(0.2, timeout)
        while time.monotonic() < hard_stop:
            chunk = t.read(64, 0.01)
            if chunk:
                self._buf += chunk
                quiet_until = time.monotonic() + 0.03
            elif time.monotonic() >= quiet_until:
                break
        self._absorb()
        if self._buf:
            self._discard(bytes(self._buf), "partial frame")
            self._buf.clear()
        marker = Request(self.address, Control.GET_VERSION, 1, 0, 0)
        try:
            self._transact(marker, timeout)
            self._dirty = False
        except (TmclTimeoutError, ChecksumError):
            self._buf.clear()

    def _transact_can(self, req: Request, timeout: float) -> Reply | None:
        t = self.transport
        assert isinstance(t, CanTransport)
        kind = req.reply_kind
        t.send(self.can_id, req.to_can())
        self.stats["sent"] += 1
        if self._tracers:
            self._trace("tx", req.to_can(), req)
        if kind == ReplyKind.NONE:
            return None
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            msg = t.recv(left)
            if msg is None:
                break
            arb, data = msg
            if arb != self.reply_id:
                continue
            try:
                if kind == ReplyKind.VERSION_STRING and len(data) == 8:
                    reply = Reply.from_can(self.host_address, data, kind, module=req.address)
                else:
                    reply = Reply.from_can(self.host_address, data, ReplyKind.NORMAL)
            except Exception:
                self._discard(data, "not a TMCL CAN reply")
                continue
            if kind == ReplyKind.MEMORY and not reply.is_event:
                reply = Reply.from_can(self.host_address, data, kind, module=req.address)
            elif reply.is_event:
                self._rx_event(data, reply)
                continue
            elif kind == ReplyKind.NORMAL and reply.opcode != req.opcode:
                self._discard(data, f"stale reply (op {reply.opcode})")
                continue
            if self._tracers:
                self._trace("rx", data, reply)
            return reply
        raise TmclTimeoutError(f"no CAN reply to {_name(req)} on id {self.reply_id} "
                               f"within {timeout:g} s")

    # -- events while idle --------------------------------------------------------------
    def poll(self) -> None:
        """Deliver pending unsolicited replies without waiting (never blocks a transaction)."""
        if not self._lock.acquire(blocking=False):
            return
        try:
            if self.ascii_link is not None or not self.transport.is_open:
                return
            if self.is_can:
                while (msg := self.transport.recv(0)) is not None:  # type: ignore[union-attr]
                    arb, data = msg
                    if arb == self.reply_id and len(data) == 7 and data[1] == Status.EVENT:
                        self._rx_event(data, Reply.from_can(self.host_address, data))
            elif self._buf or self.transport.pending():  # type: ignore[union-attr]
                self._absorb()
        finally:
            self._lock.release()

    def start_event_poller(self, interval: float = 0.05) -> None:
        if self._poller is not None:
            return
        self._poller_stop.clear()

        def run() -> None:
            while not self._poller_stop.wait(interval):
                try:
                    self.poll()
                except TransportError:
                    pass
                except Exception:
                    log.exception("event poll failed")

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
        assert reply is not None and reply.version is not None
        self.version = reply.version
        mod = from_version_string(reply.version)
        if mod is None:
            raise ValidationError(f"unknown module type in version string {reply.version!r}; "
                                  "give it with --module")
        self.module = mod
        return mod

    def encode(self, line: str) -> asm.Encoded:
        mod = self.require_module()
        parsed = asm.parse_line(line)
        if parsed.mnemonic is None:
            raise ValidationError(f"no command in {line!r}")
        return asm.encode(parsed, mod, direct=True, ascii=self.mode == "ascii")

    def execute(self, line: str, *, check: bool = True) -> Result:
        """Parse, check, send one TMCL line (``"GAP 1, 0"``); StatusError on an error status."""
        enc = self.encode(line)
        ins = enc.instruction
        reply = self.request(Request(self.address, ins.opcode, ins.type, ins.motor, ins.value))
        if check and reply is not None and not status_ok(reply.status):
            raise StatusError(reply.status, reply)
        return Result(line, enc, reply)

    def value(self, line: str) -> int:
        r = self.execute(line)
        assert r.reply is not None
        return r.reply.value

    def stop_all(self) -> list[int]:
        """MST on every motor: the safety action behind Ctrl-C."""
        mod = self.module
        motors = range(mod.motors) if mod else range(1)
        stopped = []
        for m in motors:
            try:
                self.send(3, 0, m, 0, timeout=min(self.timeout, 0.5))
                stopped.append(m)
            except (TmclTimeoutError, ChecksumError, TransportError):
                log.warning("MST %d failed", m)
        return stopped

    def wait_until(self, predicate: Callable[[], bool], timeout: float | None,
                   interval: float = 0.05) -> None:
        deadline = None if timeout is None else time.monotonic() + timeout
        while not predicate():
            if deadline is not None and time.monotonic() >= deadline:
                raise TmclTimeoutError(f"condition not met within {timeout:g} s")
            time.sleep(interval)

    def reconnect(self) -> None:
        with self._lock:
            self.transport.close()
            self.transport.open()
            self._buf.clear()
            self._dirty = False

    def close(self) -> None:
        self.stop_event_poller()
        with self._lock:
            if self.ascii_link is not None:
                try:
                    self.ascii_link.close()
                except Exception:
                    log.exception("leaving ASCII mode failed")
            self.transport.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _name(req: Request) -> str:
    from . import instructions as isa

    spec = isa.by_opcode(req.opcode)
    return spec.mnemonic if spec else f"command {req.opcode}"


def connect(port: str | None = None, *, baud: int = 9600, can: str | None = None,
            sim: str | None = None, module: str | None = None, address: int = 1,
            host_address: int = 2, timeout: float = 1.0, retries: int = 2,
            can_id: int | None = None, reply_id: int | None = None,
            ascii: bool = False) -> Client:
    """Open a client: ``connect(port="/dev/ttyACM0")``, ``connect(can="virtual:bench")``,
    ``connect(sim="TMCM-351")``; with none of them, the built-in simulated TMCM-1311.

    The module type is asked with 136 unless ``module`` is given.
    """
    from . import transport as tr

    if sum(x is not None for x in (port, can, sim)) > 1:
        raise ValidationError("give only one of port, can and sim")
    if port is not None:
        t: Transport = tr.open_serial(port, baud)
    elif can is not None:
        t = tr.open_can(can)
    else:
        name = sim or module or "TMCM-1311"
        t = tr.open_sim(name, address)
        module = module or name
    client = Client(t, address=address, host_address=host_address, module=module,
                    timeout=timeout, retries=retries, can_id=can_id, reply_id=reply_id)
    try:
        if ascii:
            from .ascii import AsciiLink

            AsciiLink.attach(client)
        if client.module is None:
            client.identify()
    except BaseException:
        client.close()
        raise
    return client
