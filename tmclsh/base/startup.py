"""The cyclic garbage collector held off while tmclsh starts.

A start imports and builds a few hundred thousand objects that live as long as the process
(modules, the instruction set, module tables, prompt_toolkit's key bindings); the collector,
run every few hundred allocations, walks them again and again: 5 ms of a ``-c`` run and 14
ms before the first prompt. So the command line's entry holds it (``hold``) and the run lets
it go (``release``) where the work begins: before a ``-c``/``-f`` run's first line, once the
prompt is on the screen, before a subcommand or several units run, at the latest when the
entry returns. Only a process started as tmclsh holds it (``python -m tmclsh``, the
``tmclsh`` command): a program calling the entry with its own list of words does not. What was built until then is frozen (``gc.freeze``): no later collection
walks it. Reference counting frees everything as ever; only cycles made during the start
are kept until the process ends.
"""

from __future__ import annotations

import gc

_held = False


def hold() -> None:
    """Hold the collector off (only if it runs: a caller that turned it off keeps it off)."""
    global _held
    if gc.isenabled():
        gc.disable()
        _held = True


def release() -> None:
    """Let it go again, the start's objects frozen; nothing when ``hold`` did not hold it."""
    global _held
    if _held:
        _held = False
        gc.freeze()
        gc.enable()
