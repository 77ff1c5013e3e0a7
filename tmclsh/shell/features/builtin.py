"""The shell's own dot-commands: help, parameters, connection, trace, stop.

Each registers itself with ``@command``; ``.help`` and completion are generated from the
registry, so a command is described in exactly one place. Handlers print through
``session.out`` and raise ``TmclError`` subclasses (the runner prints them as one line).
"""

from __future__ import annotations

import difflib
import re
from typing import TYPE_CHECKING

from ...tmcl import instructions as isa
from ...base import limits
from ...base.errors import StatusError, TmclError, TmclTimeoutError, TransportError, ValidationError
from ...tmcl.modules import Module, Parameter, available, identify, load, type1_of
from ...tmcl.version import LAYOUTS, TYPE_FIRST, VERSION_FIRST, decode_type1, parse_string
from ...tmcl.frames import Control, Request, status_ok
from ..lang import options
from ..lang.commands import CATEGORIES, all_commands, command, find, options_of
from ..repl.completer import Candidate, param_meta
from ..render import paged
from ..lang.session import reconnected

if TYPE_CHECKING:
    from ..lang.session import Session

_GAP = isa.Opcode.GAP
_GGP = isa.Opcode.GGP


# -- completions -------------------------------------------------------------------------

def _module(session: Session | None) -> Module | None:
    return session.client.module if session is not None else None  # never asks the device


def complete_help(session: Session | None, text: str) -> list[Candidate]:
    out = [Candidate(n, c.help) for c in all_commands() for n in c.names()]
    mod = _module(session)
    specs = mod.instructions if mod is not None else isa.all_instructions()
    out += [Candidate(s.mnemonic, s.summary) for s in specs]
    if mod is not None:
        out += [Candidate(p.name, param_meta(p)) for p in mod.axis_params + mod.global_params]
    if "--source" not in text.split():
        out.append(Candidate("--source", "also how the entry was read from the manuals"))
    return out


def _param_candidates(session: Session | None) -> list[Candidate]:
    mod = _module(session)
    if mod is None:
        return []
    return [Candidate(p.name, param_meta(p), also=(p.manual_name,))
            for p in mod.axis_params + mod.global_params]


def complete_param(session: Session | None, text: str) -> list[Candidate]:
    found = _param_candidates(session)
    if not found or "--source" in text.split():
        return found
    return found + [Candidate("--source", "also how the entry was read from the manual")]


def complete_params(session: Session | None, text: str) -> list[Candidate]:
    words = text.split()
    if len(words) == 0 or (len(words) == 1 and not text.endswith(" ")):
        return [Candidate("axis", "axis parameters (SAP/GAP)"),
                Candidate("global", "global parameters (SGP/GGP)")] + _param_candidates(session)
    kind = words[0].lower()
    return [c for c in _param_candidates(session)
            if kind not in ("axis", "global") or c.meta.startswith("AP" if kind == "axis" else "GP")]


def complete_connect(session: Session | None, text: str) -> list[Candidate]:
    words = text.split()
    if words and (len(words) > 1 or text.endswith(" ")):
        if words[0] == "sim":
            return [Candidate(n, load(n).summary) for n in available()]
        return []
    out = [Candidate("sim", "the built-in simulator: .connect sim TMCM-351"),
           Candidate("can", "a python-can bus: .connect can socketcan:can0")]
    try:
        from serial.tools import list_ports

        for p in sorted(list_ports.comports(), key=lambda p: p.device):
            about = p.description if p.description not in (None, "", "n/a") else ""
            out.append(Candidate(p.device, about))
    except Exception:  # listing ports is a nicety; never let it break typing
        pass
    return out


def complete_module(session: Session | None, text: str) -> list[Candidate]:
    return [Candidate(n, load(n).summary) for n in available()]


# -- .help -------------------------------------------------------------------------------

@command(".help")
@paged
def cmd_help(session: Session, arg: str) -> None:
    rest, given = options.parse(arg, options_of(".help"))
    source = "--source" in given
    if not rest:
        return _help_overview(session)
    word = rest.split()[0]
    cmd = find(word)  # `.param`, or a bare word: `help quit`
    if cmd is not None:
        return _help_command(session, cmd)
    if word.startswith("."):
        from ..lang.session import unknown_command

        raise ValidationError(unknown_command(word))
    spec = isa.by_mnemonic(word)
    if spec is not None:
        return _help_instruction(session, spec, source=source)
    number = _number(word)
    if number is not None:
        return _help_number(session, number, source=source)
    if find("." + word) is not None:
        return _help_command(session, find("." + word))  # type: ignore[arg-type]
    try:
        return cmd_param(session, arg, from_help=True)
    except ValidationError:
        near = _near_instructions(session, word)
        if not near:
            raise
        # `help SAPP` is a command misspelt, not a parameter: suggest commands of its kind
        raise ValidationError(f"no help topic or parameter matches {word!r}; did you mean "
                              f"{', '.join(near)}? (.help lists the commands)") from None


def _near_instructions(session: Session, word: str) -> list[str]:
    """The TMCL mnemonics a word shaped like one is close to in spelling (`SAPP`: SAP)."""
    every = [s.mnemonic for s in isa.all_instructions()]
    if not (word.isalpha() and len(word) <= max(map(len, every)) + 1):
        return []  # longer than any mnemonic misspelt: a name
    try:
        known = [s.mnemonic for s in session.module.instructions]
    except TmclError:
        known = every
    return difflib.get_close_matches(word.upper(), known, n=3, cutoff=0.7)


@command(".clear")
def cmd_clear(session: Session, arg: str) -> None:
    if session.out.is_terminal and not session.out.json:
        session.out.console.clear()


