"""The one way into the shell from the command line (``cli/main.py``): several units, or one
module at the prompt, in ``-c``, in ``-f`` or on piped input. Its own module because both
ways (``units.py`` and ``main.py``) are below it: neither need know of the other's entry.
"""

from __future__ import annotations

import argparse

# the options that name units: given more than once (or --all), a command line may name
# several; given at most once each, it names one (``plan_units`` finds exactly that unit)
_UNIT_LISTS = ("port", "address", "can_id", "reply_id")


def enter(args: argparse.Namespace) -> int:
    """Several modules named (``plan_units``) run as units, else the one module's run:
    whichever way in, the run ends with one exit status."""
    from .main import run_shell

    if not may_name_several(args):
        # one module: the units' machinery (threads, the stop in each, their views) is not
        # imported, so the prompt and a -c run do not wait for it at start
        return run_shell(args)
    from ..features.units import plan_units

    units = plan_units(args)
    if len(units) > 1:
        from ...base import startup
        from ..features.units import run_units

        startup.release()
        return run_units(args, units)
    return run_shell(args)


def may_name_several(args: argparse.Namespace) -> bool:
    """Whether the command line may name several units: ``--all``, or a link, address or CAN
    id given more than once (only then is ``plan_units`` asked which)."""
    return bool(getattr(args, "all_modules", False)) or any(
        len(getattr(args, name, None) or ()) > 1 for name in _UNIT_LISTS)
