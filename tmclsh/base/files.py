"""Reading and writing users' files safely: every read bounded, every write all-or-nothing.

A user may name any path: ``/dev/zero``, a FIFO, a directory, a full disk, a missing folder.
Reads go in bounded chunks and stop at a stated limit, so no input grows the process; a
write goes to a temporary file beside the target and replaces it only when complete, so a
failed write never leaves a half-written file where a good one was. Failures are
``FileError`` (a ``TmclError``) naming the path and the reason, never a bare ``OSError``.

    data = read_bytes(path, limit=MAX_FILE, what="image")
    lines = read_lines(path, what="script")            # <= MAX_LINES lines
    newest = read_tail(path, limit)                    # the last whole lines in limit bytes
    write_file(path, text)                             # all or nothing
    with atomic_writer(path) as fh:                    # streaming, replaced on close
        fh.write(...)
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from .errors import TmclError

MAX_FILE = 16 * 1024 * 1024  # bytes of any text or image a user names
MAX_LINES = 100_000  # lines of a script
MAX_LINE = 64 * 1024  # characters of one line (scripts, stdin)
# nesting of arrays, inline tables and dotted keys in a TOML file (config, module files):
# theirs is 3 at most; tomllib recurses per level and fails near 300
MAX_DEPTH = 16
MAX_DIGITS = 40  # digits of one number in a data file (Python refuses to read 4,300)
_CHUNK = 64 * 1024


class FileError(TmclError, OSError):
    """A user's file could not be read or written; the message names the path and why."""


def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError):
        return exc.strerror or str(exc)
    return str(exc)


def size_text(n: int) -> str:
    if n >= 1024 * 1024 and n % (1024 * 1024) == 0:
        return f"{n // (1024 * 1024)} MiB"
    if n >= 1024 and n % 1024 == 0:
        return f"{n // 1024} KiB"
    return f"{n} bytes"


# -- reading -----------------------------------------------------------------------------

def read_stream(fh: IO[bytes], limit: int, name: str, what: str = "file") -> bytes:
    """At most ``limit`` bytes from an open binary stream, in chunks; more is refused."""
    parts: list[bytes] = []
    total = 0
    while True:
        chunk = fh.read(min(_CHUNK, limit + 1 - total))
        if not chunk:
            return b"".join(parts)
        total += len(chunk)
        if total > limit:
            raise FileError(f"{name}: {what} larger than {size_text(limit)}; not read")
        parts.append(chunk)


def read_bytes(path: str | os.PathLike, limit: int = MAX_FILE, what: str = "file") -> bytes:
    """The bytes of ``path`` (``-`` is stdin), refused past ``limit``."""
    name = str(path)
    if name == "-":
        import sys

        return read_stream(sys.stdin.buffer, limit, "stdin", what)
    p = Path(path)
    try:
        if p.is_dir():
            raise FileError(f"cannot read {name}: it is a directory")
        with open(p, "rb") as fh:
            return read_stream(fh, limit, name, what)
    except (OSError, ValueError) as exc:
        raise _unreadable(name, exc) from None


def _unreadable(name: str, exc: OSError | ValueError) -> FileError:
    """The error for a file that could not be read (a ValueError: a NUL in the name)."""
    if isinstance(exc, FileError):
        return exc
    if isinstance(exc, FileNotFoundError):
        return FileError(f"cannot read {name}: no such file")
    return FileError(f"cannot read {name}: {_reason(exc)}")


