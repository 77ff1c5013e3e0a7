"""Completion in two steps, as pgcli does it.

1. ``suggest(text_before_cursor, module)`` is pure: it reads the line typed so far and says what
   kind of token comes next (``[AxisParam("GAP", "R")]``). It is tested without a terminal.
2. ``TmclCompleter`` maps each suggestion to a matcher that lists candidates from data (the
   instruction set, the module database, the command registry) and ranks them against the word
   under the cursor: exact, prefix, word-start, substring, then fuzzy (letters in order).

Completion never talks to the device: it reads ``client.module`` as loaded, never asks 136.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

from ...tmcl import instructions as isa
from ...tmcl.modules import Module, Parameter
from ..lang import commands
from ...client.text import AS_TYPED
from ..lang.lines import comment_at

if TYPE_CHECKING:
    from ..lang.session import Session

# -- step 1: what comes next (pure) ------------------------------------------------------


class Mnemonic(NamedTuple):
    """A TMCL command name at the start of a line."""


class ShellCommand(NamedTuple):
    """A dot-command (``dotted``) or a bare shell word (``help``, ``quit``)."""

    dotted: bool


class CommandArg(NamedTuple):
    """The argument text of a shell command; the command's own ``complete`` decides."""

    command: str
    text: str


class SymbolicType(NamedTuple):
    mnemonic: str
    only: tuple[str, ...] = ()  # inside an expression RFS reads only as RFS STATUS


class AxisParam(NamedTuple):
    """An axis parameter in the type slot; ``access`` the mnemonic needs: R, W or E."""

    mnemonic: str
    access: str


class GlobalParam(NamedTuple):
    mnemonic: str
    access: str


class MotorNumber(NamedTuple):
    mnemonic: str


class ParamBank(NamedTuple):
    """The bank slot of SGP/GGP/...: ``param`` is what the type slot holds (name or number)."""

    mnemonic: str
    param: str


class IoPort(NamedTuple):
    mnemonic: str
    outputs: bool  # SIO: only outputs (and the all-ports number)


class IoBank(NamedTuple):
    mnemonic: str
    port: str
    outputs: bool


class Interrupt(NamedTuple):
    mnemonic: str


class Label(NamedTuple):
    mnemonic: str


class ParamValue(NamedTuple):
    """The value slot of SAP/SGP: named values or choices of the parameter, if it has any."""

    mnemonic: str
    kind: str  # axis | global
    param: str
    bank: str


class ReadMnemonic(NamedTuple):
    """A read (GAP, GGP, GIO, ...) where an expression expects a value."""


class Variable(NamedTuple):
    """A shell variable (``.let``) where an expression expects a value; ``extra`` are names
    the command itself defines (the watched names inside ``.watch --until``)."""

    extra: tuple[str, ...] = ()


class Function(NamedTuple):
    """An expression function (``abs``, ``min``, ...)."""


Suggestion = (Mnemonic | ShellCommand | CommandArg | SymbolicType | AxisParam | GlobalParam
              | MotorNumber | ParamBank | IoPort | IoBank | Interrupt | Label | ParamValue
              | ReadMnemonic | Variable | Function)

# which access a mnemonic needs from the parameter in its type slot
# what a parameter's access letters must hold for a command's access (instructions.toml)
_ACCESS = {"read": "R", "write": "W", "store": "E", "restore": "E"}

_WORD = re.compile(r"[\w.$]*$")
_LABEL_PREFIX = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\s*:\s*")


def current_word(text_before_cursor: str) -> str:
    """The word the cursor is in (what a completion replaces)."""
    m = _WORD.search(text_before_cursor)
    return m.group() if m else ""


