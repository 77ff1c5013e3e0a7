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
  the rest of its line (``Command.owns_line``: ``.watch`` separates its expressions with ``;``).

A quote opens only at the start of a word, so the apostrophe in ``.echo don't`` is a letter.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import NamedTuple

from . import commands


def _scan(text: str):
    """``(index, char, quoted)`` for each character; ``quoted`` is True inside quotes."""
    quote: str | None = None
    for i, ch in enumerate(text):
        if quote is not None:
            yield i, ch, True
            if ch == quote:
                quote = None
        elif ch in "\"'" and (i == 0 or text[i - 1].isspace() or text[i - 1] in "=(,"):
            quote = ch
            yield i, ch, True
        else:
            yield i, ch, False


# a URL's scheme ending where ``//`` starts: a word of letters, digits, ``+ - .`` that
# begins with a letter, then ``:`` (RFC 3986), as pyserial's ``socket://`` and ``loop://``
_SCHEME = re.compile(r"(?:^|(?<=\s))[A-Za-z][A-Za-z0-9+.-]*:$")


def comment_at(text: str) -> int | None:
    """Where a ``//`` or ``#`` comment starts in ``text`` (None if it has none)."""
    if "/" not in text and "#" not in text:
        return None  # most lines of a script: nothing to scan for (a scan is per character)
    for i, ch, quoted in _scan(text):
        if quoted:
            continue
        if ch == "/" and text.startswith("//", i) and not _SCHEME.search(text, 0, i):
            return i
        if ch == "#" and (i == 0 or text[i - 1].isspace()):
            return i
    return None


def separators(text: str):
    """Where ``text`` has a ``;`` outside quotes, in order (the places a line may be cut)."""
    return (i for i, ch, quoted in _scan(text) if ch == ";" and not quoted)


def strip_comment(text: str) -> str:
    """``text`` without its comment, stripped."""
    at = comment_at(text)
    return (text if at is None else text[:at]).strip()


def owns_line(text: str) -> bool:
    """Whether ``text`` starts with a command that takes the rest of its line, ';' included."""
    words = text.split(None, 1)
    cmd = commands.find(words[0]) if words else None
    return cmd is not None and cmd.owns_line


def split_line(text: str, owns_line: Callable[[str], bool] = owns_line) -> list[str]:
    """One physical line as the shell lines in it (comment removed, ``;`` separating).

    ``owns_line(line)`` tells whether a line starts with a command that takes the rest of
    the line, ``;`` included."""
    rest = strip_comment(text)
    if ";" not in rest:
        return [rest] if rest else []  # what the loop below gives, without its scan
    out: list[str] = []
    while rest:
        if owns_line(rest):
            out.append(rest)
            break
        cut = next(separators(rest), None)
        head, rest = (rest, "") if cut is None else (rest[:cut], rest[cut + 1:])
        if head.strip():
            out.append(head.strip())
        rest = rest.strip()
    return out


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
