"""Several modules in one run of ``-c`` or ``-f``: a production line's station, a test jig.

A *unit* is one (link, address) pair: ``--port`` given again, ``--all`` (every Trinamic USB
module attached), ``--address 1-8`` on one line, ``--can-id 1,2,5`` on one bus. Every unit
runs the same lines in its own session (its own variables ``${unit}``, ``${port}``,
``${address}``, its own checks and counts), checked against its own module type before
anything is sent to it, exactly as one ``-c``/``-f`` run is (``main.run_connected``).

How they run: one thread per link. Units on different links run side by side; units sharing
a line or a bus run in turn on their link's thread (a bus carries one exchange at a time, so
taking turns costs nothing, and a unit is never in doubt whose reply it read). Threads, not
processes: a run is waiting on its links far more than it computes (a line at 115200 baud is
1.6 ms of wire per exchange, tmclsh's own work a few tens of microseconds), so one
interpreter keeps up with many links; it starts once (a process per unit would pay
Python's start-up, a quarter of a second of CPU, for each), python-can's in-process virtual
bus works, and Windows runs the same way. What a unit's thread writes to stdout or stderr,
wherever in tmclsh it is written, goes to that unit's view (``unitview``): a live table on
a terminal, lines prefixed with the unit in a pipe, ``"unit"`` in every JSON object.

Ctrl-C, SIGTERM and SIGHUP reach the main thread, which raises ``KeyboardInterrupt`` in
every unit's thread that is running (``PyThreadState_SetAsyncExc``, at the next bytecode:
the same exception at the same kind of place as Ctrl-C in a run of one module): each unit
stops its module with the one stop (``stop.stop_all``) and says so; units not yet started
are not started. A unit that loses its link or whose module refuses a line fails alone.
"""

from __future__ import annotations

import argparse
import copy
import sys
import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ..base.errors import (EXIT_CONNECT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE,
                           ConnectError, TmclError, UsageError)

if TYPE_CHECKING:
    from .session import Session
    from .unitview import Record, View


@dataclass(frozen=True)
class Unit:
    """One module of a run: ``kind`` is how ``link`` is reached (port, can, sim)."""

    number: int
    kind: str
    link: str
    address: int | None = None  # serial address; None: the default (or the profile's)
    can_id: int | None = None
    reply_id: int | None = None

    @property
    def bus(self) -> tuple[str, str | int]:
        """What the unit shares with others that must take turns: its line or bus (each
        simulated unit is a module of its own)."""
        return (self.kind, self.link if self.kind != "sim" else self.number)

    @property
    def where(self) -> str:
        """The unit for people: ``/dev/ttyACM0 @1``, ``virtual:bench id 3``."""
        if self.kind == "can":
            return self.link + (f" id {self.can_id}" if self.can_id is not None else "")
        link = f"sim {self.link}" if self.kind == "sim" else self.link
        return link + (f" @{self.address}" if self.address is not None else "")

    @property
    def label(self) -> str:
        return f"{self.number} {self.where}"

    def tag(self, address: int) -> dict:
        """The fields every JSON object of the unit carries first."""
        if self.kind == "can":
            return {"unit": self.number, "can": self.link,
                    "can_id": self.can_id if self.can_id is not None else address}
        return {"unit": self.number, self.kind: self.link, "address": address}

    def args(self, args: argparse.Namespace) -> argparse.Namespace:
        """The command line as if it named this unit alone."""
        one = copy.copy(args)
        one.port = [self.link] if self.kind == "port" else None
        one.can = self.link if self.kind == "can" else None
        one.sim = self.link if self.kind == "sim" else None
        one.address = (self.address,) if self.address is not None else None
        one.can_id = (self.can_id,) if self.can_id is not None else None
        one.reply_id = (self.reply_id,) if self.reply_id is not None else None
        one.all_modules = False
        return one


