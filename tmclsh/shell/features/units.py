"""Several modules in one run of ``-c`` or ``-f``: a production line's station, a test jig.

A *unit* is one (link, address) pair: ``--port`` given again, ``--all`` (every Trinamic USB
module attached), ``--address 1-8`` on one line, ``--can-id 1,2,5`` on one bus. Every unit
runs the same lines in its own session (its own variables ``${unit}``, ``${port}``,
``${address}``, its own checks and counts), checked against its own module type before
anything is sent to it, exactly as one ``-c``/``-f`` run is (``main.run_connected``).

How they run (one thread per link, units sharing a line or a bus in turn, the stop raised in
every unit's thread) is ``ops/units.py``; this is its front end. What a unit's thread writes
to stdout or stderr,
wherever in tmclsh it is written, goes to that unit's view (``unitview``): a live table on
a terminal, lines prefixed with the unit in a pipe, ``"unit"`` in every JSON object.

Ctrl-C, SIGTERM and SIGHUP stop every unit: each stops its module with the one stop
(``stop.stop_all``) and says so; units not yet started are not started. So does stdout's
reader going away (``| head``), as it cuts a run of one module short: each unit that set a
motor moving stops it and says so on stderr, the rest are sent nothing more, and the run
ends with the status a run of one module ends with there. A unit that loses its link or
whose module refuses a line fails alone.
"""

from __future__ import annotations

import argparse
import copy
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

from ...base.config import Config, load_config
from ...base.errors import (EXIT_CONNECT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE,
                            ConnectError, TmclError, UsageError)
from ...base.interrupts import Terminated
from ...client.connect import connection_settings, open_client
from ...ops import units as ops_units
from ...ops.units import Unit
from ..lang import main as shell_main
from ..lang.main import READER_GONE, exit_cleanly_on_signals, stop_on_interrupt
from . import stop as _stop  # noqa: F401  (here: a unit's thread imports nothing)

if TYPE_CHECKING:
    from ..lang.session import Session
    from .unitview import View


def unit_args(unit: Unit, args: argparse.Namespace) -> argparse.Namespace:
    """The command line as if it named this unit alone."""
    one = copy.copy(args)
    one.port = [unit.link] if unit.kind == "port" else None
    one.can = unit.link if unit.kind == "can" else None
    one.sim = unit.link if unit.kind == "sim" else None
    one.address = (unit.address,) if unit.address is not None else None
    one.can_id = (unit.can_id,) if unit.can_id is not None else None
    one.reply_id = (unit.reply_id,) if unit.reply_id is not None else None
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
        from ...link import TRINAMIC_VID, trinamic_ports

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
    from ...client.connect import attached_module_port

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
    text = args.command if args.script is None else "\n".join(_readable(args.script))
    # read here, once: parsing the file imports a TOML parser (not in a unit's thread), and
    # every unit runs with the same settings
    config = load_config()
    commands = _load_ahead(text)
    from .unitview import make_view

    view = make_view(args, units)
    return Run(args, units, view, config, writes_files=commands).go()


def _readable(path: str) -> list[str]:
    """The script is read by every unit; one that cannot be read is said once (exit 2)."""
    from pathlib import Path

    from ..lang.script import ScriptError, read_lines

    return read_lines(Path(path), lambda message, kind: ScriptError(message, kind))


def _load_ahead(text: str) -> bool:
    """Import here, in the main thread, the feature modules the lines' commands live in (a
    run of one module imports them when they first run): a stop raised in a unit's thread
    while it imports would leave the module half made for every other unit. True: the lines
    hold commands (only a command writes a file: without one, the temporary files' modules
    stay out of the start every unit waits for)."""
    from ..lang import expr, script  # noqa: F401  (every run evaluates and checks its lines)
    from ..lang.lines import classify, split_text
    from ..render import load_rich

    if text.startswith("//"):  # (a configuration backup replayed: script.as_replayed)
        from . import clone  # noqa: F401
    commands = False
    for line in split_text(text):
        command = classify(line).command
        if command is not None:
            command.load()
            commands = True
    # (a unit's notes, errors and trace lines are styled, its tables drawn by rich: even in a
    # pipe, some of them go through rich)
    load_rich()
    return commands


class ReaderGone(Exception):
    """Whoever read the run's stdout went away: the run is stopped as a signal stops it
    (``ops.units.Run``'s interrupts), with these words."""

    why = READER_GONE


