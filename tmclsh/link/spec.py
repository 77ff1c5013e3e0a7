"""A link named once: a serial port or URL, a CAN bus, or the simulator, with its rates.

Every way into a module (``connect()``, the command line, ``.connect``, ``scan``,
``firmware``, ``monitor``, ``bridge``) parses what the user named into a ``LinkSpec`` and
opens it with ``open``, so that a link means the same wherever it is opened and takes the
same defaults (``LINK_DEFAULTS``, the modules' factory settings) when nothing says otherwise.
As pyserial's ``serial_for_url`` does for its URLs, the spec says what to open; the
transports (``serial.py``, ``can.py``, ``sim.py``) are imported only when one is opened, so
start-up stays fast.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, replace

from ..base.canspec import FROM_PYTHON_CAN, LINK_DEFAULTS, parse_can
from ..base.errors import ValidationError
from .base import StreamTransport, Transport

# pyserial's URL handlers (serial.serial_for_url)
PYSERIAL_SCHEMES = ("socket", "rfc2217", "loop", "spy", "hwgrep", "alt", "cp2110")
# what --port takes: a URL scheme -> (module in this package, class); "" is a device path
# (/dev/ttyACM0, COM3). Anything else with "://" is refused, naming these.
PORT_SCHEMES: dict[str, tuple[str, str]] = {
    "": ("serial", "SerialTransport"),
    **{scheme: ("serial", "SerialTransport") for scheme in PYSERIAL_SCHEMES},
}


def port_class(port: str) -> type[StreamTransport]:
    """The transport class that takes ``port`` (a device path or a URL)."""
    scheme, sep, _ = port.partition("://")
    entry = PORT_SCHEMES.get(scheme if sep else "")
    if entry is None:
        known = ", ".join(s + "://" for s in PORT_SCHEMES if s)
        raise ValidationError(f"unknown port URL scheme {scheme + '://'!r}; known: {known}")
    module, name = entry
    return getattr(importlib.import_module(f"{__package__}.{module}"), name)


KINDS = ("port", "can", "sim")  # what names a link: a serial port or URL, a CAN bus, the simulator


@dataclass(frozen=True)
class LinkSpec:
    """``kind`` is one of ``KINDS``; ``name`` the device path or URL, ``IFACE:CHANNEL`` (or
    ``FROM_PYTHON_CAN``: python-can's own configuration), or the simulated module. ``baud``
    is for a serial line, ``bitrate`` for a CAN bus (None: the interface's own), ``address``
    and ``host_address`` for the simulator (the module it serves answers there)."""

    kind: str
    name: str
    baud: int = LINK_DEFAULTS["baud"]  # type: ignore[assignment]
    bitrate: int | None = LINK_DEFAULTS["bitrate"]
    address: int = LINK_DEFAULTS["address"]  # type: ignore[assignment]
    host_address: int = LINK_DEFAULTS["host_address"]  # type: ignore[assignment]

    @classmethod
    def parse(cls, port: str | None = None, can: str | None = None, sim: str | None = None, *,
              baud: int | None = None, bitrate: int | None = None, address: int | None = None,
              host_address: int | None = None) -> LinkSpec:
        """The one link ``port``, ``can`` or ``sim`` names (exactly one of them); a rate or
        address left None takes ``LINK_DEFAULTS`` as read now. A malformed CAN bus is a
        ``UsageError`` here, before anything is opened."""
        named = [(kind, value) for kind, value in zip(KINDS, (port, can, sim))
                 if value is not None]
        if len(named) != 1:
            raise ValidationError("give only one of port, can and sim" if named else
                                  "give one of port, can and sim")
        kind, name = named[0]
        if kind == "can" and name != FROM_PYTHON_CAN:
            parse_can(name)
        return cls(kind, name, **_filled(baud=baud, bitrate=bitrate, address=address,
                                         host_address=host_address))

    @classmethod
    def from_settings(cls, settings: dict) -> LinkSpec | None:
        """The link resolved settings name (``config.resolve``: options > environment >
        profile); None when they name none (the caller looks for an attached module)."""
        kinds = {kind: settings.get(kind) or None for kind in KINDS}
        if not any(kinds.values()):
            return None
        return cls.parse(**kinds, baud=settings.get("baud"), bitrate=settings.get("bitrate"),
                         address=settings.get("address"),
                         host_address=settings.get("host_address"))

    def at(self, **changes) -> LinkSpec:
        """The same link with other rates or addresses (None: keep this spec's)."""
        return replace(self, **{k: v for k, v in changes.items() if v is not None})

    def open(self, *, listen_only: bool = False) -> Transport:
        """The transport, opened. ``listen_only``: a tap on a serial line, which must never
        drive it (RTS and DTR stay inactive)."""
        if self.kind == "port":
            t = port_class(self.name)(self.name, self.baud)
            if listen_only:
                t.listen_only = True  # type: ignore[attr-defined]
            t.open()
            return t
        if self.kind == "can":
            from .can import PythonCanTransport, python_can_config

            bitrate = self.bitrate
            if self.name == FROM_PYTHON_CAN:
                iface, channel, configured = python_can_config()
                bitrate = bitrate if bitrate is not None else configured
            else:
                iface, channel = parse_can(self.name)
            c = PythonCanTransport(iface, channel, bitrate)
            c.open()
            return c
        from .sim import SimTransport

        s = SimTransport(self.name, self.address, host_address=self.host_address)
        s.open()
        return s


def _filled(**given) -> dict:
    """``given`` with each None taken from ``LINK_DEFAULTS`` (read at the call, so the one
    table decides for every entry point)."""
    return {k: LINK_DEFAULTS[k] if v is None else v for k, v in given.items()}


__all__ = ["LinkSpec", "KINDS", "LINK_DEFAULTS", "PORT_SCHEMES", "PYSERIAL_SCHEMES", "port_class"]
