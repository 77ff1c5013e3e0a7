"""Several modules at once, from Python: a production line's station, a test jig.

A *unit* is one (link, address) pair. ``run(units, fn)`` opens each unit's module, calls
``fn(client)`` on it and returns each unit's ``Result`` (what ``fn`` returned, or what went
wrong), never printing; the shell's several-module ``-c``/``-f`` (``shell/features/units.py``) is a
front end that passes a whole shell run as ``fn`` and shows each unit through its view.

How they run: one thread per link. Units on different links run side by side; units sharing
a line or a bus run in turn on their link's thread (a bus carries one exchange at a time, so
taking turns costs nothing, and a unit is never in doubt whose reply it read). Threads, not
processes: a run is waiting on its links far more than it computes (a line at 115200 baud is
1.6 ms of wire per exchange, tmclsh's own work a few tens of microseconds), so one
interpreter keeps up with many links; it starts once (a process per unit would pay
Python's start-up, a quarter of a second of CPU, for each), python-can's in-process virtual
bus works, and Windows runs the same way.

Ctrl-C (and whatever else ``interrupts`` names: the shell's SIGTERM and SIGHUP) reaches the
main thread, which raises ``KeyboardInterrupt`` in every unit's thread that is running
(``PyThreadState_SetAsyncExc``, at the next bytecode: the same exception at the same kind of
place as Ctrl-C in a run of one module): each unit stops its module (``stop``, the one stop
by default) and units not yet started are not started; the units that had already ended are
opened again and stopped too (a motor they set moving may still turn). A unit that loses its
link or whose module refuses fails alone. Nothing is imported in a unit's thread: a stop
landing inside an import would leave a module half made for every unit after it.

A unit's thread blocked in C when the stop comes (``fn`` in ``time.sleep``) takes it only
when that wait returns: after ``STOP_GRACE`` the main thread stops that unit's module itself,
through its client.

From Python::

    import tmclsh
    plan = [tmclsh.Unit(1, "port", "/dev/ttyUSB0", 1), tmclsh.Unit(2, "port", "/dev/ttyUSB0", 2)]
    for r in tmclsh.run_units(plan, lambda c: c.value("GAP ActualPosition, 0")):
        print(r.unit.label, r.value, r.error)
"""

from __future__ import annotations

import importlib
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from .. import link
from ..base.errors import TmclError, ValidationError
from ..base.interrupts import stopped_by
from ..link import port_class
from ..client.connect import connect
from .stop import stop_everything

KINDS = ("port", "can", "sim")  # a unit's kind: connect's argument its link is given as
WAIT_SLICE = 0.1  # s between the main thread's looks at the units (and its hooks' ticks)
# s a unit's thread has to take the stop raised in it before the main thread stops its
# module itself: a thread blocked in C (``time.sleep``, ``Event.wait``) takes it only when
# that returns, and its motor would turn until then
STOP_GRACE = 0.5


@dataclass(frozen=True)
class Unit:
    """One module of a run: ``kind`` is how ``link`` is reached (port, can, sim)."""

    number: int
    kind: str
    link: str | None
    address: int | None = None  # serial address; None: the default (or the profile's)
    can_id: int | None = None
    reply_id: int | None = None

    def __post_init__(self) -> None:
        # (said when the plan is made, not as each unit's error once the run has begun)
        if self.kind not in KINDS:
            raise ValidationError(f"unit {self.number}: kind {self.kind!r} is not one of "
                                  f"{', '.join(KINDS)} (how its link is reached)")

    @property
    def bus(self) -> tuple[str, str | int | None]:
        """What the unit shares with others that must take turns: its line or bus (each
        simulated unit is a module of its own)."""
        return (self.kind, self.link if self.kind != "sim" else self.number)

    @property
    def where(self) -> str:
        """The unit for people: ``/dev/ttyACM0 @1``, ``virtual:bench id 3``."""
        if self.kind == "can":
            return f"{self.link}" + (f" id {self.can_id}" if self.can_id is not None else "")
        link = f"sim {self.link}" if self.kind == "sim" else f"{self.link}"
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


