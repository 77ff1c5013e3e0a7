"""From settings to a working client: which link to open, and bringing the module up on it.

Shared by the command line, the shell's ``.connect`` and the ``tmclsh.connect()`` API, so a
connection means the same wherever it is made. It sits above the client and the ASCII link
(it attaches the latter to the former), below the shell and the CLI.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..base.canspec import LINK_DEFAULTS
from ..base.errors import ConnectError, UsageError, ValidationError
from ..link import TRINAMIC_VID, trinamic_ports
from ..link.base import Transport
from .advice import OPTIONS
from .bringup import start
from .text import LineClient

if TYPE_CHECKING:
    import argparse
    from collections.abc import Callable

    from ..base.config import Config


SIM_DEFAULT = "TMCM-1311"  # the module --sim simulates when neither it nor -m names one


def connection_settings(args: argparse.Namespace, config: Config | None = None) -> dict:
    """The link settings the command line, the environment and the config file give;
    ``config``: the config file read already (several units read it once, in the main
    thread: parsing it imports a TOML parser, which no unit's thread may do)."""
    from ..base.config import load_config, resolve

    cli = {k: getattr(args, k, None) for k in
           ("port", "baud", "can", "bitrate", "sim", "can_id", "reply_id", "module", "address",
            "host_address", "ascii", "timeout", "retries", "profile")}
    for key in ("port", "address", "can_id", "reply_id"):
        cli[key] = _one(key, cli[key])
    given = [f"--{k}" for k in ("port", "can", "sim") if cli[k] is not None]
    if len(given) > 1:  # one before a subcommand, one after it (argparse sees two parsers)
        raise UsageError(f"{given[0]} and {given[1]} both name the link; give one of them")
    settings = resolve(cli, load_config() if config is None else config)
    if settings.get("sim") == "":  # a bare --sim: simulate the module -m names
        module = settings.get("module")
        settings["sim"] = module if module and module.lower() != "generic" else SIM_DEFAULT
    from ..link.spec import LinkSpec

    LinkSpec.from_settings(settings)  # a malformed --can is a usage error, before opening anything
    return settings


def _one(key: str, value):
    """One value of an option that takes several (``--port`` repeated, ``--address 1,2``):
    several name units, which only ``-c`` and ``-f`` run (``shell/features/units.py``)."""
    if not isinstance(value, (list, tuple)):
        return value
    if len(value) > 1:
        flag = "--" + key.replace("_", "-")
        raise UsageError(f"{flag} {', '.join(map(str, value))}: one is needed here (several "
                         "modules are units of a -c or -f run)")
    return value[0] if value else None


def _setting(settings: dict, key: str, default):
    value = settings.get(key)
    return default if value is None else value  # address 0 is an address


def _port_label(p) -> str:
    what = [x for x in (p.description if p.description not in (None, "n/a") else None,
                        f"serial {p.serial_number}" if p.serial_number else None) if x]
    return f"{p.device} ({', '.join(what)})" if what else p.device


def attached_module_port() -> str | None:
    """The one attached Trinamic USB module's port; None if there is none. Several are a
    ``ConnectError`` naming them: tmclsh never picks one of them by itself."""
    found = trinamic_ports()
    if len(found) > 1:
        raise ConnectError(f"{len(found)} Trinamic USB modules attached: "
                           f"{', '.join(_port_label(p) for p in found)}; "
                           "pick one with --port (-c and -f: --all runs on every one)")
    return found[0].device if found else None


def open_transport(settings: dict, *, fallback: bool = False) -> Transport:
    """The transport the settings name: port, CAN bus, simulator, else the one attached
    Trinamic USB module (``settings["port"]``/``["sim"]`` record which).

    With nothing named and no module attached, ``fallback`` (the interactive shell) starts
    the simulator; otherwise (scripts, ``-c``, ``scan``) that is a ``ConnectError``: a run
    nobody watches must not pass on a simulator by accident.
    """
    from ..link.spec import LinkSpec

    spec = LinkSpec.from_settings(settings)
    if spec is not None and spec.kind != "sim":
        return spec.open()
    if spec is None:
        port = attached_module_port()
        if port is not None:
            settings["port"] = port
            return LinkSpec.from_settings(settings).open()  # type: ignore[union-attr]
        if not fallback:
            raise ConnectError(
                "no module found: no --port, --can or --sim given (nor a profile or "
                "TMCLSH_PORT/TMCLSH_CAN naming one) and no Trinamic USB module attached "
                f"(USB vendor {TRINAMIC_VID:04x}); give --port PORT ('tmclsh ports' lists "
                "the serial ports), or --sim to simulate")
    settings["sim"] = settings.get("sim") or settings.get("module") or SIM_DEFAULT
    return LinkSpec.from_settings(settings).open()  # type: ignore[union-attr]


def open_client(settings: dict, *, fallback: bool = False,
                notice: Callable[[str], None] | None = None,
                tracer: Callable[[LineClient], Callable[[str, bytes, object], None]] | None = None
                ) -> LineClient:
    """A client on ``open_transport(settings)``, in ASCII mode if asked, module identified
    and out of download mode (see ``start``); ``notice`` gets what it did on its own;
    ``tracer(client)`` makes a tracer (``Client.add_tracer``) for the frames of the connect
    itself, and no more."""
    transport = open_transport(settings, fallback=fallback)
    module = settings.get("module") or settings.get("sim")
    try:
        client = LineClient(transport,
                        address=_setting(settings, "address", LINK_DEFAULTS["address"]),
                        host_address=_setting(settings, "host_address",
                                              LINK_DEFAULTS["host_address"]), module=module,
                        timeout=_setting(settings, "timeout", 1.0),
                        retries=_setting(settings, "retries", 2),
                        can_id=settings.get("can_id"), reply_id=settings.get("reply_id"))
    except BaseException:
        transport.close()
        raise
    client.on_notice = notice
    client.advice = OPTIONS  # (the command line's and the shell's: --baud, --timeout)
    remove = client.add_tracer(tracer(client)) if tracer is not None else None
    try:
        return start(client, ascii=bool(settings.get("ascii")))
    finally:
        if remove is not None:
            remove()


def connect(port: str | None = None, *, baud: int | None = None, can: str | None = None,
            sim: str | None = None, module: str | None = None, address: int | None = None,
            host_address: int | None = None, timeout: float = 1.0, retries: int = 2,
            can_id: int | None = None, reply_id: int | None = None,
            bitrate: int | None = None, ascii: bool = False) -> LineClient:
    """Open a client: ``connect(port="/dev/ttyACM0")``, ``connect(port="socket://host:4001")``,
    ``connect(can="virtual:bench")``, ``connect(sim="TMCM-351")``; with none of them, the one
    Trinamic USB module attached, as the command line does. What is not given takes the
    modules' factory settings, as on the command line (``LINK_DEFAULTS``: 9600 baud, address
    1, host address 2). The simulator only when asked (``sim=``): a test jig written in
    Python must not pass with its cable unplugged. No module attached, or several, is a
    ``ConnectError`` saying what to give.

    The module type is asked with 136; a ``module`` that contradicts the answer is a
    ``ConnectError``. A number outside its range (``limits.LIMITS``, as for the command line:
    ``timeout`` 0.001..60 s, ``retries`` 0..10, ...) is a ``SettingError`` (a
    ``ValidationError``, also a ``ValueError``) before anything is opened.
    """
    from ..base import limits
    from ..link.spec import LinkSpec

    if sum(x is not None for x in (port, can, sim)) > 1:
        raise ValidationError("give only one of port, can and sim")
    for key, value in (("baud", baud), ("address", address), ("host_address", host_address),
                       ("timeout", timeout), ("retries", retries), ("can_id", can_id),
                       ("reply_id", reply_id), ("bitrate", bitrate)):
        if value is not None:
            limits.check(key, value, key)
    if port is None and can is None and sim is None:
        port = attached_module_port()
        if port is None:
            raise ConnectError("no module found: no Trinamic USB module is attached (USB vendor "
                               f"{TRINAMIC_VID:04x}); give port=\"/dev/ttyACM0\" (or a URL), "
                               "can=\"IFACE:CHANNEL\", or sim=\"TMCM-1311\" for the simulator")
    spec = LinkSpec.parse(port, can, sim, baud=baud, bitrate=bitrate, address=address,
                          host_address=host_address)
    t = spec.open()
    if sim is not None:
        module = module or sim
    address, host_address = spec.address, spec.host_address
    try:
        client = LineClient(t, address=address, host_address=host_address, module=module,
                        timeout=timeout, retries=retries, can_id=can_id, reply_id=reply_id)
    except BaseException:  # (an unknown module, a bad timeout): the port is not kept open
        t.close()
        raise
    return start(client, ascii=ascii)
