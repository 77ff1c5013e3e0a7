"""The links: which transport takes a ``--port``, ``--can`` or ``--sim``, opened on demand.

Transports are a table of names, imported only when used (python-can's ``BACKENDS``):
pyserial only for serial links, python-can only for CAN links, the simulator only for
``--sim``, so start-up stays fast. A new stream transport (a URL scheme ``--port`` takes) is
one file here, a ``StreamTransport`` subclass taking ``(url, baudrate)``, and one line in
``PORT_SCHEMES``; its frames are read by the serial framing like any other stream's.
"""

from __future__ import annotations

import importlib

from ..base.canspec import FROM_PYTHON_CAN, parse_can
from .base import CanTransport, StreamTransport, Transport

# pyserial's URL handlers (serial.serial_for_url)
PYSERIAL_SCHEMES = ("socket", "rfc2217", "loop", "spy", "hwgrep", "alt", "cp2110")
# what --port takes: a URL scheme -> (module in this package, class); "" is a device path
# (/dev/ttyACM0, COM3). Anything else with "://" is refused, naming these.
PORT_SCHEMES: dict[str, tuple[str, str]] = {
    "": ("serial", "SerialTransport"),
    **{scheme: ("serial", "SerialTransport") for scheme in PYSERIAL_SCHEMES},
}
TRINAMIC_VID = 0x2A3C  # the USB vendor id of Trinamic's modules


def port_class(port: str) -> type[StreamTransport]:
    """The transport class that takes ``port`` (a device path or a URL)."""
    from ..base.errors import ValidationError

    scheme, sep, _ = port.partition("://")
    entry = PORT_SCHEMES.get(scheme if sep else "")
    if entry is None:
        known = ", ".join(s + "://" for s in PORT_SCHEMES if s)
        raise ValidationError(f"unknown port URL scheme {scheme + '://'!r}; known: {known}")
    module, name = entry
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)


def open_serial(port: str, baudrate: int = 9600, *, listen_only: bool = False
                ) -> StreamTransport:
    """What ``--port`` names, opened: a serial device path (``/dev/ttyACM0``, ``COM3``) or a
    URL (``socket://host:port``, ``rfc2217://host:port``, ``loop://``, ``spy://...``,
    ``hwgrep://2a3c``, and whatever ``PORT_SCHEMES`` adds). ``listen_only``: a tap on a
    bus, which must never drive it (RTS and DTR stay inactive)."""
    t = port_class(port)(port, baudrate)
    if listen_only:
        t.listen_only = True  # type: ignore[attr-defined]
    t.open()
    return t


def trinamic_ports() -> list:
    """Serial ports whose USB vendor is Trinamic (0x2A3C), sorted by device name."""
    from serial.tools import list_ports

    return sorted((p for p in list_ports.comports() if p.vid == TRINAMIC_VID),
                  key=lambda p: p.device)


def open_can(spec: str, bitrate: int | None = None, **kw) -> CanTransport:
    """``IFACE:CHANNEL`` as in ``socketcan:can0``, ``pcan:PCAN_USBBUS1``, ``slcan:/dev/ttyACM0``;
    or ``FROM_PYTHON_CAN`` (``--can`` alone): python-can's own configuration names the bus."""
    from .can import PythonCanTransport, python_can_config

    if spec == FROM_PYTHON_CAN:
        iface, channel, configured = python_can_config()
        bitrate = bitrate if bitrate is not None else configured
    else:
        iface, channel = parse_can(spec)
    t = PythonCanTransport(iface, channel, bitrate, **kw)
    t.open()
    return t


def open_sim(module: str = "TMCM-1311", address: int = 1, **kw) -> StreamTransport:
    """The built-in simulator, in process (``kw``: further ``Simulator`` arguments such as
    ``host_address``)."""
    from .sim import SimTransport

    t = SimTransport(module, address, **kw)
    t.open()
    return t


__all__ = ["Transport", "StreamTransport", "CanTransport", "open_serial", "open_can", "open_sim",
           "parse_can", "PYSERIAL_SCHEMES", "PORT_SCHEMES", "FROM_PYTHON_CAN", "TRINAMIC_VID",
           "trinamic_ports", "port_class"]
