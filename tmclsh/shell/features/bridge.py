"""``tmclsh bridge``: another program talks to the module through tmclsh, every frame
forwarded unchanged (ops/bridge.py) and shown as ``tmclsh monitor`` shows it.

Like ``tmclsh sim``, the first line on stdout is where the program connects (the pty's path
or HOST:PORT); the traffic follows, one line per exchange (or one JSON object per frame),
until Ctrl-C or SIGTERM, then the summary. Forwarding comes first: the frames are read and
shown in a process of its own (ops/handoff.py), and lines a reader does not take (a paused
pager, a full pipe) are dropped and counted in the summary, never frames or the
forwarding's pace.

When the bridge closes, the program on the other side loses the module: what its exchanges
left behind is ended then, as tmclsh ends its own (the one safety stop, shell/features/stop.py): a
motor or the stored program it started is stopped, download mode it entered is left (133),
and ASCII mode it entered is left for binary mode.
"""

from __future__ import annotations

import os
import sys
import time
from typing import Any

from ...base.canspec import LINK_DEFAULTS
from ...base.errors import (EXIT_FAILED, EXIT_OK, ConnectError, TmclError, TransportError, UsageError,
                            ValidationError)
from ...base.interrupts import Terminated, restore, terminated_by
from ...ops.bridge import CAN_RX, CAN_TX, LOST, NOISE, TICK, CanBridge, Left, SerialBridge
from ...ops.filter import Filter
from ...ops.handoff import CAPTURE, DONE, END, FINISH, LEFT, START, Describer, give_way
from ...ops.monitor import DEFAULT_HOST, RX, TX, CanReader, Monitor, SerialPair
from .livetable import wanted
from .monitor import (Limits, View, _capture, end_live_output, end_table, interruptible,
                      live_output, live_table, load_module, off_the_wire, said_ended,
                      show_items)
from .stop import ToStderr

SOON = 2.0  # s the describer takes, as a rule, to read the rest and say what it left
LEFT_WAIT = 30.0  # s it may take beyond that (far behind on a busy machine: a pipe's 1 MiB)
OUTPUT_EVERY = 0.02  # s between the describer's writes of its lines: a batch a write, not a line
END_WAIT = 5.0  # s it may take to finish after Ctrl-C gave up on its reader
DRAIN_WAIT = 2.0  # s the describer's last lines may take to reach the terminal before the
# bridge's own words follow them (a terminal that takes longer has them after)


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
    transport = _open_module(args, port, can_spec)
    view = View(monitor, json_mode=json_mode, hex_bytes=args.hex)
    try:
        *capture, flush_capture = _capture(args.output, is_can)
        flush_capture()  # (its header: written by the describer alone from here)
    except BaseException:
        transport.close()
        raise
    if is_can:
        reader: Any = CanReader(monitor, [can_id] if can_id is not None else None,
                                [reply_id], learn=False)
    else:
        reader = SerialPair(monitor)
    teller = _Teller(reader, view, filt, monitor, capture,
                     Limits(args.count, args.duration, False), wanted(args, json_mode))
    # forwarding first: everything that describes it runs in a process of its own (forked
    # here, before the bridge has a thread), and what it cannot keep up with is dropped
    # and counted, never a frame on the wire or the forwarding's time
    describer = Describer(teller.run, name="bridge-describer")
    describer.start()
    previous = interruptible()  # (from here Ctrl-C, SIGTERM and SIGHUP end the bridge as one)
    ended_all = True  # (what the traffic left at the module was ended, or nothing was)
    ended: list[Terminated] = []  # the SIGTERM or SIGHUP that ended the forwarding
    try:
        bridge = _serve(transport, describer, args, is_can, can_id, reply_id, host)
        try:
            left = _forward(bridge, describer, transport, args.output, ended)
            if left is None or describer.notes.dropped:
                ended_all = False  # (what the traffic left is not known: "check the module")
            if left and not _put_right(transport, left, monitor, args, is_can, bridge.lost,
                                       lambda event: describer.notes.send((CAPTURE, event))):
                ended_all = False
        finally:
            transport.close()
            describer.notes.send((FINISH, describer.notes.dropped))
            _finished(describer)
            if describer.status and args.output:
                _salvage(capture[1])
    finally:
        restore(previous)
    if ended:  # (the signal's status, as every command ends on it)
        return ended[0].code  # type: ignore[return-value]
    return EXIT_OK if bridge.lost is None and describer.status == 0 and ended_all \
        else EXIT_FAILED


# the bridge's own words: never in the way of what it does (stderr may be a pipe whose
# reader has gone: the closing stop is still done)
_say = ToStderr().ok


