"""A bridge: another program (the master) talks to the module through tmclsh, which forwards
every frame unchanged and lets the monitor read each.

The master connects to a pseudo-terminal or a TCP port as it would to the module's serial
port; the servers are the simulator's (sim/serve.py), which serve any target that takes
bytes (``write``) and hands bytes back (``on_output``). Here the target is the module's own
link:

* ``SerialBridge``: a serial module (``--port``). Bytes go both ways as they come, unread
  and unchanged; each chunk is noted just before it goes. Where the module's port has a
  descriptor (a serial port on POSIX), the server's thread waits on it beside the master's
  end and forwards both ways: no exchange waits for a second thread to be woken and to take
  the interpreter.
  Measured beside a minimal forwarder, with the describer in its rhythm (ops/handoff.py):
  the p99 added 1.3-2.0x that forwarder's with a thread per direction, 1.0-1.5x with one
  (3 runs each, chunks noted after they went); as built (noted before, 7 runs), the median
  1.1-1.4x and the p99 1.5-2.2x, against 1.3-1.7x and 1.8-3.4x before either change. A port
  without a descriptor (a pyserial URL) is read by a thread of its own.
* ``CanBridge``: a CAN module (``--can``). The master speaks serial frames; each request's
  seven instruction bytes go to the module's CAN id as they are, and each reply's seven
  (of seven or eight: tmcl/decoder.py ``can_reply``), or a version string's eight, come
  back as a serial frame to the host address, checksum added. Bytes that are no frame
  cannot be forwarded on CAN: they are noted as noise.

What was forwarded is handed, as it is forwarded, to ``put`` (ops/handoff.py: a pipe to a
process of its own that describes it), which never waits: reading it, showing it and writing
it to a file never delay a byte nor take the interpreter from the forwarding, and a reader
that stops reading never stops the forwarding. ``Left`` keeps what the master's exchanges
leave behind (a motor started, download or ASCII mode entered), which the front end ends
when the bridge closes. Nothing here prints.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from ..base.errors import TransportError
from ..link.ascii import char_address
from ..link.base import CanFrame, CanTransport, StreamTransport
from ..tmcl import instructions as isa
from ..tmcl.decoder import CAN_VERSION, FRAME_PIECE, FrameDecoder, can_reply
from ..tmcl.frames import ReplyKind, checksum
from ..tmcl.status import status_ok
from ..tmcl.traffic import enters_ascii, leaves_ascii, plausible_request
from .handoff import CAN_RX, CAN_TX, LOST, NOISE
from .monitor import RX, TEXT, TX, Exchange, Item

log = logging.getLogger(__name__)

TICK = 0.1  # s the module's reader waits before it looks whether the bridge closed
# what ``notes.put`` is given: (TX | RX, bytes, time) on serial; (CAN_TX | CAN_RX, CanFrame)
# on CAN; (NOISE, bytes, time) for bytes of the master no frame could be made of; (LOST, why)
Put = Callable[[tuple], bool]


def _lost(exc: TransportError) -> str:
    """What was lost, without the link's "reconnect" (the bridge ends with it)."""
    return getattr(exc, "lost", None) or str(exc)


class _Target:
    """What the pty or TCP server serves: ``write`` gets the master's bytes, ``on_output``
    (set by the server) takes the module's to the master; ``beside``: the module's
    descriptor and what reads it, for the server's thread to wait on too (sim/serve.py), or
    None (the bridge's own thread reads the module)."""

    def __init__(self, write):
        self.write = write
        self.on_output = None
        self.beside: tuple[int, Callable[[], None]] | None = None


