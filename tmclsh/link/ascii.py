"""The module's ASCII command line as a framing: what is sent for one request and how its
answer is read, behind the same interface as the serial and CAN framings (framing.py).

The wire format (TMCM-1311 manual §4.4, TMCM-351 manual §5.6):

* a command line is ``<address char> [spaces] <command as in the TMCL-IDE> <CR>``, the address
  character being ``A`` for address 1, ``B`` for 2, and so on (``chr(0x40 + address)``);
* the reply is ``<host char><module char> <status> <value> <CR>`` (``BA 100 -5000``), the host
  character coming from GP 76; it carries no opcode, so the parsed ``Reply`` takes the opcode of
  the request it answers and looks exactly like a binary one to the rest of tmclsh;
* GP 67 bit 0 makes the module start up in ASCII mode; bits 5/4 choose the echo: ``00`` every
  character as typed (backspace erases), ``01`` the whole line after the CR, ``10`` none.
  Whether the CR itself is echoed (and whether an LF follows a CR) is not documented, so
  nothing here depends on it: the echo of the line just sent is recognised by its text,
  whether it ends in CR, CRLF, or runs straight into the reply;
* only ROR ROL MST MVP SAP GAP STAP RSAP SGP GGP STGP RSGP RFS SIO GIO (SAC on the 351) SCO GCO
  CCO UF0..UF7 are accepted, plus the ASCII-only ``BIN`` (back to binary mode), ``RUN`` and
  ``STOP`` (start and stop the stored program). ``instructions.toml`` marks the first group
  (``ascii``) and the control commands' words (``ascii_word``).

Every binary module on the line hears the ASCII bytes too, and one that counts what it hears
in nines, with no receive timeout (the manuals describe none), would be left out of step by
any count that is not a multiple of nine: it would then answer nothing, not even at its own
address. So every run of ASCII bytes tmclsh sends is a whole number of nine-byte blocks, none
of them a valid frame: a command line gets spaces after its address character, which the
manuals allow (``command_bytes``), and the CR that ends a line of binary bytes is sent as
``END_LINE``, CR, seven spaces and CR (an empty, unaddressed line in ASCII mode).

``decode_line`` and ``classify_line`` are pure (bytes in, results out, no I/O), in the style
of the frame decoder (tmcl/decoder.py); ``AsciiFraming`` does the I/O for its owner, the
client, whose lock its caller holds. Recognising the mode and switching it (139, BIN) is the
client's (client/ascii.py).
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable, Iterator
from enum import Enum, IntEnum
from typing import TYPE_CHECKING, Any, Protocol

from ..base.errors import TmclTimeoutError, TransportError, ValidationError
from ..tmcl import instructions as isa
from ..tmcl.decoder import is_frame
from ..tmcl.frames import (INT32_MIN, SERIAL_FRAME_LEN, UINT32_MAX, Control, Reply, ReplyKind,
                           Request, Status, status_ok, to_signed32)
from .modes import ASCII

if TYPE_CHECKING:
    from ..tmcl.modules import Module
    from .base import StreamTransport

log = logging.getLogger(__name__)

CR = b"\r"
BS = b"\x08"
#: ends a line of binary bytes on a module in ASCII mode; a nine-byte block (CR, seven spaces:
#: an unaddressed line, CR) whose checksum is wrong, so binary modules stay in step
END_LINE = CR + b" " * 7 + CR
_EOL = b"\r\n"
# bytes the ASCII line discipline acts on: a binary probe frame must not contain them
_LINE_BYTES = frozenset(b"\r\n\x08\x7f")
# A reply that came before the echo of the line just sent is taken only if no echo follows
# within this time (then the module does not echo, whatever GP 67 said).
_ECHO_WAIT = 0.05

#: said once where ASCII mode is chosen (connect, .mode ascii, .ascii)

GP_ASCII_MODE = 67  # bank 0
GP_HOST_ADDRESS = 76  # bank 0
GP_BANK = 0
STARTUP_ASCII_BIT = 0
ECHO_SHIFT = 4
ECHO_MASK = 0b11 << ECHO_SHIFT
_GGP, _SGP = int(isa.Opcode.GGP), int(isa.Opcode.SGP)

MAX_ADDRESS = 0xFF - 0x40  # address characters are the bytes 0x41..0xFF
_ADDRESS_BASE = 0x40


class Echo(IntEnum):
    """GP 67 bits 5/4: how the module echoes what it is sent."""

    CHAR = 0  # 00: every character as it is typed (backspace erases)
    LINE = 1  # 01: the whole line after the CR
    NONE = 2  # 10: no echo, only the reply
    UNDOCUMENTED = 3  # 11: not in the manuals

    @property
    def text(self) -> str:
        return _ECHO_TEXT[self]


_ECHO_TEXT = {Echo.CHAR: "echo each character", Echo.LINE: "echo the whole line after CR",
              Echo.NONE: "no echo, reply only", Echo.UNDOCUMENTED: "echo bits 11 (undocumented)"}
ECHO_NAMES = {"char": Echo.CHAR, "line": Echo.LINE, "none": Echo.NONE}


class Mode(str, Enum):
    BINARY = "binary"
    ASCII = "ascii"


# -- GP 67 ---------------------------------------------------------------------------------

def echo_mode(gp67: int) -> Echo:
    return Echo((gp67 & ECHO_MASK) >> ECHO_SHIFT)


def starts_in_ascii(gp67: int) -> bool:
    return bool(gp67 >> STARTUP_ASCII_BIT & 1)


def gp67_value(current: int, *, startup: Mode | str | None = None,
               echo: Echo | str | None = None) -> int:
    """``current`` with the start-up bit and/or the echo bits replaced, other bits kept."""
    value = current
    if startup is not None:
        startup = Mode(startup)
        value = (value & ~(1 << STARTUP_ASCII_BIT)) | (
            (1 << STARTUP_ASCII_BIT) if startup == Mode.ASCII else 0)
    if echo is not None:
        if isinstance(echo, str):
            if echo.lower() not in ECHO_NAMES:
                raise ValidationError(f"echo must be one of {'|'.join(ECHO_NAMES)}, got {echo!r}")
            echo = ECHO_NAMES[echo.lower()]
        if echo == Echo.UNDOCUMENTED:
            raise ValidationError("echo bits 11 are undocumented; use char, line or none")
        value = (value & ~ECHO_MASK) | (int(echo) << ECHO_SHIFT)
    return value


def describe_gp67(value: int) -> str:
    """``start up in ASCII mode, echo each character``."""
    start = "start up in ASCII mode" if starts_in_ascii(value) else "start up in binary mode"
    return f"{start}, {echo_mode(value).text}"


# -- address characters ----------------------------------------------------------------------

def address_char(address: int) -> str:
    """``A`` for address 1, ``B`` for 2, ... (host address 0 is ``@``)."""
    if not isinstance(address, int) or not 0 <= address <= MAX_ADDRESS:
        raise ValidationError(f"address {address!r} has no ASCII address character "
                              f"(0..{MAX_ADDRESS}: '@', 'A' = 1, 'B' = 2, ...)")
    return chr(_ADDRESS_BASE + address)


def char_address(ch: str | int) -> int:
    """The address an address character stands for (``"C"`` -> 3)."""
    code = ord(ch) if isinstance(ch, str) else ch
    if not _ADDRESS_BASE <= code <= 0xFF:
        raise ValidationError(f"{chr(code)!r} is not an address character")
    return code - _ADDRESS_BASE


# -- requests as command lines ---------------------------------------------------------------

FIELDS = ("type", "motor", "value")


def ascii_commands(module: Module | None = None) -> list[str]:
    """The mnemonics the module accepts in ASCII mode, then BIN, RUN and STOP."""
    names = [s.mnemonic for s in isa.all_instructions()
             if s.ascii and (module is None or s.on(module))]
    return names + list(isa.ASCII_ONLY_COMMANDS)


def not_in_ascii(req: Request) -> ValidationError:
    spec = isa.by_opcode(req.opcode)
    if spec is not None:
        name = spec.mnemonic
    else:
        ctl = isa.control(req.opcode)
        name = f"command {req.opcode} ({ctl.name.lower().replace('_', ' ')})" if ctl \
            else f"command {req.opcode}"
    ctl = isa.control(req.opcode)
    word = ctl.ascii_word if ctl is not None else None
    hint = f"; in ASCII mode, {word} does it ({isa.ASCII_ONLY[word]})" if word else ""
    own = list(isa.ASCII_ONLY_COMMANDS)
    tmcl = [c for c in ascii_commands() if c not in own]
    # (the module's own lines are listed with what sends them: typed at the prompt, BIN, RUN
    # and STOP are not TMCL lines and would be refused in turn)
    sends = [isa.ASCII_ONLY_SENT_BY.get(w, w) for w in own]
    return ValidationError(f"{name} cannot be sent in ASCII mode (the module accepts only "
                           f"{', '.join(tmcl)}, and {', '.join(own[:-1])} and {own[-1]}, "
                           f"which {', '.join(sends[:-1])} and {sends[-1]} send){hint}; "
                           "switch to binary mode with .mode binary to send it")


def format_request(req: Request, module: Module | None = None) -> str:
    """The TMCL-IDE text of a request, for the module's ASCII command line: ``GAP 1, 0``,
    ``MVP ABS, 0, -5000``. Raises ValidationError for commands ASCII mode does not accept.

    Fields the command does not use are left out (the module ignores them anyway), and numbers
    are decimal, as the manuals write every ASCII example.
    """
    spec = isa.by_opcode(req.opcode)
    if spec is None or not spec.ascii:
        raise not_in_ascii(req)
    if module is not None and not spec.on(module):
        raise ValidationError(f"{spec.mnemonic} is not available on the {module.name}")
    dropped = [f for f in FIELDS if f not in spec.fields and getattr(req, f)]
    if dropped:
        log.debug("%s: don't-care field(s) %s not sent in ASCII mode", spec.mnemonic, dropped)
    parts = {"type": str(req.type), "motor": str(req.motor), "value": str(to_signed32(req.value))}
    if spec.type_kind == "symbolic":
        parts["type"] = spec.type_name(req.type, module) or parts["type"]
    ops = ", ".join(parts[f] for f in spec.fields)
    return f"{spec.mnemonic} {ops}" if ops else spec.mnemonic


def line_for(req: Request, module: Module | None = None) -> str:
    """The command line that does what ``req`` does, for the ASCII framing: a control
    command's word (``ascii_word``: RUN, STOP, for the types ``ascii_types`` names) or the
    line that asks the same (``ascii_line``: 135 is ``GGP 128, 0``), both from the
    instruction set; else the command's text (``format_request``, which refuses what the
    ASCII mode does not accept)."""
    ctl = isa.control(req.opcode) if isa.by_opcode(req.opcode) is None else None
    if ctl is not None and (module is None or ctl.on(module)):
        if ctl.ascii_word and (ctl.ascii_types is None or req.type in ctl.ascii_types):
            return ctl.ascii_word
        if ctl.ascii_line:
            return ctl.ascii_line
    return format_request(req, module)


def command_bytes(address: int, text: str) -> bytes:
    """The command line for ``text``, padded with spaces after the address character to a
    whole number of nine-byte blocks (``command_bytes(1, "GAP 1, 0") == b"A        GAP 1,
    0\\r"``, 18 bytes): a binary module on the same line that frames in nines stays in step
    (see the module docstring). Of the paddings that do, the first in which no nine bytes
    read as a valid frame is taken (the shortest if none: the text itself holds one)."""
    if any(c in text for c in "\r\n"):
        raise ValidationError("an ASCII command is one line")
    return padded(address_char(address).encode("latin-1") + text.encode("latin-1") + CR)


def padded(line: bytes) -> bytes:
    """A whole command line (address character first, CR last), typed or made, with spaces
    after its first character as ``command_bytes`` puts them: whole nine-byte blocks."""
    head, body = line[:1], line[1:]
    need = -len(line) % SERIAL_FRAME_LEN
    lines = [head + b" " * pad + body
             for pad in range(need, need + 4 * SERIAL_FRAME_LEN, SERIAL_FRAME_LEN)]
    return next((line for line in lines if not has_valid_frame(line)), lines[0])


# -- the reply parser (pure) -----------------------------------------------------------------

_REPLY = re.compile(rb"([\x40-\xff])([\x40-\xff]) *([0-9]{1,3})(?: +([-+]?[0-9]{1,10}))? *")


def parse_reply(line: bytes, opcode: int = 0) -> Reply | None:
    """One reply line without its CR (``b"BA 100 -5000"``) as a Reply, else None.

    The reply carries no opcode: ``opcode`` (the request's) is filled in. A value written as
    an unsigned 32-bit number is folded to the signed form binary replies use.
    """
    m = _REPLY.fullmatch(bytes(line))
    if m is None:
        return None
    value = int(m.group(4) or b"0")
    status = int(m.group(3))
    if not INT32_MIN <= value <= UINT32_MAX or status not in _STATUSES:
        # (a status no manual lists is a damaged line, not the module's word: an ASCII
        # reply has no checksum to tell, and '100' with a bit lost reads '000' or '108')
        return None
    return Reply(m.group(1)[0] - _ADDRESS_BASE, m.group(2)[0] - _ADDRESS_BASE,
                 status, opcode, to_signed32(value))


_STATUSES = frozenset(int(s) for s in Status)


_REPLY_START = re.compile(rb"[\x40-\xff][\x40-\xff] *[0-9]")  # how a reply line begins
_EOL_BYTES = frozenset(_EOL)
_REPLY_AT_END = re.compile(rb"[\x40-\xff][\x40-\xff] *[0-9]{1,3}(?: +[-+]?[0-9]{1,10})? *$")


def reply_part(line: bytes) -> bytes:
    """The reply at the end of a line (all of it, or what follows an echo that ran into it)."""
    m = _REPLY_AT_END.search(bytes(line))
    return bytes(line)[m.start():] if m is not None else bytes(line)


def next_line(buf: bytes | bytearray) -> tuple[int, bytes | None]:
    """Split the first line off a byte stream: ``(consumed, line)``.

    A line ends at CR or LF (an LF right after a CR belongs to it). ``(0, None)`` means no
    complete line yet.
    """
    for i, b in enumerate(buf):
        if b in _EOL:
            end = i + 1
            if b == 0x0D and end < len(buf) and buf[end] == 0x0A:
                end += 1
            return end, bytes(buf[:i])
    return 0, None


def take_lines(buf: bytearray) -> Iterator[tuple[bytes, bytes]]:
    """The whole non-empty lines of a receive buffer, each ``(raw, line)``, each taken off
    the buffer before it is given (a reader that stops early leaves the rest there)."""
    while True:
        used, text = next_line(buf)
        if text is None:
            return
        raw = bytes(buf[:used])
        del buf[:used]
        if text:
            yield raw, text


def decode_line(buf: bytes | bytearray, opcode: int = 0) -> tuple[int, Reply | None]:
    """Pure stream decoder for ASCII replies: ``(consumed, reply)``.

    ``(0, None)``: no complete line yet. ``consumed > 0`` with None: a line that is no reply
    (an echo, an empty line between CR and LF, noise) was consumed and should be dropped.
    """
    used, line = next_line(buf)
    if line is None:
        return 0, None
    return used, parse_reply(line, opcode)


def _norm(text: bytes) -> bytes:
    return bytes(text).replace(b" ", b"").replace(b"\t", b"").upper()


class LineKind(str, Enum):
    ECHO = "echo"  # the echo of the line just sent
    REPLY = "reply"
    OTHER = "other"  # anything else: noise, another module's traffic, a stray error


def echo_candidates(sent: bytes) -> list[bytes]:
    """What the echo of ``sent`` may look like: the whole line, or the line without its
    address character (the manuals do not say whether the address character is echoed)."""
    line = bytes(sent).rstrip(b"\r\n")
    out = [line]
    if len(line) > 1:
        out.append(line[1:].lstrip(b" "))
    return [c for c in out if c]


def classify_line(line: bytes, sent: bytes | None = None, opcode: int = 0
                  ) -> tuple[LineKind, Reply | None]:
    """What one received line (without CR) is, given the command line just ``sent``.

    An echo is recognised by its text (case and spaces ignored), so character echo, line echo
    and no echo all parse the same way; a character echo whose CR was not echoed runs straight
    into the reply (``AGAP 1, 0BA 100 -5000``), which is split here as well.
    """
    line = bytes(line)
    reply = parse_reply(line, opcode)
    if reply is not None:
        return LineKind.REPLY, reply
    if sent:
        norm = _norm(line)
        for echo in echo_candidates(sent):
            target = _norm(echo)
            if norm == target:
                return LineKind.ECHO, None
            if norm.startswith(target):
                # find where the echo ends in the raw line, then parse the rest
                for cut in range(len(target), len(line) + 1):  # (spaces may be left out)
                    if _norm(line[:cut]) == target:
                        rest = parse_reply(line[cut:].lstrip(b" "), opcode)
                        if rest is not None:
                            return LineKind.REPLY, rest
    return LineKind.OTHER, None


def reply_summary(reply: Reply) -> str:
    """``ok, value -5000`` / ``error 2: invalid command``."""
    if status_ok(reply.status):
        return f"{reply.status_text}, value {reply.value}"
    return f"error {reply.status}: {reply.status_text}"


# -- mode detection --------------------------------------------------------------------------

def probe_frame(address: int) -> bytes:
    """A binary 136 type 1 request whose bytes the ASCII line discipline ignores."""
    for value in range(256):
        raw = Request(address, Control.GET_VERSION, 1, 0, value).to_bytes()
        if not _LINE_BYTES.intersection(raw[1:]):
            return raw
    raise AssertionError("unreachable: some value avoids the four line-discipline bytes")


_PROBE_TEXTS = (f"GGP {GP_ASCII_MODE}, {GP_BANK}", f"GGP {GP_ASCII_MODE},{GP_BANK}",
                f"GGP  {GP_ASCII_MODE}, {GP_BANK}")


def ascii_probe_line(address: int) -> bytes:
    """The ASCII probe's command line, ``AGGP 67, 0`` + CR, spaced so that the line ending
    before it (``END_LINE``) and the line form no binary frame with a valid checksum (for a
    few addresses the plain spelling would)."""
    for text in _PROBE_TEXTS:
        line = command_bytes(address, text)
        if not has_valid_frame(END_LINE + line):
            return line
    raise AssertionError(f"no safe ASCII probe for address {address}")  # pragma: no cover


def ascii_probe_bytes(address: int) -> bytes:
    """Everything the ASCII probe sends: ``END_LINE`` ending whatever line is pending, then
    the line: whole nine-byte blocks (27 bytes)."""
    return END_LINE + ascii_probe_line(address)


def has_valid_frame(data: bytes) -> bool:
    """Whether any nine-byte window of ``data`` reads as a TMCL reply frame."""
    return any(is_frame(data[i:i + SERIAL_FRAME_LEN], data[i])
               for i in range(len(data) - SERIAL_FRAME_LEN + 1))




def read_quiet(t: StreamTransport, quiet: float, limit: float,
                stop: Callable[[bytes], bool] | None = None) -> bytes:
    """Read until nothing arrived for ``quiet`` seconds, ``limit`` passed, or ``stop(data)``."""
    data = bytearray(t.read_available())
    end = time.monotonic() + limit
    while not (stop is not None and stop(bytes(data))):
        left = end - time.monotonic()
        if left <= 0:
            break
        chunk = t.read(1, min(quiet, left))
        if not chunk:
            break
        data += chunk + t.read_available()
    return bytes(data)



def binary_answer(data: bytes, address: int, opcode: int) -> Reply | None:
    """The reply frame among ``data`` from ``address`` to ``opcode``, if one is there (every
    window is looked at: ASCII bytes around it need not make whole frames)."""
    for i in range(len(data) - SERIAL_FRAME_LEN + 1):
        window = data[i:i + SERIAL_FRAME_LEN]
        if window[1] == address and window[3] == opcode and is_frame(window, window[0]):
            return Reply.from_frame(window)
    return None



# -- the framing ---------------------------------------------------------------------------

class Owner(Protocol):
    """What the ASCII framing needs of the client it reads for (framing.Owner, and the
    ledger: an ASCII answer names no command, so which answer is which is kept with it)."""

    address: int
    host_address: int
    module: Module | None
    timeout: float
    ledger: Any
    stats: dict[str, int]
    tracing: bool

    def trace(self, direction: str, raw: bytes, decoded: object, *,
              request: Request | None = None) -> None: ...

    def late(self, address: int, opcode: int, reply: Reply | None) -> bool: ...

    def noise_unsolicited(self) -> None: ...


class AsciiFraming:
    """Requests as ASCII command lines, answers read off the module's line discipline.

    Made by the client when the module is driven in its ASCII mode (client/ascii.py) and
    dropped for the transport's binary framing when it leaves it. ``exchange`` is one line
    and its answer, with the line checks that make the answer certain on a line whose
    replies name no command: whatever waits before a line is late (the ledger crosses it
    off or makes suspects), an echo of the line sent is the sign that every earlier reply
    has come, and after an answer that did not come the line is brought back in step with
    a read whose answer is known (``_marker``). ``echo`` and ``gp67`` are what GP 67 said.
    ``stats`` may be shared with whoever keeps counting across framings.
    """

    mode = ASCII  # (Client.mode: the facts of the mode this framing talks)

    def __init__(self, transport: StreamTransport, owner: Owner, *, echo: Echo = Echo.CHAR,
                 gp67: int | None = None, stats: dict[str, int] | None = None):
        self.transport = transport
        self.owner = owner
        self.echo = echo
        self.gp67 = gp67
        self._buf = bytearray()
        self._dirty = False
        self.copy = False  # the last answer taken may be a copy (Ledger.may_be_a_copy)
        self._pending: dict[int, int] = {}  # markers' answers still to come, by their value
        self.stats = stats if stats is not None else {
            "sent": 0, "timeouts": 0, "dropped_lines": 0, "echo_lines": 0}

    def _line(self) -> StreamTransport:
        t = self.transport
        if not t.is_open:
            raise TransportError(f"{t.describe()} is not connected")
        return t

    # -- the framing interface (framing.SerialFraming's) --------------------------------
    def waiting(self) -> bool:
        return bool(self._buf) or bool(self.transport.pending())

    def clear(self) -> None:
        """Forget what is buffered and what was expected (the line changed mode)."""
        self._buf.clear()
        self._dirty = False
        self._pending.clear()

    def quiet_time(self) -> float:
        """(The end of a run is watched by ``absorb(watch=True)``, which waits for quiet.)"""
        return 0.05

    def exchange(self, req: Request, kind: ReplyKind, timeout: float,
                 absorb: bool = True) -> Reply:
        """``req`` as a command line (``format_request``), its answer parsed into the Reply a
        binary frame gives (opcode taken from the request), written in the ledger."""
        text = line_for(req, self.owner.module)
        if kind != ReplyKind.NORMAL:  # pragma: no cover - 134/136/137 not ASCII
            raise not_in_ascii(req)
        return self.command(text, timeout, opcode=req.opcode, address=req.address,
                            request=req)

    def refusal(self, req: Request) -> str | None:
        """Why ``req`` cannot go as a command line (None: it can), asked before a run of
        requests starts, so that nothing of it is sent."""
        try:
            line_for(req, self.owner.module)
        except ValidationError as exc:
            return str(exc)
        return None

    def absorb(self, timeout: float = 0.0, *, flushing: bool = False,
               watch: bool = False) -> bool:
        """Take in what waits on the line (nothing is sent): a reply among it is a late one,
        judged as before a request. ``watch``: first wait until the line has been quiet a
        moment (the end of a run: an answer displaced by the last one comes right behind
        it); ``timeout``: what comes within it, if nothing waits. False if nothing came."""
        t = self._line()
        if watch:
            data = read_quiet(t, 0.05, 0.5)
        elif timeout:
            data = read_quiet(t, timeout, timeout)
        else:
            data = t.read_available()
        self._buf += data
        self._take_in()
        return bool(data)

    def drain(self, hard_stop: float) -> None:
        t = self._line()
        self._buf += read_quiet(t, 0.03, hard_stop)
        self._take_in()

    # -- lines ------------------------------------------------------------------------
    def command(self, text: str, timeout: float | None = None, *, opcode: int = 0,
                address: int | None = None, request: Request | None = None,
                marker: bool = False) -> Reply:
        """Send one command line (``"GAP 1, 0"``, ``"RUN"``; the address character is added)
        and return the reply; echo is skipped, other modules' lines dropped. What waits on
        the line before it is sent cannot be its answer: a reply among it is a late one
        (the ledger crosses it off, or makes the answers it may have displaced suspects,
        as on the binary link); after an answer that never came, the line is first brought
        back in step (``_resync``). ``request``: the binary request the line stands for
        (told to sent-only tracers, written in the ledger); ``marker``: an in-step marker's
        line (its answer numbers no reply)."""
        client = self.owner
        timeout = client.timeout if timeout is None else timeout
        address = client.address if address is None else address
        line = command_bytes(address, text)
        req = request or Request(address, opcode, 0, 0, 0)
        ledger = client._ledger
        ledger.by_command = False  # (the ledger is this line's while the link is on)
        t = self._line()
        self._clean(t)
        if ledger.dirty(False):
            self._resync(t, address, timeout)
        t.write(line)
        self.stats["sent"] += 1
        client.stats["sent"] += 1
        if client._tracing:
            client._trace("tx", line, line.decode("latin-1").rstrip(), request=request)
        try:
            reply = self._await(t, line, opcode, address, timeout)
        except BaseException:
            self._dirty = True
            ledger.expect_late(req, ReplyKind.NORMAL)  # its answer may still come
            raise
        if marker:
            ledger.took_marker(req, reply)
            self.copy = False
        else:
            self.copy = ledger.may_be_a_copy(req, reply)
            ledger.took(req, reply, copy=self.copy)
            if self.copy:
                # whatever is still on its way (the answer behind the copy, more copies)
                # is taken in before the next line: resynchronise first, as after a
                # reply nothing waited for (it stays evidence against this answer)
                ledger.out_of_step = True
        return reply

    def mark(self, timeout: float | None = None) -> Reply | None:
        """The client's in-step marker on the ASCII line (``Client._judge``): a read whose
        answer is known (``_markers``). An answer displaced behind a copy comes before it and
        is taken in as late. None: no answer came."""
        client = self.owner
        timeout = client.timeout if timeout is None else timeout
        t = self._line()
        self._clean(t)
        try:
            return self._marker(t, client.address, timeout)
        except TmclTimeoutError:
            return None

    def _resync(self, t: StreamTransport, address: int, timeout: float) -> None:
        """An answer may still come that no request waits for (a timeout, an answer taken
        for another): a marker is asked (``_marker``) and everything up to its answer taken
        in as late replies; the module answers in order. Only then is the line in step
        again. (The binary link's marker, 136, does not exist in ASCII mode.)"""
        client = self.owner
        client.stats["resyncs"] += 1
        why = client._ledger.why_dirty()
        if client._tracing:
            client._trace("note", b"", f"checking the line with a read whose answer is known, "
                                      f"{why}")
        try:
            self._marker(t, address, timeout)
        except TmclTimeoutError as exc:
            raise TmclTimeoutError(client._lost_check(
                address, f"{why}, a value whose answer is known was read to be sure which "
                f"reply is which: {exc}")) from None
        client._checks_lost = 0
        client._ledger.forget()

    def _markers(self) -> list[tuple[str, Request, int]]:
        """The reads whose answers are known, as (line, request, value): GP 76 (the host
        address every reply names) and GP 67 (read at attach), when it differs. Two, so that
        one is asked whose answer cannot be a late answer of the other's (as the binary link
        alternates 136 type 1 and type 0)."""
        client = self.owner
        out = [(f"GGP {GP_HOST_ADDRESS}, {GP_BANK}",
                Request(client.address, _GGP, GP_HOST_ADDRESS, GP_BANK, 0), client.host_address)]
        if self.gp67 is not None and self.gp67 != client.host_address:
            out.append((f"GGP {GP_ASCII_MODE}, {GP_BANK}",
                        Request(client.address, _GGP, GP_ASCII_MODE, GP_BANK, 0), self.gp67))
        return out

    def _marker(self, t: StreamTransport, address: int, timeout: float) -> Reply:
        """Ask a marker and read up to its answer; replies before it are late (``_late``),
        an earlier marker's answer crossed off. The marker asked is one whose answer no
        earlier marker's late answer can be taken for, and, of those, one whose answer
        differs from the last one given (a copy of the marker's answer, taken for a read
        again, then cannot agree with it). When both may still be answered, the line is
        first given a moment; silence proves nothing (a slow line keeps its order), so the
        answers of that kind still to come are counted off before this one's, as the binary
        link counts its markers. TmclTimeoutError if it does not come (it is then
        outstanding)."""
        client, ledger, buf = self.owner, self.owner._ledger, self._buf
        markers = self._markers()
        pending = self._pending
        free = [m for m in markers if not pending.get(m[2])]
        if not free:
            self._buf += read_quiet(t, max(0.05, timeout), 4 * timeout)
            self._take_in()
            free = [m for m in markers if not pending.get(m[2])] or markers[:1]
        given = next((rep.value for r, rep in reversed(ledger.recent) if r is not None), None)
        text, req, value = next((m for m in free if m[2] != given), free[0])
        earlier = pending.get(value, 0)  # answers like this one's still to come, first
        again = 0  # the marker asked again, each time an answer was counted off as earlier
        line = command_bytes(address, text)

        def ask() -> float:
            t.write(line)
            self.stats["sent"] += 1
            client.stats["sent"] += 1
            if client._tracing:
                client._trace("tx", line, text, request=req)
            return time.monotonic() + timeout

        deadline = ask()
        while True:
            for raw, got in take_lines(buf):
                kind, reply = classify_line(got, line, _GGP)
                if kind == LineKind.ECHO:
                    continue
                if (kind == LineKind.REPLY and reply is not None and reply.module == address
                        and reply.host == client.host_address):
                    if reply.status == Status.OK and reply.value == value and not earlier:
                        if client._tracing:
                            client._trace("rx", raw, reply)
                        ledger.took_marker(req, reply)
                        # (the answers counted off may have been the markers' asked now,
                        # the earlier ones lost: as many may still come)
                        pending[value] = pending.get(value, 0) + again
                        return reply
                    self._late(raw, reply)  # (an earlier check's, crossed off)
                    if reply.status == Status.OK and reply.value == value:
                        # the earlier check's answer, or this one's with the earlier one
                        # lost: no wait tells them apart, so the marker is asked again,
                        # and its answer comes after both (waiting for this one's alone
                        # would wait for ever once the earlier answer was lost)
                        earlier -= 1
                        again += 1
                        deadline = ask()
                    continue
                self._drop(raw, "not a reply")
            left = deadline - time.monotonic()
            if left <= 0:
                break
            buf += t.read(1, left)
            buf += t.read_available()
        self.stats["timeouts"] += 1
        client.stats["timeouts"] += 1
        self._dirty = True
        # (earlier answers of its kind that did not come before it were lost: this one is
        # the one still to come, and the markers asked again)
        pending[value] = 1 + again
        raise TmclTimeoutError(f"no answer to {text!r} within {timeout:g} s")

    def _clean(self, t: StreamTransport) -> None:
        """Before a command: whatever is waiting is stale (after a timeout, wait for quiet);
        replies among it are late (``_late``), the rest dropped. A line half arrived is
        waited for a moment, so that its end is not taken for the next command's answer."""
        if self._dirty:
            self._buf += read_quiet(t, 0.03, max(0.2, self.owner.timeout))
            self._dirty = False
        else:
            self._buf += t.read_available()
        if not self._buf:
            return
        self._take_in()
        if self._buf:
            self._buf += read_quiet(t, 0.02, 0.2, stop=lambda d: bool(_EOL_BYTES & set(d)))
            self._take_in()
            if self._buf:
                self._drop(bytes(self._buf), "stale input")
                self._buf.clear()

    def _take_in(self) -> None:
        """The whole lines in the buffer, which no command waits for: replies are late,
        other lines dropped (one that is no reply, after an answer: a damaged reply, possibly
        the real answer to the last request). What is left is a line not ended yet."""
        client, buf = self.owner, self._buf
        for raw, text in take_lines(buf):
            kind, reply = classify_line(text)
            if kind == LineKind.REPLY and reply is not None:
                if reply.host == client.host_address and reply.module == client.address:
                    self._late(raw, reply)
                else:
                    self._drop(raw, "another module's reply")
                continue
            self._drop(raw, "stale input")
            if _REPLY_START.match(text):  # (an echo of an earlier line starts otherwise)
                client._noise_unsolicited()

    def _late(self, raw: bytes, reply: Reply) -> None:
        """A reply of this module that no command waits for: one the ledger expected (an
        answer that had timed out) is crossed off; otherwise it makes the answers it may have
        displaced suspects (Client._late, the binary link's rule)."""
        if reply.status == Status.OK and self._pending.get(reply.value):
            self._pending[reply.value] -= 1  # an earlier marker's late answer
            self._drop(raw, "late answer to an earlier check")
            self.owner._doubts.came_late(reply.module)
            return
        self._drop(raw, "late reply to an earlier command")
        self.owner._late(reply.module, reply.opcode, reply)

    def _await(self, t: StreamTransport, sent: bytes, opcode: int, address: int,
               timeout: float) -> Reply:
        """The reply to the line just ``sent``. An ASCII reply names no command, so a late
        reply to an earlier line looks like this one's; but a module that echoes sends the
        echo of this line after every earlier reply. So while an echo is expected, a reply
        that comes before it is held: if the echo follows, the reply was late (``_late``);
        if the line stays quiet (the module does not echo after all), it is taken."""
        client, buf = self.owner, self._buf
        deadline = time.monotonic() + timeout
        echoed = self.echo not in (Echo.CHAR, Echo.LINE)
        held: tuple[bytes, Reply] | None = None  # a reply that came before the echo
        held_until = 0.0
        while True:
            for raw, text in take_lines(buf):
                kind, reply = classify_line(text, sent, opcode)
                if kind == LineKind.ECHO:
                    self.stats["echo_lines"] += 1
                    if client._tracing:
                        client._trace("rx", raw, "echo")
                    echoed = True
                    if held is not None:
                        self._late(*held)  # (it came before the echo)
                        held = None
                    continue
                if kind == LineKind.REPLY and reply is not None:
                    if reply.host != client.host_address:
                        self._drop(raw, f"reply for host {reply.host} "
                                        f"({address_char(reply.host)})")
                        continue
                    if reply.module != address:
                        self._drop(raw, f"reply from address {reply.module}")
                        continue
                    if not echoed and parse_reply(text, opcode) is not None:
                        # (a reply the echo ran into is no candidate: it came after the echo)
                        if held is not None:
                            self._late(*held)
                        held, held_until = (raw, reply), time.monotonic() + _ECHO_WAIT
                        continue
                    if client._tracing:
                        client._trace("rx", raw, reply)
                    return reply
                self._drop(raw, "not a reply")
            now = time.monotonic()
            if held is not None and (now >= held_until or now >= deadline):
                if client._tracing:
                    client._trace("rx", held[0], held[1])
                return held[1]  # no echo followed: this module does not echo
            end = deadline if held is None else min(deadline, held_until)
            left = end - now
            if left <= 0:
                break
            buf += t.read(1, left)
            buf += t.read_available()
        self.stats["timeouts"] += 1
        client.stats["timeouts"] += 1
        # (the command as typed: the address character and the padding of the line, which
        # keeps modules that frame in nines in step, are the address said after it)
        said = sent.decode("latin-1").strip()[1:].strip()
        raise TmclTimeoutError(f"no ASCII reply to {said!r} from address {address} within "
                               f"{timeout:g} s")

    def _drop(self, raw: bytes, why: str) -> None:
        self.stats["dropped_lines"] += 1
        self.owner.stats["discarded"] += len(raw)
        if self.owner._tracing:
            self.owner._trace("drop", raw, why)

    # -- raw access, for the terminal ---------------------------------------------------
    def write_raw(self, data: bytes) -> None:
        self._line().write(bytes(data))
        if self.owner._tracing:
            self.owner._trace("tx", bytes(data), "terminal")

    def read_raw(self, timeout: float) -> bytes:
        """Whatever the module sent within ``timeout``."""
        t = self._line()
        data = bytes(self._buf)
        self._buf.clear()
        if not data:
            data = t.read(1, timeout)
        data += t.read_available()
        if data and self.owner._tracing:
            self.owner._trace("rx", data, "terminal")
        return data
