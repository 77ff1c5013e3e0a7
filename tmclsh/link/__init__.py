"""The links: which transport takes a ``--port``, ``--can`` or ``--sim``, opened on demand.

Transports are a table of names, imported only when used (python-can's ``BACKENDS``):
pyserial only for serial links, python-can only for CAN links, the simulator only for
``--sim``, so start-up stays fast. A new stream transport (a URL scheme ``--port`` takes) is
one file here, a ``StreamTransport`` subclass taking ``(url, baudrate)``, and one line in
``PORT_SCHEMES`` (``spec.py``, where every link is parsed and opened: ``LinkSpec``); its
frames are read by the serial framing like any other stream's.
"""

from __future__ import annotations

from ..base.canspec import FROM_PYTHON_CAN, LINK_DEFAULTS, parse_can
from .base import CanTransport, StreamTransport, Transport
from .spec import PORT_SCHEMES, PYSERIAL_SCHEMES, LinkSpec, port_class

TRINAMIC_VID = 0x2A3C  # the USB vendor id of Trinamic's modules


def open_serial(port: str, baudrate: int | None = None, *, listen_only: bool = False
                ) -> StreamTransport:
    """What ``--port`` names, opened: a serial device path (``/dev/ttyACM0``, ``COM3``) or a
    URL (``socket://host:port``, ``rfc2217://host:port``, ``loop://``, ``spy://...``,
    ``hwgrep://2a3c``, and whatever ``PORT_SCHEMES`` adds). ``listen_only``: a tap on a
    bus, which must never drive it (RTS and DTR stay inactive). (``LinkSpec`` opens it.)"""
    spec = LinkSpec.parse(port=port, baud=baudrate)
    return spec.open(listen_only=listen_only)  # type: ignore[return-value]


def trinamic_ports() -> list:
    """Serial ports whose USB vendor is Trinamic (0x2A3C), sorted by device name."""
    from serial.tools import list_ports

    return sorted((p for p in list_ports.comports() if p.vid == TRINAMIC_VID),
                  key=lambda p: p.device)


def open_can(spec: str, bitrate: int | None = None) -> CanTransport:
    """``IFACE:CHANNEL`` as in ``socketcan:can0``, ``pcan:PCAN_USBBUS1``, ``slcan:/dev/ttyACM0``;
    or ``FROM_PYTHON_CAN`` (``--can`` alone): python-can's own configuration names the bus.
    (``LinkSpec`` opens it.)"""
    return LinkSpec.parse(can=spec, bitrate=bitrate).open()  # type: ignore[return-value]


def open_sim(module: str = "TMCM-1311", address: int = 1, **kw) -> StreamTransport:
    """The built-in simulator, in process (``kw``: further ``Simulator`` arguments such as
    ``host_address``)."""
    from .sim import SimTransport

    t = SimTransport(module, address, **kw)
    t.open()
    return t


__all__ = ["Transport", "StreamTransport", "CanTransport", "open_serial", "open_can", "open_sim",
           "parse_can", "PYSERIAL_SCHEMES", "PORT_SCHEMES", "FROM_PYTHON_CAN", "TRINAMIC_VID",
           "trinamic_ports", "port_class", "LINK_DEFAULTS", "LinkSpec"]