def suggest(text: str, module: Module | None = None) -> list[Suggestion]:
    """What may come at the end of ``text`` (the line up to the cursor)."""
    if comment_at(text) is not None:  # in a comment (`#` or `//`): nothing to offer
        return []
    inner = open_substitution(text)
    if inner is not None:  # `SAP 4, 0, ${GAP 4, ` completes the expression inside
        return suggest_expression(inner)
    stripped = text.lstrip()
    if stripped.startswith(AS_TYPED):  # `!SAP ...`: the line is TMCL all the same
        stripped = stripped[1:].lstrip()
        if not stripped:
            return [Mnemonic()]
    if not stripped:
        return [Mnemonic(), ShellCommand(dotted=True)]
    first, sep, rest = _split_first(stripped)
    if first.startswith("."):
        if not sep:
            return [ShellCommand(dotted=True)]
        cmd = commands.find(first)
        return _command_arg(cmd.name if cmd is not None else first, rest)
    cmd = commands.find(first)
    if cmd is not None and sep:
        return _command_arg(cmd.name, rest)
    m = _LABEL_PREFIX.match(stripped)
    if m:  # `Loop: MVP ...`: complete after the label
        stripped = stripped[m.end():]
        if not stripped:
            return [Mnemonic()] if m.group().endswith((" ", "\t")) else []
        first, sep, rest = _split_first(stripped)
    if not sep:
        return [Mnemonic(), ShellCommand(dotted=False)]
    spec = isa.by_mnemonic(first)
    if spec is None:
        return []
    rest = rest.lstrip()
    if rest.startswith(","):
        rest = rest[1:]  # `EI, 255`: the manuals' comma after the mnemonic
    operands = _split_operands(rest)
    slot = len(operands) - 1
    if slot >= len(spec.fields):
        return []
    field = spec.fields[slot]
    mnem = spec.mnemonic
    given = dict(zip(spec.fields, (o.strip() for o in operands)))
    if field == "type":
        kind = spec.type_kind
        if kind == "symbolic":
            return [SymbolicType(mnem)]
        if kind == "axis_param":
            return [AxisParam(mnem, _ACCESS.get(spec.access or "read", "R"))]
        if kind == "global_param":
            return [GlobalParam(mnem, _ACCESS.get(spec.access or "read", "R"))]
        if kind == "port":
            return [IoPort(mnem, outputs=spec.access == "write")]
        if kind == "interrupt":
            return [Interrupt(mnem)]
        return []
    if field == "motor":
        if spec.motor_kind == "motor":
            return [MotorNumber(mnem)]
        if spec.motor_kind == "bank":
            if spec.type_kind == "port":
                return [IoBank(mnem, given.get("type", ""), outputs=spec.access == "write")]
            if spec.type_kind == "global_param":
                return [ParamBank(mnem, given.get("type", ""))]
        return []
    # the value slot
    if spec.value_kind == "label":
        return [Label(mnem)]
    if spec.value_kind == "param" and spec.type_kind in ("axis_param", "global_param"):
        kind = "axis" if spec.type_kind == "axis_param" else "global"
        return [ParamValue(mnem, kind, given.get("type", ""), given.get("motor", ""))]
    return []


def _split_first(text: str) -> tuple[str, str, str]:
    m = re.match(r"(\S+?)(,|\s+|$)(.*)", text, re.S)
    assert m is not None
    word, sep, rest = m.groups()
    if sep == ",":
        return word, " ", "," + rest
    return word, sep, rest


def _split_operands(text: str) -> list[str]:
    """Operands at the top level (commas inside parentheses do not separate)."""
    out, depth, cur = [], 0, []
    for ch in text:
        if ch == "(":
            depth += 1
        elif ch == ")":
            depth = max(0, depth - 1)
        if ch == "," and depth == 0:
            out.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    out.append("".join(cur))
    return out


# -- inside expressions -------------------------------------------------------------------
# The commands whose argument is (partly) an expression, and how to find the expression part
# of their argument text. An expression embeds TMCL reads (``GAP 1, 0 > 500``); inside a read
# the completion is the prompt's own (``suggest`` on the read's text).

_WATCH_NAME = re.compile(r"\s*[A-Za-z_][A-Za-z0-9_]*\s*=(?!=)")
_LET_NAME = re.compile(r"\s*[A-Za-z_][A-Za-z0-9_]*\s*=(?!=)")
_EXPR_OPTION = re.compile(r"(?:^|\s)--([A-Za-z][A-Za-z0-9-]*)(?:\s+|$)")


def open_substitution(text: str) -> str | None:
    """The text inside a ``${`` that is not closed before the end, else None."""
    start = text.rfind("${")
    if start < 0 or "}" in text[start:]:
        return None
    return text[start + 2:]


def _after_options(text: str, expr_options: tuple[str, ...]) -> str | None:
    """The expression being typed, given the text after the command's fixed part: the text
    itself before any ``--option``; after ``--until`` (an expression option) what follows it
    (a leading quote dropped); after any other option None (its value is not an expression)."""
    last = None
    for m in _EXPR_OPTION.finditer(text):
        last = m
    if last is None:
        if re.search(r"(?:^|\s)-{1,2}[A-Za-z-]*$", text):
            return None  # typing an option name
        return text
    if last.group(1).lower() in expr_options and last.group().endswith((" ", "\t")):
        value = text[last.end():]
        if value[:1] in ("'", '"'):
            quote, value = value[0], value[1:]
            return None if quote in value else value  # a closed quote: the value is over
        return value
    return None


