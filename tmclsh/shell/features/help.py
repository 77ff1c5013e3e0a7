"""Help: ``.help`` (commands, instructions, parameters by number, how to read them), ``.clear``
and ``.quit``.

``.help`` and completion are generated from the command table and the instruction set, so
a command is described in exactly one place.
"""

from __future__ import annotations

import difflib
from typing import TYPE_CHECKING

from ...base.errors import TmclError, ValidationError
from ...tmcl import instructions as isa
from ...tmcl.modules import Module
from ..lang import options
from ..lang.commands import CATEGORIES, all_commands, command, find, options_of
from ..render import paged
from ..repl.completer import Candidate, param_meta
from .params import _indented, _module, _number, _params_by_number, _show_params, cmd_param

if TYPE_CHECKING:
    from ..lang.session import Session


# -- completions -------------------------------------------------------------------------

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
        kind = _PARAM_KINDS.get(spec.type_kind)
        named = rest.split(None, 1)[1].split(",")[0].strip() if " " in rest.strip() else ""
        if kind is not None and named:
            # `help GGP 67`, `help SAP MaxCurrent, 0, 100`: the parameter the line names
            return cmd_param(session, f"{kind} {named}", from_help=True)
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


_PARAM_KINDS = {"axis_param": "AP", "global_param": "GP"}  # how `help` names their parameters


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


# -- .quit -------------------------------------------------------------------------------

def _quit(session: Session, arg: str) -> None:
    from ..lang.session import QuitShell

    raise QuitShell()


command(".quit")(_quit)
command(".exit")(_quit)


# -- .param / .params --------------------------------------------------------------------
