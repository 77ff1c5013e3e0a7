"""The options of the dot-commands: declared in their table entry (``Command.options``), read
one way for every command.

``.watch a=GAP 1, 0 --interval 0.2``, ``.upload prog.tmc --at 100 --yes``: an option is a word
that starts with ``--`` (or a short form the entry gives, ``-y``), outside quotes; it takes a
value when the entry says so (``--at 100`` or ``--at=100``; a quoted value keeps its spaces),
and an option no entry declares is an error naming the ones there are. The rest of the text
stays the command's own, as typed (a watch's expressions, quotes and all); ``words`` splits it
the way a shell would. The completer offers the declared options, and a test holds every
command's syntax line (what ``.help`` and the man page show) to them.
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Iterable
from dataclasses import dataclass

from ...base import limits
from ...base.errors import ValidationError


@dataclass(frozen=True)
class Option:
    """One option of a dot-command: ``--name``, the ``value`` it takes (what the syntax
    calls it, ``S``, ``ADDR``; empty for a flag), other spellings, and a line of help."""

    name: str
    value: str = ""
    help: str = ""
    aliases: tuple[str, ...] = ()

    def spellings(self) -> tuple[str, ...]:
        return (self.name, *self.aliases)


Given = dict[str, "str | bool"]  # option name ("--at") -> its value, or True for a flag
_WORD = re.compile(r"-{1,2}[A-Za-z][A-Za-z0-9-]*")


def parse(text: str, options: Iterable[Option]) -> tuple[str, Given]:
    """Take the options out of a command's argument text: ``(the rest, stripped, {name:
    value})``. ``-5`` and other words that are no option spelling stay in the rest (an
    expression's minus); ``--x`` that no option has is an error."""
    known = {s: opt for opt in options for s in opt.spellings()}
    found: Given = {}
    rest: list[str] = []
    i, n = 0, len(text)
    quote = None
    while i < n:
        ch = text[i]
        if quote:
            rest.append(ch)
            if ch == quote:
                quote = None
            i += 1
            continue
        if ch in "\"'":
            quote = ch
            rest.append(ch)
            i += 1
            continue
        m = _WORD.match(text, i) if ch == "-" and (i == 0 or text[i - 1].isspace()) else None
        end = m.end() if m else i
        if m and (end == n or text[end].isspace() or text[end] == "="):
            word = m.group()
            opt = known.get(word) or known.get(word.lower())
            if opt is None and word.startswith("--"):
                names = ", ".join(dict.fromkeys(o.name for o in known.values())) or "none"
                raise ValidationError(f"unknown option {word} (options: {names})")
            if opt is not None:
                i = _value(text, end, opt, found)
                continue
        rest.append(ch)
        i += 1
    if quote:
        raise ValidationError("unclosed quote")
    return "".join(rest).strip(), found


def _value(text: str, i: int, opt: Option, found: Given) -> int:
    """Read ``opt``'s value (if it takes one) from ``text`` at ``i``; where the text goes on."""
    n = len(text)
    if not opt.value:
        if i < n and text[i] == "=":
            raise ValidationError(f"{opt.name} takes no value")
        found[opt.name] = True
        return i
    if i < n and text[i] == "=":
        i += 1
    else:
        while i < n and text[i].isspace():
            i += 1
    if i >= n:
        raise ValidationError(f"{opt.name} needs a value ({opt.value})")
    if text[i] in "\"'":
        end = text.find(text[i], i + 1)
        if end < 0:
            raise ValidationError(f"unclosed quote in the value of {opt.name}")
        found[opt.name] = text[i + 1:end]
        return end + 1
    j = i
    while j < n and not text[j].isspace():
        j += 1
    found[opt.name] = text[i:j]
    return j


def words(text: str) -> list[str]:
    """The words of an argument text, split as a shell splits them (quotes group)."""
    try:
        return shlex.split(text)
    except ValueError as exc:
        raise ValidationError(f"cannot split arguments: {exc}") from None


def parse_words(text: str, options: Iterable[Option]) -> tuple[list[str], Given]:
    """``parse``, the rest as words: for commands whose arguments are file names and
    numbers."""
    rest, given = parse(text, options)
    return words(rest), given


def float_value(opts: Given, name: str, default: float | None, *,
                 minimum: float = 0.0, allow_none: bool = False,
                 limit: str = "duration") -> float | None:
    """A seconds-like option (``none``/``inf`` = no limit if allowed), within ``minimum``
    and the bounds of ``limits.LIMITS[limit]`` (at most a day)."""
    raw = opts.get(name)
    if raw is None:
        return default
    text = str(raw).strip().lower()
    if allow_none and text in ("none", "inf", "forever"):
        return None
    value = limits.parse(limit, text, name)
    if value < minimum:
        raise ValidationError(f"{name}: must be {limits.LIMITS[limit].describe()} and "
                              f"at least {minimum:g}, got {raw!r}")
    return value


def int_value(opts: Given, name: str, default: int | None, *,
               minimum: int = 1, limit: str = "count") -> int | None:
    """A count option, within ``minimum`` and the bounds of ``limits.LIMITS[limit]``."""
    raw = opts.get(name)
    if raw is None:
        return default
    value = int(limits.parse(limit, str(raw), name))
    if value < minimum:
        raise ValidationError(f"{name} must be at least {minimum}, got {value}")
    return value
