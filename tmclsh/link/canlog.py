"""CAN log files and pasted log lines, read and written by python-can's own readers and
writers (``can.LogReader``, ``can.Logger``): Vector ``.asc`` and ``.blf``, PCAN ``.trc``,
candump ``.log``, ``.csv``, ``.db``, ``.mf4`` (with asammdf), compressed as ``.gz`` too, and
whatever format a python-can plugin adds. Nothing here parses a log format itself; only
candump's screen output (``can0  001   [7]  06 01 ...``), which no python-can reader takes,
is read by a pattern, for a line pasted into ``.decode``.

Like link/can.py, python-can is imported only when a log is opened.
"""

from __future__ import annotations

import io
import re
from collections.abc import Iterator
from pathlib import Path

from ..base.errors import ValidationError
from .base import CanFrame


def _suffix(path: str | Path) -> str:
    """The format's suffix (``.asc`` of ``x.asc.gz``)."""
    suffixes = [s.lower() for s in Path(path).suffixes]
    if len(suffixes) >= 2 and suffixes[-1] == ".gz":
        return suffixes[-2]
    return suffixes[-1] if suffixes else ""


def readable(path: str | Path) -> bool:
    """Is ``path`` named as a log format python-can reads (by its suffix)?"""
    from can.io.player import MESSAGE_READERS, _update_reader_plugins

    _update_reader_plugins()
    return _suffix(path) in MESSAGE_READERS


def read_log(path: str | Path) -> Iterator[CanFrame]:
    """Every frame of a python-can log file, in its order, with the log's timestamps."""
    import can

    from .can import frame_of

    try:
        reader = can.LogReader(str(path))
    except ValueError as exc:  # no reader for the suffix
        raise ValidationError(f"{path}: {exc}; python-can reads {_formats()}") from None
    except ImportError as exc:  # a format whose optional package is missing (.mf4)
        raise ValidationError(f"{path}: python-can needs another package for this "
                              f"format ({exc})") from None
    try:
        for msg in reader:
            yield frame_of(msg)
    except (ValueError, IndexError, KeyError, UnicodeDecodeError) as exc:
        raise ValidationError(f"{path}: python-can cannot read on ({exc})") from None
    finally:
        reader.stop()


def _formats() -> str:
    from can.io.player import MESSAGE_READERS

    return " ".join(sorted(MESSAGE_READERS))


class LogWriter:
    """Frames written to a python-can log file of the format its suffix names (one that
    python-can also reads back: ``monitor --log`` replays it)."""

    def __init__(self, path: str | Path):
        import can
        from can.io.logger import MESSAGE_WRITERS
        from can.io.player import MESSAGE_READERS

        suffix = _suffix(path)
        if suffix not in MESSAGE_WRITERS or suffix not in MESSAGE_READERS:
            both = " ".join(sorted(set(MESSAGE_WRITERS) & set(MESSAGE_READERS)))
            raise ValidationError(f"{path}: python-can writes and reads back CAN logs named "
                                  f"{both}; not {suffix or 'a name without a suffix'}")
        from .can import message_of

        self._can = can
        self._message = message_of
        try:
            self._logger = can.Logger(str(path))
        except ImportError as exc:
            raise ValidationError(f"{path}: python-can needs another package for this "
                                  f"format ({exc})") from None
        self.path = path

    def write(self, frame: CanFrame) -> None:
        self._logger.on_message_received(self._message(self._can, frame))

    def close(self) -> None:
        self._logger.stop()


# candump's screen output, with or without its timestamp: ``(1700000000.123456)  can0  001
# [7]  06 01 00 00 00 00 00`` (python-can reads candump -L files, not this)
_CANDUMP = re.compile(r"\s*(?:\((?P<t>\d+(?:\.\d*)?)\)\s*)?(?P<channel>[\w.-]+)\s+"
                      r"(?P<id>[0-9A-Fa-f]{1,8})\s+\[(?P<dlc>\d{1,2})\]"
                      r"(?P<data>(?:\s+[0-9A-Fa-f]{2})*)\s*")
_ASC_HEADER = "base hex  timestamps absolute\nno internal events logged\n"


def parse_line(text: str) -> CanFrame | None:
    """One CAN frame pasted as a log line: candump's screen output, a candump ``-L`` line
    (``(t) can0 001#0601...``) or a Vector ``.asc`` line (``0.0012 1 1 Rx d 7 06 01 ...``).
    None when it is none of these (hex bytes, say)."""
    m = _CANDUMP.fullmatch(text)
    if m is not None:
        data = bytes.fromhex(m.group("data").replace(" ", "").replace("\t", ""))
        if int(m.group("dlc")) != len(data):
            raise ValidationError(f"candump line says [{m.group('dlc')}] and carries "
                                  f"{len(data)} bytes: {text.strip()!r}")
        return CanFrame(float(m.group("t") or 0.0), int(m.group("id"), 16), data,
                        extended=len(m.group("id")) > 3)
    if "#" not in text and not re.match(r"\s*\d+\.\d+\s", text):
        return None
    import can

    from .can import frame_of

    readers = (lambda: can.io.CanutilsLogReader(io.StringIO(text.strip() + "\n")),
               lambda: can.io.ASCReader(io.StringIO(_ASC_HEADER + text.strip() + "\n")))
    for reader in readers:
        try:
            msgs = list(reader())
        except (ValueError, IndexError, KeyError):
            continue
        if len(msgs) == 1:
            return frame_of(msgs[0])
    return None