def expression_part(command: str, text: str) -> tuple[str, tuple[str, ...]] | None:
    """For a command that takes an expression: the expression before the cursor and the
    names the command itself defines; None where the cursor is not in an expression."""
    if command in (".expect", ".if", ".elif", ".display", ".sleep", ".repeat"):
        if command == ".repeat" and re.search(r"\sas\b", text, re.I):
            return None  # `.repeat 3 as i`: a name, not an expression
        return text, ()
    if command == ".wait":
        part = _after_options(text, ())
        return (part, ()) if part is not None else None
    if command == ".let":
        m = _LET_NAME.match(text)
        return (text[m.end():], ()) if m else None
    if command == ".watch":
        items = text.split(";")
        names = tuple(m.group().split("=")[0].strip() for item in items
                      if (m := _WATCH_NAME.match(item)))
        part = _after_options(items[-1], ("until",))
        if part is None:
            return None
        if part is not items[-1]:  # after --until: the watched names are values too
            return part, names
        m = _WATCH_NAME.match(part)
        return (part[m.end():] if m else part), ()
    return None


def _command_arg(command: str, rest: str) -> list[Suggestion]:
    part = expression_part(command, rest)
    if part is None:
        return [CommandArg(command, rest)]
    text, names = part
    out = suggest_expression(text, names)
    # the command's own options (``--timeout``) when one is being typed
    return out if out or not rest.strip() else [CommandArg(command, rest)]


_EXPR_TOKEN = re.compile(r"""
    (?P<ws>\s+)
  | (?P<num>(?:\$|0[xX])[0-9A-Fa-f]*|[0-9]+\.?[0-9]*(?:[eE][-+]?[0-9]+)?|\.[0-9]+)
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<op>==|!=|<=|>=|.)
""", re.VERBOSE | re.S)

_EXPR_KEYWORDS = ("and", "or", "not")


def _read_fields() -> dict[str, int]:
    return {s.mnemonic: len(s.fields) for s in isa.all_instructions()
            if s.reads or s.read_types}


def suggest_expression(text: str, names: tuple[str, ...] = ()) -> list[Suggestion]:
    """What may come at the end of an expression's text: inside a read (``GAP Max``) what
    the prompt offers for that read; where a value is expected a read, a variable or a
    function; after a value nothing."""
    reads = _read_fields()
    tokens = [(m.lastgroup, m.group(), m.start()) for m in _EXPR_TOKEN.finditer(text)
              if m.lastgroup != "ws"]
    if tokens and tokens[-1][0] in ("name", "num") and not text[-1:].isspace():
        tokens.pop()  # the word being typed: what it may become is the question
    # a stack of open parentheses and reads; a read frame is [mnemonic, start, given, wants]
    stack: list[list] = []
    want_value = True
    for kind, tok, pos in tokens:
        top = stack[-1] if stack else None
        in_read = top is not None and top[0] != "("
        if in_read and not top[3]:  # a read whose operand just ended
            if tok == "," and top[2] < reads[top[0]]:
                top[3] = True
                continue
            stack.pop()  # anything else ends the read; the token belongs outside it
            want_value = False
            top = stack[-1] if stack else None
            in_read = top is not None and top[0] != "("
        if in_read and top[3]:  # a read wants an operand
            if tok == "(":
                stack.append(["(", pos, 0, False])
                want_value = True
            elif kind in ("name", "num"):
                top[2] += 1
                top[3] = False
            elif tok != "-":  # `-5`: the sign belongs to the operand
                return []
            continue
        if kind == "name" and tok.upper() in reads and want_value:
            stack.append([tok.upper(), pos, 0, True])
        elif kind in ("name", "num"):
            want_value = kind == "name" and tok.lower() in _EXPR_KEYWORDS
        elif tok == "(":
            stack.append(["(", pos, 0, False])
            want_value = True
        elif tok == ")":
            while stack and stack[-1][0] != "(":
                stack.pop()
            if stack:
                stack.pop()
            want_value = False
            top = stack[-1] if stack else None
            if top is not None and top[0] != "(" and top[3]:  # `GAP (n), `: operand done
                top[2] += 1
                top[3] = False
        else:
            want_value = True
    top = stack[-1] if stack else None
    if top is not None and top[0] != "(":
        if not top[3]:
            return []
        fragment = top[0] + text[top[1] + len(top[0]):]
        out = suggest(fragment)
        spec = isa.by_mnemonic(top[0])
        if spec is not None and not spec.reads and spec.read_types:  # (RFS STATUS)
            out = [SymbolicType(top[0], spec.read_types) if isinstance(s, SymbolicType) else s
                   for s in out]
        return out
    if want_value:
        return [Variable(names), ReadMnemonic(), Function()]
    return []


