"""The ``.ascii`` terminal's conveniences behind Ctrl-T, as tio and miniterm have them: local
echo, a hex view of what arrives, timestamps, a log file of the session, and sending a file
line by line. Also how the terminal recognises a typed ``BIN``.

Everything here is pure or plain file I/O (no terminal, no bus), so it is tested on its own;
terminal.py wires it to the keys and the link.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from ...link.ascii import address_char
from ...base.errors import ValidationError

MENU_KEY = 0x14  # Ctrl-T, as in tio and miniterm

# key after Ctrl-T: (what it does, in the menu's words)
MENU: dict[str, str] = {
    "e": "local echo on/off",
    "h": "hex view of what arrives on/off",
    "t": "timestamps on/off",
    "f": "log the session to a file (again: stop logging)",
    "u": "send a file, line by line",
    "?": "this menu",
}


_SHORT = {"e": "echo", "h": "hex", "t": "time", "f": "log", "u": "send file", "?": "help"}


def _switches(state: MenuState) -> dict[str, bool]:
    return {"e": state.local_echo, "h": state.hex_view, "t": state.timestamps,
            "f": state.log is not None}


def menu_hint(state: MenuState) -> str:
    """What Ctrl-T shows while it waits for the next key: one short line."""
    on = _switches(state)
    items = [f"{key} {word}" + (f" [{'on' if on[key] else 'off'}]" if key in on else "")
             for key, word in _SHORT.items()]
    return "Ctrl-T: " + " · ".join(items)


def menu_text(state: MenuState) -> list[str]:
    """The menu in full (Ctrl-T ?), a line per entry."""
    on = _switches(state)
    out = ["Ctrl-T, then:"]
    for key, what in MENU.items():
        mark = f" [{'on' if on[key] else 'off'}]" if key in on else ""
        out.append(f"  {key}  {what}{mark}")
    out.append("  Ctrl-T twice sends Ctrl-T to the module (--raw); Ctrl-] returns to the shell")
    return out


@dataclass
class MenuState:
    """The switches the menu toggles. ``log`` is the open log file, if any."""

    local_echo: bool = False
    hex_view: bool = False
    timestamps: bool = False
    log: SessionLog | None = None

    def toggle(self, key: str) -> str | None:
        """Flip the switch of ``key`` (e, h, t) and say what it is now; None for other keys."""
        name = {"e": "local_echo", "h": "hex_view", "t": "timestamps"}.get(key.lower())
        if name is None:
            return None
        value = not getattr(self, name)
        setattr(self, name, value)
        words = {"local_echo": "local echo", "hex_view": "hex view",
                 "timestamps": "timestamps"}[name]
        return f"{words} {'on' if value else 'off'}"


# -- what arrives, as hex ---------------------------------------------------------------------

HEX_PER_LINE = 16


def hex_lines(data: bytes) -> list[str]:
    """``42 41 20 31 30 30 0d  |BA 100.|``, 16 bytes a line."""
    out = []
    for i in range(0, len(data), HEX_PER_LINE):
        chunk = data[i:i + HEX_PER_LINE]
        text = "".join(chr(b) if 32 <= b < 127 else "." for b in chunk)
        out.append(f"{chunk.hex(' '):<{HEX_PER_LINE * 3 - 1}}  |{text}|")
    return out


# -- timestamps ----------------------------------------------------------------------------------

def timestamp(now: float | None = None) -> str:
    """``[14:03:07.250] `` (local time, milliseconds), as tio writes it."""
    now = time.time() if now is None else now
    return time.strftime("[%H:%M:%S", time.localtime(now)) + f".{int(now % 1 * 1000):03d}] "


@dataclass
class Stamper:
    """Follows text written in pieces and puts a timestamp at the start of each line when
    ``on``: a line is stamped when its first character arrives, not when the previous one
    ended. ``pieces`` keeps the stamps apart (they are styled on their own)."""

    at_line_start: bool = True
    clock: Callable[[], float] = time.time

    def pieces(self, text: str, on: bool = True) -> list[tuple[bool, str]]:
        """``[(is_stamp, text), ...]``."""
        out: list[tuple[bool, str]] = []
        for piece in re.split(r"(\r\n|\n|\r)", text):
            if not piece:
                continue
            if piece in ("\r\n", "\n", "\r"):
                out.append((False, piece))
                self.at_line_start = True
                continue
            if self.at_line_start and on:
                out.append((True, timestamp(self.clock())))
            self.at_line_start = False
            out.append((False, piece))
        return out

    def __call__(self, text: str, on: bool = True) -> str:
        return "".join(t for _, t in self.pieces(text, on))


# -- the log file ----------------------------------------------------------------------------------

_ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


@dataclass
class SessionLog:
    """The session as the user saw it, plain text (no colours), appended to ``path``."""

    path: Path
    file: TextIO = field(repr=False)

    @classmethod
    def open(cls, name: str) -> SessionLog:
        path = Path(name.strip()).expanduser()
        if not name.strip():
            raise ValidationError("no file name given; not logging")
        try:
            return cls(path, path.open("a", encoding="utf-8", newline=""))
        except OSError as exc:
            raise ValidationError(f"cannot log to {path}: {exc.strerror or exc}") from None

    def write(self, text: str) -> None:
        text = _ANSI.sub("", text).replace("\r\n", "\n").replace("\b \b", "")
        try:
            self.file.write(text)
            self.file.flush()
        except (OSError, ValueError):
            pass  # a full disk must not take the terminal down; the note said where it goes

    def close(self) -> None:
        try:
            self.file.close()
        except OSError:
            pass


# -- sending a file ----------------------------------------------------------------------------------

def file_lines(name: str) -> list[str]:
    """The lines of a file to send: blank lines and ``#``/``//`` comment lines left out."""
    path = Path(name.strip()).expanduser()
    if not name.strip():
        raise ValidationError("no file name given; nothing sent")
    from ...base import files

    if not path.exists():
        raise ValidationError(f"no such file: {path}")
    try:
        text = files.read_bytes(path, what="file").decode("utf-8", errors="replace")  # bounded
    except files.FileError as exc:
        raise ValidationError(str(exc)) from None
    out = []
    for line in text.splitlines():
        stripped = line.strip()
        if stripped and not stripped.startswith(("#", "//")):
            out.append(stripped)
    return out


# -- BIN typed by the user -------------------------------------------------------------------------

def is_bin(line: bytes | str, address: int) -> bool:
    """Whether ``line`` (as sent, address character included) is ``BIN`` for this module:
    after it the module talks binary frames, not ASCII."""
    text = line.decode("latin-1") if isinstance(line, bytes) else line
    m = re.fullmatch(r"\s*([A-Za-z])\s*BIN\s*", text, re.I)
    return m is not None and m.group(1).upper() == address_char(address).upper()


def is_quit(text: str) -> bool:
    """``.quit`` (or ``.exit``) typed in the terminal: back to the shell."""
    return text.strip().lower() in (".quit", ".exit", "quit", "exit")


def choose(key: str, keys: Iterable[str] = MENU) -> str | None:
    """The menu entry a key after Ctrl-T picks (case-insensitive), or None."""
    key = key.lower()
    return key if key in keys else None


def hex_hint(on: bool) -> str:
    return " (bytes as they arrive; replies are not decoded meanwhile)" if on else ""
