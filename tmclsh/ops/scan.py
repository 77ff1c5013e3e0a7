"""Finding the modules on a serial line or a CAN bus: who answers, and what each one is.

Presence is tested with 136 type 1, whose serial reply names the module address and opcode,
so a slow module's late answer is never credited to the next address (the 136 type 0 string
reply names neither), and is recognised as that module's: a late or garbled answer puts its
address on a second, slower pass. A module that answered is then asked for its version string.

A module that answers from its bootloader (``1311B100``: a firmware update broke off) is found
like any other and marked (``Found.bootloader``): it runs no firmware until ``tmclsh
firmware`` completes the update. It answers at address 1 and 115200 baud only.

Silent addresses are most of a scan, so the wait for each is derived from the link: the wire
time of a request and its reply at the baud rate, plus a margin for the operating system and
the module (short on a pty, a module's own USB port or TCP; an RS485 adapter's latency timer
on a real line). On CAN the ids are scanned (GP 71) and every module answers on the one reply
id; a CAN reply names no sender the client can rely on, so there the wait stays long enough
to outlast the modules' answer time.

Nothing here prints: ``progress`` callbacks report, the CLI renders.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from ..client.core import Client
from ..base.errors import ChecksumError, DownloadModeError, TmclError, TmclTimeoutError
from ..tmcl.decoder import is_frame
from ..tmcl.frames import SERIAL_FRAME_LEN, Control, Request, Status
from ..link.base import Transport

BITS_PER_BYTE = 10  # 8N1: a start bit, eight data bits, a stop bit
# margins on top of the wire time (seconds)
MARGIN_LOCAL = 0.004  # a pty, the in-process simulator: only scheduling
MARGIN_USB = 0.006  # the module's own USB port (CDC), TCP: a USB frame or a network hop
MARGIN_RS485 = 0.025  # a USB-RS485 adapter (FTDI latency timer up to 16 ms) + the module
CAN_TIMEOUT = 0.05  # see the module docstring
SLOW_TIMEOUT = 0.25  # the second pass: addresses that answered late or garbled

Progress = Callable[[int, "Found | None"], None]


@dataclass(frozen=True)
class Found:
    address: int
    module: str | None
    version: str | None
    baud: int | None = None
    bootloader: bool = False  # it answers from its bootloader: an update did not complete

    def as_json(self) -> dict:
        row: dict = {"address": self.address, "module": self.module, "version": self.version}
        if self.baud is not None:
            row["baud"] = self.baud
        if self.bootloader:
            row["bootloader"] = True
        return row


def wire_time(baud: int, nbytes: int = 2 * SERIAL_FRAME_LEN) -> float:
    """Seconds ``nbytes`` take on a serial line at ``baud`` (a request and its reply)."""
    return nbytes * BITS_PER_BYTE / baud


def _is_pty(url: str) -> bool:
    try:
        return os.path.realpath(url).startswith("/dev/pts/")
    except (OSError, ValueError):
        return False


def line_baud(transport: Transport) -> int | None:
    """The baud rate the link's bytes travel at, or None when it has none: a serial port, a
    pty and an rfc2217:// port (a serial port on a server, its baud rate set through the
    protocol) have one; a CAN bus, the simulator and other URLs (socket://: bytes over TCP
    to whatever listens) do not. Only a byte stream has a baud rate (and
    ``set_baudrate``). The first pass's wait, ``Found.baud`` and ``scan --baud auto`` all
    ask this."""
    if transport.kind == "stream" and not transport.simulated and (
            "://" not in transport.url or _is_rfc2217(transport.url)):
        return getattr(transport, "baudrate", None)
    return None


def _is_rfc2217(url: str) -> bool:
    return url.lower().startswith("rfc2217://")


def address_timeout(transport: Transport, *, usb: bool = False) -> float:
    """How long to wait for each address in the first pass (see the module docstring)."""
    if transport.kind == "can":
        return CAN_TIMEOUT
    if transport.simulated:
        return MARGIN_LOCAL
    baud = line_baud(transport)
    if baud is None:
        return MARGIN_USB * 2  # socket://: no baud rate, a network hop
    if _is_rfc2217(transport.url):  # the network hop, then the server's serial line
        return wire_time(baud) + MARGIN_USB + MARGIN_RS485
    margin = MARGIN_LOCAL if _is_pty(transport.url) else MARGIN_USB if usb else MARGIN_RS485
    return wire_time(baud) + margin


def _late_answerer(raw: bytes, host: int) -> int | None:
    """The address a dropped reply came from, if it may be a module's late or garbled answer
    to a presence probe (a damaged reply that still starts with our host address most likely
    names its sender next: worth a second look)."""
    if len(raw) < 2 or raw[0] != host:
        return None
    whole = len(raw) >= SERIAL_FRAME_LEN and is_frame(raw[:SERIAL_FRAME_LEN], host)
    if whole and len(raw) == SERIAL_FRAME_LEN and raw[3] == Control.GET_VERSION:
        return raw[1]  # a late answer
    if len(raw) <= 2 * SERIAL_FRAME_LEN and not whole:
        return raw[1]  # a damaged one
    return None


def _identify(client: Client, addr: int, binary, timeout: float) -> Found:
    from ..tmcl.modules import by_firmware_id, identify
    from ..tmcl.version import parse_string

    version = None
    try:  # it is there: give it time and a retry for the string
        reply = client.request(Request(addr, Control.GET_VERSION, 0, 0, 0),
                               timeout=max(timeout, 0.2), retries=1)
        version = reply.version if reply is not None else None
    except TmclError:
        pass
    mod = identify(version, binary.value if binary.status == Status.OK else None)
    parsed = parse_string(version)
    boot = parsed is not None and parsed.bootloader
    if boot and (mod is None or mod.generic):
        mod = by_firmware_id(parsed.type_number)  # (its type, as its bootloader names it)
    name = mod.name if mod is not None and not mod.generic else None
    return Found(addr, name, version, line_baud(client.transport), boot)


def _probe(client: Client, addr: int, timeout: float, retries: int):
    client.address = addr
    if client.is_can:
        client.can_id = addr
    try:
        return client.request(Request(addr, Control.GET_VERSION, 1, 0, 0), timeout=timeout,
                              retries=retries)
    except DownloadModeError as exc:  # a firmware that stores even 136 there: it is present
        return exc.reply


def scan(client: Client, addresses: Iterable[int], *, timeout: float,
         slow_timeout: float = SLOW_TIMEOUT, progress: Progress | None = None) -> list[Found]:
    """Probe every address; ``progress(address, found_or_None)`` after each of the first
    pass. Addresses that answered late or garbled are probed again with ``slow_timeout``."""
    addresses = list(addresses)
    found: dict[int, Found] = {}
    again: set[int] = set()
    host = client.host_address

    def tracer(direction: str, raw: bytes, decoded: object) -> None:
        if direction == "drop" and not client.is_can:
            addr = _late_answerer(raw, host)
            if addr is not None:
                again.add(addr)

    unsubscribe = client.add_tracer(tracer)
    try:
        for addr in addresses:
            hit = None
            try:
                binary = _probe(client, addr, timeout, 0)
            except ChecksumError:
                again.add(addr)
            except TmclTimeoutError:
                pass
            else:
                if binary is not None:
                    hit = found[addr] = _identify(client, addr, binary, timeout)
            if progress is not None:
                progress(addr, hit)
        if not client.is_can and addresses:
            time.sleep(min(slow_timeout, 4 * timeout))  # the last address's late answer
            client.absorb()
        wanted = set(addresses)
        for addr in sorted((again & wanted) - found.keys()):
            try:
                binary = _probe(client, addr, max(slow_timeout, timeout), 1)
            except (ChecksumError, TmclTimeoutError):
                continue
            if binary is not None:
                found[addr] = _identify(client, addr, binary, slow_timeout)
    finally:
        unsubscribe()
    return [found[a] for a in sorted(found)]
