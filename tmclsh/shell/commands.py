"""The registry of dot-commands: one table with handler, syntax, help and completions.

``.help``, the completer, the man page and the lexer are all generated from it, so a command
exists in exactly one place. Feature modules register their commands when imported;
``load_all()`` imports every one of them.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .session import Session

Handler = Callable[["Session", str], None]
# completion of the argument text: returns candidate words (or (word, meta) pairs)
ArgCompleter = Callable[["Session", str], Iterable["str | tuple[str, str]"]]

FEATURES = ("builtin", "script", "watch", "debugger", "terminal", "clone")


@dataclass
class Command:
    name: str
    handler: Handler
    syntax: str
    help: str
    aliases: tuple[str, ...] = ()
    complete: ArgCompleter | list[str] | None = None
    category: str = "general"
    details: str = ""
    bare: bool = False  # also accepted without the dot (help, quit)
    # the command's arguments may contain ';' (.watch separates its expressions with it), so
    # it takes the rest of its line; for all others ';' ends the command and starts a new line
    owns_line: bool = False

    def names(self) -> tuple[str, ...]:
        return (self.name, *self.aliases)


REGISTRY: dict[str, Command] = {}
_ALIASES: dict[str, str] = {}


def command(name: str, syntax: str, help: str, *, aliases: Iterable[str] = (),
            complete: ArgCompleter | list[str] | None = None, category: str = "general",
            details: str = "", bare: bool = False, owns_line: bool = False
            ) -> Callable[[Handler], Handler]:
    """Register ``handler(session, argtext)`` as the dot-command ``name`` (with the dot)."""

    def register(fn: Handler) -> Handler:
        cmd = Command(name, fn, syntax, help, tuple(aliases), complete, category, details, bare,
                      owns_line)
        REGISTRY[name] = cmd
        for alias in cmd.aliases:
            _ALIASES[alias] = name
        return fn

    return register


def find(word: str) -> Command | None:
    if word == "?":  # `?` and `? 140` are help, as in most consoles
        word = "help"
    if not word.startswith("."):
        cmd = REGISTRY.get("." + word.lower())
        return cmd if cmd is not None and cmd.bare else None
    word = word.lower()
    return REGISTRY.get(word) or REGISTRY.get(_ALIASES.get(word, ""))


def all_commands() -> list[Command]:
    return sorted(REGISTRY.values(), key=lambda c: c.name)


def load_all() -> None:
    for feature in FEATURES:
        try:
            importlib.import_module(f"{__package__}.{feature}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__package__}.{feature}":
                raise