def open_unit(unit: Unit) -> Any:
    """The unit's module, opened as ``tmclsh.connect`` opens one (the default opener)."""
    options: dict[str, Any] = {"can_id": unit.can_id, "reply_id": unit.reply_id}
    if unit.address is not None:
        options["address"] = unit.address
    return connect(**{unit.kind: unit.link}, **options)


def _stop(client: Any, why: str) -> None:
    stop_everything(client)


@dataclass
class Result:
    """How one unit's run went. ``ran``: it was started (False: the run was stopped first,
    ``why_not`` says why); ``error``: what ended it (no module, a lost link, a refusal);
    ``connected``: its module was opened; ``stopped``: the run's stop reached it."""

    unit: Unit
    value: Any = None
    error: BaseException | None = None
    connected: bool = False
    stopped: bool = False
    ran: bool = False
    why_not: str = ""

    @property
    def ok(self) -> bool:
        return self.ran and self.error is None and not self.stopped


class Hooks:
    """What a front end hears of a run; every method but ``note`` and ``tick`` is called in
    the unit's thread (``attached`` around all the unit does there), so they only record."""

    @contextmanager
    def attached(self, unit: Unit) -> Iterator[None]:
        yield

    def begin(self, unit: Unit) -> None:
        pass

    def connected(self, unit: Unit, client: Any) -> None:
        pass

    def failed(self, unit: Unit, exc: BaseException) -> None:
        """``fn`` or the opening raised (not a stop): said before the unit's module is
        stopped and closed."""

    def end(self, result: Result) -> None:
        pass

    def not_run(self, unit: Unit, why: str) -> None:
        pass

    def to_stop(self, unit: Unit) -> bool:
        """Whether the run's stop is to reach this unit's module (every unit by default: a
        front end may spare a module its run set nothing moving on). Its thread, or the
        main thread for a unit that had ended."""
        return True

    def not_stopped(self, unit: Unit, exc: BaseException) -> None:
        """A unit that had ended could not be opened again to be stopped, or one whose
        thread did not take the stop could not be stopped from the main thread."""

    def note(self, text: str) -> None:
        """The run's own words (main thread)."""

    def tick(self) -> None:
        """Every ``WAIT_SLICE`` while units run, and once as the last ends (main thread)."""


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
    client: Any = None  # its module, once opened (the main thread stops it if need be)
    raised: bool = False  # a stop was raised in the thread and may not have landed yet
    taken: bool = False  # the main thread stopped the current unit's module itself
    tried: bool = False  # ... or tried to
    lock: threading.Lock = field(default_factory=threading.Lock)
    # the units whose run ended before any stop (a motor may still turn: a stop of the
    # whole run reaches them too)
    done: list[Unit] = field(default_factory=list)


