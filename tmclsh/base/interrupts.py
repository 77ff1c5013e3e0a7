"""Signals that end a run as exceptions, and are never lost on the way.

SIGTERM (kill, systemd, a CI job's timeout), SIGHUP (the terminal or SSH session went away)
and Ctrl-C end a run by raising in the main thread, so that it unwinds: the motors are
stopped and the module is taken out of ASCII or download mode on the way out.

Why such an exception is watched until it has reached the run's code: Python runs a signal's
handler in whatever the main thread is doing at that moment, and two kinds of place there
drop what the handler raises. Code the interpreter calls on its own (a weak reference's
callback, such as the one importlib runs when a module lock is dropped, or a ``__del__``)
prints it as "Exception ignored" and goes on; and some of the interpreter's C code clears it
(seen: the compiler, building a module's code when a module is first imported from source,
clears anything but a KeyboardInterrupt). Either way the signal was lost and the run went on
as if it had never come (seen: ``kill`` during the switch into ASCII mode, and a 30 s
``.sleep`` slept to its end). So ``keep`` puts a ``sys.unraisablehook`` in place for the
first kind, and an exception raised for a signal that is freed before any code of the run
saw it says so when it goes (``_Sent.__del__``). Either sends the signal again (from a thread
of its own, so that the handler does not run again where it was just dropped), and its
handler runs once more, in the run's own code.
``keep`` is the program's (``cli.main``), not the library's: the hook is process-wide.
"""

from __future__ import annotations

import _thread
import signal
import sys
import threading
from typing import Callable, Iterable

_kept = False


class _Sent:
    """An exception raised for a signal (by the handler ``unwind_on`` sets), which sends the
    signal again if it is freed before any code outside this module saw it: C code cleared
    it (see above). Code that caught it (an ``except`` or a ``finally`` on its way) gave it
    a traceback through that code, and answers for it from then on."""

    signum: int
    _watched = False  # raised by the handler (not made by a test or a caller)

    def __del__(self) -> None:
        try:
            if self._watched and _unseen(self.__traceback__):  # type: ignore[attr-defined]
                _send_again(self.signum)
        except Exception:  # (the interpreter ending: nothing left to send it to)
            pass


def _watched(exc: BaseException) -> BaseException:
    """``exc``, watched until it has reached the run's code (when it is one of ours)."""
    if isinstance(exc, _Sent):
        exc._watched = True
    return exc


def taken(exc: BaseException) -> None:
    """The signal ``exc`` was raised for is being acted on, though it reached the run wrapped
    in another error (C code raised that one from it): not sent again as it goes."""
    if isinstance(exc, _Sent):
        exc._watched = False


def _unseen(tb: object) -> bool:
    """Whether a traceback passes through no code but this module's: the handler raised,
    and nothing of the run took the exception (Python 3.11 leaves it without a traceback
    until it is caught; later versions give it the handler's frame as it is raised)."""
    while tb is not None:
        if tb.tb_frame.f_code.co_filename != __file__:  # type: ignore[attr-defined]
            return False
        tb = tb.tb_next  # type: ignore[attr-defined]
    return True


class Terminated(_Sent, SystemExit):
    """SIGTERM or SIGHUP: ends the run like Ctrl-C does (the one stop), with the signal's
    exit status. A SystemExit, not a KeyboardInterrupt: the prompt, which stops and goes on
    after Ctrl-C, must end here."""

    def __init__(self, signum: int):
        super().__init__(128 + signum)
        self.signum = signum
        self.why = ("terminated (SIGTERM)" if signum == signal.SIGTERM
                    else "hung up (SIGHUP)")


def terminated_by(exc: BaseException) -> Terminated | None:
    """The SIGTERM or SIGHUP behind ``exc``: a ``Terminated``, or the Ctrl-C ``interrupted``
    made for one (a run that ends on all three alike, such as ``monitor``, still ends with
    the signal's words and exit status, as every other command does). None: Ctrl-C, or no
    signal at all."""
    if isinstance(exc, Terminated):
        return exc
    signum = getattr(exc, "signum", None) if isinstance(exc, KeyboardInterrupt) else None
    if signum is None or signum == signal.SIGINT:
        return None
    return Terminated(signum)  # (made here, not raised by a handler: never sent again)


def stopped_words(exc: BaseException) -> str:
    """What stopped a run, in the words its summary says it with: the signal's
    (``terminated (SIGTERM)``, ``hung up (SIGHUP)``), what a unit was stopped for
    (``stopped_by``), else ``interrupted (Ctrl-C)``."""
    why = getattr(exc, "why", None)
    if isinstance(why, str) and why:
        return why
    signalled = terminated_by(exc)
    return signalled.why if signalled is not None else "interrupted (Ctrl-C)"


def hung_up(why: str = "hung up (the terminal went away)") -> Terminated:
    """The SIGHUP a terminal's going away stands for where no signal came (tmclsh was not
    the terminal's controlling process, or was started ignoring SIGHUP): the prompt's reads
    failed instead. It ends the run as the signal does: the one stop, exit status 129."""
    exc = Terminated(signal.SIGHUP)
    exc.why = why
    return exc