class Run(ops_units.Hooks):
    """The shell's front end of ``ops.units.Run``: each unit a run of ``main.run_connected``
    on its module, shown through the view (``unitview``)."""

    def __init__(self, args: argparse.Namespace, plan: list[Unit], view: View,
                 config: Config | None = None, *, writes_files: bool = True):
        self.args, self.units, self.view = args, plan, view
        self.config = config if config is not None else load_config()  # (see run_units)
        self.run = ops_units.Run(plan, self._fn, open=self._open, stop=stop_on_interrupt,
                                 hooks=self, interrupts=(Terminated, ReaderGone),
                                 writes_files=writes_files)
        self._told_gone = False  # (the run was stopped for it once)

    def go(self) -> int:
        exit_cleanly_on_signals()
        with self.view.showing():
            results = self.run.go()
        status = self._status(results)
        if self.view.out_gone:  # (the interpreter's last flush must not fail again)
            from ...base.edges import reader_gone

            gone = reader_gone()
            return status if isinstance(self.run.stopped_by, Terminated) else gone
        return status

    @property
    def stop_status(self) -> int:
        by = self.run.stopped_by
        if isinstance(by, ReaderGone):
            return EXIT_FAILED  # (as a run of one module: base/edges.reader_gone)
        return by.code if isinstance(by, Terminated) else EXIT_INTERRUPTED  # type: ignore

    # -- opening and running a unit (its own thread) -------------------------------------
    def _open(self, unit: Unit):
        record = self.view.record(unit)
        settings = connection_settings(unit_args(unit, self.args), self.config)
        # (the connect's frames go to the transcript; not those of a stop after it ended)
        tracer = record.tracer if record.state == "connecting" else None
        client = open_client(settings, notice=record.notice, tracer=tracer)
        _CURRENT.settings = settings  # (for _fn, next in this thread)
        return client

    def _fn(self, client) -> int:
        unit, settings = _CURRENT.unit, _CURRENT.settings
        # (looked up at each call, not bound at import: the one -c/-f run, whoever set it)
        return shell_main.run_connected(unit_args(unit, self.args), client, settings,
                                        prepare=lambda session: self._prepare(unit, session),
                                        config=self.config)

    # -- what the ops runner tells -------------------------------------------------------
    @contextmanager
    def attached(self, unit: Unit) -> Iterator[None]:
        _CURRENT.unit = unit
        try:
            with self.view.record(unit).attached():  # what this thread writes: the unit's
                yield
        finally:
            _CURRENT.unit = _CURRENT.settings = None

    def begin(self, unit: Unit) -> None:
        self.view.record(unit).begin()

    def connected(self, unit: Unit, client) -> None:
        self.view.record(unit).connected(client)

    def failed(self, unit: Unit, exc: BaseException) -> None:
        record = self.view.record(unit)
        if isinstance(exc, (TmclError, OSError)):  # no module (or no link) for this unit
            print(f"tmclsh: {exc}", file=sys.stderr)
            record.error(str(exc))
        else:
            print(f"tmclsh: internal error: {exc!r}", file=sys.stderr)
            record.error(repr(exc))

    def end(self, result: ops_units.Result) -> None:
        self.view.record(result.unit).end(self._unit_status(result),
                                          interrupted=self.run.stopping)

    def not_run(self, unit: Unit, why: str) -> None:
        self.view.record(unit).not_run(why)

    def not_stopped(self, unit: Unit, exc: BaseException) -> None:
        print(f"tmclsh: could not stop unit {unit.label}: {exc}", file=sys.stderr)
        self.view.record(unit).error(f"not stopped: {exc}")

    def note(self, text: str) -> None:
        self.view.note(text)

    def tick(self) -> None:
        self.view.tick()
        if self.view.out_gone and not self._told_gone and self.run.stopping is None:
            self._told_gone = True
            raise ReaderGone(READER_GONE)

    def to_stop(self, unit: Unit) -> bool:
        """A run cut short by its reader stops what each unit set moving, as a run of one
        module does (main._run_unattended); a signal stops every unit's module."""
        if not isinstance(self.run.stopped_by, ReaderGone):
            return True
        session = self.view.record(unit).session
        return session is not None and session.moved()

    def _unit_status(self, result: ops_units.Result) -> int:
        if result.stopped:
            return self.stop_status
        if result.error is None:
            return result.value
        if isinstance(result.error, (TmclError, OSError)) and not result.connected:
            return EXIT_CONNECT
        return EXIT_FAILED

    def _prepare(self, unit: Unit, session: Session) -> None:
        """The unit's own session: its variables, its tag on every JSON object, its view told
        of errors and progress."""
        record = self.view.record(unit)
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

    def _status(self, results: list[ops_units.Result]) -> int:
        records = [self.view.record(r.unit) for r in results]
        missing = [r for r in records if r.status == EXIT_CONNECT]
        self.view.finish(records)
        if missing:
            self.view.note("no module for unit " + ", unit ".join(r.unit.label
                                                                  for r in missing))
        if self.run.stopping is not None:
            return self.stop_status
        if missing:
            return EXIT_CONNECT
        if all(r.status == EXIT_OK for r in records):
            return EXIT_OK
        if all(r.status == EXIT_USAGE for r in records):
            return EXIT_USAGE
        return EXIT_FAILED


_CURRENT = threading.local()  # .unit: the unit the current thread runs; .settings: its link's
