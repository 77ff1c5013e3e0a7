"""The module's ASCII mode: recognising it (``probe_mode``), switching it (binary 139, ASCII
``BIN``) and ``AsciiLink``, which swaps the client's framing for the ASCII one while the
module is driven in its ASCII mode. What is sent for one request and how its answer is read
(address characters, echo modes, the reply parser, the line checks) is the framing's:
tmclsh/link/ascii.py, whose names are found here as well.

Mode detection (``probe_mode``) is built so that nothing harmful happens in either mode. A
binary 136 type 1 (read the version number, harmless) goes first: a binary module answers it;
in ASCII mode its bytes are an unaddressed line with no CR in it (the don't-care value field
is chosen so that neither the checksum nor any other byte is CR, LF, BS or DEL), which the
following CR ends, and the line discipline drops. Only then an ASCII ``GGP 67, 0`` line
asks for the echo mode. Should a binary module have missed the first probe, the ASCII bytes
reach its binary framer: no nine-byte window of them carries a valid checksum (a unit test
checks every address), so they are never taken for a command. Every run of ASCII bytes is
whole nine-byte blocks (link/ascii.py says why).

The probes and the mode switches read the transport themselves, under the client's lock:
they run while neither framing is the module's yet.

What the mode's front ends (``.mode``, ``.ascii``, ``.ascii-config``) decide is here too
(``drive``, ``switch``, ``mode_record``, ``mode_text``, ``echo_written``, the link's
``after_bin`` and ``settle``): a front end only parses and prints, and never works out again
which mode the client is in. Everyone else reads ``Client.mode``'s facts (link/modes.py).
"""

from __future__ import annotations

import logging
import time
import weakref
from typing import TYPE_CHECKING

from ..base.errors import (StatusError, TmclError, TmclTimeoutError, TransportError,
                           ValidationError)
from ..link.ascii import (  # noqa: F401  (the codec's names, for those who import them here)
    BS, CR, ECHO_MASK, ECHO_NAMES, ECHO_SHIFT, END_LINE, FIELDS, GP_ASCII_MODE, GP_BANK,
    GP_HOST_ADDRESS, MAX_ADDRESS, STARTUP_ASCII_BIT, AsciiFraming, Echo, LineKind, Mode,
    address_char, ascii_commands, ascii_probe_bytes, ascii_probe_line, binary_answer,
    char_address, classify_line, command_bytes, decode_line, describe_gp67, echo_candidates,
    echo_mode, format_request, gp67_value, line_for, has_valid_frame, next_line, not_in_ascii,
    padded,
    parse_reply, probe_frame, read_quiet, reply_part, reply_summary, starts_in_ascii,
    take_lines)
from ..link.base import StreamTransport
from ..tmcl import instructions as isa
from ..tmcl.frames import SERIAL_FRAME_LEN, Control, Reply, Request, Status, status_ok

if TYPE_CHECKING:
    from .core import Client

log = logging.getLogger(__name__)

_GGP = int(isa.Opcode.GGP)
_read_quiet = read_quiet
_binary_answer = binary_answer

#: said where tmclsh reads through the ASCII mode (connect, .mode ascii, .ascii), once in a
#: run of tmclsh (not again at each .connect or reconnect); not by scan, nor on the raw
#: terminal, where nothing is read twice
NO_CHECKSUM = ("ASCII replies carry no checksum: a digit changed on the line gives a valid "
               "reply with a wrong value, which no single read can reveal. tmclsh reads every "
               "setting twice and takes it only when both reads agree; motion state, "
               "measurements and inputs are read once")


def _transport(client: Client) -> StreamTransport:
    t = client.transport
    if not isinstance(t, StreamTransport):
        raise ValidationError("ASCII mode is a serial-line feature; it is not available over CAN")
    if not t.is_open:
        raise TransportError(f"{t.describe()} is not connected")
    return t



class Probe:
    """What ``probe_mode`` found out."""

    def __init__(self, mode: Mode, gp67: int | None = None, host: int | None = None,
                 binary_garbage: bool = False):
        self.mode = mode
        self.gp67 = gp67
        self.host = host  # the host address the module replied to (ASCII replies carry it)
        self.binary_garbage = binary_garbage  # a binary module saw the ASCII probe

    def __repr__(self) -> str:
        return f"Probe({self.mode.value}, gp67={self.gp67}, host={self.host})"



