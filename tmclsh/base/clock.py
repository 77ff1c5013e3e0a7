"""Waiting that can be cut short: ``sleep`` in slices of at most ``SLICE`` seconds.

``time.sleep`` blocks in C: an exception raised in the sleeping thread from another one (the
stop of a run of several units raises KeyboardInterrupt in each unit's thread, as Ctrl-C does
in the main thread; shell/features/units.py) lands only when it returns. Slept in slices, it lands
within a slice. A signal still ends the sleep at once in the main thread.
"""

from __future__ import annotations

import time

SLICE = 0.1  # seconds


def sleep(seconds: float) -> None:
    """``time.sleep(seconds)``, in slices (see the module docstring)."""
    if seconds <= SLICE:
        if seconds > 0:
            time.sleep(seconds)
        return
    end = time.monotonic() + seconds
    while True:
        left = end - time.monotonic()
        if left <= 0:
            return
        time.sleep(min(SLICE, left))
