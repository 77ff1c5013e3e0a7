"""How a CAN bus is named on the command line, shared by the client (``--can``) and the
simulator server (``tmclsh sim --can``) so that both read one spelling the same way.

``IFACE:CHANNEL`` splits on the first colon: interface names have none, channels may
(``slcan:/dev/ttyACM0@115200``, ``udp_multicast:[ff15:7079:7468:6f6e:6465:6d6f:6d63:6173]``,
``virtual:bench:1``). ``--can`` alone means python-can's own configuration.
"""

from __future__ import annotations

from .errors import UsageError

# `--can` given without IFACE:CHANNEL: take interface, channel and bit rate from python-can's
# configuration (its config files, CAN_INTERFACE / CAN_CHANNEL / CAN_BITRATE)
FROM_PYTHON_CAN = "python-can"


def parse_can(spec: str) -> tuple[str, str]:
    """``IFACE:CHANNEL`` -> (interface, channel); the channel may contain colons."""
    iface, sep, channel = spec.partition(":")
    if not sep or not iface or not channel:
        raise UsageError(f"--can wants IFACE:CHANNEL (e.g. socketcan:can0, pcan:PCAN_USBBUS1),"
                              f" or nothing for python-can's own configuration; got {spec!r}")
    return iface, channel