def probe_mode(client: Client, timeout: float | None = None) -> Probe:
    """Find out whether the module at ``client.address`` is in binary or ASCII mode.

    See the module docstring for why neither probe can make either mode do anything.
    Raises TmclTimeoutError when nothing answers either way.
    """
    t = _transport(client)
    timeout = min(client.timeout, 0.5) if timeout is None else timeout
    addr, host = client.address, client.host_address
    with client.lock:
        stale = _read_quiet(t, 0.02, 0.2)
        if stale:
            client._trace("drop", stale, "stale input before the mode probe")
        raw = probe_frame(addr)
        t.write(raw)
        client._trace("tx", raw, "mode probe: binary 136 type 1")
        data = _read_quiet(t, timeout, timeout,
                           stop=lambda d: _binary_answer(d, addr, Control.GET_VERSION) is not None)
        reply = _binary_answer(data, addr, Control.GET_VERSION)
        if reply is not None:
            client._trace("rx", data, reply)
            if reply.host != host:
                raise ValidationError(
                    f"the module at address {addr} answers host address {reply.host} (GP 76), "
                    f"not {host}; use --host-address {reply.host}")
            return Probe(Mode.BINARY, host=reply.host)
        if data:
            client._trace("drop", data, "no binary answer to the mode probe")
            if _version_string(data, host):
                client._doubts.came_late(addr)  # (136's answer, after it was given up)
        late = end_line(client, timeout)
        if _binary_answer(late, addr, Control.GET_VERSION) is not None:
            # a slow binary module: resynchronise before its next use
            client._lifecycle.resync_next()
            return Probe(Mode.BINARY, host=host)
        return probe_ascii(client, timeout)


def _version_string(data: bytes, host: int) -> bool:
    """Does ``data`` hold a version string (136 type 0's answer: the host address, then
    eight printable characters)?"""
    return any(data[i] == host and all(32 <= b < 127 for b in data[i + 1:i + 9])
               for i in range(len(data) - 8))


def end_line(client: Client, timeout: float) -> bytes:
    """End the unaddressed line that binary bytes (a probe, a scan's probes) started on a
    module in ASCII mode, with ``END_LINE``, and let any answer to it pass: what came is
    returned (and traced as dropped). Callers hold ``client.lock``."""
    t = _transport(client)
    t.write(END_LINE)
    client._trace("tx", END_LINE, "end of line for a module in ASCII mode")
    late = _read_quiet(t, 0.05, timeout)
    if late:
        client._trace("drop", late, "after ending the probe line")
    return late


def probe_ascii(client: Client, timeout: float | None = None) -> Probe:
    """Ask ``GGP 67, 0`` on the ASCII command line: an ASCII reply means ASCII mode (and gives
    the echo mode); binary frames coming back mean a binary module saw it (and refused it: no
    window of the probe's bytes has a valid checksum)."""
    t = _transport(client)
    timeout = min(client.timeout, 0.5) if timeout is None else timeout
    addr, host = client.address, client.host_address
    with client.lock:
        line = ascii_probe_line(addr)
        t.write(line)
        client._trace("tx", line, "mode probe: ASCII GGP 67, 0")
        buf = bytearray()
        deadline = time.monotonic() + timeout
        other_host: int | None = None
        while True:
            while True:
                used, text = next_line(buf)
                if text is None:
                    break
                del buf[:used]
                kind, rep = classify_line(text, line, _GGP)
                if kind == LineKind.REPLY and rep is not None and rep.module == addr:
                    client._trace("rx", text + CR, rep)
                    if rep.host != host:
                        other_host = rep.host
                        continue
                    gp67 = rep.value if rep.status == Status.OK else None
                    return Probe(Mode.ASCII, gp67, rep.host)
                if text:
                    client._trace("rx" if kind == LineKind.ECHO else "drop", text, kind.value)
            left = deadline - time.monotonic()
            if left <= 0:
                break
            buf += t.read(1, left) + t.read_available()
        if other_host is not None:
            raise ValidationError(
                f"the module at address {addr} answers host address {other_host} (GP 76), "
                f"not {host}; use --host-address {other_host}")
        rest = bytes(buf)
        if has_valid_frame(rest):
            client._lifecycle.resync_next()
            return Probe(Mode.BINARY, host=host, binary_garbage=True)
        raise TmclTimeoutError(f"no module answered at address {addr} "
                               f"({address_char(addr)}) in binary or ASCII mode "
                               f"within {timeout:g} s")


# -- the link --------------------------------------------------------------------------------

