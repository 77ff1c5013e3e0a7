"""Style names with meaning, in one place: a rich Theme and a prompt_toolkit Style."""

from __future__ import annotations

RICH_THEME = {
    "tmcl.ok": "green",
    "tmcl.error": "bold red",
    "tmcl.warn": "yellow",
    "tmcl.event": "bold cyan",
    "tmcl.value": "bold",
    "tmcl.unit": "dim",
    "tmcl.name": "cyan",
    "tmcl.note": "dim",
    "tmcl.bit.on": "green",
    "tmcl.bit.off": "dim",
    "tmcl.trace.tx": "magenta",
    "tmcl.trace.rx": "blue",
    "tmcl.trace.drop": "yellow",
    "tmcl.changed": "reverse",
    "tmcl.sim": "bold yellow",
}

PROMPT_STYLE = {
    "prompt": "ansicyan bold",
    "prompt.sim": "ansiyellow bold",
    "mnemonic": "ansibrightblue bold",
    "symbol": "ansimagenta",
    "parameter": "ansicyan",
    "number": "ansigreen",
    "dotcommand": "ansiyellow",
    "comment": "ansibrightblack italic",
    "error": "ansired underline",
    "bottom-toolbar": "bg:#222222 #aaaaaa",
    "bottom-toolbar.on": "bg:#222222 #55ff55 bold",
    "bottom-toolbar.sim": "bg:#222222 #ffff55 bold",
    "bottom-toolbar.off": "bg:#222222 #ff5555 bold",
}


def rich_theme():
    from rich.theme import Theme

    return Theme(RICH_THEME)


def prompt_style():
    from prompt_toolkit.styles import Style

    return Style.from_dict(PROMPT_STYLE)
