"""The one way into the shell from the command line (``cli/main.py``): several units, or one
module at the prompt, in ``-c``, in ``-f`` or on piped input. Its own module because both
ways (``units.py`` and ``main.py``) are below it: neither need know of the other's entry.
"""

from __future__ import annotations

import argparse


def enter(args: argparse.Namespace) -> int:
    """Several modules named (``plan_units``) run as units, else the one module's run:
    whichever way in, the run ends with one exit status."""
    from .main import run_shell
    from ..features.units import plan_units

    units = plan_units(args)
    if len(units) > 1:
        from ..features.units import run_units

        return run_units(args, units)
    return run_shell(args)
