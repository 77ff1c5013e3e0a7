"""The safety stop: stop the stored program and every motor, and say what reads back.

The one stop behind every entry point: Ctrl-C at the prompt and in ``-c``/``-f``,
``.stopall``, the watch's stop key, the ASCII terminal's Ctrl-C (shell/stop.py is its one
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
from ..client.ledger import CONFIRM_ROUNDS
from ..tmcl import instructions as isa
from ..tmcl.frames import Control
from .program import GGP, GP_APPLICATION_STATUS, AppState, _ascii_control, _ok, _send


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
    """Whether anything is going on: the stored program runs, motors turn (motor -> speed)."""

    program_running: bool = False
    turning: dict[int, int] = field(default_factory=dict)
    slowing: set[int] = field(default_factory=set)  # turning, its target speed read 0 (MST)

    @property
    def idle(self) -> bool:
        return not self.program_running and not self.turning

    @property
    def only_slowing(self) -> bool:
        """Every motor that turns is ramping down to a target speed of 0, no program runs."""
        return (bool(self.turning) and not self.program_running
                and set(self.turning) <= self.slowing)

    def __str__(self) -> str:
        """``motor 0 turns (speed 2000) and the stored program runs``."""
        parts = [f"motor {m} slows down (speed {v}, target speed 0)" if m in self.slowing
                 else f"motor {m} turns (speed {v})" for m, v in sorted(self.turning.items())]
        if self.program_running:
            parts.append("the stored program runs")
        return " and ".join([", ".join(parts[:-1]), parts[-1]] if len(parts) > 2 else parts)


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
    """135 (GP 128 in ASCII mode): True if the stored program runs, None if unknown."""
    if client.mode != "ascii" and not _has(client, Control.GET_STATUS):
        return False
    try:
        if client.mode == "ascii":
            reply = _send(client, GGP, GP_APPLICATION_STATUS, 0, timeout=timeout,
                          retries=retries)
        else:
            reply = _send(client, Control.GET_STATUS, timeout=timeout, retries=retries)
        return _ok(reply, "application status").value == AppState.RUN
    except TmclError:
        return None


def _speed(client, motor: int, number: int, timeout: float, retries: int | None = None) -> int:
    reply = _ok(_send(client, _GAP, number, motor, timeout=timeout, retries=retries),
                f"GAP {number}, {motor}")
    return reply.value


def activity(client, *, timeout: float | None = None) -> Activity:
    """Is a program running, is a motor turning? (135 and each motor's actual speed; a read
    that fails counts as nothing going on: this is for a question, not for safety.)"""
    t = min(client.timeout, 0.5) if timeout is None else timeout
    act = Activity(bool(_program_running(client, t, retries=0)))
    number = _speed_parameter(client)
    target = _axis_parameter(client, "TargetSpeed")
    for m in _motors(client):
        try:
            v = _speed(client, m, number, t, retries=0)
        except TmclError as exc:
            if _no_such_motor(client, m, exc):
                break
            continue
        if v:
            act.turning[m] = v
            try:  # (after MST: the motor ramps down, nothing drives it any more)
                if target is not None and _speed(client, m, target, t, retries=0) == 0:
                    act.slowing.add(m)
            except TmclError:
                pass
    return act


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
    running = _program_running(client, t)
    if running is not False and (client.mode == "ascii" or _has(client, Control.STOP_APPLICATION)):
        try:
            if client.mode == "ascii":
                _ascii_control(client, Control.STOP_APPLICATION)
            else:
                _ok(_send(client, Control.STOP_APPLICATION, timeout=t), "stop (128)")
            report.program = "stopped" if running else None
        except TmclError as exc:
            report.program_error = str(exc)
    elif running is False:
        report.program = "not running"
    pending: list[int] = []
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
    zero_at: dict[int, int] = {}  # motor -> Client._replies when its speed read 0
    doubtful: list[int] = []
    for _ in range(CONFIRM_ROUNDS):
        _settle(client, report, pending, zero_at, number, t, deadline, sleep)
        doubtful = sorted(client.in_doubt({seq: m for m, seq in zero_at.items()}))
        if not doubtful:
            break
        for m in doubtful:  # read again: that 0 may have been another motor's
            report.stopped.remove(m)
            del zero_at[m]
        pending = doubtful
    else:
        for m in doubtful:
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
                v = _speed(client, m, number, t)
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
