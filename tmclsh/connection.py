"""From settings to a working client: which link to open, and bringing the module up on it.

Shared by the command line, the shell's ``.connect`` and the ``tmclsh.connect()`` API, so a
connection means the same wherever it is made. It sits above the client and the ASCII link
(it attaches the latter to the former), below the shell and the CLI.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

from .canspec import FROM_PYTHON_CAN, parse_can
from .client import Client
from .errors import ValidationError
from .transport.base import Transport

if TYPE_CHECKING:
    import argparse

TRINAMIC_VID = 0x2A3C


def trinamic_ports() -> list:
    """Serial ports whose USB vendor is Trinamic (0x2A3C), sorted by device name."""
    from serial.tools import list_ports

    return sorted((p for p in list_ports.comports() if p.vid == TRINAMIC_VID),
                  key=lambda p: p.device)


def connection_settings(args: argparse.Namespace) -> dict:
    from .config import load_config, resolve

    cli = {k: getattr(args, k, None) for k in
           ("port", "baud", "can", "bitrate", "sim", "can_id", "reply_id", "module", "address",
            "host_address", "ascii", "timeout", "retries", "profile")}
    settings = resolve(cli, load_config())
    if settings.get("can") and settings["can"] != FROM_PYTHON_CAN:
        parse_can(settings["can"])  # a malformed --can is a usage error, before opening anything
    return settings


def _setting(settings: dict, key: str, default):
    value = settings.get(key)
    return default if value is None else value  # address 0 is an address


def open_transport(settings: dict) -> Transport:
    """The transport the settings name: port, CAN bus, the one attached Trinamic module, or
    else the in-process simulator (``settings["port"]``/``["sim"]`` record which)."""
    from . import transport as tr

    baud = _setting(settings, "baud", 9600)
    if settings.get("port"):
        return tr.open_serial(settings["port"], baud)
    if settings.get("can"):
        return tr.open_can(settings["can"], settings.get("bitrate"))
    if not settings.get("sim"):
        found = trinamic_ports()
        if len(found) == 1:
            settings["port"] = found[0].device
            return tr.open_serial(found[0].device, baud)
        if len(found) > 1:
            print(f"tmclsh: {len(found)} Trinamic modules attached "
                  f"({', '.join(p.device for p in found)}); pick one with --port. "
                  "Starting the simulator.", file=sys.stderr)
    module = settings.get("sim") or settings.get("module") or "TMCM-1311"
    settings["sim"] = module
    return tr.open_sim(module, _setting(settings, "address", 1),
                       host_address=_setting(settings, "host_address", 2))


def open_client(settings: dict) -> Client:
    """A client on ``open_transport(settings)``, in ASCII mode if asked, module identified."""
    transport = open_transport(settings)
    module = settings.get("module") or settings.get("sim")
    client = Client(transport, address=_setting(settings, "address", 1),
                    host_address=_setting(settings, "host_address", 2), module=module,
                    timeout=_setting(settings, "timeout", 1.0),
                    retries=_setting(settings, "retries", 2),
                    can_id=settings.get("can_id"), reply_id=settings.get("reply_id"))
    return start(client, ascii=bool(settings.get("ascii")))


def connect(port: str | None = None, *, baud: int = 9600, can: str | None = None,
            sim: str | None = None, module: str | None = None, address: int = 1,
            host_address: int = 2, timeout: float = 1.0, retries: int = 2,
            can_id: int | None = None, reply_id: int | None = None,
            bitrate: int | None = None, ascii: bool = False) -> Client:
    """Open a client: ``connect(port="/dev/ttyACM0")``, ``connect(port="socket://host:4001")``,
    ``connect(can="virtual:bench")``, ``connect(sim="TMCM-351")``; with none of them, the
    built-in simulated TMCM-1311.

    The module type is asked with 136 unless ``module`` is given.
    """
    from . import transport as tr

    if sum(x is not None for x in (port, can, sim)) > 1:
        raise ValidationError("give only one of port, can and sim")
    if port is not None:
        t: Transport = tr.open_serial(port, baud)
    elif can is not None:
        t = tr.open_can(can, bitrate)
    else:
        name = sim or module or "TMCM-1311"
        t = tr.open_sim(name, address, host_address=host_address)
        module = module or name
    client = Client(t, address=address, host_address=host_address, module=module,
                    timeout=timeout, retries=retries, can_id=can_id, reply_id=reply_id)
    return start(client, ascii=ascii)


def start(client: Client, *, ascii: bool = False) -> Client:
    """Bring a new client up: into ASCII mode if asked, module type identified (136).

    On any failure the client is closed, so a half-opened port is never left behind.
    """
    try:
        if ascii:
            from .ascii import AsciiLink

            AsciiLink.attach(client)
        if client.module is None:
            client.identify()
        elif client.module.generic and not client.module.firmware_id:
            _name_generic(client)
    except BaseException:
        client.close()
        raise
    return client


def _name_generic(client: Client) -> None:
    """``-m generic``: no data is used, but the banner can still say which type answers."""
    from .errors import TmclError
    from .modules import generic_for
    from .protocol import Control, Request

    try:
        reply = client.request(Request(client.address, Control.GET_VERSION, 0, 0, 0))
    except TmclError:
        return
    named = generic_for(reply.version) if reply is not None and reply.version else None
    if named is not None:
        client.module, client.version = named, reply.version  # type: ignore[union-attr]