class Run:
    """One run of ``fn`` on ``units`` (see the module docstring); ``go()`` returns the
    results in the units' order. ``stopping``: why the run was stopped (None: it was not),
    ``stopped_by``: the exception that stopped it. ``writes_files``: ``fn`` may write a file
    (its temporary file's module is imported before the threads start; a front end that
    knows its units write none spares every run that start)."""

    def __init__(self, units: list[Unit], fn: Callable[[Any], Any], *,
                 open: Callable[[Unit], Any] = open_unit,
                 stop: Callable[[Any, str], None] = _stop, hooks: Hooks | None = None,
                 interrupts: tuple[type[BaseException], ...] = (), writes_files: bool = True):
        self.units, self.fn, self.open, self.stop = units, fn, open, stop
        self.writes_files = writes_files
        self.hooks = hooks if hooks is not None else Hooks()
        self.interrupts = (KeyboardInterrupt, *interrupts)
        self.stopping: str | None = None
        self.stopped_by: BaseException | None = None
        self._stopped_at = 0.0  # (time.monotonic() of the stop)
        self.results = {u.number: Result(u) for u in units}
        lines: dict[tuple, _Line] = {}
        for unit in units:
            lines.setdefault(unit.bus, _Line([])).units.append(unit)
        self.lines = list(lines.values())

    def go(self) -> list[Result]:
        # here, in the main thread, not at start-up: _raise_in uses ctypes in the units'
        # threads, and a unit writing a file imports tempfile (base/files.write_file)
        import ctypes  # noqa: F401
        if self.writes_files:
            import tempfile  # noqa: F401

        _load_transports(self.units)
        for line in self.lines:
            line.thread = threading.Thread(target=self._line, args=(line,),
                                           name=f"unit-line-{line.units[0].number}",
                                           daemon=True)
            line.thread.start()
        while True:
            try:
                self._wait()
                # one look more as the units end: a unit's last lines may be the first to
                # meet the reader gone, the unit done before the next tick (its motor set
                # turning after them, and the run silently ended 1)
                self.hooks.tick()
                break
            except self.interrupts as exc:
                self._stop(exc)
        if self.stopping is not None:
            self._stop_finished()
        return [self.results[u.number] for u in self.units]

    def _wait(self) -> None:
        for line in self.lines:
            while not line.finished.wait(WAIT_SLICE):
                self.hooks.tick()
                if self.stopping is not None:
                    self._stop_overdue()

    def _stop(self, exc: BaseException) -> None:
        """Stop every unit that runs (each stops its module); none starts."""
        if self.stopping is not None:
            self.hooks.note("stopping every unit; the stops are under way")
            return
        self.stopping = getattr(exc, "why", None) or "interrupted"
        self.stopped_by = exc
        self._stopped_at = time.monotonic()
        self.hooks.note(f"{self.stopping}: stopping every unit")
        kind = KeyboardInterrupt if self.stopping == "interrupted" else stopped_by(self.stopping)
        for line in self.lines:
            with line.lock:
                if line.current is not None and line.thread is not None:
                    line.raised = True
                    _raise_in(line.thread, kind)

    def _stop_overdue(self) -> None:
        """A unit's thread that has not taken the stop within ``STOP_GRACE`` is blocked in
        C (``fn`` sleeping in ``time.sleep``): its module is stopped from here, through its
        client (one exchange at a time whichever thread asks). The line's lock is held
        meanwhile, so the thread, woken, neither closes the client under the stop nor stops
        again a module stopped here; a stop that failed or was cut short is its again."""
        if time.monotonic() - self._stopped_at < STOP_GRACE:
            return
        for line in self.lines:
            with line.lock:
                unit, client = line.current, line.client
                if not line.raised or line.tried or unit is None or client is None:
                    continue
                line.tried = True  # (once: a stop that failed is said once)
                with self.hooks.attached(unit):
                    if not self.hooks.to_stop(unit):
                        line.taken = True  # (nothing of it to stop)
                        self.results[unit.number].stopped = True
                        continue
                    try:
                        self.stop(client, self.stopping or "interrupted")
                    except (TmclError, OSError) as exc:
                        self.hooks.not_stopped(unit, exc)
                    else:
                        line.taken = True
                        self.results[unit.number].stopped = True

    def _stop_finished(self) -> None:
        """A stop of the run reaches the units that had already ended too: a run may end
        with a motor turning, and Ctrl-C stops every motor of the run."""
        for line in self.lines:
            for unit in line.done:
                if not self.hooks.to_stop(unit):
                    continue
                for _ in range(3):  # (Ctrl-C again while it stops: it stops all the same)
                    try:
                        self._stop_one(unit)
                        break
                    except self.interrupts:
                        self.hooks.note("stopping every unit; the stops are under way")

    def _stop_one(self, unit: Unit) -> None:
        with self.hooks.attached(unit):
            client = None
            try:
                client = self.open(unit)
                self.stop(client, self.stopping or "interrupted")
                self.results[unit.number].stopped = True
            except (TmclError, OSError) as exc:
                self.hooks.not_stopped(unit, exc)
            finally:
                if client is not None:
                    client.close()

    def _line(self, line: _Line) -> None:
        try:
            for unit in line.units:
                with line.lock:
                    if self.stopping is not None:
                        self._not_run(unit, self.stopping)
                        continue
                    line.current, line.taken, line.tried = unit, False, False
                self._unit(line, unit)
        finally:
            try:
                for unit in line.units:
                    self._not_run(unit, self.stopping or "not reached")
            finally:
                line.finished.set()

    def _not_run(self, unit: Unit, why: str) -> None:
        result = self.results[unit.number]
        if not result.ran and not result.why_not:
            result.why_not = why
            self.hooks.not_run(unit, why)

    def _unit(self, line: _Line, unit: Unit) -> None:
        result = self.results[unit.number]
        result.ran = True
        client = None
        hooks = self.hooks
        with hooks.attached(unit):
            try:
                try:
                    hooks.begin(unit)
                    client = self.open(unit)
                    with line.lock:
                        line.client = client
                    result.connected = True
                    hooks.connected(unit, client)
                    result.value = self.fn(client)
                finally:
                    self._leave(line)  # from here on no stop is raised in this thread
            except KeyboardInterrupt:
                result.stopped = True
            except Exception as exc:  # (no module, a lost link; a bug must not take the
                result.error = exc     # other units down)
                hooks.failed(unit, exc)
            try:
                if client is not None and self.stopping is not None and not line.taken:
                    # interrupted, or it ended just as the stop came: stopped all the same
                    if hooks.to_stop(unit):
                        self.stop(client, self.stopping)
                    result.stopped = True
            finally:
                if client is not None:
                    client.close()
            if client is not None and not result.stopped:
                line.done.append(unit)
            hooks.end(result)

    def _leave(self, line: _Line) -> None:
        """The unit's run is over: the stop is no longer raised in this thread, and one that
        was raised but has not landed yet is taken back (the unit is stopped by hand)."""
        with line.lock:
            line.current = None
            line.client = None
            if line.raised:
                line.raised = False
                _raise_in(threading.current_thread(), None)


