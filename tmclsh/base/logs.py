"""A module's logger that imports ``logging`` when it first logs.

``logging`` brings ``traceback``, ``string`` and their regular expressions with it: a start
that logs nothing (a ``-c`` run, the prompt) should not pay for them. The logger is
``logging.getLogger(name)``, the same one whoever set logging up configured.
"""

from __future__ import annotations

from typing import Any


class Logger:
    """``logging.getLogger(name)``, looked up at each use (logging is rare here)."""

    __slots__ = ("name",)

    def __init__(self, name: str):
        self.name = name

    def __getattr__(self, attr: str) -> Any:
        import logging

        return getattr(logging.getLogger(self.name), attr)