class _Bridge:
    """The forwarding, and the handing over of what was forwarded.

    Each chunk is put just before it is forwarded, so the notes keep the order the wire
    had (with a thread per direction too): an answer is never noted ahead of its request,
    nor a request ahead of the answer the master waited for; and whatever the master or
    the module got was noted, even if the bridge is killed right after. ``put`` never
    waits (ops/handoff.py); what it could not hand over was forwarded all the same and is
    counted there. ``lost``: why the module's link was lost, once it was (``ended`` is set
    then).
    """

    def __init__(self, put: Put, *, pty: bool = False, tcp: tuple[str, int] | None = None,
                 fd: int | None = None):
        from ..sim.serve import serve_pty, serve_tcp

        self.note = put
        self.lost: str | None = None
        self.ended = threading.Event()
        self._closed = threading.Event()
        self._reader: threading.Thread | None = None  # (before the server: it may forward at once)
        self.target = _Target(self._from_master)
        if fd is not None:  # (the server's thread reads the module as well)
            self.target.beside = (fd, self._ready)
        if pty:
            self.server = serve_pty(self.target)
            self.endpoint = self.server.path
        else:
            assert tcp is not None
            self.server = serve_tcp(self.target, *tcp)
            host, port = self.server.address
            self.endpoint = f"{host}:{port}"
        if fd is None:
            self._reader = threading.Thread(target=self._loop, name="bridge-module",
                                            daemon=True)
            self._reader.start()

    def _lose(self, why: str) -> None:
        if self.lost is None:
            self.lost = why
        self.note((LOST, why))
        self.ended.set()

    def _to_master(self, data: bytes) -> None:
        out = self.target.on_output
        if out is not None:
            out(data)

    def _from_master(self, data: bytes) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def _loop(self) -> None:
        try:
            while not self._closed.is_set():
                self._step(TICK)
        except Exception as exc:
            self._failed(exc)

    def _ready(self) -> None:
        """(The server's thread: the module's descriptor is readable.)"""
        if self._closed.is_set():
            return  # (closing: nothing more is read, nor noted as forwarded)
        try:
            self._step(0)
        except Exception as exc:
            self.target.beside = None  # (the server stops waiting on it)
            self._failed(exc)

    def _failed(self, exc: Exception) -> None:
        """Reading the module failed: the link was lost, or the bridge must say why it
        stopped forwarding."""
        if isinstance(exc, TransportError):
            if not self._closed.is_set():
                self._lose(_lost(exc))
        else:
            log.exception("the bridge's module reader failed", exc_info=exc)
            self._lose(f"the bridge stopped forwarding: {exc}")

    def _step(self, wait: float) -> None:  # pragma: no cover - overridden
        """What the module sent within ``wait`` seconds, noted and forwarded."""
        raise NotImplementedError

    def close(self) -> None:
        """Stop serving the master and stop reading the module (its link stays open: the
        front end may still need it); nothing is put after this returns."""
        if self._closed.is_set():
            return
        self._closed.set()
        self.server.close()
        if self._reader is not None:
            self._reader.join(timeout=2)


class SerialBridge(_Bridge):
    """A master on a pty or TCP port and a serial module: bytes forwarded unchanged."""

    def __init__(self, module: StreamTransport, put: Put, **kw):
        self.module = module
        super().__init__(put, fd=module.fileno(), **kw)

    def _from_master(self, data: bytes) -> None:
        self.note((TX, data, time.time()))
        try:
            self.module.write(data)
        except TransportError as exc:
            self._lose(_lost(exc))

    def _step(self, wait: float) -> None:
        data = self.module.read_some(wait)
        if data:
            self.note((RX, data, time.time()))
            self._to_master(data)


class CanBridge(_Bridge):
    """A master on a pty or TCP port speaking serial frames, and a module on CAN.

    ``can_id``: where requests go (None: the CAN id is each request's address byte, as a
    module's factory settings make them equal); ``reply_id``: where replies come from;
    ``host``: the address byte of the serial replies the master gets.
    """

    def __init__(self, module: CanTransport, put: Put, *, can_id: int | None = None,
                 reply_id: int = 2, host: int = 2, **kw):
        self.module = module
        self.can_id = can_id
        self.reply_id = reply_id
        self.host = host
        self.requests = FrameDecoder(None, resync=plausible_request)
        self._versions = 0  # version strings asked for and not yet answered
        super().__init__(put, **kw)

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
            if isa.reply_kind(raw[1], raw[2]) is ReplyKind.VERSION_STRING:
                self._versions += 1
            self.note((CAN_TX, CanFrame(time.time(), arb, raw[1:8])))
            try:
                self.module.send(arb, raw[1:8])
            except TransportError as exc:
                self._lose(_lost(exc))
                break

    def _step(self, wait: float) -> None:
        f = self.module.listen(wait)  # type: ignore[attr-defined]
        if f is None:
            return
        self.note((CAN_RX, f))
        if f.arbitration_id == self.reply_id and not (f.error or f.remote or f.extended):
            data = can_reply(f.data, version=self._versions > 0)  # (the one reading)
            if data is None:
                return
            if len(data) == CAN_VERSION:  # a version string: the host byte, no checksum
                self._versions -= 1
                self._to_master(bytes((self.host,)) + data)
            else:
                body = bytes((self.host,)) + data
                self._to_master(body + bytes((checksum(body),)))


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

    def to_dict(self) -> dict[str, list[int]]:
        """As the describer hands it back to the bridge's process (ops/handoff.py)."""
        return {"started": sorted(self.started), "download": sorted(self.download),
                "ascii": sorted(self.ascii)}

    @classmethod
    def from_dict(cls, d: dict) -> Left:
        return cls(set(d.get("started", ())), set(d.get("download", ())),
                   set(d.get("ascii", ())))

    def describe(self, address: int) -> str:
        what = [w for w, s in (("a motor or the stored program started", self.started),
                               ("the module in download mode", self.download),
                               ("the module in ASCII mode", self.ascii)) if address in s]
        return " and ".join(what)


__all__ = ["SerialBridge", "CanBridge", "Left", "TX", "RX", "CAN_TX", "CAN_RX", "NOISE",
           "LOST", "TICK"]
