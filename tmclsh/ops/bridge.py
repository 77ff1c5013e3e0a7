"""A bridge: another program (the master) talks to the module through tmclsh, which forwards
every frame unchanged and lets the monitor read each.

The master connects to a pseudo-terminal or a TCP port as it would to the module's serial
port; the servers are the simulator's (sim/serve.py), which serve any target that takes
bytes (``write``) and hands bytes back (``on_output``). Here the target is the module's own
link:

* ``SerialBridge``: a serial module (``--port``). Bytes go both ways as they come, unread
  and unchanged; each chunk is then told to the monitor (``heard``).
* ``CanBridge``: a CAN module (``--can``). The master speaks serial frames; each request's
  seven instruction bytes go to the module's CAN id as they are, and each reply's seven
  (or a version string's eight) come back as a serial frame to the host address, checksum
  added. Bytes that are no frame cannot be forwarded on CAN: they are told as noise.

What was forwarded is told to the caller (``heard``) in the order the wire carried it, after
it was forwarded (see ``_Bridge``): reading it never delays a byte. ``Left`` keeps what the master's exchanges
leave behind (a motor started, download or ASCII mode entered), which the front end ends
when the bridge closes. Nothing here prints.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from ..base.errors import TransportError
from ..link.ascii import char_address
from ..link.base import CanFrame, CanTransport, StreamTransport
from ..tmcl import instructions as isa
from ..tmcl.decoder import FRAME, FRAME_PIECE, FrameDecoder
from ..tmcl.frames import checksum
from ..tmcl.status import status_ok
from ..tmcl.traffic import enters_ascii, leaves_ascii, plausible_request
from .monitor import RX, TEXT, TX, Exchange, Item

log = logging.getLogger(__name__)

TICK = 0.1  # s the module's reader waits before it looks whether the bridge closed
# what ``heard`` is told: (TX | RX, bytes, time) on serial; (CAN_TX | CAN_RX, CanFrame) on
# CAN; (NOISE, bytes, time) for bytes of the master no frame could be made of; (LOST, why)
CAN_TX, CAN_RX, NOISE, LOST = "can-tx", "can-rx", "noise", "lost"

Heard = Callable[[tuple], None]


class _Target:
    """What the pty or TCP server serves: ``write`` gets the master's bytes, ``on_output``
    (set by the server) takes the module's to the master."""

    def __init__(self, write):
        self.write = write
        self.on_output = None