def _salvage(close_capture) -> None:
    """The describer ended before it closed the ``-o`` file: what reached the disk until
    then (pushed every half second) is kept under its name, as the describer would have."""
    try:
        close_capture()
    except OSError:  # (FileError is one)
        pass  # (it had closed it after all: its reader, not its file, was gone)


def _terminal_back() -> None:
    """The describer ended with the terminal as its live table left it (cursor hidden, in
    the middle of a line): the cursor shown and a line begun, where stdout is a terminal."""
    try:
        if sys.stdout.isatty():
            sys.stdout.write("\x1b[?25h\n")
            sys.stdout.flush()
    except (OSError, ValueError):
        pass


def _serve(transport, describer: Describer, args, is_can: bool, can_id, reply_id, host):
    serve: dict[str, Any] = {"pty": True} if args.pty else {"tcp": args.tcp}
    put = describer.notes.put
    try:
        if is_can:
            return CanBridge(transport, put, can_id=can_id, reply_id=reply_id, host=host,
                             **serve)
        return SerialBridge(transport, put, **serve)
    except BaseException as exc:
        transport.close()
        describer.notes.close()  # (it ends without a word: nothing was bridged)
        describer.join(END_WAIT)
        if isinstance(exc, OSError):
            raise ConnectError(f"cannot serve the bridge: {exc}") from exc
        raise


def _open_module(args, port: str | None, can_spec: str | None):
    from ...link.spec import LinkSpec

    try:
        return LinkSpec.parse(port, can_spec, baud=getattr(args, "baud", None),
                              bitrate=getattr(args, "bitrate", None)).open()
    except (TransportError, ValidationError) as exc:
        raise ConnectError(str(exc)) from exc


def _forward(bridge, describer: Describer, transport, output: str | None,
             ended: list[Terminated]) -> Left | None:
    """Say where the program connects, then forward until Ctrl-C, SIGTERM, a limit the
    describer reached, or the module's link lost; then what the traffic left, as the
    describer read it (None: it could not say). A SIGTERM or SIGHUP that ended it is said
    and put in ``ended``."""
    try:
        sys.stdout.write(bridge.endpoint + "\n")
        sys.stdout.flush()
        _say(f"bridging {bridge.endpoint} <-> {transport.describe()}; Ctrl-C ends")
        describer.notes.send((START,))  # (the table may draw now: below those two lines)
        describing = True
        while not bridge.ended.is_set():
            if not describing:
                bridge.ended.wait(TICK)
                continue
            describer.notes.catch_up()  # (what the pipe could not take, a tick late at most)
            got = describer.back.take(TICK)
            if got is None:  # (it is gone: the forwarding is not)
                describing = False
                _terminal_back()
                written = f"; {output} keeps what was written until now" if output else ""
                _say(f"bridge: the process that shows the traffic has ended: nothing more "
                     f"is shown{written}; forwarding goes on until Ctrl-C")
            elif any(event[0] == DONE for event in got):
                break
    except KeyboardInterrupt as exc:
        signalled = terminated_by(exc)
        if signalled is not None:
            ended.append(signalled)
    finally:
        bridge.close()  # (nothing is put after this)
    if ended:
        said_ended(ended[0], "stopped forwarding")
    describer.notes.send((END,))
    try:
        said = describer.wait_for(LEFT, SOON)
        if said is None and describer.alive:
            _say("bridge: reading the rest of what was forwarded, to end what it left at "
                 "the module (Ctrl-C skips that)")
            said = describer.wait_for(LEFT, LEFT_WAIT)
    except KeyboardInterrupt:
        said = None
    if bridge.lost is not None:
        _say(f"bridge: {bridge.lost}")
    if said is None:
        why = "could not be read in time" if not describer.gone(0.5) else \
            "is not known (the process that showed the traffic ended)"
        _say(f"bridge closed: what the traffic through it left at the module {why}: check "
             "the module")
        return None
    if describer.notes.dropped:
        _say(f"bridge closed: {describer.notes.dropped} chunks of the traffic were forwarded "
             "but not read (reading fell too far behind): what they left at the module is "
             "not known: check the module")
    return Left.from_dict(said[1])


def _finished(describer: Describer) -> None:
    """Wait for the describer's last lines and summary to reach their reader; Ctrl-C gives
    up on a reader that does not take them (the describer then writes the summary)."""
    try:
        while not describer.join(TICK):
            pass
    except KeyboardInterrupt:
        describer.interrupt()
        if not describer.join(END_WAIT):
            describer.kill()


