"""Cutting text into shell lines, as pure code: comments off, then ``;`` between lines.

The rules are the shell language's (``tmclsh.shell.lang.lines`` states them and adds which
commands own the rest of their line); they live here, below the shell, so that what reads a
file of shell lines without a shell (a configuration backup: ``tmclsh.ops.backup``) cuts it
exactly as the shell does.
"""

from __future__ import annotations

import re
from collections.abc import Callable


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


def split_line(text: str, owns_line: Callable[[str], bool] = lambda _text: False,
               owned_until: Callable[[str], int | None] = lambda _text: None) -> list[str]:
    """One physical line as the shell lines in it (comment removed, ``;`` separating).

    ``owns_line(line)`` tells whether a line starts with a command that takes the rest of
    the line, ``;`` included (the shell's commands: ``tmclsh.shell.lang.lines``; none here), and
    ``owned_until(line)`` where such a line ends all the same (the ``;`` before another
    command; None: at its end)."""
    rest = strip_comment(text)
    if ";" not in rest:
        return [rest] if rest else []  # what the loop below gives, without its scan
    out: list[str] = []
    while rest:
        if owns_line(rest):
            cut = owned_until(rest)
            out.append(rest if cut is None else rest[:cut].strip())
            rest = "" if cut is None else rest[cut + 1:].strip()
            continue
        cut = next(separators(rest), None)
        head, rest = (rest, "") if cut is None else (rest[:cut], rest[cut + 1:])
        if head.strip():
            out.append(head.strip())
        rest = rest.strip()
    return out
