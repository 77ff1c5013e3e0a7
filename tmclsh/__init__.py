"""tmclsh: a shell, ASCII terminal, assembler and simulator for Trinamic TMCL modules.

``tmclsh.connect(...)`` opens a client for programs and benchmarks; it is imported lazily so
``import tmclsh`` stays cheap for the command line.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

if TYPE_CHECKING:
    from .client.text import LineClient


def connect(*args: Any, **kwargs: Any) -> "LineClient":
    """Open a client; see :func:`tmclsh.client.connect.connect` for the arguments."""
    from .client.connect import connect as _connect

    return _connect(*args, **kwargs)


__all__ = ["connect", "__version__"]
