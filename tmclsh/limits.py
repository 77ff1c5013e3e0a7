"""Moved to ``tmclsh.base.limits``: this name is kept so scripts that import it still work."""

from ._moved import alias

alias(__name__, "tmclsh.base.limits")
