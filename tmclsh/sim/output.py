"""What the simulated module sends, on its way out: replies held back (telegram pause, a fault's
delay), damaged, doubled or dropped by the faults a test set, and handed over in order to
whoever reads the serial line or the CAN bus.

A reply is queued with the real time it is due; ``drain`` hands over what is due, serial
bytes in one piece, as a UART sends them. Communication timing is real time, never module
time (the module's ``speed`` does not hurry a telegram pause).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from typing import TYPE_CHECKING

from .faults import RANDOM_DELAY
from .model import GLOBAL

if TYPE_CHECKING:
    from .device import Simulator

log = logging.getLogger(__name__)

SERIAL = "serial"
CAN = "can"


class Output:
    """The module's outgoing queue and the two buffers its readers take from."""

    def __init__(self, host: Simulator) -> None:
        self._host = host  # its faults, its callbacks, its bootloader, its telegram pause
        self._lock = threading.Lock()
        self._rx_cond = threading.Condition()
        self._can_cond = threading.Condition()
        self._outbuf = bytearray()
        self._canbuf: deque[tuple[int, bytes]] = deque()
        self._outq: deque[tuple[float, str, object]] = deque()
        self._late_copies: deque[tuple[str, object]] = deque()  # the "dup-late" fault
        self._last_due = 0.0

    def pending(self) -> bool:
        """Something is queued (due now or later)."""
        return bool(self._outq)

    def next_due(self) -> float | None:
        """The real time the first queued piece is due, if any."""
        try:
            return self._outq[0][0]
        except IndexError:
            return None

    def clear(self) -> None:
        """A power cycle: what was queued is gone."""
        with self._lock:
            self._outq.clear()

    def has_late_copies(self) -> bool:
        return bool(self._late_copies)

    def queue(self, channel: str, payload: object, *, reply: bool) -> None:
        """``payload`` (bytes, or ``(can_id, data)`` on CAN) out; a reply meets the faults."""
        delay = 0.0
        copies = 1
        if reply:
            host = self._host
            f = host.faults
            # (the faults are looked at only when one is set: this runs for every reply)
            faulty = f.rates or f.drop_next or f.dup_next or f.dup_late_next
            if faulty and f.take("drop_next", "drop"):
                return
            payload = self._apply_faults(channel, payload)
            delay = f.delay
            if channel == SERIAL and not host.boot.active:
                delay += host.store.get(GLOBAL, "TelegramPauseTime") / 1000.0
            if faulty:
                if f.rates and f.roll("delay"):
                    delay += f.rng.uniform(*RANDOM_DELAY)
                if f.take("dup_next", "dup"):
                    copies = 2
                if f.take("dup_late_next", "dup-late"):
                    self._late_copies.append((channel, payload))
        due = max(time.monotonic() + delay, self._last_due)
        self._last_due = due
        for _ in range(copies):
            self._outq.append((due, channel, payload))

    def send_late_copies(self) -> None:
        """A request arrived: the copies held back by the "dup-late" fault go out first."""
        while self._late_copies:
            channel, payload = self._late_copies.popleft()
            due = max(time.monotonic(), self._last_due)
            self._last_due = due
            self._outq.append((due, channel, payload))

    def _apply_faults(self, channel: str, payload: object) -> object:
        f = self._host.faults
        if f.rates and f.roll("garbage"):
            f.garbage += bytes(f.rng.randrange(256) for _ in range(f.rng.randint(1, 8)))
        if channel == CAN:
            can_id, data = payload  # type: ignore[misc]
            data = self._mangle(data)
            if f.garbage:
                self._outq.append((self._last_due, CAN, (can_id, f.garbage[:8])))
                f.garbage = b""
            return can_id, data
        data = self._mangle(payload)  # type: ignore[arg-type]
        if f.garbage:
            data, f.garbage = f.garbage + data, b""
        return data

    def _mangle(self, data: bytes) -> bytes:
        f = self._host.faults
        if not (f.rates or f.corrupt_next or f.truncate_next):
            return data
        if data and f.take("corrupt_next", "corrupt"):
            buf = bytearray(data)
            i = f.rng.randrange(max(1, len(buf) - 1))
            buf[i] ^= 1 << f.rng.randrange(8)
            data = bytes(buf)
        if f.take("truncate_next", "truncate"):
            data = data[:len(data) // 2]
        return data

    def drain(self) -> None:
        """Hand over everything that is due."""
        if not self._outq:
            return  # (most calls: a read finds the reply handed over when it was queued)
        with self._lock:
            now = time.monotonic()
            serial = bytearray()  # what is due goes out in one piece, as a UART sends it
            while self._outq and self._outq[0][0] <= now:
                _, channel, payload = self._outq.popleft()
                if channel == SERIAL:
                    serial += payload  # type: ignore[operator]
                    continue
                if serial:
                    self._deliver(SERIAL, bytes(serial))
                    serial.clear()
                self._deliver(channel, payload)
            if serial:
                self._deliver(SERIAL, bytes(serial))

    def _deliver(self, channel: str, payload: object) -> None:
        host = self._host
        try:
            if channel == CAN:
                can_id, data = payload  # type: ignore[misc]
                cb = host.on_can_output
                if cb is not None:
                    cb(can_id, data)
                    return
                with self._can_cond:
                    self._canbuf.append((can_id, data))
                    self._can_cond.notify_all()
                return
            cb_serial = host.on_output
            if cb_serial is not None:
                cb_serial(payload)  # type: ignore[arg-type]
                return
            with self._rx_cond:
                self._outbuf += payload  # type: ignore[operator]
                self._rx_cond.notify_all()
        except Exception:  # a broken consumer must not kill the module
            log.exception("delivering output failed")

    def read(self, timeout: float | None = 0.0) -> bytes:
        """Serial bytes sent: waits up to ``timeout`` for the first, returns all there are."""
        self.drain()
        with self._rx_cond:
            if not self._outbuf and timeout != 0:
                self._rx_cond.wait_for(lambda: bool(self._outbuf), timeout)
            data = bytes(self._outbuf)
            self._outbuf.clear()
        return data

    def can_read(self, timeout: float | None = 0.0) -> tuple[int, bytes] | None:
        """One CAN frame sent, waiting up to ``timeout`` for it."""
        self.drain()
        with self._can_cond:
            if not self._canbuf and timeout != 0:
                self._can_cond.wait_for(lambda: bool(self._canbuf), timeout)
            return self._canbuf.popleft() if self._canbuf else None