def stopped_by(why: str) -> type[KeyboardInterrupt]:
    """A KeyboardInterrupt whose instances say ``why`` (``terminated (SIGTERM)``): what a
    run of several units raises in each unit's thread, which takes a class, not an
    instance, so that a unit's last line names the signal that stopped it."""
    return type("StoppedBy", (KeyboardInterrupt,), {"why": why})


class _Interrupted(_Sent, KeyboardInterrupt):
    """The Ctrl-C a signal stands for (``interrupted``)."""


def interrupted(signum: int) -> KeyboardInterrupt:
    """The Ctrl-C a signal stands for where it ends a run as Ctrl-C does (``monitor``)."""
    exc = _Interrupted()
    exc.signum = signum  # (which one to send again, should it be lost)
    return exc


def unwind_on(signals: Iterable[str], make: Callable[[int], BaseException] = Terminated
              ) -> dict:
    """From now on each of ``signals`` (names, such as ``"SIGTERM"``; those this platform
    lacks are left out) raises ``make(signum)`` in the main thread. The handlers before, for
    ``restore``; nothing outside the main thread, where no handler can be set. A signal the
    process is ignoring stays ignored: ``nohup tmclsh -f ...`` is a run meant to outlive its
    terminal (as Python leaves Ctrl-C alone when it starts with SIGINT ignored)."""
    def leave(signum: int, frame: object) -> None:
        raise _watched(make(signum))  # (no local name: the frame would hold it in a cycle)

    previous: dict = {}
    for name in signals:
        sig = getattr(signal, name, None)
        if sig is None:
            continue
        try:
            if signal.getsignal(sig) == signal.SIG_IGN:
                continue
            previous[sig] = signal.signal(sig, leave)
        except (ValueError, OSError):  # not the main thread, or not on this platform
            pass
    return previous


def restore(previous: dict) -> None:
    """The handlers ``unwind_on`` replaced, back."""
    for sig, handler in previous.items():
        try:
            signal.signal(sig, handler)
        except (ValueError, OSError):
            pass


_ENDING = ("SIGINT", "SIGTERM", "SIGHUP")


class held:
    """A block the signals that end a run wait for: the stop's commands (128, MST), which a
    second Ctrl-C or SIGTERM landing between them would leave unsent, the motors turning.
    Each signal whose handler is the run's own (a Python function) is noted while the block
    runs, and handed to that handler when it ends; one that is ignored or left to the
    system is left as it is. Nothing outside the main thread, where no handler can be set.
    The block must be short and bounded (requests with their timeouts). ``deliver=False``
    where the run ends with the block anyway (the stop after the signal that ends it): a
    signal noted meanwhile is part of that end, not handed on."""

    def __init__(self, deliver: bool = True):
        self.deliver = deliver

    def __enter__(self) -> held:
        self._previous: dict = {}
        self._pending: list[int] = []
        if threading.current_thread() is not threading.main_thread():
            return self
        for name in _ENDING:
            sig = getattr(signal, name, None)
            if sig is None:
                continue
            try:
                handler = signal.getsignal(sig)
                if callable(handler):
                    self._previous[sig] = signal.signal(sig, self._note)
            except (ValueError, OSError):
                pass
        return self

    def _note(self, signum: int, frame: object) -> None:
        self._pending.append(signum)

    def __exit__(self, *exc: object) -> None:
        restore(self._previous)
        for signum in self._pending[:1] if self.deliver else ():  # (the first acts)
            self._previous[signum](signum, None)


def keep() -> None:
    """A signal whose exception was dropped in a callback is sent again (see above)."""
    global _kept
    if _kept:
        return
    _kept = True
    before = sys.unraisablehook

    def hook(unraisable: object) -> None:
        exc = getattr(unraisable, "exc_value", None)
        signum = _signal_of(exc)
        if signum is None:
            before(unraisable)  # type: ignore[arg-type]
            return
        if isinstance(exc, _Sent):
            exc._watched = False  # (sent again here: not once more as it is freed)
        _send_again(signum)

    sys.unraisablehook = hook


def _send_again(signum: int) -> None:
    """``signum`` again, to the main thread, from a thread of its own: sent from here, its
    handler would run at once, where it was just dropped, and be dropped again; the main
    thread runs it at its next step (``_thread``: ``Thread.start`` waits for the thread to
    run, and would run the handler here). *To* the main thread: ``raise_signal`` would
    deliver it to the sending thread, and a main thread that has gone on into a wait
    (``.sleep 30``) would not wake until the wait ended (seen under CI: a SIGTERM obeyed
    30 s late)."""
    try:
        _thread.start_new_thread(_send_to_main, (signum,))
    except RuntimeError:  # (no new thread while the interpreter ends: it is ending)
        pass


def _send_to_main(signum: int) -> None:
    """``signum`` to the main thread, which a wait it is in gives up for it."""
    try:
        signal.pthread_kill(threading.main_thread().ident, signum)  # type: ignore[arg-type]
    except (AttributeError, ProcessLookupError, OSError):  # (no pthread_kill here)
        signal.raise_signal(signum)


def _signal_of(exc: object) -> int | None:
    """The signal ``exc`` was raised for, if it stands for one."""
    if isinstance(exc, Terminated):
        return exc.signum
    if isinstance(exc, KeyboardInterrupt):
        return getattr(exc, "signum", signal.SIGINT)
    return None