def plan_units(args: argparse.Namespace) -> list[Unit]:
    """The units the command line names, in order: each link (``--port`` in the order given,
    then ``--all``'s), each address (or CAN id) on it. ``--all`` is resolved into ``--port``
    here, so a run of one unit goes on as any run of one module. Usage errors for what
    cannot be: a link or an address named twice, several CAN ids with several addresses."""
    ports = list(getattr(args, "port", None) or [])
    if getattr(args, "all_modules", False):
        if args.can or args.sim:
            raise UsageError("--all takes the attached USB modules; not with --can or --sim")
        from ..link import TRINAMIC_VID, trinamic_ports

        attached = [p.device for p in trinamic_ports()]
        if not attached:
            raise ConnectError(f"--all: no Trinamic USB module is attached (USB vendor "
                               f"{TRINAMIC_VID:04x}); 'tmclsh ports' lists the serial ports")
        ports += [d for d in attached if d not in ports]
        args.port = ports
    _no_twice("--port", ports)
    addresses = list(getattr(args, "address", None) or ())
    can_ids = list(getattr(args, "can_id", None) or ())
    reply_ids = list(getattr(args, "reply_id", None) or ())
    _no_twice("--address", addresses)
    _no_twice("--can-id", can_ids)
    kind, links = _links(args, ports, several=len(addresses) > 1 or len(can_ids) > 1)
    if kind == "can":
        if len(addresses) > 1:
            raise UsageError("on a CAN bus the modules are told apart by their CAN ids: "
                             "give --can-id 1,2,... (not --address)")
        ids: list[int | None] = list(can_ids) or [None]
        if len(reply_ids) > 1 and len(reply_ids) != len(ids):
            raise UsageError(f"--reply-id names {len(reply_ids)} ids for {len(ids)} CAN ids: "
                             "give one for all, or one for each")
        replies = reply_ids if len(reply_ids) > 1 else (reply_ids or [None]) * len(ids)
        return [Unit(n, kind, links[0], addresses[0] if addresses else None, can_id, reply)
                for n, (can_id, reply) in enumerate(zip(ids, replies), 1)]
    if len(can_ids) > 1 or len(reply_ids) > 1:
        raise UsageError("--can-id and --reply-id lists are for a CAN bus (--can)")
    per_link: list[int | None] = list(addresses) or [None]
    units = []
    for link in links:
        for address in per_link:
            units.append(Unit(len(units) + 1, kind, link, address,
                              can_ids[0] if can_ids else None,
                              reply_ids[0] if reply_ids else None))
    return units


def _no_twice(flag: str, values: list) -> None:
    seen = set()
    for v in values:
        if v in seen:
            raise UsageError(f"{flag} {v} is given twice")
        seen.add(v)


def _links(args: argparse.Namespace, ports: list[str], *, several: bool) -> tuple[str, list]:
    """(kind, links) the command line names; with none named and several addresses, the
    link a run of one module would take (a profile, TMCLSH_PORT, the one USB module)."""
    if ports:
        return "port", ports
    if getattr(args, "can", None):
        return "can", [args.can]
    if getattr(args, "sim", None):
        return "sim", [args.sim]
    if not several:
        return "port", [None]  # (one unit: whatever the run of one module finds)
    from ..client.connect import attached_module_port, connection_settings

    one = copy.copy(args)
    one.address = one.can_id = one.reply_id = None
    settings = connection_settings(one)
    for kind in ("port", "can", "sim"):
        if settings.get(kind):
            return kind, [settings[kind]]
    port = attached_module_port()
    if port is None:
        raise ConnectError("no module found: several addresses given but no --port, --can or "
                           "--sim (nor a profile or TMCLSH_PORT/TMCLSH_CAN naming one) and no "
                           "Trinamic USB module attached; give --port PORT")
    return "port", [port]


# -- running -----------------------------------------------------------------------------

def run_units(args: argparse.Namespace, units: list[Unit]) -> int:
    """Run ``-c``/``-f`` on every unit (see the module docstring); the exit status is 0 when
    every unit passed, 3 when a unit had no module (they are named), else 1 (2 when every
    unit refused the lines before anything was sent; the signal's status when stopped)."""
    if args.command is None and args.script is None:
        given = f"{len(units)} units given ({', '.join(u.where for u in units)})"
        if sys.stdin.isatty():
            raise UsageError(f"the prompt talks to one module; {given}: run -c or -f on them "
                             "all, or give one")
        raise UsageError(f"standard input is read once; {given}: give the lines with -c or "
                         "a script file with -f")
    if args.script == "-":
        raise UsageError("-f - reads standard input once; several units need a script file "
                         "(or -c)")
    if args.script is not None:
        _readable(args.script)
    from .unitview import make_view

    view = make_view(args, units)
    return Run(args, units, view).go()