class _Teller:
    """The describing side (ops/handoff.py ``Describer``): what the bridge forwarded, read
    into items, shown, written to ``-o``, and what it leaves behind kept (``left``, handed
    back at ``END``); at ``FINISH``, the summary."""

    def __init__(self, reader, view: View, filt: Filter, monitor: Monitor, capture,
                 limits: Limits, with_table: bool):
        self.reader, self.view, self.filt, self.monitor = reader, view, filt, monitor
        self.capture, self.close_capture = capture
        self.limits, self.with_table = limits, with_table
        self.left = Left()
        self.lost: str | None = None
        self.done = False  # a limit reached or the module's link lost
        self.heard = time.time()  # the time of the newest thing forwarded that was read

    def run(self, notes, back) -> None:
        """Until ``FINISH`` (or the end of ``notes``: the bridge's process has gone)."""
        view, monitor, reader = self.view, self.monitor, self.reader
        self.capture, close_capture, capture_dropped = off_the_wire(self.capture,
                                                                      self.close_capture)
        self.out = None
        self.waiting: list[tuple] | None = []  # (what came before the endpoint was out)
        self.ended = said_done = orphaned = False
        last = ticked = time.monotonic()
        try:
            while (got := notes.take(TICK)) is not None:
                now = time.monotonic()
                for event in got:
                    if self.take(event, back):
                        return
                    give_way()
                if got:
                    last = now
                if not self.ended and now - ticked >= TICK:
                    # (a line quiet for a tick has partial frames; else the requests are
                    # expired as of the newest thing read, not of the clock: a describer
                    # behind the wire would call answers it has yet to read missing)
                    ticked = now
                    self.show(reader.quiet(time.time()) if now - last >= TICK
                              else monitor.expire(self.heard))
                if self.done and not said_done:
                    said_done = back.send((DONE,), timeout=0)
            # (the bridge's process has gone: a shell may be back at its prompt below the
            # table, so the end is not drawn over it: the cursor is given back, no more;
            # what it forwarded before it could say the endpoint was out is still shown)
            if view.table is not None:
                view.table.abandon()
            elif self.waiting:
                self.begin(table=False)
            orphaned = True
        finally:
            if not self.ended and not orphaned:
                self.show(reader.end(time.time()))
            close_capture()  # (after the closing stop: a replayed capture shows it too)
            monitor.summary.capture_dropped = capture_dropped()
            end_table(view)
            if self.out is not None:
                end_live_output(view, self.out, monitor.summary)
                if not orphaned:
                    view.summary(monitor.summary)
            view.flush()

    def take(self, event: tuple, back) -> bool:
        """One thing from the bridge's process; True at ``FINISH``."""
        kind = event[0]
        if self.waiting is not None:
            if kind not in (START, END, FINISH):
                self.waiting.append(event)
                return False
            self.begin(table=kind == START)
        if kind == END:
            self.show(self.reader.end(time.time()))
            self.ended = True
            end_table(self.view)  # (before what the bridge says on stderr)
            if self.out is not None:
                self.out.drain(DRAIN_WAIT)
            back.send((LEFT, self.left.to_dict()))
        elif kind == CAPTURE:
            _write(self.capture, event[1])
        elif kind == FINISH:
            self.monitor.summary.untold = event[1]
            return True
        elif kind != START:
            self.tell(event)
        return False

    def begin(self, table: bool) -> None:
        """The endpoint is out: the lines (and the table) follow it from here."""
        self.out = live_output(self.view, OUTPUT_EVERY)
        if table:
            live = live_table(self.with_table, self.view, self.monitor, self.out, True)
            if live is not None:
                live.start()
        early, self.waiting = self.waiting or [], None
        for event in early:
            self.tell(event)

    def tell(self, event: tuple) -> None:
        kind = event[0]
        if kind in (TX, RX, NOISE):
            self.heard = event[2]
        elif kind in (CAN_TX, CAN_RX):
            self.heard = event[1].t
        items, lost = _read(event, self.reader, self.monitor, self.capture)
        if lost is not None and self.lost is None:
            self.lost = lost
            self.done = True
        self.show(items)

    def show(self, items: list) -> None:
        for item in items:
            self.left.take(item)
        if self.done and self.lost is None:
            return  # (the count was reached: still read and counted, not shown)
        summary = self.monitor.summary
        if show_items(items, self.view, self.filt, summary, self.limits) \
                or self.limits.reached(summary.shown, summary):
            self.done = True
        self.view.flush()


def _write(capture, event: tuple) -> None:
    """A chunk (TX, RX) or CAN frame the bridge forwarded, or one of the closing stop's,
    written to the ``-o`` file."""
    if capture is None:
        return
    if event[0] in (TX, RX):
        capture(event[2], event[1], event[0])
    else:
        capture(event[1])


