"""``tmclsh bridge``: another program talks to the module through tmclsh, every frame
forwarded unchanged (ops/bridge.py) and shown as ``tmclsh monitor`` shows it.

Like ``tmclsh sim``, the first line on stdout is where the program connects (the pty's path
or HOST:PORT); the traffic follows, one line per exchange (or one JSON object per frame),
until Ctrl-C or SIGTERM, then the summary. Forwarding comes first: the frames are read and
shown on another thread, and lines a reader does not take (a paused pager, a full pipe) are
dropped and counted in the summary, never frames or the forwarding's pace.

When the bridge closes, the program on the other side loses the module: what its exchanges
left behind is ended then, as tmclsh ends its own (the one safety stop, shell/features/stop.py): a
motor or the stored program it started is stopped, download mode it entered is left (133),
and ASCII mode it entered is left for binary mode.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from typing import Any

from ...base.canspec import LINK_DEFAULTS
from ...base.errors import (EXIT_FAILED, EXIT_OK, ConnectError, TmclError, TransportError, UsageError,
                            ValidationError)
from ...ops.bridge import CAN_RX, CAN_TX, LOST, TICK, CanBridge, Left, SerialBridge
from ...ops.filter import Filter
from ...ops.monitor import DEFAULT_HOST, RX, TX, CanReader, Monitor, SerialPair
from .livetable import wanted
from .monitor import (Limits, View, _capture, end_live_output, end_table, interruptible,
                      live_output, live_table, load_module, off_the_wire, restore, show_items)


FORWARDING_SWITCH = 0.0002  # s a thread may hold the interpreter while another waits


def run_bridge(args) -> int:
    module = load_module(getattr(args, "module", None))
    monitor = Monitor(module, timeout=getattr(args, "timeout", None) or 1.0)
    filt = Filter(args.address or (), args.op or (), args.param or (), monitor)
    port, can_spec = getattr(args, "port", None), getattr(args, "can", None)
    if (port is None) == (can_spec is None):
        raise UsageError("bridge forwards to one module: give --port PORT or "
                         "--can [IFACE:CHANNEL]")
    if args.pty and not hasattr(os, "openpty"):
        raise UsageError("a pseudo-terminal needs Linux or macOS; use --tcp HOST:PORT")
    is_can = can_spec is not None
    can_id = getattr(args, "can_id", None)
    reply_id = getattr(args, "reply_id", None) or LINK_DEFAULTS["reply_id"]
    host = getattr(args, "host_address", None)
    host = DEFAULT_HOST if host is None else host
    json_mode = bool(getattr(args, "json", False))
    with_table = wanted(args, json_mode)
    transport = _open_module(args, port, can_spec)
    view = View(monitor, json_mode=json_mode, hex_bytes=args.hex)
    try:
        capture, close_capture = _capture(args.output, is_can)
    except BaseException:
        transport.close()
        raise
    # forwarding first: showing and the -o file never hold it up (what they cannot keep
    # up with is dropped and counted, never a frame on the wire)
    capture, close_capture, capture_dropped = off_the_wire(capture, close_capture)
    out = live_output(view)
    table = live_table(with_table, view, monitor, out, True)
    serve: dict[str, Any] = {"pty": True} if args.pty else {"tcp": args.tcp}
    if is_can:
        reader: Any = CanReader(monitor, [can_id] if can_id is not None else None,
                                [reply_id], learn=False)
    else:
        reader = SerialPair(monitor)
    told = _Told(reader, view, filt, monitor, capture, Limits(args.count, args.duration, False))
    try:
        if is_can:
            bridge: Any = CanBridge(transport, told, can_id=can_id, reply_id=reply_id,
                                    host=host, **serve)
        else:
            bridge = SerialBridge(transport, told, **serve)
    except OSError as exc:
        transport.close()
        close_capture()
        end_live_output(view, out, monitor.summary)
        raise ConnectError(f"cannot serve the bridge: {exc}") from exc
    sys.stdout.write(bridge.endpoint + "\n")
    sys.stdout.flush()
    print(f"bridging {bridge.endpoint} <-> {transport.describe()}; Ctrl-C ends",
          file=sys.stderr, flush=True)
    if table is not None:
        table.start()
    # the forwarding threads wait for the interpreter while the teller reads and shows
    # what was forwarded: a short switch interval bounds that wait (the default 5 ms would
    # be the forwarding's worst case)
    switch = sys.getswitchinterval()
    sys.setswitchinterval(FORWARDING_SWITCH)
    try:
        _forward(bridge, told)
    finally:
        sys.setswitchinterval(switch)
        monitor.summary.untold = bridge.untold
        try:
            if told.left:
                _put_right(transport, told.left, monitor, args, is_can, told.lost, capture)
        finally:
            close_capture()  # (after the closing stop: a replayed capture shows it too)
            monitor.summary.capture_dropped = capture_dropped()
            transport.close()
            end_table(view)  # (again: once only, if _forward did not end it)
            end_live_output(view, out, monitor.summary)
    view.summary(monitor.summary)
    return EXIT_OK if told.lost is None else EXIT_FAILED


def _open_module(args, port: str | None, can_spec: str | None):
    from ...link.spec import LinkSpec

    try:
        return LinkSpec.parse(port, can_spec, baud=getattr(args, "baud", None),
                              bitrate=getattr(args, "bitrate", None)).open()
    except (TransportError, ValidationError) as exc:
        raise ConnectError(str(exc)) from exc


class _Told:
    """What the bridge tells (on its forwarding threads, in the wire's order, under its
    lock): read into items, shown, and what they leave behind kept (``left``)."""

    def __init__(self, reader, view: View, filt: Filter, monitor: Monitor, capture,
                 limits: Limits):
        self.reader, self.view, self.filt, self.monitor = reader, view, filt, monitor
        self.capture, self.limits = capture, limits
        self.left = Left()
        self.lost: str | None = None
        self.done = threading.Event()  # a limit reached or the module's link lost

    def __call__(self, event: tuple) -> None:
        items, lost = _read(event, self.reader, self.monitor, self.capture)
        if lost is not None and self.lost is None:
            self.lost = lost
            self.done.set()
        self.show(items)

    def show(self, items: list) -> None:
        for item in items:
            self.left.take(item)
        if self.done.is_set() and self.lost is None:
            return  # (the count was reached: still read and counted, not shown)
        summary = self.monitor.summary
        if show_items(items, self.view, self.filt, summary, self.limits) \
                or self.limits.reached(summary.shown, summary):
            self.done.set()
        self.view.flush()


def _forward(bridge, told: _Told) -> None:
    """Forward until Ctrl-C, SIGTERM, a limit, or the module's link is lost; in between,
    a silence ends partial frames and requests wait no longer than their timeout."""
    previous = interruptible()
    try:
        try:
            while not told.done.wait(TICK):
                quiet = bridge.quiet_for() >= TICK  # (else bytes may still be told)
                with bridge.lock:
                    now = time.time()
                    told.show(told.reader.quiet(now) if quiet else told.monitor.expire(now))
        except KeyboardInterrupt:
            pass
        finally:
            bridge.close()  # (what was forwarded before is told)
        with bridge.lock:
            told.show(told.reader.end(time.time()))
        end_table(told.view)  # (before what is said on stderr from here on)
        if told.lost is not None:
            print(f"bridge: {told.lost}", file=sys.stderr)
    finally:
        restore(previous)
        told.view.flush()


def _read(event: tuple, reader, monitor: Monitor, capture) -> tuple[list, str | None]:
    """One thing the bridge told, read: (the items, why the module's link was lost)."""
    kind = event[0]
    if kind == LOST:
        return [], event[1]
    if kind in (TX, RX):
        _, data, t = event
        if capture is not None:
            capture(t, data, kind)
        return reader.feed(kind, data, t), None
    if kind in (CAN_TX, CAN_RX):
        f = event[1]
        if capture is not None:
            capture(f)
        if kind == CAN_TX:
            reader.request_ids.add(f.arbitration_id)
        return reader.feed(f.t, f.arbitration_id, f.data, extended=f.extended, error=f.error,
                           remote=f.remote), None
    _, data, t = event  # NOISE: the master's bytes no frame could be made of
    return monitor.noise(t, data, f"{len(data)} bytes of the program's that are no frame: "
                                  "not forwarded to CAN", TX), None


def _put_right(transport, left: Left, monitor: Monitor, args, is_can: bool,
               lost: str | None, capture=None) -> None:
    """The program can no longer reach the module: end what its exchanges left behind.
    ``capture`` (``-o``) gets the frames sent for that too, so a replayed capture ends as
    the module was left."""
    from ...client import bringup
    from ...client.ascii import leave_binary
    from ...client.core import Client
    from .stop import ToStderr, stop_all

    for address in left.addresses:
        what = left.describe(address)
        if lost is not None:
            print(f"bridge closed: the traffic through it left {what} at address "
                  f"{address}, and the link to the module is lost: check the module",
                  file=sys.stderr)
            continue
        print(f"bridge closed: the traffic through it left {what} at address {address}; "
              "ending that", file=sys.stderr)
        if not transport.is_open:
            transport.open()
        can_id = getattr(args, "can_id", None)
        client = Client(transport, address=address if address <= 0xFF else 1,
                        host_address=monitor.host_of.get(address, DEFAULT_HOST),
                        module=monitor.module_for(address), timeout=0.5,
                        can_id=(can_id if can_id is not None else address) if is_can else None,
                        reply_id=getattr(args, "reply_id", None))
        if capture is not None:
            client.add_tracer(_capturing(capture, client, is_can))
        try:
            bringup.bring_up(client, strict=False)  # (leaves download mode, finds ASCII)
            if address in left.ascii:
                leave_binary(client)
            if address in left.started:
                stop_all(client, ToStderr(), "bridge closed")
        except TmclError as exc:
            print(f"bridge closed: could not end it at address {address}: {exc}",
                  file=sys.stderr)
        finally:
            client.close()


def _capturing(capture, client, is_can: bool):
    """A tracer that writes what the closing stop sends and gets to the ``-o`` capture, as
    the bridge writes what it forwards (bytes with their direction; CAN frames)."""
    from ...link.base import CanFrame

    def trace(direction: str, raw: bytes, decoded: object) -> None:
        if direction not in ("tx", "rx", "drop") or not isinstance(raw, (bytes, bytearray)):
            return
        now = time.time()
        if not is_can:
            capture(now, bytes(raw), TX if direction == "tx" else RX)
        elif direction == "tx":
            capture(CanFrame(now, client.can_id, bytes(raw)))
        elif direction == "rx":
            capture(CanFrame(now, client.reply_id, bytes(raw)))
    return trace
