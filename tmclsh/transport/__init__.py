"""Moved to ``tmclsh.link``: this name is kept so scripts that import it still work."""

from .._moved import forward

__getattr__ = forward(__name__, "tmclsh.link")