def _readable(path: str) -> None:
    """The script is read by every unit; one that cannot be read is said once (exit 2)."""
    from pathlib import Path

    from .script import ScriptError, read_lines

    read_lines(Path(path), lambda message, kind: ScriptError(message, kind))


@dataclass
class _Line:
    """One link and its units, run in turn on one thread."""

    units: list[Unit]
    thread: threading.Thread | None = None
    # set as the thread ends; the main thread waits on it, not on Thread.join: a
    # KeyboardInterrupt landing in join(timeout) can mark a running thread as ended
    # (CPython's bpo-45274 handling), and the run would end with a unit still running
    finished: threading.Event = field(default_factory=threading.Event)
    current: Unit | None = None  # the unit running (a stop is raised in its thread)
    raised: bool = False  # a stop was raised in the thread and may not have landed yet
    lock: threading.Lock = field(default_factory=threading.Lock)
    # the units whose run ended before any stop (a motor may still turn: a stop of the
    # whole run reaches them too)
    done: list[Unit] = field(default_factory=list)


class Run:
    def __init__(self, args: argparse.Namespace, units: list[Unit], view: View):
        self.args, self.units, self.view = args, units, view
        self.stopping: str | None = None  # why the run is being stopped (Ctrl-C, a signal)
        self.stop_status = EXIT_INTERRUPTED
        lines: dict[tuple, _Line] = {}
        for unit in units:
            lines.setdefault(unit.bus, _Line([])).units.append(unit)
        self.lines = list(lines.values())

    def go(self) -> int:
        from .main import Terminated, exit_cleanly_on_signals

        exit_cleanly_on_signals()
        with self.view.showing():
            for line in self.lines:
                line.thread = threading.Thread(target=self._line, args=(line,),
                                               name=f"unit-line-{line.units[0].number}",
                                               daemon=True)
                line.thread.start()
            while True:
                try:
                    self._wait()
                    break
                except KeyboardInterrupt:
                    self._stop("interrupted", EXIT_INTERRUPTED)
                except Terminated as exc:
                    self._stop(exc.why, exc.code)
            if self.stopping is not None:
                self._stop_finished()
        return self._status()

    def _stop_finished(self) -> None:
        """A stop of the run reaches the units that had already ended too: a script may end
        with a motor turning ("left running"), and Ctrl-C stops every motor of the run."""
        for line in self.lines:
            for unit in line.done:
                record = self.view.record(unit)
                for _ in range(3):  # (Ctrl-C again while it stops: it stops all the same)
                    try:
                        self._stop_one(unit, record)
                        break
                    except KeyboardInterrupt:
                        self.view.note("stopping every unit; the stops are under way")

    def _stop_one(self, unit: Unit, record: Record) -> None:
        from ..client.connect import connection_settings, open_client
        from .main import stop_on_interrupt

        with record.attached():
            client = None
            try:
                client = open_client(connection_settings(unit.args(self.args)),
                                     notice=record.notice)
                stop_on_interrupt(client, self.stopping or "interrupted")
            except (TmclError, OSError) as exc:
                print(f"tmclsh: could not stop unit {unit.label}: {exc}", file=sys.stderr)
                record.error(f"not stopped: {exc}")
            finally:
                if client is not None:
                    client.close()

    def _wait(self) -> None:
        for line in self.lines:
            while not line.finished.wait(0.1):
                self.view.tick()

    def _stop(self, why: str, status: int) -> None:
        """Stop every unit that runs (each stops its module and says so); none starts."""
        if self.stopping is not None:
            self.view.note("stopping every unit; the stops are under way")
            return
        self.stopping, self.stop_status = why, status
        self.view.note(f"{why}: stopping every unit")
        for line in self.lines:
            with line.lock:
                if line.current is not None and line.thread is not None:
                    line.raised = True
                    _raise_in(line.thread, KeyboardInterrupt)

    def _line(self, line: _Line) -> None:
        try:
            for unit in line.units:
                record = self.view.record(unit)
                with line.lock:
                    if self.stopping is not None:
                        record.not_run(self.stopping)
                        continue
                    line.current = unit
                self._unit(line, unit, record)
        finally:
            try:
                for unit in line.units:
                    self.view.record(unit).not_run(self.stopping or "not reached")
            finally:
                line.finished.set()

    def _unit(self, line: _Line, unit: Unit, record: Record) -> None:
        from ..client.connect import connection_settings, open_client
        from .main import run_connected, stop_on_interrupt

        args = unit.args(self.args)
        client = None
        stopped = False
        with record.attached():  # what this thread writes goes to the unit's view
            try:
                try:
                    record.begin()
                    settings = connection_settings(args)
                    client = open_client(settings, notice=record.notice, tracer=record.tracer)
                    record.connected(client)
                    status = run_connected(args, client, settings,
                                           prepare=lambda session: self._prepare(
                                               unit, record, session))
                finally:
                    self._leave(line)  # from here on no stop is raised in this thread
            except KeyboardInterrupt:
                stopped = True
                status = self.stop_status
            except (TmclError, OSError) as exc:  # no module (or no link) for this unit
                print(f"tmclsh: {exc}", file=sys.stderr)
                record.error(str(exc))
                status = EXIT_CONNECT if client is None else EXIT_FAILED
            except Exception as exc:  # a bug must not take the other units down
                print(f"tmclsh: internal error: {exc!r}", file=sys.stderr)
                record.error(repr(exc))
                status = EXIT_FAILED
            try:
                if client is not None and self.stopping is not None:
                    # interrupted, or it ended just as the stop came: stopped all the same
                    stop_on_interrupt(client, self.stopping)
                    stopped = True
            finally:
                if client is not None:
                    client.close()
            if client is not None and not stopped:
                line.done.append(unit)
            record.end(status if not stopped else self.stop_status, interrupted=self.stopping)

    def _leave(self, line: _Line) -> None:
        """The unit's run is over: the stop is no longer raised in this thread, and one that
        was raised but has not landed yet is taken back (the unit is stopped by hand)."""
        with line.lock:
            line.current = None
            if line.raised:
                line.raised = False
                _raise_in(threading.current_thread(), None)

    def _prepare(self, unit: Unit, record: Record, session: Session) -> None:
        """The unit's own session: its variables, its tag on every JSON object, its view told
        of errors and progress."""
        client = session.client
        address = client.can_id if client.is_can else client.address
        session.variables.update(unit=unit.number, port=unit.link, address=address)
        session.out.tag = unit.tag(address)
        session.out.stdout, session.out.stderr = record.streams
        session.out.on_error = record.error
        session.progress = record.progress
        record.session = session
        if record.tracer is not None:
            session.closers.append(client.add_tracer(record.tracer(client)))

    def _status(self) -> int:
        records = [self.view.record(u) for u in self.units]
        missing = [r for r in records if r.status == EXIT_CONNECT]
        self.view.finish(records)
        if missing:
            self.view.note("no module for unit " + ", unit ".join(r.unit.label
                                                                  for r in missing))
        if self.stopping is not None:
            return self.stop_status
        if missing:
            return EXIT_CONNECT
        if all(r.status == EXIT_OK for r in records):
            return EXIT_OK
        if all(r.status == EXIT_USAGE for r in records):
            return EXIT_USAGE
        return EXIT_FAILED


def _raise_in(thread: threading.Thread, exc_type: type[BaseException] | None) -> None:
    """Raise ``exc_type`` in ``thread`` at its next bytecode (what Ctrl-C does to the main
    thread), so a unit unwinds and stops its module as a run of one module does; None takes
    back one raised that has not landed yet."""
    import ctypes

    if thread.ident is None:
        return
    ctypes.pythonapi.PyThreadState_SetAsyncExc(
        ctypes.c_ulong(thread.ident), None if exc_type is None else ctypes.py_object(exc_type))

