"""The module side of the TMCL ASCII interface: line editing, addressing, echo and replies.

The line discipline is pure: bytes in, echo bytes and finished command lines out. What a line
means is the simulator's business (it parses it with the shared ``asm`` line parser).

Decisions where the manuals (TMCM-1311 §4.4, TMCM-351 §5.6) are silent:

* A line is for this module when its first non-blank character is the module's address
  character (``A`` = 1, ``B`` = 2 ... i.e. ``chr(64 + address)``). Until that character has
  arrived nothing is echoed (the module cannot know the line is meant for it); lines for
  other modules are neither echoed nor answered.
* Lines end with CR; LF alone is accepted too, and the LF of CRLF is swallowed.
* Echo each character (GP 67 bits 5/4 = 00): every character of an addressed line is echoed
  as it arrives, including the address character and the terminating CR; backspace (0x08)
  or DEL (0x7F) erases the last character and echoes ``\\b \\b`` if that character had
  been echoed. Echo whole line (01): after the terminator the edited line is echoed, followed
  by CR. No echo (10, and the undocumented 11): only the reply is sent.
* Replies are ``<host char><module char> <status> <value>\\r``, the value as a signed
  decimal (as the binary value field carries it).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

CR, LF, BS, DEL = 0x0D, 0x0A, 0x08, 0x7F
ERASE = b"\b \b"
MAX_LINE = 1024


class Echo(IntEnum):
    EACH = 0
    LINE = 1
    NONE = 2


def echo_mode(gp67: int) -> Echo:
    """GP 67 bits 5 and 4."""
    if gp67 & 0x20:
        return Echo.NONE
    if gp67 & 0x10:
        return Echo.LINE
    return Echo.EACH


def address_char(address: int) -> int:
    return (64 + address) & 0xFF


def reply_line(host: int, module: int, status: int, value: int) -> bytes:
    return bytes((address_char(host), address_char(module))) + f" {status} {value}\r".encode()


@dataclass
class LineDiscipline:
    chars: list[tuple[int, bool]] = field(default_factory=list)  # (byte, echoed)
    after_cr: bool = False

    def clear(self) -> None:
        self.chars.clear()
        self.after_cr = False

    def _addressed(self, me: int) -> bool:
        for ch, _ in self.chars:
            if ch != 0x20:
                return ch == me
        return False

    def feed(self, byte: int, me: int, mode: Echo) -> tuple[bytes, str | None]:
        """One received byte -> (echo, finished line for this module without its address)."""
        if self.after_cr and byte == LF:
            self.after_cr = False
            return b"", None
        self.after_cr = False
        if byte in (CR, LF):
            self.after_cr = byte == CR
            raw = bytes(ch for ch, _ in self.chars)
            mine = self._addressed(me)
            self.chars.clear()
            if not mine:
                return b"", None
            echo = bytes((byte,)) if mode == Echo.EACH else raw + b"\r" if mode == Echo.LINE else b""
            body = raw.lstrip(b" ")[1:]
            return echo, body.decode("latin-1")
        if byte in (BS, DEL):
            if not self.chars:
                return b"", None
            _, echoed = self.chars.pop()
            return (ERASE if echoed else b""), None
        if len(self.chars) >= MAX_LINE:
            return b"", None
        self.chars.append((byte, False))
        echoed = mode == Echo.EACH and self._addressed(me)
        self.chars[-1] = (byte, echoed)
        return (bytes((byte,)) if echoed else b""), None