class _Bridge:
    """The forwarding, and the telling of what was forwarded.

    Each chunk is noted (a deque append, atomic) just before it is forwarded, so the notes
    keep the order the wire had: an answer is never noted ahead of its request, nor a
    request ahead of the answer the master waited for. Once forwarded, the thread that
    forwarded it tells ``heard`` every note in order, holding ``lock`` (the caller takes it
    too, for its own looks at the monitor). Telling on the forwarding threads after the
    forwarding wakes no other thread: an exchange through the bridge costs its two hops
    and its reading, nothing more.
    """

    def __init__(self, heard: Heard, *, pty: bool = False,
                 tcp: tuple[str, int] | None = None):
        from ..sim.serve import serve_pty, serve_tcp

        self.heard = heard
        self.lock = threading.Lock()
        self._notes: deque[tuple] = deque()
        self._closed = threading.Event()
        self.target = _Target(self._from_master)
        if pty:
            self.server = serve_pty(self.target)
            self.endpoint = self.server.path
        else:
            assert tcp is not None
            self.server = serve_tcp(self.target, *tcp)
            host, port = self.server.address
            self.endpoint = f"{host}:{port}"
        self._reader = threading.Thread(target=self._loop, name="bridge-module", daemon=True)
        self._reader.start()

    def note(self, event: tuple) -> None:
        self._notes.append(event)

    def tell(self) -> None:
        """Tell ``heard`` what was noted, in order (on whichever thread gets here first)."""
        notes = self._notes
        with self.lock:
            while notes:
                try:
                    self.heard(notes.popleft())
                except Exception:  # a reader's failure must not stop the forwarding
                    log.exception("reading what the bridge forwarded failed")

    def _to_master(self, data: bytes) -> None:
        out = self.target.on_output
        if out is not None:
            out(data)

    def _from_master(self, data: bytes) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def _loop(self) -> None:
        try:
            while not self._closed.is_set():
                self._step()
        except TransportError as exc:
            if not self._closed.is_set():
                self.note((LOST, str(exc)))
        except Exception as exc:  # the bridge must say why it stopped forwarding
            log.exception("the bridge's module reader failed")
            self.note((LOST, f"the bridge stopped forwarding: {exc}"))
        self.tell()

    def _step(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def close(self) -> None:
        """Stop serving the master and stop reading the module (its link stays open: the
        front end may still need it); what was forwarded is told."""
        if self._closed.is_set():
            return
        self._closed.set()
        self.server.close()
        self._reader.join(timeout=2)
        self.tell()


class SerialBridge(_Bridge):
    """A master on a pty or TCP port and a serial module: bytes forwarded unchanged."""

    def __init__(self, module: StreamTransport, heard: Heard, **kw):
        self.module = module
        super().__init__(heard, **kw)

    def _from_master(self, data: bytes) -> None:
        self.note((TX, data, time.time()))
        try:
            self.module.write(data)
        except TransportError as exc:
            self.note((LOST, str(exc)))
        self.tell()

    def _step(self) -> None:
        data = self.module.read_some(TICK)
        if data:
            self.note((RX, data, time.time()))
            self._to_master(data)
            self.tell()


class CanBridge(_Bridge):
    """A master on a pty or TCP port speaking serial frames, and a module on CAN.

    ``can_id``: where requests go (None: the CAN id is each request's address byte, as a
    module's factory settings make them equal); ``reply_id``: where replies come from;
    ``host``: the address byte of the serial replies the master gets.
    """

    def __init__(self, module: CanTransport, heard: Heard, *, can_id: int | None = None,
                 reply_id: int = 2, host: int = 2, **kw):
        self.module = module
        self.can_id = can_id
        self.reply_id = reply_id
        self.host = host
        self.requests = FrameDecoder(None, resync=plausible_request)
        super().__init__(heard, **kw)

    def _from_master(self, data: bytes) -> None:
        dec = self.requests
        dec.feed(data)
        now = time.time()
        while (piece := dec.next()) is not None:
            kind, raw = piece
            if kind != FRAME_PIECE:
                self.note((NOISE, raw, now))
                continue
            arb = self.can_id if self.can_id is not None else raw[0]
            self.note((CAN_TX, CanFrame(time.time(), arb, raw[1:8])))
            try:
                self.module.send(arb, raw[1:8])
            except TransportError as exc:
                self.note((LOST, str(exc)))
                break
        self.tell()

    def _step(self) -> None:
        f = self.module.listen(TICK)  # type: ignore[attr-defined]
        if f is None:
            return
        self.note((CAN_RX, f))
        if f.arbitration_id == self.reply_id and not (f.error or f.remote or f.extended):
            data = f.data
            if len(data) == FRAME - 1:  # a version string: the host byte, no checksum
                self._to_master(bytes((self.host,)) + data)
            elif len(data) == FRAME - 2:
                body = bytes((self.host,)) + data
                self._to_master(body + bytes((checksum(body),)))
        self.tell()


@dataclass
class Left:
    """What the master's exchanges leave behind at the module, by address: a motor or the
    stored program started, download mode or ASCII mode entered (and not left)."""

    started: set[int] = field(default_factory=set)
    download: set[int] = field(default_factory=set)
    ascii: set[int] = field(default_factory=set)

    def take(self, item: Item) -> None:
        if isinstance(item, Exchange):
            req, reply = item.request, item.reply
            if reply is None or reply.reply is None or not status_ok(reply.reply.status) \
                    or req.address is None:
                return
            op = req.instruction.opcode
            if op in isa.starting_opcodes():
                self.started.add(req.address)
            spec = isa.control(op)
            if spec is not None and spec.download == "enter":
                self.download.add(req.address)
            elif spec is not None and spec.download == "leave":
                self.download.discard(req.address)
            if enters_ascii(req.instruction):
                self.ascii.add(req.address)
        elif item.kind == TEXT and item.direction == TX and leaves_ascii(item.raw):
            try:
                self.ascii.discard(char_address(item.raw[0]))
            except ValueError:
                pass

    @property
    def addresses(self) -> list[int]:
        return sorted(self.started | self.download | self.ascii)

    def __bool__(self) -> bool:
        return bool(self.started or self.download or self.ascii)

    def describe(self, address: int) -> str:
        what = [w for w, s in (("a motor or the stored program started", self.started),
                               ("the module in download mode", self.download),
                               ("the module in ASCII mode", self.ascii)) if address in s]
        return " and ".join(what)


__all__ = ["SerialBridge", "CanBridge", "Left", "TX", "RX", "CAN_TX", "CAN_RX", "NOISE",
           "LOST", "TICK"]
