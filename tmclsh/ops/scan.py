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

A module in its ASCII mode ignores binary frames: the addresses nothing answered are asked
again on the ASCII command line, with the bring-up's own probe (``client.ascii.probe_ascii``),
and a module found so is identified and left in ASCII mode. That pass costs as much as the
first, so by default it is made only when nothing answered in binary (``ascii=True``: always).

Two modules at one address both answer every request (on an RS485 line they may collide,
on a simulated bus each reply comes twice): an address whose answer came twice is asked
again until the client's rule (``client._ledger.Doubles``, the one rule, also what every
other command is told by) finds it shared, or an answer comes once; a shared address is
reported (``Found.answers``).

Whether the baud rate matters on a link: a module's own USB port (CDC) and TCP carry bytes
at any rate (``rate_matters``), so ``scan --baud auto`` there scans once; elsewhere it stops
once modules found at one rate answer at the next (``answer_at``): a UART module answers at
one rate only, so the rate has no effect on that link (a pty a simulator serves, a USB
module of another vendor) and every further pass would find the same modules again.

Nothing here prints: ``progress`` callbacks report, the CLI renders.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace

from ..client.core import Client
from ..client.ledger import SHARED_AFTER
from ..base.errors import (ChecksumError, DownloadModeError, TmclError, TmclTimeoutError,
                           ValidationError)
from ..tmcl.decoder import is_frame
from ..tmcl.frames import SERIAL_FRAME_LEN, Control, Request, Status
from ..link.base import Transport

BITS_PER_BYTE = 10  # 8N1: a start bit, eight data bits, a stop bit
# margins on top of the wire time (seconds)
MARGIN_LOCAL = 0.004  # a pty, the in-process simulator: only scheduling
MARGIN_USB = 0.006  # the module's own USB port (CDC), TCP: a USB frame or a network hop
MARGIN_RS485 = 0.025  # a USB-RS485 adapter (FTDI latency timer up to 16 ms) + the module
CAN_TIMEOUT = 0.05  # see the module docstring
# what crosses the line for one address in the ASCII pass: the probe line (AGGP 67, 0 CR,
# padded with spaces to two nine-byte blocks: link/ascii.py), its echo (a module may echo
# every character) and the reply (BA 100 0 CR, a longer value)
ASCII_WIRE_BYTES = 2 * 2 * SERIAL_FRAME_LEN + 14
SLOW_TIMEOUT = 0.25  # the second pass: addresses that answered late or garbled

Progress = Callable[[int, "Found | None"], None]


@dataclass(frozen=True)
class Found:
    """A module that answered a scan: its address, type and version string as it named
    them (None when it did not say), and how it was found."""

    address: int
    module: str | None
    version: str | None
    baud: int | None = None
    ascii: bool = False  # found in its ASCII mode (and left in it)
    answers: int = 1  # 2: every reply came twice, two modules answer at this address
    bootloader: bool = False  # it answers from its bootloader: an update did not complete

    def as_json(self) -> dict:
        row: dict = {"address": self.address, "module": self.module, "version": self.version}
        if self.baud is not None:
            row["baud"] = self.baud
        if self.ascii:
            row["mode"] = "ascii"
        if self.answers > 1:
            row["answers"] = self.answers
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


def address_timeout(transport: Transport, *, usb: bool = False,
                    nbytes: int = 2 * SERIAL_FRAME_LEN) -> float:
    """How long to wait for each address in the first pass (see the module docstring);
    ``nbytes``: what crosses the line for one address (the ASCII pass's probe line, its echo
    and the reply are longer than two frames)."""
    if transport.kind == "can":
        return CAN_TIMEOUT
    if transport.simulated:
        return MARGIN_LOCAL
    baud = line_baud(transport)
    if baud is None:
        return MARGIN_USB * 2  # socket://: no baud rate, a network hop
    if _is_rfc2217(transport.url):  # the network hop, then the server's serial line
        return wire_time(baud, nbytes) + MARGIN_USB + MARGIN_RS485
    margin = MARGIN_LOCAL if _is_pty(transport.url) else MARGIN_USB if usb else MARGIN_RS485
    return wire_time(baud, nbytes) + margin


def rate_matters(transport: Transport, *, usb: bool = False) -> str | None:
    """None if the baud rate decides what the module hears on this link; else why it does
    not (a module's own USB port, a pty, TCP, the simulator), in words for users."""
    if transport.kind != "stream":
        return "a CAN bus has no baud rate"
    if transport.simulated:
        return "the built-in simulator has no baud rate"
    url = transport.url
    if "://" in url and not _is_rfc2217(url):
        return "bytes over TCP carry no baud rate"
    if usb:
        return "a module's own USB port (CDC) takes any rate"
    return None


def answer_at(client: Client, addresses: Iterable[int], baud: int, timeout: float) -> bool:
    """Does any module at ``addresses`` answer at ``baud``? (``--baud auto``: a module that
    answers at two rates is on a link where the rate has no effect.)"""
    client.transport.set_baudrate(baud)  # type: ignore[attr-defined]
    client._lifecycle.forget_stale()
    for addr in addresses:
        try:
            if _probe(client, addr, max(timeout, 0.05), 1) is not None:
                return True
        except (ChecksumError, TmclTimeoutError):
            continue
    return False


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
    return Found(addr, name, version, line_baud(client.transport), bootloader=boot)


