"""The safety stop: stop the stored program and every motor, and say what reads back.

The one stop behind every entry point: Ctrl-C at the prompt and in ``-c``/``-f``,
``.stopall``, the watch's stop key, the ASCII terminal's Ctrl-C (shell/features/stop.py is its one
front end). A stored program that runs would drive the motors again right after MST, so it
is stopped first; then MST to every motor; then each motor's actual speed is read back until
it is 0 (a motor ramps down) or a few seconds have passed. "Stopped" is said of a motor only
when its speed read 0, with a certain answer. Nothing here prints.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from ..base.errors import StatusError, TmclError, ValidationError
from ..base.interrupts import held
from ..client.ledger import CONFIRM_ROUNDS
from ..client.motion import Commanded
from ..tmcl import instructions as isa
from ..tmcl.frames import Control
from .certain import read_until_certain
from .program import AppState, _ok, _send


_MST, _GAP = int(isa.Opcode.MST), int(isa.Opcode.GAP)
SPEED_PARAMETER = 3  # AP 3 ActualSpeed on every module in the database (used when unknown)
SETTLE = 3.0  # s a motor is given to ramp down after MST before it is called still turning


@dataclass
class StopReport:
    """What :func:`stop_everything` found, motor by motor, read back from the module.

    ``program``: "stopped" (it ran; 128 accepted), "not running", or None when its state
    could not be read (128 was sent all the same); ``program_error`` if 128 failed.
    ``stopped``: motors whose actual speed read 0 after MST; ``turning``: motor -> the
    speed last read; ``unknown``: motor -> why MST or the read-back failed.
    """

    program: str | None = None
    program_error: str | None = None
    running: bool | None = None  # what 135 said of the program before 128 (None: not known)
    stopped: list[int] = field(default_factory=list)
    turning: dict[int, int] = field(default_factory=dict)
    unknown: dict[int, str] = field(default_factory=dict)
    reconnected: bool = False  # the link was lost and brought back for the stop
    link_error: str | None = None  # the link was lost and could not be: nothing was sent

    @property
    def ok(self) -> bool:
        return (not self.turning and not self.unknown and self.program_error is None
                and self.link_error is None)

    def to_json(self) -> dict[str, object]:
        return {"program": self.program, "stopped": self.stopped,
                "turning": {str(m): v for m, v in self.turning.items()},
                "unknown": {str(m): v for m, v in self.unknown.items()},
                **({"program_error": self.program_error} if self.program_error else {}),
                **({"reconnected": True} if self.reconnected else {}),
                **({"link_error": self.link_error} if self.link_error else {})}


@dataclass
class Activity:
    """Whether anything is going on: the stored program runs, motors turn (motor -> speed),
    motors tmclsh set moving that read still (motor -> what it was told, the speed read or
    None: a stalled motor, one that has not started yet, a read that failed)."""

    program_running: bool = False
    turning: dict[int, int] = field(default_factory=dict)
    slowing: set[int] = field(default_factory=set)  # turning, its target speed read 0 (MST)
    commanded: dict[int, tuple[Commanded, int | None]] = field(default_factory=dict)

    @property
    def idle(self) -> bool:
        return not self.program_running and not self.turning and not self.commanded

    @property
    def only_slowing(self) -> bool:
        """Every motor that turns is ramping down to a target speed of 0, no program runs."""
        return (bool(self.turning) and not self.program_running and not self.commanded
                and set(self.turning) <= self.slowing)

    def __str__(self) -> str:
        """``motor 0 turns (speed 2000) and the stored program runs``."""
        parts = [f"motor {m} slows down (speed {v}, target speed 0)" if m in self.slowing
                 else f"motor {m} turns (speed {v})" for m, v in sorted(self.turning.items())]
        parts += [_told(m, c, v) for m, (c, v) in sorted(self.commanded.items())]
        if self.program_running:
            parts.append("the stored program runs")
        return " and ".join([", ".join(parts[:-1]), parts[-1]] if len(parts) > 2 else parts)

    def to_json(self) -> dict[str, object]:
        return {"program_running": self.program_running,
                "turning": {str(m): v for m, v in sorted(self.turning.items())},
                "slowing": sorted(self.slowing),
                "commanded": {str(m): {"line": c.line, "speed": v,
                                       **({"target_speed": c.target} if c.kind == "speed"
                                          else {})}
                              for m, (c, v) in sorted(self.commanded.items())}}


def _told(motor: int, told: Commanded, speed: int | None) -> str:
    """``motor 0 was told to turn (ROR 0, 1000: target speed 1000); it reads speed 0``."""
    what = (f"was told to turn ({told.line}: target speed {told.target})" if told.kind == "speed"
            else f"was told to move ({told.line}) and has not reached its target")
    reads = "its speed could not be read" if speed is None else f"it reads speed {speed}"
    return f"motor {motor} {what}; {reads}"


# generic mode (a type without data): how many motors is not known, so every motor number
# up to the most axes a TMCL module has (TMCM-6110, TMCM-6214) is tried, until one is refused
_GENERIC_MOTORS = 6


def _motors(client) -> range:
    mod = client.module
    if mod is not None and getattr(mod, "generic", False):
        return range(_GENERIC_MOTORS)
    return range(mod.motors if mod is not None else 1)


def _no_such_motor(client, motor: int, exc: TmclError) -> bool:
    """In generic mode, a refusal (status) for a motor after 0: the module has no such motor,
    nor any after it."""
    mod = client.module
    return (motor > 0 and isinstance(exc, StatusError) and mod is not None
            and getattr(mod, "generic", False))


def _speed_parameter(client) -> int:
    number = _axis_parameter(client, "ActualSpeed")
    return SPEED_PARAMETER if number is None else number


def _axis_parameter(client, name: str) -> int | None:
    """The number of the module's axis parameter ``name``; None without data on it."""
    mod = client.module
    if mod is None or getattr(mod, "generic", False):
        return None
    try:
        return mod.lookup("axis", name).number
    except (ValidationError, KeyError):
        return None


