"""python-can as a transport (socketcan, pcan, slcan, virtual, ...), one standard-id bus.

python-can is imported here and only here, when a CAN link is opened, so serial users never pay
for its import (about 0.1 s).
"""

from __future__ import annotations

from ..base.errors import TransportError, ValidationError
from .base import CanFrame, CanTransport


def python_can_config() -> tuple[str, str, int | None]:
    """(interface, channel, bit rate) as python-can's own tools find them: its config files
    (~/can.conf, ~/.canrc, ./can.ini on Windows, ...) and CAN_INTERFACE, CAN_CHANNEL,
    CAN_BITRATE."""
    import can

    try:
        config = can.util.load_config()
    except (can.CanInterfaceNotImplementedError, ValueError) as exc:
        what = "names no interface" if '"None"' in str(exc) else f"is not usable ({exc})"
        raise ValidationError(
            f"--can without IFACE:CHANNEL takes the bus from python-can's configuration, which "
            f"{what}; set CAN_INTERFACE and CAN_CHANNEL, write "
            f"~/can.conf ([default] interface = ..., channel = ...), or give --can IFACE:CHANNEL"
        ) from None
    channel = config.get("channel")
    if channel is None:
        raise ValidationError(f"python-can's configuration names the interface "
                              f"{config['interface']!r} but no channel; set CAN_CHANNEL or "
                              "channel in ~/can.conf, or give --can IFACE:CHANNEL")
    bitrate = config.get("bitrate")
    return str(config["interface"]), str(channel), int(bitrate) if bitrate else None


class PythonCanTransport(CanTransport):
    def __init__(self, interface: str, channel: str, bitrate: int | None = None, **kwargs):
        super().__init__(f"{interface}:{channel}")
        self.interface = interface
        self.channel = channel
        self.bitrate = bitrate
        self.kwargs = kwargs
        self._bus = None
        self._can = None  # the python-can module, once opened

    def open(self) -> None:
        if self._bus is not None:
            return
        try:
            import can
        except ImportError as exc:  # pragma: no cover - python-can is a dependency
            raise TransportError(f"CAN needs python-can ({exc})") from exc
        kw = dict(self.kwargs)
        if self.bitrate is not None:
            kw["bitrate"] = self.bitrate
        try:
            self._bus = can.Bus(interface=self.interface, channel=self.channel, **kw)
        except (can.CanError, OSError, ValueError, ImportError, NotImplementedError) as exc:
            raise TransportError(f"cannot open CAN {self.url}: {exc}") from exc
        self._can = can

    def close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except Exception:  # shutting down a vanished adapter must not mask the real error
                pass

    @property
    def is_open(self) -> bool:
        return self._bus is not None

    def _lost(self, what: str, exc: Exception) -> TransportError:
        self.close()
        gone = f"lost CAN {self.url} ({what} failed: {exc}); adapter unplugged or bus down?"
        err = TransportError(f"{gone} Reconnect once it is back.")
        err.lost = gone  # type: ignore[attr-defined]  # (no advice: the bridge ends with it)
        return err

    def send(self, arbitration_id: int, data: bytes) -> None:
        bus, can = self._bus, self._can
        if bus is None or can is None:
            raise TransportError(f"CAN {self.url} is not open")
        msg = can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)
        try:
            bus.send(msg)
        except can.CanOperationError as exc:
            raise TransportError(f"CAN send failed on {self.url}: {exc}") from exc
        except (can.CanError, OSError) as exc:
            raise self._lost("send", exc) from exc

    def _next(self, timeout: float | None):
        """The bus's next message (None after ``timeout``); a failing bus is a lost link."""
        bus, can = self._bus, self._can
        if bus is None or can is None:
            raise TransportError(f"CAN {self.url} is not open")
        try:
            return bus.recv(timeout)
        except (can.CanError, OSError) as exc:
            raise self._lost("receive", exc) from exc

    def recv(self, timeout: float | None) -> tuple[int, bytes] | None:
        msg = self._next(timeout)
        if msg is None:
            return None
        if msg.is_error_frame or msg.is_remote_frame:
            return msg.arbitration_id, b""
        return msg.arbitration_id, bytes(msg.data)

    def listen(self, timeout: float | None) -> CanFrame | None:
        """The next frame on the bus, whatever its id or kind, with the bus's timestamp
        (a listener's receive: ``recv`` keeps what a client needs, this keeps everything)."""
        msg = self._next(timeout)
        return None if msg is None else frame_of(msg)

    def describe(self) -> str:
        return f"CAN {self.url}"


def frame_of(msg) -> CanFrame:
    """A python-can ``Message`` as a ``CanFrame``."""
    return CanFrame(msg.timestamp, msg.arbitration_id, bytes(msg.data), msg.is_extended_id,
                    msg.is_error_frame, msg.is_remote_frame)


def message_of(can, frame: CanFrame):
    """A ``CanFrame`` as a python-can ``Message`` (``can``: the python-can module)."""
    return can.Message(timestamp=frame.t, arbitration_id=frame.arbitration_id,
                       data=frame.data, is_extended_id=frame.extended,
                       is_error_frame=frame.error, is_remote_frame=frame.remote,
                       dlc=len(frame.data))