def _load_transports(units: list[Unit]) -> None:
    """Import each unit's transport in the main thread (see the module docstring)."""
    for unit in units:
        if unit.kind == "port":
            try:
                port_class(unit.link or "")
            except ValidationError:  # (said by the unit's own opening, as for one module)
                pass
        elif unit.kind in ("sim", "can"):
            importlib.import_module(f"{link.__name__}.{unit.kind}")
            if unit.kind == "sim":
                from .. import sim  # noqa: F401  (the simulator the transport starts)


def run(units: list[Unit], fn: Callable[[Any], Any], *,
        open: Callable[[Unit], Any] = open_unit, stop: Callable[[Any, str], None] = _stop,
        hooks: Hooks | None = None) -> list[Result]:
    """``fn(client)`` on every unit's module, units on one link in turn, links side by side;
    each unit's ``Result`` in order. Ctrl-C stops every unit's motors (``stop``) and the run
    returns with ``Result.stopped`` set."""
    return Run(units, fn, open=open, stop=stop, hooks=hooks).go()


def _raise_in(thread: threading.Thread, exc_type: type[BaseException] | None) -> None:
    """Raise ``exc_type`` in ``thread`` at its next bytecode (what Ctrl-C does to the main
    thread), so a unit unwinds and stops its module as a run of one module does; None takes
    back one raised that has not landed yet."""
    import ctypes  # loaded by Run.go, before any unit's thread

    if thread.ident is None:
        return
    ctypes.pythonapi.PyThreadState_SetAsyncExc(
        ctypes.c_ulong(thread.ident), None if exc_type is None else ctypes.py_object(exc_type))
