"""Moved to ``tmclsh.base.files``: this name is kept so scripts that import it still work."""

from ._moved import alias

alias(__name__, "tmclsh.base.files")