# -- ranking -----------------------------------------------------------------------------

@dataclass(frozen=True)
class Candidate:
    text: str
    meta: str = ""
    display: str | None = None
    also: tuple[str, ...] = ()  # other strings that match (manual name, number)


def _norm(s: str) -> str:
    return re.sub(r"[^a-z0-9.$]", "", s.lower())


def _subsequence(needle: str, hay: str) -> bool:
    it = iter(hay)
    return all(ch in it for ch in needle)


def _word_starts(s: str) -> list[str]:
    """``MaxPositioningSpeed`` -> maxpositioningspeed, positioningspeed, speed."""
    parts = re.findall(r"[A-Z]?[a-z0-9]+|[A-Z]+(?![a-z])|[a-z0-9]+", s)
    return ["".join(parts[i:]).lower() for i in range(len(parts))]


def rank(word: str, candidate: Candidate) -> int | None:
    """0 exact, 1 prefix, 2 a later word starts with it, 3 substring, 4 fuzzy; None: no match."""
    w = _norm(word)
    if not w:
        return 1
    if w.isdigit() and candidate.text.isdigit():  # numbers: prefix only (14 -> 14, 140, 141)
        return 0 if candidate.text == w else 1 if candidate.text.startswith(w) else None
    best = None
    for i, s in enumerate((candidate.text, *candidate.also)):
        n = _norm(s)
        penalty = 0 if i == 0 else 1
        if n == w:
            r = 0
        elif n.startswith(w):
            r = 1
        elif any(ws.startswith(w) for ws in _word_starts(s)[1:]):
            r = 2
        elif w in n:
            r = 3
        elif i == 0 and _subsequence(w, n):
            r = 4
        else:
            continue
        r = min(r + penalty, 4)
        best = r if best is None else min(best, r)
    return best


def ranked(word: str, candidates: Iterable[Candidate]) -> list[Candidate]:
    scored = []
    for order, c in enumerate(candidates):
        r = rank(word, c)
        if r is not None:
            scored.append((r, order, c))
    scored.sort(key=lambda t: (t[0], t[1]))
    return [c for _, _, c in scored]


# -- step 2: candidates from data --------------------------------------------------------

def param_meta(p: Parameter) -> str:
    """``AP 4 · 0..327679999 pps · RWE · Maximum positioning speed``."""
    rng = p.range_text + (f" {p.unit}" if p.unit else "")
    named = f" · {p.manual_name}" if p.manual_name != p.name else ""  # not the name twice
    return f"{p.label} · {rng} · {p.access}{named}"


def _param_candidates(params: Iterable[Parameter], access: str, numeric: bool) -> list[Candidate]:
    out = []
    for p in params:
        if access not in p.access:
            continue
        if numeric:
            out.append(Candidate(str(p.number), param_meta(p), f"{p.number} {p.name}"))
        else:
            out.append(Candidate(p.name, param_meta(p), also=(p.manual_name,)))
    return out


def labels_of(session: Session | None) -> dict[str, int]:
    """Labels of the program the debugger holds (``session.state.program``), if any."""
    if session is None:
        return {}
    for key in ("program", "debugger"):
        obj = getattr(session.state, key)
        prog = getattr(obj, "program", obj)
        labels = getattr(prog, "labels", None)
        if isinstance(labels, dict):
            return {str(k): v for k, v in labels.items()}
    return {}


def _offered(session: Session | None) -> Callable[[isa.InstructionSpec], bool]:
    """Which commands the link carries as it is now (the mode's facts: the module's ASCII
    mode knows only some); without a session, all."""
    if session is None:
        return lambda _spec: True
    return session.client.mode.offers


