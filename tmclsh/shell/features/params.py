"""Parameters explained and tabled: ``.param`` (one parameter, with its current value and how
to use it) and ``.params`` (the module's parameters, read or not), from the module data.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from ...base.errors import StatusError, TmclTimeoutError, TransportError, ValidationError
from ...tmcl import instructions as isa
from ...tmcl.frames import Request, status_ok
from ...tmcl.modules import Module, Parameter
from ..lang import options
from ..lang.commands import command, options_of
from ..render import paged
from ..repl.completer import Candidate, param_meta

if TYPE_CHECKING:
    from ..lang.session import Session

_GAP = isa.Opcode.GAP
_GGP = isa.Opcode.GGP


def _module(session: Session | None) -> Module | None:
    return session.client.module if session is not None else None  # never asks the device


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


def _indented(text: str, style: str = "", indent: int = 2):
    """Prose that wraps at word boundaries, every line indented by ``indent``."""
    from rich.padding import Padding
    from rich.text import Text

    return Padding(Text(text, style=style), (0, 0, 0, indent), expand=False)


def _params_by_number(mod: Module, number: int) -> list[Parameter]:
    """AP n, then named global parameters n in any bank (user-variable ranges left out)."""
    out = [p for p in mod.axis_params if p.number == number]
    out += [p for p in mod.global_params if p.number == number and p.count == 1]
    return out
