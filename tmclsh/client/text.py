"""TMCL lines as text, on top of the client: ``client.value("GAP ActualPosition, 0")``.

The client (core.py) moves requests and replies and knows nothing of mnemonics or parameter
names; this layer parses and checks a line against the module's data (the assembler's
``encode``, where every check lives), keeps what it checked, and sends the request. The
shell, the Python API (``tmclsh.connect()`` returns a ``LineClient``) and the benchmarks use
it; everything below it works with ``Request`` objects.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

from ..base.errors import StatusError, ValidationError
from ..tmcl.frames import Reply, Request, status_ok
from ..tmcl.modules import Module
from .core import Client

if TYPE_CHECKING:  # the assembler is imported when a line is first encoded
    from ..tmcl import asm

ENCODE_CACHE = 512  # checked lines kept per client (prepare)
# A TMCL line that starts with this is sent with the value as typed, whatever the module data
# says of its range (``!SAP 140, 0, 12``): for a firmware that accepts what its manual's table
# does not list. Everything else is checked as usual; the module's answer decides.
AS_TYPED = "!"


class Result(NamedTuple):
    """A typed line and what the module answered (reply is None for 137). A named tuple: a
    script makes one a line, and a frozen dataclass costs several times as much to make."""

    line: str
    encoded: asm.Encoded
    reply: Reply | None
    # the answer may have been another request's, and reading again did not settle it (the
    # client judges an answer that may be a copy before returning it: Client._judge)
    in_doubt: bool = False

    @property
    def request(self):
        return self.encoded.instruction

    @property
    def ok(self) -> bool:
        return self.reply is None or self.reply.ok

    @property
    def value(self) -> int | None:
        return None if self.reply is None else self.reply.value


class LineClient(Client):
    """A client that also takes TMCL lines: ``prepare``, ``encode``, ``execute``, ``value``."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # checked lines: line -> (Encoded, Request), for (module, binary mode); see prepare()
        self._encoded: dict[str, tuple[asm.Encoded, Request]] = {}
        self._encoded_for: tuple[Module | None, bool] = (None, False)

    def encode(self, line: str) -> asm.Encoded:
        """Parse and check one TMCL line against the module (nothing is sent)."""
        return self.prepare(line)[0]

    def prepare(self, line: str) -> tuple[asm.Encoded, Request]:
        """The checked instruction of one TMCL line and its request to this address.

        A script or a watch repeats its lines: the result of a line that passed the checks is
        kept (ENCODE_CACHE lines, the oldest dropped first) for the module and mode it was
        checked against; another module or mode starts the cache afresh. Lines that fail are
        checked again every time. ``${...}`` is expanded by the shell before it gets here."""
        mod = self.module if self.module is not None else self.require_module()
        ascii_mode = self._ascii_link is not None  # (the attribute: every line asks)
        cache = self._encoded
        if mod is not self._encoded_for[0] or ascii_mode is not self._encoded_for[1]:
            cache.clear()
            self._encoded_for = (mod, ascii_mode)
        hit = cache.get(line)
        if hit is not None:
            enc, req = hit
            if req.address == self.address:
                return hit
        else:
            from ..tmcl import asmline as asm  # (one line's reading and encoding)

            if not isinstance(line, str):
                raise TypeError(f"a TMCL line is a str (\"GAP 1, 0\"), got {line!r}")
            as_typed = line.startswith(AS_TYPED)
            parsed = asm.parse_line(line[1:] if as_typed else line)
            if parsed.mnemonic is None:
                raise ValidationError(f"no command in {line!r}")
            enc = asm.encode(parsed, mod, direct=True, ascii=ascii_mode, as_typed=as_typed)
            if len(cache) >= ENCODE_CACHE:
                del cache[next(iter(cache))]
        ins = enc.instruction
        hit = (enc, Request.make(self.address, ins.opcode, ins.type, ins.motor, ins.value))
        if ascii_mode:
            # a typed line goes as typed: a raw 128, 129 or 135 is refused (with the word
            # the ASCII mode has for it), not sent as the line an operation's request is
            from ..link.ascii import format_request

            format_request(hit[1], mod)
        cache[line] = hit
        return hit

    def _send_encoded(self, enc: asm.Encoded, req: Request, *,
                     timeout: float | None = None) -> Reply | None:
        """Send a checked line's request; a write that moves the module (its address, CAN
        ids, baud rate: the data's ``reaches``) is followed to where it answers now."""
        p = enc.parameter
        if p is not None and p.reaches is not None and enc.spec is not None \
                and enc.spec.sets_parameter:
            from .reach import write

            return write(self, req, p, timeout)
        return self.request(req, timeout=timeout)

    def execute(self, line: str, *, check: bool = True, timeout: float | None = None) -> Result:
        """Parse, check, send one TMCL line (``"GAP 1, 0"``); StatusError on an error status.
        ``Result.in_doubt``: the answer may have been another request's (Client._judge could
        not settle it). It stays a suspect too (``take_suspects``, ``in_doubt``), for callers
        that ask there."""
        enc, req = self.prepare(line)
        reply = self._send_encoded(enc, req, timeout=timeout)
        doubt = reply is not None and self.doubt_on_last(take=False)
        if check and reply is not None and not status_ok(reply.status):
            raise StatusError(reply.status, reply)
        return Result(line, enc, reply, doubt)

    def value(self, line: str, *, timeout: float | None = None) -> int:
        """The reply value of one TMCL line: ``client.value("GAP ActualPosition, 0")``."""
        r = self.execute(line, timeout=timeout)
        if r.reply is None:
            raise ValidationError(f"{line!r} gets no reply, so it has no value")
        return r.reply.value
