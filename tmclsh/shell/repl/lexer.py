"""The TMCL lexer, written once as a Pygments lexer.

The prompt uses it through ``PygmentsLexer(TmclLexer)``; ``.list`` and disassembly output use
it through ``highlight()`` (rich). It reads the instruction set and the module database, so
mnemonics, symbolic types and parameter names are coloured from the same data the assembler
checks against:

=====================  ==================================================
``Keyword``            a mnemonic in command position (``SAP``, ``MVP``)
``Keyword.Pseudo``     a dot-command, or bare ``help``/``quit``/``exit``
``Name.Builtin``       a symbolic type or interrupt name (``ABS``, ``TI_TIMER0``)
``Name.Attribute``     a parameter name (``MaxPositioningSpeed``)
``Name.Label``         a label definition (``Loop:``)
``Name.Constant``      a constant definition (``Speed = 1000``)
``Number.*``           ``1000``, ``$1F``, ``0x1F``, ``0b101``
``Comment``            ``// ...`` and ``#include``
``Error``              a character no TMCL line can contain
=====================  ==================================================
"""

from __future__ import annotations

import re
from functools import cache

from pygments.lexer import Lexer
from pygments.token import (Comment, Error, Keyword, Name, Number, Operator, Punctuation, Text,
                            Whitespace)

from ...tmcl import instructions as isa
from ...tmcl.modules import Module, available, load

_TOKEN = re.compile(r"""
    (?P<ws>[ \t\r\f\v]+)
  | (?P<comment>//.*)
  | (?P<hash>(?<![^ \t])\#.*)
  | (?P<hex>(?:\$|0[xX])[0-9A-Fa-f]+\b)
  | (?P<bin>0[bB][01]+\b)
  | (?P<num>[0-9]+\b)
  | (?P<name>[A-Za-z_][A-Za-z0-9_.]*)
  | (?P<help>\?)
  | (?P<op>[-+*/%=])
  | (?P<punct>[(),:;])
  | (?P<other>.)
""", re.VERBOSE)



@cache
def _bare() -> frozenset[str]:
    """Shell words accepted without the dot (help, quit, exit), from the command table."""
    from ..lang import commands

    return frozenset(commands.bare_words())


@cache
def _symbol_names() -> frozenset[str]:
    names = {n.upper() for s in isa.all_instructions() for n in s.type_names()}
    names |= {n.upper() for n in isa.interrupts()}
    return frozenset(names)


@cache
def _param_names(module_name: str | None) -> frozenset[str]:
    mods = [load(module_name)] if module_name else [load(n) for n in available()]
    return frozenset(p.name.lower() for m in mods for p in m.axis_params + m.global_params)


def _is_mnemonic(word: str) -> bool:
    return isa.by_mnemonic(word) is not None or word.upper() in isa.ASCII_ONLY_COMMANDS


