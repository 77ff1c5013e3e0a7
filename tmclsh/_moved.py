"""Import paths users already used, kept working after the modules moved into layers.

A script written against tmclsh 0.1 imported ``tmclsh.errors`` or ``tmclsh.protocol``; those
modules now live in ``tmclsh/base/``, ``tmclsh/tmcl/``, ... (HACKING.md). Each old name is a
small module that calls ``alias`` and becomes the new module itself, not a copy, so
``except tmclsh.errors.TmclError`` catches what tmclsh raises, and the importer is told,
once, where the module lives now.
"""

from __future__ import annotations

import importlib
import sys
import warnings
from collections.abc import Callable
from types import ModuleType


def alias(old: str, new: str) -> ModuleType:
    """Make the module ``old`` the module ``new`` (in ``sys.modules``), with a warning."""
    module = alias_warning(old, new)
    sys.modules[old] = module
    return module


def alias_warning(old: str, new: str) -> ModuleType:
    """The module ``new``, imported, and the importer told where it lives now."""
    module = importlib.import_module(new)
    # 4: the line that imported the old path (the warnings module skips the import
    # machinery's frames), where Python shows a DeprecationWarning in ``__main__``
    warnings.warn(moved_text(old, new), DeprecationWarning, stacklevel=4)
    return module


def moved_text(old: str, new: str) -> str:
    """Where to import from now: the new place alone would send a script from one private
    path to another, so what ``import tmclsh`` offers of it is named as coming from there."""
    from . import _LAZY

    public = [name for name, (where, _) in _LAZY.items() if where == new]  # (as listed there)
    if not public:
        return f"{old} has moved to {new}: import it from there"
    names = ", ".join(public[:4]) + (", ..." if len(public) > 4 else "")
    return (f"{old} has moved to {new}, which is private and may change: import {names} "
            "from tmclsh, its public API")


def forward(old: str, new: str) -> Callable[[str], object]:
    """The module ``__getattr__`` of an old package (``tmclsh.transport``): its names come
    from ``new``. The package stays itself, so its old submodules (``tmclsh.transport.serial``)
    are the small modules beside it that ``alias`` the new ones, never second copies."""
    module = alias_warning(old, new)

    def __getattr__(name: str) -> object:
        try:
            return getattr(module, name)
        except AttributeError:
            raise AttributeError(f"module {old!r} has no attribute {name!r}") from None

    return __getattr__