def _read(event: tuple, reader, monitor: Monitor, capture) -> tuple[list, str | None]:
    """One thing the bridge forwarded, read: (the items, why the module's link was lost)."""
    kind = event[0]
    if kind == LOST:
        return [], event[1]
    if kind in (TX, RX):
        _write(capture, event)
        _, data, t = event
        return reader.feed(kind, data, t), None
    if kind in (CAN_TX, CAN_RX):
        _write(capture, event)
        f = event[1]
        if kind == CAN_TX:
            reader.request_ids.add(f.arbitration_id)
        return reader.feed(f.t, f.arbitration_id, f.data, extended=f.extended, error=f.error,
                           remote=f.remote), None
    _, data, t = event  # NOISE: the master's bytes no frame could be made of
    return monitor.noise(t, data, f"{len(data)} bytes of the program's that are no frame: "
                                  "not forwarded to CAN", TX), None


def _put_right(transport, left: Left, monitor: Monitor, args, is_can: bool,
               lost: str | None, capture=None) -> bool:
    """The program can no longer reach the module: end what its exchanges left behind.
    ``capture`` gets the frames sent for that as the bridge's events, for the ``-o`` file,
    so a replayed capture ends as the module was left. False: something may still be left
    (said; the run then fails). What it says never stops it: stderr may be a pipe whose
    reader has gone (``_say``)."""
    ended = True
    try:
        for address in left.addresses:
            what = left.describe(address)
            if lost is not None:
                _say(f"bridge closed: the traffic through it left {what} at address "
                     f"{address}, and the link to the module is lost: check the module")
                continue
            _say(f"bridge closed: the traffic through it left {what} at address {address}; "
                 "ending that")
            try:
                ended = _end_at(transport, address, left, monitor, args, is_can,
                                capture) and ended
            except TmclError as exc:  # (a TransportError too: the port could not reopen)
                _say(f"bridge closed: could not end it at address {address}: {exc}")
                ended = False
    except KeyboardInterrupt:
        _say("bridge closed: interrupted again: what the traffic left may still be there: "
             "check the module")
        return False
    return ended and lost is None


def _end_at(transport, address: int, left: Left, monitor: Monitor, args, is_can: bool,
            capture) -> bool:
    """``_put_right`` at one address: False when a motor may still turn there."""
    from ...client import bringup
    from ...client.ascii import leave_binary
    from ...client.advice import OPTIONS
    from ...client.core import Client
    from .stop import stop_all

    if not transport.is_open:
        transport.open()
    can_id = getattr(args, "can_id", None)
    client = Client(transport, address=address if address <= 0xFF else 1,
                    host_address=monitor.host_of.get(address, DEFAULT_HOST),
                    module=monitor.module_for(address), timeout=0.5,
                    can_id=(can_id if can_id is not None else address) if is_can else None,
                    reply_id=getattr(args, "reply_id", None))
    client.advice = OPTIONS  # (its messages' advice names the command line's options)
    try:
        if capture is not None:
            client.add_tracer(_capturing(capture, client, is_can))
        # what the bring-up notices on its own is said as the bridge's; of the ASCII mode
        # it finds, nothing ("it stays in ASCII mode at exit" would be wrong): the bridge
        # has said it ends that, and does right after
        client.on_notice = _unsaid if address in left.ascii else _said_closing
        bringup.bring_up(client, strict=False)  # (leaves download mode, finds ASCII)
        if address in left.ascii:
            leave_binary(client)
        if address not in left.started:
            return True
        report = stop_all(client, ToStderr(), "bridge closed")
        # (a motor that may still turn fails the run, and a program the module said runs
        # that 128 could not stop; a 128 refused where 135 told nothing is said, as a
        # module without stored programs runs none)
        return report is not None and not (
            report.turning or report.unknown or report.link_error
            or (report.program_error and report.running))
    finally:
        client.close()


def _said_closing(text: str) -> None:
    _say(f"bridge closed: {text}")


def _unsaid(text: str) -> None:
    """(A notice the closing stop's own words supersede.)"""


def _capturing(capture, client, is_can: bool):
    """A tracer that hands what the closing stop sends and gets on as the bridge's own
    events (bytes with their direction; CAN frames), for the ``-o`` capture."""
    from ...link.base import CanFrame

    def trace(direction: str, raw: bytes, decoded: object) -> None:
        if direction not in ("tx", "rx", "drop") or not isinstance(raw, (bytes, bytearray)):
            return
        now = time.time()
        if not is_can:
            capture((TX if direction == "tx" else RX, bytes(raw), now))
        elif direction == "tx":
            capture((CAN_TX, CanFrame(now, client.can_id, bytes(raw))))
        elif direction == "rx":
            capture((CAN_RX, CanFrame(now, client.reply_id, bytes(raw))))
    return trace