_LINKS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_told = [False]  # NO_CHECKSUM was said in this run


def tell_no_checksum(client: Client) -> None:
    """NO_CHECKSUM, the first time this run reads through an ASCII mode: a paragraph
    repeated at every connect is one the user learns to skip. (``.ascii``'s terminal reads
    nothing itself: it tells this when the shell goes on in ASCII mode after it.)"""
    if not _told[0]:
        _told[0] = True
        client._taps.notice(NO_CHECKSUM)


class AsciiLink:
    """A client's requests, carried over the module's ASCII command line.

    ``AsciiLink.attach(client)`` finds the mode the module is in, enters ASCII mode if needed
    (binary 139), reads GP 67 for the echo mode and sets ``client.ascii_link``, which makes
    the link's ``AsciiFraming`` the client's framing: from then on ``client.request`` sends
    command lines. ``detach()`` sends BIN and gives the client its binary framing back. One link object is
    kept per client (``for_client``) so that it remembers the mode the module was found in:
    ``close()`` (called by ``Client.close``) leaves the module in that mode unless ``on_exit``
    says otherwise.
    """

    def __init__(self, client: Client, *, found: Mode, echo: Echo = Echo.CHAR,
                 gp67: int | None = None):
        self.client = client
        self.found = found
        self.on_exit: Mode = found
        self._closed = False
        self.entered = False  # the last attach sent 139 (the module was in binary mode)
        self.stats = {"sent": 0, "timeouts": 0, "dropped_lines": 0, "echo_lines": 0}
        # the client's framing while the link is on (Client.ascii_link swaps it in)
        self.framing = AsciiFraming(_transport(client), client, echo=echo, gp67=gp67,
                                    stats=self.stats)
        # Client.close runs its close hooks while the transport is still open: restore the
        # mode there even after .mode binary detached the link
        client._lifecycle.close_hooks.append(self._on_client_close)

    # -- attaching ----------------------------------------------------------------------
    @classmethod
    def for_client(cls, client: Client) -> AsciiLink | None:
        """The link made for ``client`` earlier (attached or not), if any."""
        return _LINKS.get(client)

    @classmethod
    def attach(cls, client: Client, *, timeout: float | None = None,
               found: Probe | None = None, tell: bool = True) -> AsciiLink:
        """Drive ``client`` through the module's ASCII mode (entering it with 139 if needed).
        ``found``: what a ``probe_mode`` just now found (it is not asked again). ``tell``:
        settings will be read through it, so the missing checksum is said (once to each
        run); a scan or the raw terminal reads nothing twice and says nothing."""
        if client.ascii_link is not None:
            return client.ascii_link
        _transport(client)
        if client.module is not None and not client.module.ascii_mode:
            raise ValidationError(f"the {client.module.name} has no ASCII mode")
        link = _LINKS.get(client)
        with client.lock:
            probe = found or probe_mode(client, timeout)
            if probe.mode == Mode.ASCII and client.module is None:
                # 136 does not exist in ASCII mode: step out briefly to identify the module
                try:
                    cls._bin(client)
                    client.identify()
                except BaseException:
                    # stopped (Ctrl-C, SIGTERM) or unanswered while stepped out: back to
                    # the ASCII mode it was found in
                    try:
                        cls._enter(client)
                    except Exception:
                        pass
                    raise
                probe = Probe(Mode.BINARY, host=probe.host)
                entered_from = Mode.ASCII
            else:
                entered_from = probe.mode
            entered = probe.mode == Mode.BINARY
            sent_139 = False
            try:
                if entered:
                    if client.module is None:
                        client.identify()
                    if not client.module.ascii_mode:  # type: ignore[union-attr]
                        raise ValidationError(f"the {client.module.name} has no ASCII mode")  # type: ignore[union-attr]
                    sent_139 = True  # from here the module may be in ASCII mode
                    cls._enter(client)
                    probe = None
                    for _ in range(2):  # a probe or its answer lost on a bad line: ask again
                        try:
                            probe = probe_ascii(client, timeout)
                            break
                        except TmclTimeoutError:
                            continue
                    if probe is None:
                        # silence proves nothing: the module may be in ASCII mode, and the
                        # shell goes on in binary frames, so the except below sends BIN
                        raise TransportError(
                            f"the module at address {client.address} did not answer in ASCII "
                            "mode after command 139 (enter ASCII mode); sent BIN so that it "
                            "stays in binary mode")
                    if probe.mode != Mode.ASCII:
                        sent_139 = False  # binary frames came back: it did not take
                        client._lifecycle.resync_next()
                        raise TransportError(f"the module at address {client.address} did not "
                                             "enter ASCII mode after command 139")
                echo = echo_mode(probe.gp67) if probe.gp67 is not None else Echo.CHAR
                if link is None:
                    link = cls(client, found=entered_from, echo=echo, gp67=probe.gp67)
                    _LINKS[client] = link
                else:
                    link.echo, link.gp67, link._closed = echo, probe.gp67, False
                if tell:
                    tell_no_checksum(client)
                link.entered = entered
                link.framing.clear()
                client._lifecycle.clear_input()
                client._ledger.forget()  # (what the binary link still expected cannot come)
                client._ledger.by_command = False  # ASCII replies name no command
                client.ascii_link = link
            except BaseException:
                # interrupted (Ctrl-C, SIGTERM) between 139 and the link taking over: leave
                # the module in binary mode, as it was found (one found in ASCII mode, and
                # stepped out only to be identified, is in the mode it was found in again)
                if sent_139 and client.ascii_link is None and entered_from == Mode.BINARY:
                    try:
                        cls._bin(client)
                    except Exception:
                        pass
                    client._lifecycle.resync_next()
                raise
        log.info("ASCII mode on address %d (%s; found in %s mode)", client.address,
                 link.echo.text, link.found.value)
        return link

    @staticmethod
    def _enter(client: Client, address: int | None = None) -> None:
        """Binary 139 (to ``address``, else the client's); its reply (if the firmware sends
        one) is read and dropped."""
        t = _transport(client)
        address = client.address if address is None else address
        raw = Request(address, Control.ENTER_ASCII, 0, 0, 0).to_bytes()
        if t.pending():
            client._lifecycle.absorb()  # stale replies dropped, events kept
        t.write(raw)
        client.stats["sent"] += 1
        client._trace("tx", raw, "enter ASCII mode (139)")
        got = _read_quiet(t, 0.05, min(client.timeout, 0.3),
                          stop=lambda d: len(d) >= SERIAL_FRAME_LEN)
        if got:
            client._trace("rx", got, "answer to 139")
        answer = _binary_answer(got, address, Control.ENTER_ASCII)
        if answer is not None and not status_ok(answer.status):
            raise StatusError(answer.status, answer,
                              f"the module refused to enter ASCII mode (139): status "
                              f"{answer.status}, {answer.status_text}")

    @staticmethod
    def _bin(client: Client, timeout: float | None = None, address: int | None = None) -> None:
        """ASCII ``BIN`` (to ``address``, else the client's); what follows it (echo, a reply
        if any) is read and dropped, and the client resynchronises its binary framing before
        its next request (not for another module's BIN: what came was read whole)."""
        t = _transport(client)
        line = command_bytes(client.address if address is None else address, isa.ASCII_BIN)
        t.write(line)
        client._trace("tx", line, isa.ASCII_BIN)
        timeout = min(client.timeout, 0.3) if timeout is None else timeout
        got = _read_quiet(t, 0.05, timeout)
        if got:
            client._trace("rx", got, "after BIN")
        if address is None:
            client._lifecycle.resync_next()

    # -- leaving ------------------------------------------------------------------------
    @property
    def active(self) -> bool:
        return self.client.ascii_link is self

    def detach(self, *, send_bin: bool = True, verify: bool = True) -> None:
        """Stop using ASCII mode: send BIN (back to binary mode) and give the client back its
        binary path. ``send_bin=False`` only forgets the link (the module stays in ASCII mode
        and binary requests would go unanswered)."""
        client = self.client
        with client.lock:
            if send_bin:
                self._bin(client)
            client.ascii_link = None
            client._ledger.by_command = True
            self.framing.clear()
        if send_bin and verify:
            try:
                client.request(Request(client.address, Control.GET_VERSION, 1, 0, 0))
            except TmclTimeoutError:
                raise TransportError(f"the module at address {client.address} did not return "
                                     "to binary mode after BIN") from None

    def after_bin(self) -> None:
        """The module left its ASCII mode by a BIN the client did not send (typed on the
        terminal): take the binary framing back, in step, and leave the module in binary
        mode at exit. A 136 type 1 proves it answers binary frames (TmclError if not)."""
        client = self.client
        self.detach(send_bin=False)
        client._lifecycle.resync_next()
        self.on_exit = Mode.BINARY
        client.request(Request(client.address, Control.GET_VERSION, 1, 0, 0))

    @property
    def found_in_binary(self) -> bool:
        """The module was in binary mode when the link took it over: leaving the terminal
        proposes BIN, to leave it as it was found."""
        return self.found == Mode.BINARY

    def settle(self, to_binary: bool) -> None:
        """The mode chosen on leaving the terminal, now and at exit: binary (BIN sent now)
        or ASCII (the module stays in it, also after the client closes)."""
        if to_binary:
            self.detach(send_bin=True)
        self.on_exit = Mode.BINARY if to_binary else Mode.ASCII

    def close(self) -> None:
        """Leave the module in the mode it was found in (or ``on_exit``). Called by
        ``Client.close`` (and when ``.connect`` leaves the link); safe to call more than
        once. The client is done with this module: a later ``attach`` makes a new link."""
        if self._closed:
            return
        self._closed = True
        client = self.client
        if _LINKS.get(client) is self:
            del _LINKS[client]
        if not client.transport.is_open:
            return
        try:
            if self.active and self.on_exit == Mode.BINARY:
                self.detach(send_bin=True, verify=False)
            elif not self.active and self.on_exit == Mode.ASCII:
                with client.lock:
                    self._enter(client)
        except TransportError:
            log.warning("could not restore %s mode on exit", self.on_exit.value)

    def _on_client_close(self) -> None:
        self.close()

    # -- another address ----------------------------------------------------------------
    @staticmethod
    def take_away(client: Client) -> AsciiLink | None:
        """The client turns to another address (``.address``): the link made for the module
        it leaves is that module's, so the next one gets a link of its own (or none)."""
        return _LINKS.pop(client, None)

    @staticmethod
    def put_back(client: Client, link: AsciiLink | None) -> None:
        """The other address did not come up: the client stays with this link's module."""
        if link is not None:
            _LINKS[client] = link

    def leave(self, address: int, *, in_ascii: bool) -> None:
        """The client talks to another module now: leave the one at ``address`` in the mode
        it was found in (``on_exit``) at once, as the client's close would have, since at
        exit the client's address is no longer its. ``in_ascii``: the link was driving it."""
        if self._closed:
            return
        self._closed = True
        client = self.client
        if self._on_client_close in client._lifecycle.close_hooks:
            client._lifecycle.close_hooks.remove(self._on_client_close)
        if not client.transport.is_open:
            return
        with client.lock:
            try:
                if in_ascii and self.on_exit == Mode.BINARY:
                    self._bin(client, address=address)
                elif not in_ascii and self.on_exit == Mode.ASCII:
                    self._enter(client, address)
            except TmclError:
                log.warning("could not restore %s mode at address %d", self.on_exit.value,
                            address)

    def let_go(self) -> None:
        """Stop using the link and leave the module in ASCII mode, where it was found (a
        scan looked at it and goes on to the next address)."""
        self.on_exit = Mode.ASCII
        self.close()  # (active and to stay in ASCII mode: nothing is sent)
        self.client.ascii_link = None
        self.framing.clear()

    # -- the request path ---------------------------------------------------------------

    # -- the line, under the client's lock (the framing's) ------------------------------
    @property
    def echo(self) -> Echo:
        return self.framing.echo

    @echo.setter
    def echo(self, value: Echo) -> None:
        self.framing.echo = value

    @property
    def gp67(self) -> int | None:
        return self.framing.gp67

    @gp67.setter
    def gp67(self, value: int | None) -> None:
        self.framing.gp67 = value

    def command(self, text: str, timeout: float | None = None, *, opcode: int = 0,
                address: int | None = None, request: Request | None = None,
                marker: bool = False) -> Reply:
        """One command line and its answer (``AsciiFraming.command``): ``"GAP 1, 0"``,
        ``"RUN"``; the address character is added."""
        with self.client.lock:
            return self.framing.command(text, timeout, opcode=opcode, address=address,
                                        request=request, marker=marker)

    def mark(self, timeout: float | None = None) -> Reply | None:
        with self.client.lock:
            return self.framing.mark(timeout)

    def absorb(self, *, watch: bool = False) -> None:
        with self.client.lock:
            self.framing.absorb(watch=watch)

    # -- ASCII-only commands ------------------------------------------------------------
    def run(self, timeout: float | None = None) -> Reply:
        """``RUN``: start the TMCL program stored in the module."""
        return self.control(Control.RUN_APPLICATION, timeout)

    def stop_program(self, timeout: float | None = None) -> Reply:
        """``STOP``: stop the running TMCL program."""
        return self.control(Control.STOP_APPLICATION, timeout)

    def control(self, opcode: int, timeout: float | None = None) -> Reply:
        """A control command by the line the module's ASCII mode has for it (the
        instruction set's ``ascii_word``: RUN for 129, STOP for 128; ``line_for``)."""
        req = Request(self.client.address, opcode, 0, 0, 0)
        word = line_for(req, self.client.module)
        reply = self.command(word, timeout, opcode=opcode, request=req)
        if not status_ok(reply.status):
            raise StatusError(reply.status, reply, f"{word}: module answered status "
                                                   f"{reply.status}: {reply.status_text}")
        return reply

    def refresh_echo(self) -> Echo:
        """Read GP 67 again (after it was changed) and adopt its echo mode."""
        reply = self.command(f"GGP {GP_ASCII_MODE}, {GP_BANK}", opcode=_GGP)
        if reply.status == Status.OK:
            self.gp67, self.echo = reply.value, echo_mode(reply.value)
        return self.echo

    # -- raw access, for the terminal ---------------------------------------------------
    def write_raw(self, data: bytes) -> None:
        with self.client.lock:
            self.framing.write_raw(data)

    def read_raw(self, timeout: float) -> bytes:
        """Whatever the module sent within ``timeout`` (holding the client's lock while
        waiting, so keep ``timeout`` short when other threads transact)."""
        with self.client.lock:
            return self.framing.read_raw(timeout)

    def describe(self) -> str:
        found = f"found in {self.found.value} mode"
        leave = "BIN at exit" if self.active and self.on_exit == Mode.BINARY else \
            f"left in {self.on_exit.value} mode at exit"
        return f"ASCII mode, {self.echo.text} ({found}; {leave})"


