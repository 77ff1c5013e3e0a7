"""The one front end of the safety stop (ops/stop.py), for every place a user can ask for it:
Ctrl-C at the prompt and during a command, ``.stopall``, ``.watch`` (its stop key and
Ctrl-C), the ASCII terminal's Ctrl-C, and Ctrl-C in ``-c``/``-f``.

Wherever it is asked for, it does the same: a lost link is brought back first (one attempt;
the stop is worth it), the stored program is stopped, every motor gets MST, and what the
module reads back is said in one wording (``interrupted: stopped motor 0 (MST; speed reads
0)``, ``motor 1 did NOT stop``). Only where it is said differs: the session's output, the
watch's caption, the terminal's notes, stderr after an interrupted run. It never raises.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Protocol

from ...base.errors import TmclError
from ...base.interrupts import Terminated

if TYPE_CHECKING:
    from ...client.core import Client
    from ...ops.stop import StopReport
    from ..lang.session import Session


class Say(Protocol):
    """Where a stop is said: ``ok`` what was done, ``warn`` what was not, ``info`` the rest."""

    def ok(self, text: str) -> None: ...

    def warn(self, text: str) -> None: ...

    def info(self, text: str) -> None: ...


class ToStderr:
    """Say it on stderr (a run whose stdout may be a pipe or JSON; after a hang-up there may
    be nobody to say it to: the stop is done all the same)."""

    def ok(self, text: str) -> None:
        try:
            print(text, file=sys.stderr)
        except (OSError, ValueError):
            pass

    warn = info = ok


class ToNotes:
    """Say it through one function (the watch's caption, the ASCII terminal's notes)."""

    def __init__(self, note):
        self.ok = self.warn = self.info = note


def stop_all(client: Client, say: Say, why: str = "", *,
             session: Session | None = None) -> StopReport | None:
    """Stop the stored program and every motor, bringing a lost link back first, and say
    what the module reports afterwards. ``why`` (``Ctrl-C``, ``interrupted``) starts every
    line said. Returns the report (None when nothing could be asked). Never raises."""
    from ...ops.stop import stop_everything

    prefix = f"{why}: " if why else ""

    def reconnect() -> BaseException | None:
        if session is not None:
            return session.reconnect()
        try:
            client.reconnect()
        except (TmclError, OSError) as exc:
            return exc
        return None

    try:
        report = stop_everything(client, reconnect=reconnect)
    except (KeyboardInterrupt, Terminated) as exc:
        # (the program's stop and MST went out first: base/interrupts.py ``held``)
        again = getattr(exc, "why", "interrupted")
        say.warn(f"{prefix}{again} again: the stop was sent, not read back: the motors may "
                 "still turn")
        if isinstance(exc, Terminated):  # (the run ends: at the prompt too)
            raise
        return None
    except (TmclError, OSError) as exc:  # not expected (it reports instead); a stop never raises
        say.warn(f"{prefix}stopping failed: {exc}; the motors may still turn")
        return None
    except Exception as exc:  # the safety key must never break the shell
        say.warn(f"{prefix}stopping failed: {exc}; the motors may still turn")
        return None
    if report.link_error is not None:
        say.warn(f"{prefix}not connected ({report.link_error}); nothing could be stopped")
        return report
    if report.reconnected:
        from ..lang.session import reconnected

        say.info(reconnected(client))
    if session is not None and report.program is not None and report.program_error is None:
        session.state.program_state = "stop"  # the toolbar and prompt follow
    say_report(say, report, why)
    return report


def stop_everywhere(client: Client, say: Say, why: str = "", *,
                    session: Session | None = None, back: bool = True) -> bool:
    """``stop_all`` at the address in use, then at each address ``.address`` left a motor
    told to move at (this client's modules only: no other address is sent anything), each
    said with its address; with ``back``, the client talks to its own address again
    afterwards (the prompt goes on there). True when every stop read back stopped."""
    from ...client.bringup import switch_address
    from ...ops.stop import addresses_left, where_in_use

    report = stop_all(client, say, why, session=session)
    ok = report is not None and report.ok
    home = where_in_use(client)
    for address in addresses_left(client):
        where = f"{why}: address {address}" if why else f"address {address}"
        try:
            switch_address(client, address)
        except (TmclError, OSError) as exc:
            motors = ", ".join(map(str, sorted(client._motion_left[address].motors())))
            say.warn(f"{where}: motor {motors} may still turn: {str(exc).splitlines()[0]}")
            ok = False
            continue
        report = stop_all(client, say, where, session=session)
        ok = ok and report is not None and report.ok
    if back and where_in_use(client) != home:
        try:
            switch_address(client, home)
        except (TmclError, OSError) as exc:
            say.warn(f"still talking to address {where_in_use(client)}, not {home}: "
                     f"{str(exc).splitlines()[0]}")
            ok = False
    return ok


def say_report(say: Say, report: StopReport, why: str = "") -> None:
    """What a stop did, in the stop's one wording (``describe_stop``)."""
    prefix = f"{why}: " if why else ""
    done, warnings = describe_stop(report, prefix)
    if done is not None:
        say.ok(done)
    elif not warnings:
        say.info(f"{prefix}nothing to stop: the module reports no motor")
    for text in warnings:
        say.warn(text)


def stop_session(session: Session, why: str = "") -> StopReport | None:
    """``stop_all`` said on the session's output (the prompt, ``.stopall``)."""
    return stop_all(session.client, session.out, why, session=session)


def describe_stop(report: StopReport, prefix: str = "") -> tuple[str | None, list[str]]:
    """The confirmation (None if nothing stopped) and the warnings for a StopReport:
    ``stored program stopped; stopped motor 0 (MST; speed reads 0)``."""
    parts = []
    if report.program == "stopped":
        parts.append("stored program stopped")
    if report.stopped:
        which = "motor" if len(report.stopped) == 1 else "motors"
        parts.append(f"stopped {which} {', '.join(map(str, report.stopped))} "
                     "(MST; speed reads 0)")
    warnings = []
    if report.program_error:
        warnings.append(f"{prefix}the stored program may still run: {report.program_error}")
    for m, speed in sorted(report.turning.items()):
        warnings.append(f"{prefix}motor {m} did NOT stop: it still turns at speed {speed} "
                        "after MST")
    for m, why_not in sorted(report.unknown.items()):
        warnings.append(f"{prefix}motor {m} may still turn: {why_not}; check the connection!")
    return (prefix + "; ".join(parts) if parts else None), warnings
