"""Open a transport from what the command line says: a port/URL, a CAN spec or the simulator.

Backends are imported on demand (python-can only for CAN links), so start-up stays fast.
"""

from __future__ import annotations

from .base import CanTransport, StreamTransport, Transport

PYSERIAL_SCHEMES = ("socket", "rfc2217", "loop", "spy", "hwgrep", "alt", "cp2110")


def open_serial(port: str, baudrate: int = 9600) -> StreamTransport:
    from .serial import SerialTransport

    t = SerialTransport(port, baudrate)
    t.open()
    return t


def open_can(spec: str, bitrate: int | None = None, **kw) -> CanTransport:
    """``IFACE:CHANNEL`` as in ``socketcan:can0``, ``virtual:bench``, ``slcan:/dev/ttyACM0``."""
    from ..errors import ValidationError
    from .can import PythonCanTransport

    iface, sep, channel = spec.partition(":")
    if not sep or not iface or not channel:
        raise ValidationError(f"--can wants IFACE:CHANNEL (e.g. socketcan:can0), got {spec!r}")
    t = PythonCanTransport(iface, channel, bitrate, **kw)
    t.open()
    return t


def open_sim(module: str = "TMCM-1311", address: int = 1, **kw) -> StreamTransport:
    from .sim import SimTransport

    t = SimTransport(module, address, **kw)
    t.open()
    return t


__all__ = ["Transport", "StreamTransport", "CanTransport", "open_serial", "open_can", "open_sim",
           "PYSERIAL_SCHEMES"]
