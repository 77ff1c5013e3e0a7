"""Cutting typed text into shell lines: comments off, then ``;`` between commands.

One set of rules for the REPL, ``-c``, ``-f`` and ``.source``, so a line means the same
wherever it is typed:

- ``// comment`` and ``# comment`` run to the end of the line. ``#`` starts a comment only at
  the start of a word (``GAP 1, 0 # where``), so nothing that contains one mid-word is cut.
  Neither counts inside quotes (``.echo "a # b"``), and ``//`` right after a URL's scheme
  is part of the URL (``.connect socket://host:4001``, ``.connect rfc2217://...``).
- A line is classified once (``classify``): a shell command (with a dot, or ``help``,
  ``quit`` and ``?`` bare), a dot-word no command has, or TMCL. The REPL, ``-c``, ``-f``
  and the checks before a run all go by that one reading.
- ``;`` outside quotes separates lines (``help 4; help 5``), except after a command that owns
  the rest of its line (``Command.owns_line``: ``.watch`` separates its expressions with ``;``)
  up to a ``;`` that another dot-command follows.

A quote opens only at the start of a word, so the apostrophe in ``.echo don't`` is a letter.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

from ...tmcl.textlines import comment_at, separators, strip_comment  # noqa: F401 (users of this file)
from ...tmcl.textlines import split_line as _split_line
from . import commands


def owns_line(text: str) -> bool:
    """Whether ``text`` starts with a command that takes the rest of its line, ';' included."""
    words = text.split(None, 1)
    cmd = commands.find(words[0]) if words else None
    return cmd is not None and cmd.owns_line


def split_line(text: str, owns_line: Callable[[str], bool] = owns_line) -> list[str]:
    """One physical line as the shell lines in it (comment removed, ``;`` separating).

    ``owns_line(line)`` tells whether a line starts with a command that takes the rest of
    the line, ``;`` included."""
    return _split_line(text, owns_line, _next_command)


def _next_command(text: str) -> int | None:
    """In a line a command owns: the ``;`` that a dot-command follows (``.decode 01 06; .decode
    02 06``), which ends it all the same: its own pieces (bytes, expressions) never start
    with a dot-command's name."""
    for cut in separators(text):
        after = text[cut + 1:].split(None, 1)
        if after and after[0].startswith(".") and commands.find(after[0]) is not None:
            return cut
    return None


def split_text(text: str, owns_line: Callable[[str], bool] = owns_line) -> list[str]:
    """Every shell line of ``text`` (newlines and ``;`` separate)."""
    return [line for raw in text.splitlines() for line in split_line(raw, owns_line)]


class Line(NamedTuple):
    """One shell line, read once: its text without the comment, its first word, and the
    shell command it starts (None: TMCL, or a dot-word no command has)."""

    text: str
    word: str
    command: commands.Command | None

    @property
    def args(self) -> str:
        return self.text[len(self.word):].strip()

    @property
    def tmcl(self) -> bool:
        """A TMCL line (not blank, not a shell command, not a mistyped one)."""
        return bool(self.text) and self.command is None and not self.word.startswith(".")

    @property
    def unknown(self) -> bool:
        """A dot-word that names no shell command."""
        return self.command is None and self.word.startswith(".")


def classify(text: str) -> Line:
    """What a typed line is (its comment taken off first)."""
    text = strip_comment(text)
    word = text.split(None, 1)[0] if text else ""
    return Line(text, word, commands.find(word) if word else None)