def _probe(client: Client, addr: int, timeout: float, retries: int):
    client.address = addr
    if client.is_can:
        client.can_id = addr
    try:
        return client.request(Request(addr, Control.GET_VERSION, 1, 0, 0), timeout=timeout,
                              retries=retries)
    except DownloadModeError as exc:  # a firmware that stores even 136 there: it is present
        return exc.reply


def _answers_twice(client: Client, addr: int, timeout: float) -> bool:
    """Is ``addr`` shared? While its last answer came twice, ask again, giving a second
    answer the time to come, until the client's rule says so (``Client.shared``): two
    modules at one address answer every request, a reply copied on a bad line is not
    copied every time."""
    for _ in range(SHARED_AFTER):
        if not _second_came(client, addr):
            return False
        if addr in client.shared:
            return True
        try:
            _probe(client, addr, max(timeout, 0.05), 1)
        except (ChecksumError, TmclTimeoutError):
            return False
    _second_came(client, addr)
    return addr in client.shared


def _second_came(client: Client, addr: int, wait: float = SLOW_TIMEOUT) -> bool:
    """Wait for another reply behind the last answer from ``addr`` (``wait`` at most: a
    busy machine or a slow second module); whatever came is taken in."""
    end = time.monotonic() + wait
    while True:
        client._lifecycle.absorb()
        if client.answered_twice(addr) or addr in client.shared:
            return True
        if time.monotonic() >= end:
            return False
        time.sleep(0.01)


def _in_ascii_mode(client: Client, addr: int, timeout: float) -> Found | None:
    """The module at ``addr`` if it answers on the ASCII command line (the bring-up's probe);
    identified (it is stepped out of ASCII mode for the 136 that names it, and back) and left
    in ASCII mode."""
    from ..client.ascii import AsciiLink, Mode, probe_ascii

    client.address = addr
    try:
        probe = probe_ascii(client, timeout)
    except (TmclTimeoutError, ValidationError):  # silence, or another host address
        return None
    if probe.mode != Mode.ASCII:
        return None
    client.module, client.version = None, None
    baud = line_baud(client.transport)
    try:
        link = AsciiLink.attach(client, found=probe, timeout=max(timeout, 0.05), tell=False)
    except TmclError:
        return Found(addr, None, None, baud, ascii=True)
    try:
        mod = client.module
        name = mod.name if mod is not None and not mod.generic else None
        return Found(addr, name, client.version, baud, ascii=True)
    finally:
        link.let_go()


def scan(client: Client, addresses: Iterable[int], *, timeout: float,
         slow_timeout: float = SLOW_TIMEOUT, progress: Progress | None = None,
         ascii: bool | None = None, ascii_timeout: float | None = None,
         ascii_also: Iterable[int] = ()) -> list[Found]:
    """Probe every address; ``progress(address, found_or_None)`` after each of the first
    pass. Addresses that answered late or garbled are probed again with ``slow_timeout``;
    an address that answered twice is asked once more (``Found.answers``). On a serial
    line the addresses still silent are then asked in ASCII mode (``ascii``: None when
    nothing answered in binary, True always, False never), waiting ``ascii_timeout`` each;
    those of ``ascii_also`` that are silent are asked in any case (an inventory names a
    module there: it may be in its ASCII mode, and the ASCII pass over only those costs
    little)."""
    addresses = list(addresses)
    found: dict[int, Found] = {}
    again: set[int] = set()
    checked: set[int] = set()
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
                    client._lifecycle.absorb()  # (a second answer to the string, if it came)
                    if client.answered_twice(addr, lately=True) or _second_came(
                            client, addr, timeout):  # (as long as an answer takes)
                        checked.add(addr)
                        if _answers_twice(client, addr, timeout):
                            hit = found[addr] = replace(hit, answers=2)
            if progress is not None:
                progress(addr, hit)
        if not client.is_can and addresses:
            time.sleep(min(slow_timeout, 4 * timeout))  # the last address's late answer
            client._lifecycle.absorb()
        wanted = set(addresses)
        for addr in sorted((again & wanted) - found.keys()):
            try:
                binary = _probe(client, addr, max(slow_timeout, timeout), 1)
            except (ChecksumError, TmclTimeoutError):
                continue
            if binary is not None:
                found[addr] = _identify(client, addr, binary, slow_timeout)
        for addr in sorted(a for a in found if a not in checked and (
                a in client.shared or client.answered_twice(a, lately=True))):
            if _answers_twice(client, addr, timeout):  # (a second answer that came later)
                found[addr] = replace(found[addr], answers=2)
        if _has_ascii_mode(client):
            everywhere = ascii is not False and (ascii or not found)
            also = set(ascii_also)
            silent = [a for a in addresses if a not in found and (everywhere or a in also)]
            found.update(_ascii_pass(client, silent, ascii_timeout or timeout))
    finally:
        unsubscribe()
    return [found[a] for a in sorted(found)]


def _has_ascii_mode(client: Client) -> bool:
    return client.transport.kind == "stream"


def _ascii_pass(client: Client, addresses: list[int], timeout: float) -> dict[int, Found]:
    from ..client.ascii import MAX_ADDRESS, end_line

    found: dict[int, Found] = {}
    addresses = [a for a in addresses if 1 <= a <= MAX_ADDRESS]
    if not addresses:
        return found
    with client.lock:
        end_line(client, timeout)  # the binary probes were one long line to such a module
    for addr in addresses:
        hit = _in_ascii_mode(client, addr, timeout)
        if hit is not None:
            found[addr] = hit
    client._lifecycle.resync_next()  # (binary frames after ASCII lines start from a clean line)
    return found
