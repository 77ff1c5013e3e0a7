"""A signal that lands in a callback the interpreter runs on its own is not lost."""

from __future__ import annotations

import os
import signal
import sys
import time
import weakref

import pytest

from tmclsh.base import interrupts
from tmclsh.base.interrupts import Terminated, interrupted, restore, unwind_on


class _Thing:
    pass


def _signal_inside_a_callback(sig: int) -> None:
    """Drop an object whose weak reference's callback sends ``sig`` to this process and runs
    on, so the handler runs inside the callback (as in importlib's module-lock cleanup, where
    a SIGTERM during the switch into ASCII mode was dropped and the run slept on)."""
    def callback(_ref: object) -> None:
        os.kill(os.getpid(), sig)
        for _ in range(10_000):  # the handler runs between these, inside the callback
            pass

    thing = _Thing()
    ref = weakref.ref(thing, callback)  # noqa: F841  (kept until the object goes)
    del thing


def _run_on(seconds: float = 10.0) -> None:
    """The run going on (a ``.sleep``): a signal sent again lands here, however busy the
    machine is; a lost one never does."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        time.sleep(0.005)


@pytest.fixture
def kept(monkeypatch):
    monkeypatch.setattr(interrupts, "_kept", False)
    monkeypatch.setattr(sys, "unraisablehook", sys.unraisablehook)
    interrupts.keep()


@pytest.mark.parametrize("name, make, expected", [
    ("SIGTERM", Terminated, Terminated),
    ("SIGHUP", Terminated, Terminated),
    ("SIGTERM", interrupted, KeyboardInterrupt),  # monitor, bridge: SIGTERM as Ctrl-C
])
def test_a_signal_dropped_in_a_callback_is_raised_again_in_the_run(kept, name, make, expected):
    sig = getattr(signal, name)
    previous = unwind_on([name], make)
    try:
        with pytest.raises(expected) as caught:
            _signal_inside_a_callback(sig)
            _run_on()  # the run's own code: where it must land
        assert caught.value.signum == sig
        if expected is Terminated:
            assert caught.value.code == 128 + sig
    finally:
        restore(previous)


@pytest.mark.parametrize("name", ["SIGTERM", "SIGHUP"])
def test_a_signal_sent_again_wakes_a_run_that_went_on_into_a_long_wait(kept, name):
    """The run's next step after the callback is one long wait (``.sleep 30``): the signal
    sent again must cut it short, not be obeyed when it ends (it was: sent to the thread
    that sent it again, the main thread slept on; CI saw SIGTERM obeyed 30 s late)."""
    sig = getattr(signal, name)
    previous = unwind_on([name])
    started = time.monotonic()
    try:
        with pytest.raises(Terminated):
            _signal_inside_a_callback(sig)
            time.sleep(30)
    finally:
        restore(previous)
    assert time.monotonic() - started < 30


def test_ctrl_c_dropped_in_a_callback_is_raised_again(kept):
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            _signal_inside_a_callback(signal.SIGINT)
            _run_on()
    finally:
        signal.signal(signal.SIGINT, previous)


def test_without_keep_the_signal_is_lost(monkeypatch):
    """What ``keep`` is for (and that the test above does put the handler in a callback)."""
    seen = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(u.exc_value))
    previous = unwind_on(["SIGTERM"])
    try:
        _signal_inside_a_callback(signal.SIGTERM)
        _run_on(0.2)
    finally:
        restore(previous)
    assert len(seen) == 1 and isinstance(seen[0], Terminated)


def test_other_unraisable_errors_still_reach_the_hook_before(monkeypatch):
    seen = []
    monkeypatch.setattr(interrupts, "_kept", False)
    monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(u.exc_value))
    interrupts.keep()

    def callback(_ref: object) -> None:
        raise ValueError("a bug in a callback")

    thing = _Thing()
    ref = weakref.ref(thing, callback)  # noqa: F841
    del thing
    assert len(seen) == 1 and isinstance(seen[0], ValueError)


def test_a_handler_outside_the_main_thread_is_not_set():
    import threading

    got = []
    t = threading.Thread(target=lambda: got.append(unwind_on(["SIGTERM"])))
    t.start()
    t.join()
    assert got == [{}]