def _has(client, opcode: int) -> bool:
    mod = client.module
    return mod is None or mod.has_control(opcode)


def _program_running(client, timeout: float, retries: int | None = None) -> bool | None:
    """135 (GP 128 on the module's ASCII line, which the framing sends for it): True if the
    stored program runs, None if unknown."""
    if not _has(client, Control.GET_STATUS):
        return False
    try:
        reply = _send(client, Control.GET_STATUS, timeout=timeout, retries=retries)
        return _ok(reply, "application status").value == AppState.RUN
    except TmclError:
        return None


def _read_axis(client, motor: int, number: int, timeout: float,
               retries: int | None = None) -> int:
    reply = _ok(_send(client, _GAP, number, motor, timeout=timeout, retries=retries),
                f"GAP {number}, {motor}")
    return reply.value


def activity(client, *, timeout: float | None = None) -> Activity:
    """Is a program running, is a motor turning, or meant to? (135, each motor's actual
    speed, and what tmclsh told the motors, ``client.motion``: a motor told to turn that
    reads 0, stalled or not yet started, is still meant to turn. A read that fails counts
    as nothing going on, unless tmclsh told the motor to move: this is for a question, not
    for safety.)"""
    t = min(client.timeout, 0.5) if timeout is None else timeout
    act = Activity(bool(_program_running(client, t, retries=0)))
    number = _speed_parameter(client)
    target = _axis_parameter(client, "TargetSpeed")
    record = getattr(client, "motion", None)  # (a stand-in client in a test has none)
    told = record.motors() if record is not None else {}
    for m in _motors(client):
        try:
            v = _read_axis(client, m, number, t, retries=0)
        except TmclError as exc:
            if _no_such_motor(client, m, exc):
                break
            v = None
        if v:
            act.turning[m] = v
            try:  # (after MST: the motor ramps down, nothing drives it any more)
                if target is not None and _read_axis(client, m, target, t, retries=0) == 0:
                    act.slowing.add(m)
            except TmclError:
                pass
        elif m in told and not _move_ended(client, told[m], m, t):
            act.commanded[m] = (told[m], v)
    return act


def where_in_use(client) -> int:
    """The address the client talks to (on CAN its id): the key of ``Client._motion_left``."""
    return client.can_id if getattr(client, "is_can", False) else client.address


def addresses_left(client) -> list[int]:
    """The addresses other than the one in use where this client left a motor told to move
    (``Client._motion_left``): the only others the end of a run asks or stops anything at."""
    home = where_in_use(client)
    return [a for a in getattr(client, "_motion_left", {}) if a != home]


def activity_everywhere(client, *, timeout: float | None = None
                        ) -> list[tuple[int, Activity, str | None]]:
    """``activity`` at the address in use, then at each address this client left a motor
    told to move at (``Client._motion_left``), as (address, activity, why it could not be
    asked or None): a user who set a motor turning at address 1 and went on at address 2
    is told of both, and no address the client never talked to is asked anything. An
    address that does not answer counts its told motors as told, their speed unread. The
    client talks to its own address again afterwards (a failure to get back raises: it
    would talk to another module than its user thinks)."""
    home = where_in_use(client)
    found = [(home, activity(client, timeout=timeout), None)]
    others = addresses_left(client)
    if not others:
        return found
    from ..client.bringup import switch_address

    try:
        for address in others:
            try:
                switch_address(client, address)
                found.append((address, activity(client, timeout=timeout), None))
            except (TmclError, OSError) as exc:
                told = client._motion_left[address].motors() if where_in_use(
                    client) != address else client.motion.motors()
                found.append((address, Activity(commanded={m: (c, None) for m, c in
                                                           told.items()}),
                              str(exc).splitlines()[0]))
    finally:
        if where_in_use(client) != home:
            switch_address(client, home)
    return found


