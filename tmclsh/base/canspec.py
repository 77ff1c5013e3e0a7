"""How a link is spelt and what it takes when nothing says otherwise, shared by the client
(``--can``, ``--port``), the config file and the simulator server (``tmclsh sim --can``) so
that all read one spelling the same way and fill in the same defaults. (``link/spec.py``
parses and opens a link with them; they live here because the config file and the simulator,
which sit above the links, read them too.)

``IFACE:CHANNEL`` splits on the first colon: interface names have none, channels may
(``slcan:/dev/ttyACM0@115200``, ``udp_multicast:[ff15:7079:7468:6f6e:6465:6d6f:6d63:6173]``,
``virtual:bench:1``). ``--can`` alone means python-can's own configuration.
"""

from __future__ import annotations

from .errors import UsageError

# What a link takes when no option, variable or profile says: the modules' factory settings
# (GP 65 = 0: 9600 baud; GP 66: address 1; GP 76: host address 2; GP 71 / GP 70: CAN id 1,
# reply id 2). ``bitrate`` None: the CAN interface's own (or python-can's configuration), as
# the module's factory 1000 kbit/s is not what every adapter can be told.
LINK_DEFAULTS: dict[str, int | None] = {
    "baud": 9600, "bitrate": None, "address": 1, "host_address": 2, "can_id": 1, "reply_id": 2,
}

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
