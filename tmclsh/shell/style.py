"""Style names with meaning, in one place: a rich Theme and a prompt_toolkit Style.

No colour is written anywhere else: code names a role (``tmcl.status.error``, ``mnemonic``)
and this file says what it looks like. ``NO_COLOR`` is honoured by both libraries (rich and
prompt_toolkit read it themselves); ``color_enabled()`` tells the rest of the shell.
"""

from __future__ import annotations

import os

RICH_THEME = {
    "tmcl.ok": "green",
    "tmcl.status.ok": "green",
    "tmcl.status.error": "bold red",
    "tmcl.error": "bold red",
    "tmcl.warn": "yellow",
    "tmcl.event": "bold cyan",
    "tmcl.value": "bold",
    "tmcl.unit": "dim",
    "tmcl.name": "cyan",
    "tmcl.mnemonic": "bold blue",
    "tmcl.note": "dim",
    "tmcl.heading": "bold underline",
    "tmcl.bit.on": "green",
    "tmcl.bit.off": "dim",
    "tmcl.trace.time": "dim",
    "tmcl.trace.tx": "magenta",
    "tmcl.trace.rx": "blue",
    "tmcl.trace.drop": "yellow",
    "tmcl.trace.note": "dim italic",
    "tmcl.trace.hex": "default",
    "tmcl.changed": "reverse",
    "tmcl.sim": "bold yellow",
}

# pygments token classes as PygmentsLexer names them ("class:pygments.keyword", ...); the
# TmclLexer (lexer.py) decides which token each piece of a line is.
PROMPT_STYLE = {
    "prompt": "ansicyan bold",
    "prompt.sim": "ansiyellow bold",
    "prompt.state": "ansimagenta",
    "banner.title": "bold",                              # the banner above the first prompt
    "banner.name": "ansicyan",                           # (as tmcl.name in RICH_THEME)
    "banner.sim": "ansiyellow bold",                     # (as tmcl.sim)
    "pygments.keyword": "ansibrightblue bold",           # mnemonics
    "pygments.keyword.pseudo": "ansiyellow",             # .commands, help, quit
    "pygments.name.builtin": "ansimagenta",              # ABS REL COORD, TI_TIMER0
    "pygments.name.attribute": "ansicyan",               # parameter names
    "pygments.name.label": "ansibrightmagenta bold",
    "pygments.name.constant": "ansibrightcyan",
    "pygments.literal.number": "ansigreen",
    "pygments.comment": "ansibrightblack italic",
    "pygments.error": "ansired underline",
    "bottom-toolbar": "noreverse bg:ansiblack ansiwhite",
    "bottom-toolbar.key": "noreverse bg:ansiblack ansiwhite bold",
    "bottom-toolbar.on": "noreverse bg:ansiblack ansibrightgreen bold",
    "bottom-toolbar.sim": "noreverse bg:ansiblack ansibrightyellow bold",
    "bottom-toolbar.off": "noreverse bg:ansiblack ansibrightred bold",
    "bottom-toolbar.dim": "noreverse bg:ansiblack ansibrightblack",
    "completion-menu.completion": "bg:ansibrightblack ansiwhite",
    "completion-menu.completion.current": "bg:ansiwhite ansiblack",
    "completion-menu.meta.completion": "bg:ansiblack ansiwhite",
    "completion-menu.meta.completion.current": "bg:ansiwhite ansiblack",
    "auto-suggestion": "ansibrightblack",
}

# rich styles for pygments tokens (the lexer's output rendered by rich, e.g. in .list)
TOKEN_STYLE = {
    "Keyword": "bold blue",
    "Keyword.Pseudo": "yellow",
    "Name.Builtin": "magenta",
    "Name.Attribute": "cyan",
    "Name.Label": "bold magenta",
    "Name.Constant": "bright_cyan",
    "Number": "green",
    "Comment": "dim italic",
    "Error": "red underline",
}


def color_enabled() -> bool:
    return not os.environ.get("NO_COLOR") and os.environ.get("TERM") != "dumb"


def rich_theme():
    from rich.theme import Theme

    return Theme(RICH_THEME)


def prompt_style():
    from prompt_toolkit.styles import Style

    return Style.from_dict(PROMPT_STYLE)


def token_style(token) -> str:
    """The rich style of a pygments token (falls back along the token's parents)."""
    while token is not None:
        name = str(token).removeprefix("Token.").replace("Literal.", "")
        if name in TOKEN_STYLE:
            return TOKEN_STYLE[name]
        token = token.parent
    return ""