def _move_ended(client, told: Commanded, motor: int, timeout: float) -> bool:
    """A position move the module says has ended (TargetPositionReached, or the actual
    position at the target): tmclsh forgets it. A speed it was told is never over by
    itself."""
    if told.kind != "position":
        return False
    flag = _axis_parameter(client, "TargetPositionReached")
    try:
        if flag is not None:
            ended = _read_axis(client, motor, flag, timeout, retries=0) == 1
        else:
            at, to = (_axis_parameter(client, n) for n in ("ActualPosition", "TargetPosition"))
            ended = (at is not None and to is not None
                     and _read_axis(client, motor, at, timeout, 0)
                     == _read_axis(client, motor, to, timeout, 0))
    except TmclError:
        return False
    if ended:
        client.motion.forget(motor)
    return ended


def stop_everything(client, *, settle: float = SETTLE,
                    sleep: Callable[[float], None] = time.sleep,
                    reconnect: Callable[[], BaseException | None] | None = None) -> StopReport:
    """The safety stop behind Ctrl-C, ``.stopall`` and the watch's stop key.

    ``reconnect`` (None when the link is back, else why not): a link that is lost before
    the stop, or found lost on its way (a cable pulled and put back while a script waited),
    is worth one attempt to bring it back, and then the whole stop again;
    ``report.reconnected`` says it was, ``report.link_error`` why it could not be.
    """
    if reconnect is not None and not client.connected:
        why = reconnect()
        if why is not None:
            return StopReport(link_error=str(why))
        report = _stop_everything(client, settle, sleep)
        report.reconnected = True
        return report
    report = _stop_everything(client, settle, sleep)
    if reconnect is not None and not report.ok and not client.connected:
        why = reconnect()
        if why is None:
            report = _stop_everything(client, settle, sleep)
            report.reconnected = True
    return report


def _stop_everything(client, settle: float, sleep: Callable[[float], None]) -> StopReport:
    """``stop_everything`` on the link as it is.

    A stored program that runs would drive the motors again right after MST, so it is
    stopped first (128; the state is read with 135, and 128 is sent anyway when that read
    fails); then MST to every motor; then each motor's actual speed is read back until it
    is 0 (a motor ramps down) or ``settle`` seconds have passed. A 0 that may have been
    another request's answer (the line brought a late copy of the reply before it) is read
    again, and is "unknown" if it stays in doubt. Never raises a TmclError: everything that
    went wrong is in the report.
    """
    report = StopReport()
    t = min(client.timeout, 0.5)
    pending: list[int] = []
    with held():  # (a second Ctrl-C or SIGTERM waits until the stop's commands are out)
        running = report.running = _program_running(client, t)
        if running is not False and _has(client, Control.STOP_APPLICATION):
            try:
                _ok(_send(client, Control.STOP_APPLICATION, timeout=t), "stop (128)")
                report.program = "stopped" if running else None
            except TmclError as exc:
                report.program_error = str(exc)
        elif running is False:
            report.program = "not running"
        for m in _motors(client):
            try:
                _ok(_send(client, _MST, 0, m, timeout=t), f"MST {m}")
                pending.append(m)
            except TmclError as exc:
                if _no_such_motor(client, m, exc):
                    break
                report.unknown[m] = str(exc)
    number = _speed_parameter(client)
    deadline = time.monotonic() + settle
    def read(doubt: set[int] | None) -> dict[int, int]:
        """The speeds of the motors not known to be still (``doubt``: those whose 0 may
        have been another motor's, read again) -> which reply said 0 (Client._replies)."""
        if doubt is not None:
            for m in doubt:
                report.stopped.remove(m)
        zero_at: dict[int, int] = {}  # motor -> Client._replies when its speed read 0
        _settle(client, report, pending if doubt is None else sorted(doubt), zero_at, number,
                t, deadline, sleep)
        return {seq: m for m, seq in zero_at.items()}

    # (the first read and CONFIRM_ROUNDS - 1 more, as this loop has always done)
    doubtful = read_until_certain(client, read, again=CONFIRM_ROUNDS - 1).doubt
    for m in sorted(doubtful):
        report.stopped.remove(m)
        report.unknown[m] = ("its speed read 0, but that answer may have been another "
                             "request's (the line brought a reply nothing was waiting for)")
    report.stopped.sort()
    return report


def _settle(client, report: StopReport, pending: list[int], zero_at: dict[int, int],
            number: int, t: float, deadline: float, sleep: Callable[[float], None]) -> None:
    """Read each pending motor's speed until it is 0 or the deadline has passed (at least
    once): 0 moves it to ``report.stopped`` (``zero_at``: which reply said so)."""
    while pending:
        for m in list(pending):
            try:
                v = _read_axis(client, m, number, t)
            except TmclError as exc:
                report.unknown[m] = f"its speed could not be read: {exc}"
                report.turning.pop(m, None)
                pending.remove(m)
                continue
            if v == 0:
                report.stopped.append(m)
                zero_at[m] = client._replies
                report.turning.pop(m, None)
                pending.remove(m)
            else:
                report.turning[m] = v
        if not pending or time.monotonic() >= deadline:
            break
        sleep(0.05)
