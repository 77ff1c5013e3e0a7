"""What the ASCII terminal shows, kept pure: bytes in, display segments out (``LineView``: line
mode, replies decoded; ``RawView``: raw mode, as the module sends), and the painter that
writes segments in colour. Tested on canned byte sequences; ``terminal.py`` moves the bytes.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field

from ...client.ascii import (LineKind, address_char, ascii_commands, classify_line, next_line,
                             reply_part, reply_summary)
from ...tmcl.frames import Reply, status_ok


Segment = tuple[str, str]  # (style name from style.py or "", text)


# -- pure views ------------------------------------------------------------------------------

def printable(data: bytes) -> str:
    """Received bytes as text: printable ASCII as is, anything else as ``\\xNN``."""
    return "".join(chr(b) if 32 <= b < 127 or b == 9 else f"\\x{b:02x}" for b in data)


def reply_segments(line: bytes, reply: Reply) -> list[Segment]:
    """``BA 100 -5000`` + ``   ok, value -5000``, styled by status."""
    style = "tmcl.ok" if status_ok(reply.status) else "tmcl.error"
    return [("tmcl.value", printable(line)), ("", "   "), (style, reply_summary(reply))]


@dataclass
class Shown:
    """One line the line-mode terminal received: an echo (hidden), a reply or other text."""

    kind: LineKind
    line: bytes
    reply: Reply | None = None

    @property
    def segments(self) -> list[Segment]:
        if self.reply is not None:
            return reply_segments(self.line, self.reply)
        return [("", printable(self.line))]


@dataclass
class LineView:
    """Line mode: complete lines out; the echo of the line just sent is recognised and
    marked (whatever the echo mode and whether the CR is echoed)."""

    sent: bytes | None = None
    buf: bytearray = field(default_factory=bytearray)

    def expect(self, sent: bytes) -> None:
        self.sent = bytes(sent)

    def feed(self, data: bytes) -> list[Shown]:
        self.buf += data
        out = []
        while True:
            used, line = next_line(self.buf)
            if line is None:
                break
            del self.buf[:used]
            if not line:
                continue
            kind, reply = classify_line(line, self.sent)
            if kind == LineKind.REPLY and reply is not None:
                # show the reply alone even when it ran on from the echo
                out.append(Shown(kind, reply_part(line), reply))
                self.sent = None
            else:
                out.append(Shown(kind, line))
        return out

    def flush(self) -> list[Shown]:
        """What is left without a line end (shown when leaving)."""
        if not self.buf:
            return []
        line = bytes(self.buf)
        self.buf.clear()
        return [Shown(LineKind.OTHER, line)]


@dataclass
class RawView:
    """Raw mode: the module's bytes for the terminal as they arrive (CR and LF become a
    line break, backspace passes through), a decoded status after each reply line, and a
    line break of our own when the module echoed a line the user ended but not its CR (so
    the reply does not run on from the echo)."""

    line: bytearray = field(default_factory=bytearray)  # the current line, backspaces applied
    shown: int = 0  # characters on the current display line
    ended: bytes | None = None  # the line the user ended with Enter, until its echo is over
    last_cr: bool = False
    replies: int = 0  # reply lines seen (a file being sent waits for each)

    def user_enter(self, typed: bytes) -> None:
        """The user pressed Enter after typing ``typed`` (backspaces applied)."""
        self.ended = bytes(typed) if typed else None

    def local(self, data: bytes) -> list[Segment]:
        """Local echo of typed characters (``--echo``, for modules with echo off)."""
        out: list[Segment] = []
        for b in data:
            if b in (0x08, 0x7F):
                if self.shown:
                    self.shown -= 1
                    out.append(("", "\b \b"))
            elif b in (0x0D, 0x0A):
                if self.shown:
                    out.append(("", "\r\n"))
                    self.shown = 0
            else:
                self.shown += 1
                out.append(("tmcl.note", printable(bytes((b,)))))
        return out

    def _end_line(self) -> list[Segment]:
        out: list[Segment] = []
        kind, reply = classify_line(bytes(self.line))
        if reply is not None:
            self.replies += 1
            style = "tmcl.ok" if status_ok(reply.status) else "tmcl.error"
            out += [("", "   "), (style, reply_summary(reply))]
        out.append(("", "\r\n"))
        self.line.clear()
        self.shown = 0
        return out

    def feed(self, data: bytes) -> list[Segment]:
        out: list[Segment] = []
        for b in data:
            if self.ended is not None and self.line and b not in (0x0D, 0x0A) \
                    and bytes(self.line) == self.ended:
                self.ended = None
                out += self._end_line()  # the echo is complete and no CR came
            if b == 0x0A and self.last_cr:
                self.last_cr = False
                continue
            self.last_cr = b == 0x0D
            if b in (0x0D, 0x0A):
                self.ended = None
                out += self._end_line()
            elif b in (0x08, 0x7F):
                if self.line:
                    self.line.pop()
                self.shown = max(0, self.shown - 1)
                out.append(("", "\b"))
            elif 32 <= b < 127:
                self.line.append(b)
                self.shown += 1
                out.append(("", chr(b)))
            else:
                self.line.append(b)
                text = printable(bytes((b,)))
                self.shown += len(text)
                out.append(("tmcl.warn", text))
        return out


def with_address(text: str, address: int, module_commands: Iterable[str] = ()) -> str:
    """The line to send for what the user typed: ``GAP 1, 0`` -> ``AGAP 1, 0``; a line that
    already starts with an address character (``AGAP 1, 0``, ``C MST 0``) is kept."""
    text = text.strip()
    words = {w.upper() for w in (module_commands or ascii_commands())}
    m = re.match(r"([A-Za-z]+)", text)
    if m is None:
        return address_char(address) + text
    word = m.group(1).upper()
    if word in words:
        return address_char(address) + text
    if len(word) == 1 and text[1:].lstrip()[:1].isalpha():
        return text  # `A MST 0`: address character, spaces, command
    if word[1:] in words:
        return text  # `AMST 0`
    return address_char(address) + text


# -- rendering ---------------------------------------------------------------------------------

class Painter:
    """Style names to ANSI sequences (through the rich theme), or plain text."""

    def __init__(self, color: bool | None = None):
        from ..style import color_enabled

        self.color = (color_enabled() and sys.stdout.isatty()) if color is None else color
        self._console = None
        if self.color:
            from rich.console import Console

            from ..style import rich_theme

            self._console = Console(theme=rich_theme(), force_terminal=True,
                                    color_system="standard")

    def __call__(self, segments: Iterable[Segment]) -> str:
        out = []
        for style, text in segments:
            if style and self._console is not None and text.strip():
                from rich.color import ColorSystem

                st = self._console.get_style(style)
                out.append(st.render(text, color_system=ColorSystem.STANDARD))
            else:
                out.append(text)
        return "".join(out)