def read_tail(path: str | os.PathLike, limit: int = MAX_FILE, what: str = "file") -> bytes:
    """The whole lines in the last ``limit`` bytes of the regular file ``path`` (all of it if
    shorter): the newest part of a log or a history. A line cut by the limit is dropped.
    Anything but a regular file (a FIFO, ``/dev/zero``, a directory) is a ``FileError``."""
    import stat

    name = str(path)
    try:
        if not stat.S_ISREG(os.stat(name).st_mode):
            raise FileError(f"cannot read {name}: the {what} is not a regular file")
        with open(name, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            if size <= limit:
                return fh.read(limit)
            fh.seek(size - limit - 1)  # the byte before: a newline there means a whole line
            data = fh.read(limit + 1)
    except (OSError, ValueError) as exc:
        raise _unreadable(name, exc) from None
    cut = data.find(b"\n")
    return data[cut + 1:] if cut >= 0 else b""


def decode(data: bytes, name: str, what: str = "file") -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise FileError(f"{name} is not a text file (not UTF-8)") from None


def read_text(path: str | os.PathLike, limit: int = MAX_FILE, what: str = "file") -> str:
    """A UTF-8 text file, refused past ``limit`` bytes."""
    return decode(read_bytes(path, limit, what), str(path), what)


def read_lines(path: str | os.PathLike, what: str = "script", max_lines: int = MAX_LINES,
               limit: int = MAX_FILE) -> list[str]:
    """The lines of a text file, refused past ``max_lines`` lines or ``limit`` bytes."""
    lines = read_text(path, limit, what).splitlines()
    if len(lines) > max_lines:
        raise FileError(f"{path}: {what} longer than {max_lines:,} lines; not run")
    return lines


def stream_lines(stream: Iterable[str], name: str = "stdin",
                 max_line: int = MAX_LINE) -> Iterator[str]:
    """Lines of a text stream as they arrive (``-f -``), each at most ``max_line`` long.

    Reads with ``readline(limit)`` when the stream has it, so an endless line (``/dev/zero``)
    is refused after ``max_line`` characters instead of filling the memory.
    """
    readline = getattr(stream, "readline", None)
    if readline is None:
        for no, line in enumerate(stream, 1):
            if len(line) > max_line:
                raise FileError(f"{name}:{no}: line longer than {max_line:,} characters")
            yield line.rstrip("\r\n")
        return
    no = 0
    while True:
        try:
            line = readline(max_line + 1)
        except UnicodeDecodeError:
            raise FileError(f"{name}:{no + 1}: not UTF-8 text") from None
        if not line:
            return
        no += 1
        if len(line) > max_line and not line.endswith("\n"):
            raise FileError(f"{name}:{no}: line longer than {max_line:,} characters")
        yield line.rstrip("\r\n")


def toml_limits(text: str) -> tuple[int, str] | None:
    """The first place a TOML text goes past what tmclsh reads, as ``(line, what)``, else
    None: looked for before tomllib parses it, because tomllib recurses once per level of
    nesting (a file nested 5,000 deep is a RecursionError) and turns a 5,000-digit number
    into a ValueError, neither of which says where. Strings and comments are skipped; the
    text need not be valid TOML (tomllib says what else is wrong)."""
    depth = dots = digits = 0
    line, i, n = 1, 0, len(text)
    while i < n:
        c = text[i]
        if c == "\n":
            line, dots, digits, i = line + 1, 0, 0, i + 1
            continue
        if c == "#":
            end = text.find("\n", i)
            i = n if end < 0 else end
            continue
        if c in "\"'":
            end = _string_end(text, i)
            line += text.count("\n", i, end)
            i, digits = end, 0
            continue
        if c in "0123456789_":
            digits += 1
            if digits > MAX_DIGITS:
                return line, f"a number longer than {MAX_DIGITS} digits"
        else:
            if c == "." and not digits:
                dots += 1  # a dotted key (a.b.c), not a decimal point
            elif c in "[{":
                depth += 1
            elif c in "]}":
                depth = max(0, depth - 1)
            digits = 0
            if depth > MAX_DEPTH or dots >= MAX_DEPTH:
                return line, f"values nested more than {MAX_DEPTH} deep"
        i += 1
    return None


def _string_end(text: str, i: int) -> int:
    """Where the TOML string starting at ``i`` ends (just past its closing quote; at the
    line end or the text's end for one never closed)."""
    quote = text[i]
    close = quote * 3 if text.startswith(quote * 3, i) else quote
    j = i + len(close)
    if quote == "'":
        end = text.find(close, j)
        if close == "'" and (end < 0 or "\n" in text[j:end]):
            end = text.find("\n", j)
            return len(text) if end < 0 else end
        return len(text) if end < 0 else end + len(close)
    n = len(text)
    while j < n:
        ch = text[j]
        if ch == "\\":
            j += 2
        elif ch == "\n" and close == '"':
            return j
        elif text.startswith(close, j):
            return j + len(close)
        else:
            j += 1
    return n


MAX_READ_MEMORY = 512 * 1024 * 1024  # bytes a reader of a user's file may grow the process
SIGNAL_GRACE = 0.5  # s a SIGTERM/SIGHUP waits for its handler during a read, then ends it


@contextmanager
def bounded_read(name: str, what: str = "file",
                 limit: int = MAX_READ_MEMORY) -> Iterator[None]:
    """Reading ``name`` inside this block grows the process by ``limit`` bytes at most, and
    a SIGTERM or SIGHUP ends it within ``SIGNAL_GRACE`` seconds.

    For readers that are not ours (python-can's log readers, tomllib, intelhex): a damaged
    or hostile file can claim a 4 GiB record or hold a container that inflates a
    thousandfold, and they allocate what it says; past the limit that is a ``FileError``
    instead of the machine's memory. A signal's Python handler runs only between bytecodes,
    so one long step in C (inflating that container) would hold it off: the watchdog hears
    the signal at once (``signal.set_wakeup_fd``) and, if the read is still going after the
    grace, ends the process with the signal's exit status."""
    with _prompt_signals(name), _memory_bound(name, what, limit):
        yield


@contextmanager
def _memory_bound(name: str, what: str, limit: int) -> Iterator[None]:
    """The address-space limit is the process's: set and put back by the main thread only,
    so two threads' reads never put back each other's."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield  # (and nothing imported: a stop may be raised in a unit's thread, ops/units.py)
        return
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        resource = None
    if resource is None:
        yield
        return
    restore: tuple[int, int] | None = None
    try:
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        want = _address_space() + limit
        if hard != resource.RLIM_INFINITY:
            want = min(want, hard)
        if soft == resource.RLIM_INFINITY or soft > want:
            resource.setrlimit(resource.RLIMIT_AS, (want, hard))
            restore = (soft, hard)
    except (OSError, ValueError):
        pass
    try:
        yield
    except MemoryError:
        raise FileError(f"{name}: reading the {what} needs more than {size_text(limit)} "
                        "of memory (a damaged or hostile file?); not read on") from None
    finally:
        if restore is not None:
            try:
                resource.setrlimit(resource.RLIMIT_AS, restore)
            except (OSError, ValueError):
                pass


@contextmanager
def _prompt_signals(name: str) -> Iterator[None]:
    """SIGTERM/SIGHUP during the block: the handler's way if it comes within the grace,
    else ``os._exit(128 + signal)``. Only in the main thread, and only where nothing else
    (an asyncio loop) listens on the wake-up fd already."""
    import signal
    import threading

    try:
        reader, writer = os.pipe()
    except OSError:
        yield
        return
    os.set_blocking(writer, False)
    try:
        previous = signal.set_wakeup_fd(writer, warn_on_full_buffer=False)
    except (ValueError, OSError):  # not the main thread
        previous = None
    if previous is None or previous != -1:
        if previous is not None:
            signal.set_wakeup_fd(previous)
        os.close(reader)
        os.close(writer)
        yield
        return
    done = threading.Event()
    ends = {getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n)}

    def watch() -> None:
        try:
            while True:
                got = os.read(reader, 64)
                if not got:  # the block is over: its end closed the writer
                    return
                signum = next((n for n in got if n in ends), None)
                if signum is not None and not done.wait(SIGNAL_GRACE):
                    os.write(2, f"tmclsh: {name}: ended by signal {signum} while reading "
                             "it\n".encode(errors="replace"))
                    os._exit(128 + signum)
        except OSError:
            return
        finally:  # closed here, never under a read: its number may be reused at once
            os.close(reader)

    threading.Thread(target=watch, name="signal-watch", daemon=True).start()
    try:
        yield
    finally:
        done.set()
        signal.set_wakeup_fd(-1)
        os.close(writer)  # the watcher's read ends, and it closes the reader


def _address_space() -> int:
    """The process's address space now, in bytes (/proc; a guess where there is none)."""
    try:
        with open("/proc/self/statm", "rb") as fh:
            return int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 4 * 1024 * 1024 * 1024


# -- writing -----------------------------------------------------------------------------

class AtomicWriter:
    """A file written beside ``path`` and moved over it by ``commit()``; ``abort()`` (or an
    exception in a ``with`` block) removes it and leaves ``path`` as it was.

    Every failure (cannot create, disk full, cannot rename) is a ``FileError`` naming
    ``path``. Text mode unless ``binary``; ``newline`` as for ``open``.
    """

    def __init__(self, path: str | os.PathLike, *, binary: bool = False,
                 encoding: str = "utf-8", newline: str | None = None):
        self.path = Path(path)
        self.binary = binary
        self.closed = False
        target = self.path
        self.direct = False  # a device or pipe (/dev/null, a FIFO) is written as it is
        try:
            if target.is_dir():
                raise IsADirectoryError(21, "it is a directory")
            if target.exists() and not target.is_file():
                self.direct = True
                fd = os.open(target, os.O_WRONLY)
                tmp = str(target)
            else:
                import tempfile  # (with shutil and random: 4 ms of a start that writes nothing)

                fd, tmp = tempfile.mkstemp(dir=target.parent if str(target.parent) else ".",
                                           prefix=f".{target.name}.", suffix=".tmp")
        except (OSError, ValueError) as exc:
            raise self._error(exc) from None
        self.tmp = Path(tmp)
        try:
            if binary:
                self.fh: IO[Any] = os.fdopen(fd, "wb")
            else:
                self.fh = os.fdopen(fd, "w", encoding=encoding, newline=newline)
        except OSError as exc:
            os.close(fd)
            self._remove()
            raise self._error(exc) from None

    def _error(self, exc: BaseException) -> FileError:
        folder = self.path.parent
        if isinstance(exc, FileNotFoundError) and not folder.exists():
            return FileError(f"cannot write {self.path}: no such folder {folder}")
        return FileError(f"cannot write {self.path}: {_reason(exc)}")

    def _remove(self) -> None:
        if self.direct:
            return
        try:
            self.tmp.unlink()
        except OSError:
            pass

    def write(self, data: Any) -> None:
        try:
            self.fh.write(data)
        except (OSError, ValueError) as exc:
            self.abort()
            raise self._error(exc) from None

    def flush(self) -> None:
        """Push what is written to the temporary file (so a full disk shows now)."""
        try:
            self.fh.flush()
        except (OSError, ValueError) as exc:
            self.abort()
            raise self._error(exc) from None

    def commit(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self.fh.flush()
            if self.direct:
                self.fh.close()
                return
            os.fsync(self.fh.fileno())
            self.fh.close()
            try:  # keep the mode of the file being replaced
                os.chmod(self.tmp, self.path.stat().st_mode & 0o7777)
            except OSError:
                os.chmod(self.tmp, 0o666 & ~_umask())
            os.replace(self.tmp, self.path)
        except (OSError, ValueError) as exc:
            self._discard()
            raise self._error(exc) from None

    def abort(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._discard()

    def _discard(self) -> None:
        """Close without caring how, and remove the temporary file: the target stays as it was."""
        try:
            self.fh.close()
        except (OSError, ValueError):
            pass
        self._remove()

    def __enter__(self) -> AtomicWriter:
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if kind is None:
            self.commit()
        else:
            self.abort()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_writer(path: str | os.PathLike, *, binary: bool = False,
                  newline: str | None = None) -> AtomicWriter:
    return AtomicWriter(path, binary=binary, newline=newline)


def write_file(path: str | os.PathLike, data: str | bytes) -> None:
    """Write all of ``data`` to ``path`` or nothing (``FileError`` with path and reason)."""
    with AtomicWriter(path, binary=isinstance(data, bytes)) as fh:
        fh.write(data)