def candidates(s: Suggestion, word: str, module: Module | None,
               session: Session | None = None) -> list[Candidate]:
    """Candidates for one suggestion, unranked (the order is the tie-break)."""
    numeric = bool(re.fullmatch(r"\d+", word))
    if isinstance(s, Mnemonic):
        specs = module.instructions if module is not None else isa.all_instructions()
        offered = _offered(session)
        return [Candidate(sp.mnemonic, sp.summary) for sp in specs
                if sp.direct and offered(sp)]
    if isinstance(s, ShellCommand):
        out = []
        for cmd in commands.all_commands():
            if s.dotted:
                out.extend(Candidate(n, cmd.help) for n in cmd.names())
            elif cmd.bare:
                out.append(Candidate(cmd.name[1:], cmd.help))
        return out
    if isinstance(s, SymbolicType):
        spec = isa.by_mnemonic(s.mnemonic)
        names = spec.type_names(module) if spec else {}
        return [Candidate(n, f"type {v}") for n, v in names.items()
                if not s.only or n in s.only]
    if isinstance(s, ReadMnemonic):
        specs = module.instructions if module is not None else isa.all_instructions()
        offered = _offered(session)
        return [Candidate(sp.mnemonic, sp.summary if sp.reads else
                          f"{sp.mnemonic} {'|'.join(sp.read_types)}, {sp.motor_kind}: "
                          f"{sp.summary.lower()}")
                for sp in specs if (sp.reads or sp.read_types) and sp.direct and offered(sp)]
    if isinstance(s, Variable):
        values = dict(getattr(session, "variables", None) or {})
        out = [Candidate(n, "watched value") for n in s.extra]
        out += [Candidate(n, f"variable = {v}") for n, v in sorted(values.items())
                if n not in s.extra]
        return out
    if isinstance(s, Function):
        from ..lang.expr import FUNCTIONS

        return [Candidate(f"{n}(", "function", display=f"{n}()") for n in FUNCTIONS]
    if module is None:
        return []
    if isinstance(s, AxisParam):
        return _param_candidates(module.axis_params, s.access, numeric)
    if isinstance(s, GlobalParam):
        return _param_candidates(module.global_params, s.access, numeric)
    if isinstance(s, MotorNumber):
        spec = isa.by_mnemonic(s.mnemonic)
        out = [Candidate(str(m), f"motor {m} of {module.motors}") for m in range(module.motors)]
        if spec is not None:
            special = getattr(spec, "motor_special", {}).get(module.name, {})
            out.extend(Candidate(str(num), text) for num, text in sorted(special.items()))
        return out
    if isinstance(s, ParamBank):
        key = s.param.strip()
        if re.fullmatch(r"\d{1,9}", key):
            banks = [b for b in module.banks() if module.glob(int(key), b) is not None]
        elif key:
            banks = sorted({p.bank for p in module.global_params
                            if _norm(p.name) == _norm(key)}) or module.banks()
        else:
            banks = module.banks()
        return [Candidate(str(b), _bank_meta(module, b)) for b in banks]
    if isinstance(s, IoPort):
        return _port_candidates(module, s.outputs)
    if isinstance(s, IoBank):
        banks = module.io_banks()
        if re.fullmatch(r"\d{1,9}", s.port.strip()):
            n = int(s.port)
            banks = [b for b in banks if module.port(b, n) is not None
                     or (n == module.io_all_port and b in module.io_all_banks)]
        if s.outputs:
            banks = [b for b in banks if any(p.kind == "digital_out" for p in module.io
                                             if p.bank == b)]
        return [Candidate(str(b), _io_bank_meta(module, b)) for b in banks]
    if isinstance(s, Interrupt):
        return [Candidate(n, f"interrupt {v}") for n, v in isa.interrupts().items()]
    if isinstance(s, Label):
        return [Candidate(n, f"address {a}") for n, a in sorted(labels_of(session).items(),
                                                                 key=lambda kv: kv[1])]
    if isinstance(s, ParamValue):
        p = _resolve_param(module, s.kind, s.param, s.bank)
        if p is None:
            return []
        if p.values:
            return [Candidate(str(v), meaning) for v, meaning in sorted(p.values.items())]
        if p.choices:
            return [Candidate(str(v), p.describe_value(v)) for v in p.choices]
        return []
    return []


def _bank_meta(module: Module, bank: int) -> str:
    params = [p for p in module.global_params if p.bank == bank]
    what = {0: "module settings", 1: "user C variables", 2: "user variables",
            3: "interrupt configuration"}.get(bank, "")
    return f"bank {bank}: {what}, {len(params)} entries".replace(": , ", ": ")


