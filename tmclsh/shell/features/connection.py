"""The link and the module at its end: ``.connect``, ``.address``, ``.module``, ``.version``, and
``.stopall`` (the one stop, through ``stop.py``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ...base import limits
from ...base.errors import TmclError, ValidationError
from ...tmcl.frames import Control, Request
from ...tmcl.modules import Module, available, identify, load, type1_of
from ...tmcl.version import LAYOUTS, TYPE_FIRST, VERSION_FIRST, decode_type1, parse_string
from ..lang.commands import command
from ..lang.session import reconnected
from ..repl.completer import Candidate

if TYPE_CHECKING:
    from ..lang.session import Session


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
    client._lifecycle.switch_transport(transport, module)
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
    ask = Request(client.address, Control.GET_VERSION, 0, 0, 0)
    if client.refusal(ask) is not None:
        return _version_not_carried(session)
    reply = client.request(ask)
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


def _version_not_carried(session: Session) -> None:
    """The link as it is now cannot carry 136 (the module's ASCII mode has no form of it):
    say the version read in binary mode at connect (nothing sent), or how to read it."""
    client = session.client
    mode = client.mode
    how = f".mode binary, .version, .mode {mode} reads it again"
    if not client.version:
        raise ValidationError(f"the firmware version (136) cannot be read in {mode.label} mode "
                              f"and was not read at connect; {how}")
    mod = client.module.name if client.module is not None else None
    if session.out.json:
        session.out.emit({"version": client.version, "binary": None, "module": mod,
                          "read_at_connect": True})
        return
    session.out.print(f"firmware {client.version}" + (f" ({mod})" if mod else ""), markup=False)
    session.out.info(f"(as read at connect: 136 has no {mode.label} form; {how})")


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