def _help_overview(session: Session) -> None:
    from rich.table import Table
    from rich.text import Text

    out = session.out
    if out.json:
        out.emit({"commands": [{"name": c.name, "syntax": c.syntax, "help": c.help,
                                "category": c.category, "aliases": list(c.aliases)}
                               for c in all_commands()]})
        return
    cats: dict[str, list] = {}
    for c in _unique_commands():
        cats.setdefault(c.category, []).append(c)
    known = [name for name, _ in CATEGORIES]
    order = [c for c in known if c in cats] + sorted(set(cats) - set(known))
    # one syntax column for all categories, at most 45% of the width: a longer syntax gets a
    # line of its own with the description under it, so no description is squeezed away
    titles = {c.name: _command_title(c) for cs in cats.values() for c in cs}
    limit = max(20, min(42, out.console.width * 9 // 20))
    col = max((len(t) for t in titles.values() if len(t) <= limit), default=limit)

    def flush(rows: list) -> None:
        if rows:
            grid = Table.grid(padding=(0, 2))
            grid.add_column(style="tmcl.name", no_wrap=True, width=col)
            grid.add_column()
            for title, text in rows:
                grid.add_row(Text(title), Text(text))
            out.print(grid)
            rows.clear()

    for cat in order:
        out.print(Text(dict(CATEGORIES).get(cat, cat.capitalize()), style="tmcl.heading"))
        rows: list[tuple[str, str]] = []
        for c in cats[cat]:
            if len(titles[c.name]) <= col:
                rows.append((titles[c.name], c.help))
                continue
            flush(rows)
            out.print(Text(titles[c.name], style="tmcl.name"), soft_wrap=False)
            out.print(_indented(c.help, indent=col + 2), soft_wrap=False)
        flush(rows)
        out.print()
    mod = session.client.module
    out.print(Text("TMCL commands", style="tmcl.heading"))
    names = " ".join(s.mnemonic for s in (mod.instructions if mod else isa.all_instructions())
                     if s.direct)
    out.print(Text("Type them as in the TMCL-IDE: ", style="") +
              Text("SAP 4, 0, 1000", style="tmcl.mnemonic") + Text("  or  ") +
              Text("GAP MaxPositioningSpeed, 0", style="tmcl.mnemonic") +
              Text(". Numbers may be hex ($1F, 0x1F). Any command number works raw: "
                   "136 0, 0, 0."), soft_wrap=False)
    out.print(Text(f"On the {mod.name if mod else 'module'}: {names}", style="tmcl.note"),
              soft_wrap=False)
    out.print(Text("help MNEMONIC explains one; help NUMBER or .param NAME explains a parameter.",
                   style="tmcl.note"), soft_wrap=False)
    out.print()
    out.print(Text("Keys", style="tmcl.heading"))
    out.print("Tab completes (parameter names show their number, range and unit).  "
              "Ctrl-C stops all motors and clears the line.  Ctrl-D or .quit leaves.  "
              "An empty line repeats the last .step.", markup=False, soft_wrap=False)


def _unique_commands():
    """Commands in name order; entries sharing a handler (.quit/.exit) shown once, under the
    one registered first."""
    return [c for c in all_commands() if not c.same_as]


def _twins(c) -> list[str]:
    """The other names of the same handler (``.exit`` for ``.quit`` and back)."""
    key = c.same_as or c.name
    return [o.name for o in all_commands() if (o.same_as or o.name) == key and o is not c]


def _command_title(c) -> str:
    twins = _twins(c)
    names = [c.syntax] + list(c.aliases) + twins
    return ", ".join(names)


def _help_command(session: Session, cmd) -> None:
    from rich.text import Text

    out = session.out
    if out.json:
        out.emit({"name": cmd.name, "syntax": cmd.syntax, "help": cmd.help,
                  "details": cmd.details, "aliases": list(cmd.aliases)})
        return
    out.print(Text(cmd.syntax, style="tmcl.name"))
    out.print(_indented(cmd.help), soft_wrap=False)
    if cmd.details:
        out.print(_indented(_paragraphs(cmd.details)), soft_wrap=False)
    extra = list(cmd.aliases) + _twins(cmd)
    if cmd.bare:
        extra.append(cmd.name[1:])
    if extra:
        out.print(Text(f"  also: {', '.join(extra)}", style="tmcl.note"))


def _indented(text: str, style: str = "", indent: int = 2):
    """Prose that wraps at word boundaries, every line indented by ``indent``."""
    from rich.padding import Padding
    from rich.text import Text

    return Padding(Text(text, style=style), (0, 0, 0, indent), expand=False)


def _paragraphs(text: str) -> str:
    """Help details as written in the source (wrapped at ~90 columns) re-flowed: a line break
    inside a paragraph becomes a space; blank lines and indented (example) lines stay."""
    out: list[str] = []
    for line in text.splitlines():
        if out and out[-1] and line.strip() and not line[:1].isspace() \
                and not out[-1][:1].isspace():
            out[-1] += " " + line.strip()
        else:
            out.append(line.rstrip())
    return "\n".join(out)


def _help_instruction(session: Session, spec: isa.InstructionSpec,
                      source: bool = False) -> None:
    from rich.table import Table
    from rich.text import Text

    out = session.out
    mod = session.client.module
    if out.json:
        out.emit({"mnemonic": spec.mnemonic, "opcode": spec.opcode, "summary": spec.summary,
                  "syntax": spec.syntax, "types": spec.type_names(mod),
                  "modules": sorted(spec.modules), "direct": spec.direct, "ascii": spec.ascii,
                  "note": spec.note_for(mod), **({"source": spec.source} if source else {})})
        return
    title = Text()
    title.append(spec.mnemonic, style="tmcl.mnemonic")
    title.append(f"  (command {spec.opcode})  {spec.summary}")
    out.print(title, soft_wrap=False)
    grid = Table.grid(padding=(0, 2))
    grid.add_column(style="tmcl.note", no_wrap=True)
    grid.add_column()
    grid.add_row("syntax", _syntax(spec, mod))
    for fld in spec.fields:
        grid.add_row(fld, _field_help(spec, fld, mod))
    grid.add_row("modules", ", ".join(sorted(spec.modules)) +
                 ("" if mod is None or spec.on(mod) else
                  f"  (not the connected {mod.name})"))
    where = []
    where.append("at the prompt" if spec.direct else "only inside a stored program")
    if spec.direct:
        where.append("in ASCII mode too" if spec.ascii else "not in ASCII mode")
    grid.add_row("use", ", ".join(where))
    if spec.persists:
        grid.add_row("EEPROM", "writes the module's EEPROM (asks for confirmation)")
    note = spec.note_for(mod)
    if note:
        grid.add_row("note", note)
    if source:
        grid.add_row("source", spec.source or "as the manuals describe it")
    out.print(grid)


def _syntax(spec: isa.InstructionSpec, mod: Module | None) -> str:
    if mod is None or spec.type_kind != "symbolic":
        return spec.syntax
    names = "|".join(spec.type_names(mod))
    return spec.syntax.replace("|".join(spec.type_names()), names)


def _field_help(spec: isa.InstructionSpec, fld: str, mod: Module | None) -> str:
    if fld == "type":
        kind = spec.type_kind
        if kind == "symbolic":
            return ", ".join(f"{n} = {v}" for n, v in spec.type_names(mod).items())
        if kind in ("axis_param", "global_param"):
            what = "axis" if kind == "axis_param" else "global"
            count = ""
            if mod is not None:
                n = len(mod.axis_params if what == "axis" else mod.global_params)
                count = f" ({n} on the {mod.name}; list them with .params {what})"
            return f"{what} parameter: number or name{count}"
        if kind == "port":
            if mod is None:
                return "I/O port number"
            ports = ", ".join(f"{p.port} {p.name}" for p in mod.io if p.bank == 0)
            all_ports = f"; {mod.io_all_port} = all at once" if mod.io_all_port is not None else ""
            return f"port number (bank 0: {ports}{all_ports})"
        if kind == "interrupt":
            return "interrupt number or name (TI_TIMER0 ...)"
        if kind == "coordinate":
            return f"coordinate number 0..{(mod.coordinates if mod else 21) - 1}"
        return "number 0..255"
    if fld == "motor":
        if spec.motor_kind == "motor":
            if mod is None:
                return "motor number"
            return f"motor 0..{mod.motors - 1}" if mod.motors > 1 else "motor 0"
        if spec.motor_kind == "bank":
            if mod is None:
                return "bank"
            banks = mod.io_banks() if spec.type_kind == "port" else mod.banks()
            return f"bank: {', '.join(map(str, banks))}"
        return "number 0..255"
    kind = spec.value_kind
    if kind == "velocity" and mod is not None:
        return f"velocity {mod.velocity_min}..{mod.velocity_max} {mod.units.get('velocity', '')}"
    if kind == "position" and mod is not None:
        return f"position {mod.position_min}..{mod.position_max} {mod.units.get('position', '')}"
    return {"param": "value in the parameter's range (see .param NAME)",
            "port_value": "0 or 1 (a bit mask for all outputs at once)",
            "label": "program address or label", "ticks": "time in ticks of 10 ms",
            "velocity": "velocity", "position": "position"}.get(kind, "number")


def _help_number(session: Session, number: int, source: bool = False) -> None:
    mod = session.module
    found = _params_by_number(mod, number)
    spec = isa.by_opcode(number)
    ctl = isa.control(number)
    if found:
        _show_params(session, found, numbered=number, source=source)
    elif mod.generic:
        session.out.info(f"{mod.label}: GAP {number}, 0 or GGP {number}, 0 reads it; "
                         + ("without -m generic, help names it" if getattr(mod, "forced", False)
                            else "a module file (--module-file) names it"))
    elif spec is None and ctl is None:  # nothing at all answers to it: an error, as a name is
        raise ValidationError(f"the {mod.name} has no parameter {number}, and no command has "
                              "that number (.params lists the parameters)")
    else:
        session.out.info(f"the {mod.name} has no parameter {number}")
    if not session.out.json:
        if spec is not None:
            session.out.info(f"(command {number} is {spec.mnemonic}: help {spec.mnemonic})")
        elif ctl is not None:
            session.out.info(f"(command {number}: {ctl.name})")


def _params_by_number(mod: Module, number: int) -> list[Parameter]:
    """AP n, then named global parameters n in any bank (user-variable ranges left out)."""
    out = [p for p in mod.axis_params if p.number == number]
    out += [p for p in mod.global_params if p.number == number and p.count == 1]
    return out


# -- .quit -------------------------------------------------------------------------------

def _quit(session: Session, arg: str) -> None:
    from ..lang.session import QuitShell

    raise QuitShell()


command(".quit")(_quit)
command(".exit")(_quit)


# -- .param / .params --------------------------------------------------------------------

@command(".param")
@paged
def cmd_param(session: Session, arg: str, from_help: bool = False) -> None:
    query, given = options.parse(arg, options_of(".param"))
    source = "--source" in given
    query = " ".join(query.split())
    if not query:
        raise ValidationError("which parameter? .param 140, .param MaxPositioningSpeed, "
                              ".param microstep")
    mod = session.module
    kind, bank, query = _kind_prefix(query)
    number = _number(query)
    if number is not None:
        if kind is None:
            found = _params_by_number(mod, number)
        elif kind == "axis":
            found = [p for p in mod.axis_params if p.number == number]
        else:
            found = [p for p in mod.global_params if p.covers(number)
                     and (bank is None or p.bank == bank)]
        if not found:
            what = {"axis": "axis ", "global": "global "}.get(kind or "", "")
            raise ValidationError(f"the {mod.name} has no {what}parameter {number}")
        return _show_params(session, found, numbered=number, source=source)
    found = mod.search(query, kind)
    if bank is not None:
        found = [p for p in found if p.bank == bank]
    exact = [p for p in found if p.name.lower() == query.lower()]
    if exact:
        found = exact
    if found and (not any(_contains(p, query) for p in found) if from_help
                  else _near_misses_only(found, query)):
        # `help foo` or `.param foo` must not answer with MaxFollowingError (f..o..o) as if
        # that were it
        raise _only_guesses(mod, query, found, from_help)
    if not found:
        what = "help topic or parameter" if from_help else "parameter"
        raise ValidationError(f"no {what} matches {query!r} on the {mod.name}"
                              + ("; .help lists the commands" if from_help else
                                 "; .params lists them all"))
    if len(found) == 1:
        return _show_params(session, found, source=source)
    _param_table(session, found, title=f"{len(found)} parameters match {query!r}", read=False)
    if not session.out.json:
        session.out.info("(.param NAME for one of them)")


def _only_guesses(mod: Module, query: str, found: list[Parameter],
                  from_help: bool) -> ValidationError:
    """No parameter has ``query`` in its name, only near misses: say so and name them."""
    names = ", ".join(p.name for p in found[:3])
    if not re.sub(r"[^a-z0-9]", "", query.lower()):  # `help [/]`: everything is as near
        names = ""
    what, where = (("help topic or parameter", ".help lists the commands") if from_help
                   else ("parameter", ".params lists them all"))
    guess = f"did you mean {names}? ({where})" if names else where
    return ValidationError(f"no {what} matches {query!r} on the {mod.name}; {guess}")


def _near_misses_only(found: list[Parameter], query: str) -> bool:
    """Whether the search found only near misses (a query of no letters or digits, such as
    ``[/]``, matches everything, as an empty one does)."""
    return bool(re.sub(r"[^a-z0-9]", "", query.lower())) and not any(
        _contains(p, query) for p in found)


def _contains(p: Parameter, query: str) -> bool:
    """Whether the query is part of the parameter's name or manual name (not merely letters
    of it in order, or a near miss)."""
    def norm(text: str) -> str:
        return re.sub(r"[^a-z0-9]", "", text.lower())

    q = norm(query)
    return bool(q) and (q in norm(p.name) or q in norm(p.manual_name or ""))


def _kind_prefix(query: str) -> tuple[str | None, int | None, str]:
    words = query.split()
    kinds = {"ap": "axis", "axis": "axis", "gp": "global", "global": "global"}
    if len(words) >= 2 and words[0].lower() in kinds:
        kind = kinds[words[0].lower()]
        bank = None
        if kind == "global" and len(words) >= 3 and re.fullmatch(r"\d{1,9}", words[2]):
            bank = int(words[2])
            words = words[:2]
        return kind, bank, " ".join(words[1:])
    return None, None, query


def _number(text: str) -> int | None:
    # at most 40 digits: longer is no parameter number (and more than Python converts)
    if re.fullmatch(r"\d{1,40}", text):
        return int(text)
    if re.fullmatch(r"(\$|0[xX])[0-9A-Fa-f]{1,40}", text):
        return int(text.lstrip("$").removeprefix("0x").removeprefix("0X"), 16)
    return None


def read_param(session: Session, p: Parameter, motor_or_number: int | None = None,
               number: int | None = None) -> int:
    """One GAP/GGP, straight through the client: the raw value (StatusError on refusal)."""
    client = session.client
    if p.kind == "axis":
        req = Request(client.address, _GAP, p.number, motor_or_number or 0, 0)
    else:
        req = Request(client.address, _GGP, p.number if number is None else number, p.bank, 0)
    reply = client.request(req)
    session.stats.commands += 1  # a script's summary counts what .params read
    assert reply is not None
    if not status_ok(reply.status):
        raise StatusError(reply.status, reply)
    return reply.value


def _current(session: Session, p: Parameter, number: int | None
             ) -> list[tuple[str, str, int | None]]:
    """``[("motor 0", "1000 pps", 1000), ...]``, or one row saying why there is no value."""
    from ..render import _unsigned, value_text

    if not p.readable:
        return [("", "write-only: cannot be read", None)]
    if p.count > 1 and number is None:
        return [("", f"{p.count} values: GGP {p.number}..{p.number + p.count - 1}, {p.bank}",
                 None)]
    mod = session.client.module
    motors = range(mod.motors) if (p.kind == "axis" and mod is not None) else [None]
    rows: list[tuple[str, str, int | None]] = []
    for m in motors:
        label = f"motor {m}" if (m is not None and len(motors) > 1) else ""
        try:
            value = read_param(session, p, m, number)
            rows.append((label, value_text(value, p), _unsigned(value, p)))
        except (StatusError, TmclTimeoutError) as exc:
            rows.append((label, f"could not read: {exc}", None))
    return rows


def _show_params(session: Session, params: list[Parameter], numbered: int | None = None,
                 source: bool = False) -> None:
    from rich.table import Table
    from rich.text import Text

    out = session.out
    for i, p in enumerate(params):
        number = numbered if (numbered is not None and p.count > 1) else None
        current = _current(session, p, number)
        if out.json:
            obj = _param_json(p, current)
            if source:
                obj["source"] = p.source
            out.emit(obj)
            continue
        if i:
            out.print()
        title = Text()
        title.append(p.label if number is None else f"GP {number} (bank {p.bank})",
                     style="tmcl.note")
        title.append("  ")
        title.append(p.name, style="bold tmcl.name")
        if p.manual_name and p.manual_name != p.name:
            title.append(f"  \u201c{p.manual_name}\u201d")
        out.print(title, soft_wrap=False)
        if p.description:
            out.print(_indented(p.description), soft_wrap=False)
        grid = Table.grid(padding=(0, 2))
        grid.add_column(style="tmcl.note", no_wrap=True)
        grid.add_column()
        rng = p.range_text + (f" {p.unit}" if p.unit else "")
        grid.add_row("  range", rng)
        grid.add_row("  access", f"{p.access} ({_access_words(p.access)})")
        if p.default is not None:
            from ..render import value_text

            grid.add_row("  default", value_text(p.default, p))
        if p.values:
            grid.add_row("  values", "\n".join(f"{v} = {t}" for v, t in sorted(p.values.items())))
        if p.bits:
            grid.add_row("  bits", "\n".join(f"bit {b}: {t}" for b, t in sorted(p.bits.items())))
        if p.note:
            grid.add_row("  note", p.note)
        if p.io is not None:
            grid.add_row("  same as", _io_twin(session.module, p.io))
        if source:
            grid.add_row("  source", p.source or "as the manual prints it")
        simulated = _simulated_note(session, p) if (source or _simulated(session)) else None
        if simulated:
            grid.add_row("  simulator", simulated)
        for label, text, _ in current:
            grid.add_row("  now" + (f" ({label})" if label else ""),
                         Text(text, style="tmcl.value" if not text.startswith(
                             ("could not", "write-only")) else "tmcl.warn"))
        how = _how_to_use(p, number)
        if how:
            grid.add_row("  use", how)
        out.print(grid)


def _io_twin(mod: Module, name: str) -> str:
    """``GIO 8, 1 (SupplyVoltage)``: the input that reads the same quantity."""
    port = next((q for q in mod.io if q.name == name and q.kind == "analog_in"), None)
    return f"GIO {port.port}, {port.bank} ({name})" if port is not None else name


def _simulated(session: Session) -> bool:
    return bool(getattr(session.client.transport, "simulated", False))


def _simulated_note(session: Session, p: Parameter) -> str | None:
    """What the built-in simulator does for ``p`` where it derives or invents its value."""
    mod = session.module
    if mod.generic:
        return None
    from ...sim.derived import simulated_notes

    return simulated_notes(mod).get((p.kind, p.name))


def _how_to_use(p: Parameter, number: int | None) -> str:
    n = p.number if number is None else number
    if p.kind == "axis":
        uses = []
        if p.readable:
            uses.append(f"GAP {p.name}, 0")
        if p.writable:
            uses.append(f"SAP {p.name}, 0, <value>")
        if p.storable:
            uses.append(f"STAP {p.name}, 0")
        return "\n".join(uses)
    uses = []
    name = p.name if p.count == 1 else str(n)
    if p.readable:
        uses.append(f"GGP {name}, {p.bank}")
    if p.writable:
        uses.append(f"SGP {name}, {p.bank}, <value>")
    if p.storable:
        uses.append(f"STGP {name}, {p.bank}")
    return "\n".join(uses)


def _access_words(access: str) -> str:
    words = []
    if "R" in access:
        words.append("read")
    if "W" in access:
        words.append("write")
    if "E" in access:
        words.append("store in EEPROM")
    return ", ".join(words) or "none"


def _param_json(p: Parameter, current: list[tuple[str, str, int | None]] | None = None
                ) -> dict:
    obj = {"kind": p.kind, "number": p.number, "bank": p.bank, "name": p.name,
           "manual_name": p.manual_name, "description": p.description, "min": p.min,
           "max": p.max, "unit": p.unit, "access": p.access, "default": p.default,
           "note": p.note}
    if p.count > 1:
        obj["count"] = p.count
    if p.values:
        obj["values"] = {str(k): v for k, v in p.values.items()}
    if p.bits:
        obj["bits"] = {str(k): v for k, v in p.bits.items()}
    if current is not None:
        values = [v for _, _, v in current]
        if len(values) == 1:
            obj["value"] = values[0]
        else:
            obj["values"] = values
    return obj


@command(".params")
@paged
def cmd_params(session: Session, arg: str) -> None:
    mod = session.module
    if mod.generic:  # no list of parameters to go through
        raise ValidationError(f"{mod.label}: there is no list of its parameters; read one by "
                              "number (GAP 4, 0 or GGP 66, 0)")
    words = arg.split()
    kinds = ["axis", "global"]
    kind_words = {"axis": "axis", "ax": "axis", "ap": "axis", "global": "global",
                  "gp": "global", "glob": "global"}
    if words and words[0].lower() in kind_words:
        kinds = [kind_words[words[0].lower()]]
        words = words[1:]
    query = " ".join(words)
    if query and not query.isdigit():
        found = [p for kind in kinds for p in mod.search(query, kind)]
        if found and _near_misses_only(found, query):
            raise _only_guesses(mod, query, found, False)  # not a table titled "matching"
    shown = 0
    for kind in kinds:
        pool = mod.axis_params if kind == "axis" else mod.global_params
        params = sorted(mod.search(query, kind), key=lambda p: (p.bank, p.number)) \
            if query else list(pool)
        if not params:
            continue
        title = f"{mod.name} {kind} parameters" + (f" matching {query!r}" if query else "")
        _param_table(session, params, title=title, read=True)
        shown += len(params)
    if not shown:
        raise ValidationError(f"no {' or '.join(kinds)} parameter of the {mod.name} matches "
                              f"{query!r}")


def range_short(p: Parameter) -> str:
    """``0..8``; choices as runs: ``1..8, 129..136``."""
    if not p.choices:
        return p.range_text
    runs: list[list[int]] = []
    for c in sorted(p.choices):
        if runs and c == runs[-1][1] + 1:
            runs[-1][1] = c
        else:
            runs.append([c, c])
    return ", ".join(str(a) if a == b else f"{a}, {b}" if b == a + 1 else f"{a}..{b}"
                     for a, b in runs)


def _value_only(value: int, p: Parameter) -> str:
    """The value and its meaning, without the unit (the table has a unit column)."""
    from ..render import _unsigned

    value = _unsigned(value, p)
    meaning = p.describe_value(value)
    return f"{value} ({meaning})" if meaning else str(value)


def _param_table(session: Session, params: list[Parameter], title: str, read: bool) -> None:
    out = session.out
    mod = session.module
    axis = all(p.kind == "axis" for p in params)
    motors = list(range(mod.motors)) if axis else [0]
    rows: list[dict[str, object]] = []
    failures = 0
    for p in params:
        values: list[str] = []
        raw: list[int | None] = []
        if read:
            for m in motors:
                text, value = "", None
                if p.count > 1:
                    text = "-"
                elif not p.readable:
                    text = "(write-only)"
                else:
                    try:
                        value = read_param(session, p, m if p.kind == "axis" else None)
                        text = _value_only(value, p)
                        failures = 0
                    except StatusError as exc:
                        text = f"status {exc.status}"
                    except TmclTimeoutError:
                        text = "no reply"
                        failures += 1
                        if failures >= 3:
                            raise TransportError("the module stopped answering "
                                                 "(3 reads in a row timed out)") from None
                values.append(text)
                raw.append(value)
        if out.json:
            obj = _param_json(p)
            if read:
                obj["value" if len(motors) == 1 else "values"] = raw[0] if len(motors) == 1 else raw
            out.emit(obj)
            continue
        number = (f"{p.number}..{p.number + p.count - 1}" if p.count > 1 else str(p.number))
        rows.append({"No.": number, "Kind": "AP" if p.kind == "axis" else str(p.bank),
                     "Name": p.name, "values": values, "Unit": p.unit,
                     "Range": range_short(p), "Access": p.access,
                     "Description": p.manual_name})
    if out.json:
        return
    # on a narrow terminal Range and then Unit are left out, so the values stay readable
    for drop in ((), ("Range",), ("Range", "Unit")):
        if _table_width(rows, read, axis, motors, drop) <= out.console.width:
            break
    out.print(_build_param_table(params, rows, title, read, axis, motors, drop))


def _table_width(rows: list[dict[str, object]], read: bool, axis: bool, motors: list[int],
                 drop: tuple[str, ...]) -> int:
    """The width the table needs with names and ranges whole and values at least 12 wide."""
    def widest(key: str, header: str, cap: int = 10_000) -> int:
        return min(cap, max([len(header)] + [len(str(r[key])) for r in rows]))

    cols = [widest("No.", "No."), widest("Name", "Name"), widest("Access", "Access")]
    if not axis:
        cols.append(widest("Kind", "Kind"))
    if read:
        for i, m in enumerate(motors):
            cols.append(min(12, max([len(f"Motor {m}")] +
                                    [len(r["values"][i]) for r in rows])))  # type: ignore[index]
    else:
        cols.append(20)  # the description wraps
    if "Unit" not in drop:
        cols.append(widest("Unit", "Unit", 16))
    if "Range" not in drop:
        cols.append(widest("Range", "Range"))
    return sum(cols) + 2 * (len(cols) - 1)


def _build_param_table(params: list[Parameter], rows: list[dict[str, object]], title: str,
                       read: bool, axis: bool, motors: list[int], drop: tuple[str, ...]):
    from rich.table import Table

    table = Table(title=title, title_justify="left", title_style="tmcl.heading",
                  header_style="bold", box=None, pad_edge=False, show_edge=False)
    table.add_column("No.", justify="right", no_wrap=True)
    if not axis:
        table.add_column("Kind" if any(p.kind == "axis" for p in params) else "Bank",
                         justify="right")
    table.add_column("Name", style="tmcl.name", no_wrap=True)
    if read:
        for m in motors:
            table.add_column(f"Motor {m}" if len(motors) > 1 else "Value", style="tmcl.value",
                             min_width=7)
    if "Unit" not in drop:
        table.add_column("Unit", style="tmcl.unit", max_width=16)
    if "Range" not in drop:
        table.add_column("Range", no_wrap=True)
    table.add_column("Access", no_wrap=True, min_width=6)
    if not read:
        table.add_column("Description", style="tmcl.note")
    for r in rows:
        row = [r["No."]]
        if not axis:
            row.append(r["Kind"])
        row.append(r["Name"])
        row += r["values"]  # type: ignore[operator]
        row += [r[k] for k in ("Unit", "Range") if k not in drop]
        row.append(r["Access"])
        if not read:
            row.append(r["Description"])
        table.add_row(*row)
    return table


# -- trace and decode --------------------------------------------------------------------

@command(".trace")
def cmd_trace(session: Session, arg: str) -> None:
    from .trace import disable_trace, enable_trace, trace_enabled

    word = arg.strip().lower()
    if word not in ("", "on", "off"):
        raise ValidationError(f".trace takes on or off, not {arg.strip()!r}")
    on = (not trace_enabled(session)) if not word else word == "on"
    if on:
        enable_trace(session)
        session.out.info("trace on: frames are shown on stderr")
    else:
        disable_trace(session)
        session.out.info("trace off")


@command(".decode")
def cmd_decode(session: Session, arg: str) -> None:
    from rich.text import Text

    from .trace import decode_hex

    frames = decode_hex(arg, session.client.module)
    out = session.out
    for frame, readings in frames:
        if out.json:
            out.emit({"bytes": frame.hex(" "), "readings": [
                {"kind": r.kind, "text": r.text, "checksum": r.checksum} for r in readings]})
            continue
        out.print(Text(frame.hex(" "), style="tmcl.value"))
        for r in readings:
            line = Text("  ")
            line.append(r.kind, style="tmcl.name")
            line.append(f": {r.text}")
            out.print(line)
            if r.checksum:
                out.print(Text(f"    checksum {r.checksum}",
                               style="tmcl.ok" if r.checksum.startswith("ok") else "tmcl.error"))


# -- connection and module ---------------------------------------------------------------

@command(".connect")
def cmd_connect(session: Session, arg: str) -> None:
    from ...base.canspec import FROM_PYTHON_CAN
    from ...link.spec import LinkSpec
    from ...client.bringup import bring_up
    from ...base.errors import ConnectError

    client = session.client
    words = arg.split()
    if not words:
        why = session.reconnect()
        if why is not None:
            raise why
        if client.module is None:
            client.identify()
        _refresh_program_state(session)
        session.out.ok(f"{reconnected(client)}: {_where(session)}")
        return
    settings = session.settings
    module: str | None = None
    if words[0].lower() == "sim":
        module = words[1] if len(words) > 1 else (client.module.name if client.module
                                                  else "TMCM-1311")
        load(module)  # unknown names fail before the old link is closed
        transport = LinkSpec.parse(sim=module, address=client.address).open()
        module = load(module).name
        new = {"sim": module}
    elif words[0].lower() == "can":
        spec = words[1] if len(words) > 1 else FROM_PYTHON_CAN
        transport = LinkSpec.parse(can=spec, bitrate=settings.get("bitrate")).open()
        new = {"can": spec}
    else:
        # the whole argument: a pyserial URL may hold a space (``hwgrep://USB VID``)
        port = arg.strip()
        transport = LinkSpec.parse(port=port, baud=settings.get("baud")).open()
        new = {"port": port}
    # the old module is left in the mode it was found in; the new one is brought up as at
    # the command line (136, -m checked, download mode ended, ASCII mode recognised)
    client._switch_transport(transport, module)
    for key in ("port", "can", "sim"):
        settings.pop(key, None)
    settings.update(new)
    try:
        bring_up(client)
    except ConnectError as exc:  # says what was tried and what to try next
        _refresh_program_state(session)
        session.out.warn(f"connected to {client.describe()}, but {exc}")
        return
    except TmclError as exc:
        _refresh_program_state(session)
        session.out.warn(f"connected to {client.describe()}, but no module identified at "
                         f"address {client.address}: {exc}")
        return
    _refresh_program_state(session)
    session.out.ok(f"connected: {_where(session)}")


def _refresh_program_state(session: Session) -> None:
    """The prompt and toolbar show the new link's program state at once (debugger.py)."""
    from .debugger import refresh_program_state

    refresh_program_state(session)


def _where(session: Session) -> str:
    c = session.client
    sim = " (SIMULATED)" if c.transport.simulated and "SIMULATED" not in c.describe() else ""
    mod = c.module.name if c.module else "unknown module"
    return f"{mod} at address {c.address} on {c.describe()}{sim}"


def complete_address(session: Session | None, text: str) -> list[Candidate]:
    if session is None:
        return []
    return [Candidate(str(session.client.address), "the current address")]


@command(".address")
def cmd_address(session: Session, arg: str) -> None:
    client = session.client
    text = arg.strip()
    if not text:
        session.out.info(f"address {client.address}" + (f" (CAN id {client.can_id})"
                                                         if client.is_can else ""))
        return
    n = _address_value(session, text)
    from ...client.bringup import switch_address

    switch_address(client, n)  # brought up as at connect; the old one kept if it fails
    mod, version = client.module, client.version
    session.out.ok(f"address {n}: {mod.label if mod else 'unknown module type'}"
                   + (f", firmware {version}" if version else ""))


def _address_value(session: Session, text: str) -> int:
    """A number as -a takes it (``3``, ``$1F``), else an expression (``base + ${unit}``),
    so one script can walk a bus; either is checked against the address range."""
    try:
        return int(limits.parse("address", text, ".address"))
    except limits.SettingError:
        from ..lang.expr import evaluate

        value = evaluate(session, text)  # (its error names what is wrong: a variable, ...)
        return int(limits.check("address", value, ".address"))


@command(".module")
def cmd_module(session: Session, arg: str) -> None:
    from rich.table import Table

    client = session.client
    name = arg.strip()
    if name:
        mod = load(name)
        detected = identify(client.version) if client.version else None
        client.module = mod
        if detected is not None and detected.name != mod.name:
            session.out.warn(f"the module reported {client.version} ({detected.name}); "
                             f"checking against {mod.name} anyway")
        session.out.ok(f"module type: {mod.name}")
        return
    mod = session.module
    out = session.out
    if out.json:
        out.emit({"module": mod.name, "address": client.address, "connection": client.describe(),
                  "simulated": client.transport.simulated, "version": client.version,
                  "motors": mod.motors, "mode": client.mode})
        return
    grid = Table.grid(padding=(0, 2))
    grid.add_column(style="tmcl.note")
    grid.add_column()
    grid.add_row("module", f"{mod.name}: {mod.summary}")
    if getattr(mod, "origin", None):
        grid.add_row("data", f"from {mod.origin} ({mod.source})")
    grid.add_row("motors", "not known (motor numbers are sent as typed, 0..255)"
                 if mod.generic else str(mod.motors))
    grid.add_row("firmware", client.version or "(not asked; .version)")
    grid.add_row("address", str(client.address))
    grid.add_row("connection", client.describe() + (" (SIMULATED)" if client.transport.simulated
                                                    and "SIMULATED" not in client.describe()
                                                    else ""))
    grid.add_row("mode", client.mode)
    grid.add_row("parameters", f"{len(mod.axis_params)} axis, {len(mod.global_params)} global")
    grid.add_row("program memory", "not known" if mod.generic or mod.origin
                 else f"{mod.program_memory} instructions")
    out.print(grid)


@command(".version")
def cmd_version(session: Session, arg: str) -> None:
    client = session.client
    if client.mode == "ascii":
        return _version_in_ascii(session)
    reply = client.request(Request(client.address, Control.GET_VERSION, 0, 0, 0))
    version = reply.version if reply is not None else None
    binary = client.request(Request(client.address, Control.GET_VERSION, 1, 0, 0))
    session.stats.commands += 2
    value = binary.value & 0xFFFFFFFF if binary is not None and binary.ok else None
    client.version = version or client.version
    from ..render import version_text

    found = identify(version, value)
    mod = found if found is not None and not found.generic else None
    layout_of = mod or client.module
    parsed = parse_string(version)
    from_string = (parsed.type_number, parsed.number) if parsed is not None else None
    from_binary = type1_of(value, layout_of) if value is not None else None
    agrees = None if from_string is None or value is None else from_binary == from_string
    other = _layout_of_string(value, from_string, layout_of) if value is not None \
        and not agrees else None
    if session.out.json:
        if other is not None:
            from_binary, agrees = decode_type1(value, other), True  # type: ignore[arg-type]
        session.out.emit({"version": version, "binary": value,
                          "module": mod.name if mod else None,
                          "binary_type": from_binary[0] if from_binary else None,
                          "binary_version": from_binary[1] if from_binary else None,
                          "agrees": agrees, **({"layout": other} if other else {})})
        return
    text = f"firmware {version}" if version else "firmware: no string reply (136 type 0)"
    if mod is not None:
        text += f" ({mod.name})"
    session.out.print(text, markup=False)
    # the binary reply on a line of its own: two replies that contradict each other are
    # never shown as one version
    if value is None:
        session.out.info("binary (136 type 1): no reply")
    elif agrees:
        session.out.print(f"binary (136 type 1): {version_text(value, layout_of)}; "
                          "the same as the string", markup=False)
    elif other is not None:
        # the manuals disagree on the byte order; this firmware uses the other one
        said = layout_of.version_layout if layout_of is not None else LAYOUTS[0]
        session.out.print(f"binary (136 type 1): {version_text(value, layout_of, other)}; the "
                          f"same as the string, read {_LAYOUT_WORDS[other]} (the "
                          f"{layout_of.name if layout_of else 'module'} data says "
                          f"{_LAYOUT_WORDS[said]}; the manuals disagree on this order)",
                          markup=False)
    else:
        session.out.warn(f"binary (136 type 1): {version_text(value, layout_of)}; "
                         + ("does not match the string" if version else "no string to check"))


_LAYOUT_WORDS = {TYPE_FIRST: "type first", VERSION_FIRST: "version first"}


def _layout_of_string(value: int, from_string: tuple[int, int | None] | None,
                      module: Module | None) -> str | None:
    """The other byte order of a 136 type 1 value, when read so it says what the string
    says (None: no layout does, or the module's own already did)."""
    if from_string is None:
        return None
    own = module.version_layout if module is not None else LAYOUTS[0]
    return next((layout for layout in LAYOUTS if layout != own
                 and decode_type1(value, layout) == from_string), None)


def _version_in_ascii(session: Session) -> None:
    """136 has no ASCII form: say the version read in binary mode at connect (nothing sent),
    or how to read it."""
    client = session.client
    how = ".mode binary, .version, .mode ascii reads it again"
    if not client.version:
        raise ValidationError("the firmware version (136) cannot be read in ASCII mode and was "
                              f"not read at connect; {how}")
    mod = client.module.name if client.module is not None else None
    if session.out.json:
        session.out.emit({"version": client.version, "binary": None, "module": mod,
                          "read_at_connect": True})
        return
    session.out.print(f"firmware {client.version}" + (f" ({mod})" if mod else ""), markup=False)
    session.out.info(f"(as read at connect: 136 has no ASCII form; {how})")


# -- motion ------------------------------------------------------------------------------

@command(".stopall")
def cmd_stopall(session: Session, arg: str) -> None:
    from .stop import stop_session

    report = stop_session(session)
    if report is not None and session.out.json:
        session.out.emit(report.to_json())
    if report is None or not report.ok:
        err = TmclError("not everything stopped (see above)")
        err.shown = True  # type: ignore[attr-defined]
        raise err
