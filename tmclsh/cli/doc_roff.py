"""Roff for the man page: escaping, fonts, and the usage lines and option lists of a command
line as ``doc_model`` reads it."""

from __future__ import annotations

import re
from collections.abc import Iterable

from .doc_model import CommandLine, Group, Option, PROG, module_names

# -- roff -----------------------------------------------------------------------------------

def _inline(text: str) -> str:
    """Escape text for roff inside a line: backslashes and option hyphens."""
    text = text.replace("\\", "\\e")
    return re.sub(r"(?<![\w.])-", r"\\-", text)


def _esc(text: str) -> str:
    """Escape running text for roff; lines starting with a dot or quote are protected."""
    return "\n".join("\\&" + ln if ln[:1] in (".", "'") else ln
                     for ln in _inline(text).split("\n"))


def _prose(text: str) -> str:
    """Escape help text, setting `code spans` in bold."""
    parts = text.split("`")
    if len(parts) % 2 == 0:  # an unpaired backtick: leave them all as they are
        return _esc(text)
    out = "".join(_b(p) if i % 2 else _inline(p) for i, p in enumerate(parts))
    return "\\&" + out if out[:1] in (".", "'") else out


def _b(text: str) -> str:
    return f"\\fB{_inline(text)}\\fR"


def _i(text: str) -> str:
    return f"\\fI{_inline(text)}\\fR"


def _opt_tag(o: Option, all_flags: bool = True) -> str:
    flags = ", ".join(_b(f) for f in (o.flags if all_flags else (o.long,)))
    if o.metavar is None:
        return flags
    value = _i(o.metavar)
    return f"{flags} [{value}]" if o.optional else f"{flags} {value}"


def _opt_usage(o: Option) -> str:
    flag = o.flags[0] if len(o.flags[0]) == 2 and len(o.flags) > 1 else o.long
    if o.metavar is None:
        return _b(flag)
    value = f"[{_i(o.metavar)}]" if o.optional else _i(o.metavar)
    return f"{_b(flag)} {value}"


def _sentence(text: str) -> str:
    text = text.strip()
    if not text:
        return text
    first = text.split(None, 1)[0]
    if not first.startswith(("python-", "pyserial")):  # names keep their case
        text = text[0].upper() + text[1:]
    return text if text.endswith((".", "!", "?")) else text + "."


def _summarised(g: Group) -> bool:
    """A subcommand's copy of a group of tmclsh's own options (the connection options) is
    named, not listed; a group the subcommand has for itself is listed."""
    return g.copy


def _usage(cmd: CommandLine) -> str:
    """One synopsis line of a subcommand."""
    parts = [_b(f"{PROG} {cmd.name}".strip())]
    parts += [_i(p.name) for p in cmd.positionals]
    required = {id(o) for grp in cmd.required_choices for o in grp}
    for g in cmd.groups:
        if _summarised(g):
            parts.append(f"[{_i(g.title.split()[0])}]")
            continue
        for o in g.options:
            if o.dest == "help" or id(o) in required:
                continue
            parts.append(f"[{_opt_usage(o)}]")
    for grp in cmd.required_choices:
        parts.append("(" + " | ".join(_opt_usage(o) for o in grp) + ")")
    return " ".join(parts)


def _option_extra(o: Option) -> list[str]:
    from ..base.config import CONNECTION_KEYS, ENVIRONMENT

    extra = []
    if o.kind == "modules":
        extra.append("Modules: " + ", ".join(module_names()) + ".")
    if o.choices and not all(c in o.help for c in o.choices):
        extra.append("One of: " + ", ".join(o.choices) + ".")
    env = [var for var, key in ENVIRONMENT.items() if key == o.dest]
    if env:
        extra.append(f"Environment: {', '.join(env)}.")
    if o.dest in CONNECTION_KEYS and o.dest != "profile":
        extra.append(f"Profile key: {o.dest}.")
    if o.excludes:
        extra.append("Excludes " + ", ".join(o.excludes) + ".")
    return extra


def _options_block(options: Iterable[Option], *, top: bool) -> list[str]:
    out = []
    for o in options:
        out += [".TP", _opt_tag(o)]
        if o.help:
            out.append(_esc(_sentence(o.help)))
        extra = _option_extra(o) if top else (
            ["Modules: " + ", ".join(module_names()) + "."] if o.kind == "modules" else [])
        if extra:
            out.append(_esc(" ".join(extra)))
    return out


def _synopsis(top: CommandLine, subs: list[CommandLine]) -> list[str]:
    lines: list[str] = []
    conn = " ".join(f"[{_i(g.title.split()[0])}]" for g in top.groups if not g.default)

    def line(text: str) -> None:
        if lines:
            lines.append(".br")
        lines.append(text)

    line(f"{_b(PROG)} {conn}")
    for g in top.groups:
        if not g.default:
            continue
        for o in g.options:
            if o.dest in ("help", "version"):
                continue
            prefix = f" {conn}" if o.excludes else ""
            line(f"{_b(PROG)}{prefix} {_opt_usage(o)}")
    for s in subs:
        line(_usage(s))
    return lines
