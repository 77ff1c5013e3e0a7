"""Open a transport from what the command line says: a port/URL, a CAN spec or the simulator.

Backends are imported on demand (pyserial only for serial links, python-can only for CAN
links, the simulator only for ``--sim``), so start-up stays fast.
"""

from __future__ import annotations

from ..base.canspec import FROM_PYTHON_CAN, parse_can
from .base import CanTransport, StreamTransport, Transport

# pyserial's URL handlers (serial.serial_for_url); anything else with "://" is refused by it
PYSERIAL_SCHEMES = ("socket", "rfc2217", "loop", "spy", "hwgrep", "alt", "cp2110")


def open_serial(port: str, baudrate: int = 9600) -> StreamTransport:
    """A serial device path (``/dev/ttyACM0``, ``COM3``) or a pyserial URL
    (``socket://host:port``, ``rfc2217://host:port``, ``loop://``, ``spy://...``,
    ``hwgrep://2a3c``)."""
    from ..base.errors import ValidationError
    from .serial import SerialTransport

    scheme, sep, _ = port.partition("://")
    if sep and scheme not in PYSERIAL_SCHEMES:
        raise ValidationError(f"unknown port URL scheme {scheme + '://'!r}; known: "
                              f"{', '.join(s + '://' for s in PYSERIAL_SCHEMES)}")
    t = SerialTransport(port, baudrate)
    t.open()
    return t


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
           "parse_can", "PYSERIAL_SCHEMES", "FROM_PYTHON_CAN"]