def leave_binary(client: Client) -> None:
    """Leave the module in binary mode when the client is done with it, if it is driven in
    its ASCII mode now (whoever switched it there is gone: a bridge's program)."""
    link = client.ascii_link
    if link is not None:
        link.on_exit = Mode.BINARY


# -- what the front ends of the mode ask (.mode, .ascii, .ascii-config) -------------------------

def drive(client: Client, *, tell: bool = True) -> tuple[AsciiLink, str | None]:
    """Drive ``client`` through the module's ASCII mode (``AsciiLink.attach``): the link,
    and what was done to the module for it, for the user (None: it was driven so already)."""
    link = client.ascii_link
    if link is not None:
        return link, None
    link = AsciiLink.attach(client, tell=tell)
    return link, ("module entered ASCII mode (command 139)" if link.entered
                  else "module was already in ASCII mode")


def switch(client: Client, want: str, *, keep: bool = False) -> None:
    """Drive ``client`` in the mode named ``want`` ("ascii" or "binary"; BIN is sent when it
    leaves ASCII mode). ``keep``: leave the module in that mode when the client closes."""
    mode = Mode(want)
    if mode == Mode.ASCII:
        AsciiLink.attach(client)
    elif client.ascii_link is not None:
        client.ascii_link.detach(send_bin=True)
    link = AsciiLink.for_client(client)
    if keep and link is not None:
        link.on_exit = mode


def mode_record(client: Client) -> dict[str, object]:
    """The mode as JSON fields: the mode in use and, once an ASCII link was made, its echo,
    the mode the module was found in and the one it is left in at exit."""
    obj: dict[str, object] = {"mode": client.mode}
    link = AsciiLink.for_client(client)
    if link is not None:
        obj.update(echo=link.echo.name.lower(), found=link.found.value,
                   on_exit=link.on_exit.value)
    return obj


def mode_text(client: Client) -> str:
    """The mode in words: the ASCII link's description, or binary and what happens at exit."""
    if client.ascii_link is not None:
        return client.ascii_link.describe()
    link = AsciiLink.for_client(client)
    if link is None or link.on_exit != Mode.ASCII:
        return "binary"
    return "binary" + (" (module was found in ASCII mode: 139 is sent at exit)"
                       if link.found == Mode.ASCII else
                       " (back to ASCII mode at exit, as chosen when leaving .ascii)")


def echo_written(client: Client) -> None:
    """GP 67 was written: a link driving the module now reads its echo mode again."""
    if client.ascii_link is not None:
        client.ascii_link.refresh_echo()
