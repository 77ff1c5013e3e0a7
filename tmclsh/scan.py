"""Moved to ``tmclsh.ops.scan``: this name is kept so scripts that import it still work."""

from ._moved import alias

alias(__name__, "tmclsh.ops.scan")