def _io_bank_meta(module: Module, bank: int) -> str:
    kinds = sorted({p.kind.replace("_", " ") for p in module.io if p.bank == bank})
    return f"bank {bank}: {', '.join(kinds)}"


def _port_candidates(module: Module, outputs: bool) -> list[Candidate]:
    by_port: dict[int, list[str]] = {}
    for p in module.io:
        if outputs and p.kind != "digital_out":
            continue
        kind = {"digital_in": "in", "analog_in": "analog", "digital_out": "out"}[p.kind]
        by_port.setdefault(p.port, []).append(f"{p.name} ({kind}, bank {p.bank})")
    out = [Candidate(str(n), " / ".join(names)) for n, names in sorted(by_port.items())]
    if module.io_all_port is not None:
        what = "all outputs at once (bit mask)" if outputs else "all digital inputs/outputs at once"
        out.append(Candidate(str(module.io_all_port), what))
    return out


def _resolve_param(module: Module, kind: str, key: str, bank: str) -> Parameter | None:
    key = key.strip()
    if not key:
        return None
    try:
        b = int(bank, 0) if bank.strip() else None
    except ValueError:
        b = None
    try:
        return module.lookup(kind, int(key, 0) if re.fullmatch(r"\d{1,9}|0x[0-9a-fA-F]{1,8}", key)
                             else key, b)
    except Exception:
        return None


def complete_arg(session: Session | None, command: str, text: str) -> list[Candidate]:
    """Candidates of a shell command's own completion (``Command.complete``), and its
    options (``Command.options``) where an option may start."""
    cmd = commands.find(command)
    if cmd is None:
        return []
    word = arg_word(text)
    given = set(text.split())
    options = [Candidate(o.name, o.help) for o in cmd.options
               if word.startswith("-") or not word
               if not given & set(o.spellings())]
    if cmd.complete is None:
        return options if word.startswith("-") else []
    try:
        source = cmd.completion()
        items = source(session, text) if callable(source) else source
    except Exception:  # a feature's broken completion must not break typing
        return []
    out = []
    for item in items or ():
        if isinstance(item, Candidate):
            out.append(item)
        elif isinstance(item, tuple):
            out.append(Candidate(str(item[0]), str(item[1]) if len(item) > 1 else ""))
        else:
            out.append(Candidate(str(item)))
    named = {c.text for c in out}
    return out + [c for c in options if c.text not in named and word.startswith("-")]


def arg_word(text: str) -> str:
    """The word being completed inside a shell command's argument text."""
    m = re.search(r"[^\s,=]*$", text)
    return m.group() if m else ""


# -- the prompt_toolkit completer --------------------------------------------------------

try:
    from prompt_toolkit.completion import CompleteEvent, Completer, Completion
    from prompt_toolkit.document import Document
except ImportError:  # pragma: no cover - prompt_toolkit is a dependency
    Completer = object  # type: ignore[misc,assignment]


class TmclCompleter(Completer):  # type: ignore[misc]
    """Completions for the prompt, from ``suggest`` and the data tables.

    ``module`` overrides the session's (for tests and for completing without a session).
    """

    def __init__(self, session: Session | None = None, module: Module | None = None):
        self.session = session
        self._module = module

    @property
    def module(self) -> Module | None:
        if self._module is not None:
            return self._module
        if self.session is None:
            return None
        return self.session.client.module  # as loaded: never ask the device

    def _arg_session(self, module: Module | None):
        """The session handed to commands' own completions; without a real one (completing
        for a module alone), a stand-in that only knows the module."""
        if self.session is not None and self._module is None:
            return self.session
        client = type("DetachedClient", (), {"module": module, "mode": "binary"})()
        return type("DetachedSession", (), {"client": client, "state": {}})()

    def get_completions(self, document: Document, complete_event: CompleteEvent
                        ) -> Iterator[Completion]:
        text = document.text_before_cursor
        module = self.module
        seen: set[str] = set()
        for s in suggest(text, module):
            if isinstance(s, CommandArg):
                word = arg_word(s.text)
                cands = complete_arg(self._arg_session(module), s.command, s.text)
            else:
                word = current_word(text)
                cands = candidates(s, word, module, self.session)
            for c in ranked(word, cands):
                if c.text in seen:
                    continue
                seen.add(c.text)
                yield Completion(c.text, start_position=-len(word),
                                 display=c.display or c.text, display_meta=c.meta)
