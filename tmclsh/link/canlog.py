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
import logging
import math
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..base.errors import ValidationError
from .base import CanFrame

MAX_DATA = 64  # data bytes of a CAN FD frame, the most any CAN frame carries


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
    """Every frame of a python-can log file, in its order, with the log's timestamps.

    The readers are python-can's, and a damaged log (cut, empty, bytes flipped) makes them
    fail in their own ways: struct, zlib and sqlite errors, a format error, a TypeError on a
    row without a time. Whatever they raise is one line naming the file and the frame it
    got to; what they allocate is bounded (``bounded_read``), since a log's sizes and
    compressed containers say how much they take."""
    import can

    from ..base.files import bounded_read
    from .can import frame_of

    with bounded_read(str(path), "CAN log"), _warnings() as warned:
        try:
            reader = can.LogReader(str(path))
        except ValueError as exc:  # no reader for the suffix
            raise ValidationError(f"{path}: {exc}; python-can reads {_formats()}") from None
        except ImportError as exc:  # a format whose optional package is missing (.mf4)
            raise ValidationError(f"{path}: python-can needs another package for this "
                                  f"format ({exc})") from None
        except MemoryError:
            raise
        except Exception as exc:  # a header python-can cannot read (an empty .blf)
            raise ValidationError(f"{path}: not a log python-can reads ({_why(exc)})") from None
        count = 0
        # (the loop a log's every frame takes: python-can's message read into a frame and
        # its plain cases checked inline; anything else goes through ``_checked``'s words)
        finite = math.isfinite
        make = tuple.__new__  # (CanFrame's own __new__ is a Python function: a call a frame)
        try:
            for msg in reader:
                t, arb, data = msg.timestamp, msg.arbitration_id, msg.data
                count += 1
                if type(t) is float and finite(t) and type(arb) is int \
                        and 0 <= arb < 0x20000000 and len(data) <= MAX_DATA:
                    yield make(CanFrame, (t, arb, bytes(data), msg.is_extended_id,
                                          msg.is_error_frame, msg.is_remote_frame))
                else:
                    yield _checked(frame_of(msg), path, count)
        except (ValidationError, MemoryError):  # (the bound says the memory's own line)
            raise
        except Exception as exc:  # the log's damage, in the reader's words
            raise ValidationError(f"{path}: frame {count + 1}: python-can cannot read on "
                                  f"({_why(exc)})") from None
        finally:
            try:
                reader.stop()
            except Exception:  # closing a damaged log; its error is said above
                pass
        if not count:
            said = f"; python-can: {_why(warned[0].getMessage())}" if warned else ""
            warned.clear()  # (said here, in the one line)
            raise ValidationError(f"{path}: no CAN frames in it (an empty log, or not the "
                                  f"{_suffix(path) or 'format'} its name says{said})")


@contextmanager
def _warnings() -> Iterator[list[logging.LogRecord]]:
    """python-can's warnings while it reads a log (a line it skips), held back: of a log
    that fails, the one error line is what is said (with the first warning when there were
    no frames); of one read to its end, they are shown as python-can would have."""
    held: list[logging.LogRecord] = []

    class Hold(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if len(held) < 100:
                held.append(record)

    logger = logging.getLogger("can")
    handler = Hold(logging.WARNING)
    logger.addHandler(handler)
    try:
        yield held
    except ValidationError:
        held.clear()  # the one line says where the log went wrong
        raise
    finally:
        logger.removeHandler(handler)
        if logger.hasHandlers():
            for record in held:
                logger.handle(record)
        elif logging.lastResort is not None:
            for record in held:
                logging.lastResort.handle(record)


def _checked(frame: CanFrame, path: str | Path, number: int) -> CanFrame:
    """A frame as a log gives it, refused when it is no frame a bus carries (a row of a
    damaged .db without a time, an id beyond 29 bits)."""
    t = frame.t
    if not isinstance(t, (int, float)) or not math.isfinite(t):
        raise ValidationError(f"{path}: frame {number}: its time is {_why_value(t)}, not "
                              "seconds")
    if not isinstance(frame.arbitration_id, int) or not 0 <= frame.arbitration_id < 2**29:
        raise ValidationError(f"{path}: frame {number}: its id is "
                              f"{_why_value(frame.arbitration_id)}, not one of 0..2**29-1")
    if len(frame.data) > MAX_DATA:
        raise ValidationError(f"{path}: frame {number}: {len(frame.data)} data bytes, more "
                              f"than the {MAX_DATA} of a CAN FD frame")
    return frame


def _why_value(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _why(exc: BaseException) -> str:
    """A reader's exception as a few words on one line."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 120 else text[:117] + "..."


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

    def flush(self) -> None:
        """What python-can's writer has put in its file's buffer, pushed to the disk (its
        own buffers, as a .blf's, stay with it)."""
        file = getattr(self._logger, "file", None)
        if file is not None:
            file.flush()

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