class TmclLexer(Lexer):
    """TMCL source and shell lines. ``TmclLexer(module=load("TMCM-1311"))`` restricts the
    parameter names it recognises to that module's (default: any module's)."""

    name = "TMCL"
    aliases = ["tmcl"]
    filenames = ["*.tmcl", "*.tmc"]
    mimetypes = ["text/x-tmcl"]

    def __init__(self, module: Module | str | None = None, **options):
        super().__init__(**options)
        self.module_name = module.name if isinstance(module, Module) else module

    def get_tokens_unprocessed(self, text: str):
        pos = 0
        for line in text.splitlines(keepends=True):
            yield from self._line(line, pos)
            pos += len(line)

    def _line(self, line: str, base: int):
        body = line.rstrip("\r\n")
        end = line[len(body):]
        stripped = body.lstrip()
        indent = len(body) - len(stripped)
        if indent:
            yield base, Whitespace, body[:indent]
        if stripped.startswith("#"):
            yield base + indent, Comment.Preproc, stripped
        elif stripped.startswith("!"):  # the override: the value is sent as typed
            yield base + indent, Keyword.Pseudo, "!"
            rest = stripped[1:]
            gap = len(rest) - len(rest.lstrip())
            if gap:
                yield base + indent + 1, Whitespace, rest[:gap]
            if rest.strip():
                yield from self._tokens(rest.lstrip(), base + indent + 1 + gap)
        elif stripped:
            yield from self._tokens(stripped, base + indent)
        if end:
            yield base + len(body), Whitespace, end

    def _tokens(self, text: str, base: int):
        params = _param_names(self.module_name)
        symbols = _symbol_names()
        toks = [(m.start(), m.lastgroup, m.group()) for m in _TOKEN.finditer(text)]
        # command position: the first name, or the name after `Label:`; `.cmd` owns its line
        significant = [i for i, t in enumerate(toks) if t[1] != "ws"]
        command_at = significant[0] if significant else None
        dot = text.startswith(".")
        if dot:
            m = re.match(r"\.[\w.-]*", text)
            assert m is not None
            yield base, Keyword.Pseudo, m.group()
            toks = [(m.end() + p, k, s) for p, k, s in
                    (((x.start(), x.lastgroup, x.group()) for x in _TOKEN.finditer(text[m.end():])))]
            significant = [i for i, t in enumerate(toks) if t[1] != "ws"]
            command_at = None
        labelled = False
        if (not dot and len(significant) >= 2 and toks[significant[0]][1] == "name"
                and toks[significant[1]][2] == ":"):
            labelled = True
            command_at = significant[2] if len(significant) > 2 else None
        constant = (not dot and not labelled and len(significant) >= 2
                    and toks[significant[0]][1] == "name" and toks[significant[1]][2] == "=")
        spec = isa.by_mnemonic(toks[command_at][2]) if command_at is not None else None
        jumps = spec is not None and spec.jumps  # JA Loop: the operand names a label
        for i, (pos, kind, tok) in enumerate(toks):
            at = base + pos
            if kind == "ws":
                yield at, Whitespace, tok
            elif kind == "comment":
                yield at, Comment.Single, tok
            elif kind == "hash":  # `GAP 1, 0 # where`: a comment to the end of the line
                yield at, Comment.Single, tok
            elif kind == "hex":
                yield at, Number.Hex, tok
            elif kind == "bin":
                yield at, Number.Bin, tok
            elif kind == "num":
                yield at, Number.Integer, tok
            elif kind == "op":
                yield at, Operator, tok
            elif kind == "punct":
                yield at, Punctuation, tok
            elif kind == "help":  # `?` is help where a command goes, else no TMCL
                yield at, Keyword.Pseudo if i == command_at else Error, tok
            elif kind == "other":
                yield at, Error, tok
            elif labelled and i == significant[0]:
                yield at, Name.Label, tok
            elif constant and i == significant[0]:
                yield at, Name.Constant, tok
            elif i == command_at:
                if _is_mnemonic(tok):
                    yield at, Keyword, tok
                elif tok.lower() in _bare():
                    yield at, Keyword.Pseudo, tok
                else:
                    yield at, Name, tok
            elif tok.upper() in symbols:
                yield at, Name.Builtin, tok
            elif tok.lower() in params:
                yield at, Name.Attribute, tok
            elif dot and _is_mnemonic(tok):
                yield at, Keyword, tok
            elif jumps:
                yield at, Name.Label, tok
            else:
                yield at, Name.Variable if not dot else Text, tok


def highlight(text: str, module: Module | None = None):
    """``text`` (TMCL source, a disassembly, a typed line) as a rich ``Text``."""
    from rich.text import Text as RichText

    from ..style import color_enabled, token_style

    out = RichText()
    lexer = TmclLexer(module)
    for _, token, value in lexer.get_tokens_unprocessed(text):
        out.append(value, style=token_style(token) if color_enabled() else "")
    return out
