"""The allowed range of every number a user can set, as one table.

The command line, the ``TMCLSH_*`` variables, config profiles and the shell's dot-commands
all check a value here, so a timeout that one of them takes is taken by all of them, and a
refusal reads the same wherever the value came from::

    --timeout: must be a number of seconds from 0.001 to 60, got 'nan'
    TMCLSH_TIMEOUT: must be a number of seconds from 0.001 to 60, got 'nan'
    config.toml [profiles.bench] timeout: must be a number of seconds from 0.001 to 60, got nan

The bounds are generous for real use and keep every value far from what Python, the OS or
the modules cannot represent (``time.sleep(1e300)``, a 20-digit baud rate). ``--help``, the
man page and ``default.toml`` state them from this table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .errors import UsageError

DAY = 86400.0
# the modules' RS485/RS232 baud rates (GP 65 codes 0..11 in all three manuals)
BAUD_RATES = (9600, 14400, 19200, 28800, 38400, 57600, 76800, 115200, 230400, 250000,
              500000, 1000000)
MAX_DIGITS = 40  # longest number literal taken from any text


class SettingError(UsageError):
    """A setting out of its range or of the wrong kind: a usage error (exit status 2)."""


@dataclass(frozen=True)
class Limit:
    kind: type  # int or float
    low: float
    high: float
    unit: str = ""  # "seconds" or ""
    choices: tuple[int, ...] = ()
    what: str = ""  # where it is set, for the man page

    def describe(self) -> str:
        """``a number of seconds from 0.001 to 60``, ``a whole number from 0 to 255``."""
        if self.choices:
            return "one of " + ", ".join(map(str, self.choices))
        what = "a whole number" if self.kind is int else "a number"
        if self.unit:
            what += f" of {self.unit}"
        return f"{what} from {_fmt(self.low)} to {_fmt(self.high)}"

    def short(self) -> str:
        """For --help: ``0.001..60 s``, ``0..255``."""
        if self.choices:
            return f"{self.choices[0]}..{self.choices[-1]}, a module baud rate"
        unit = " s" if self.unit == "seconds" else ""
        return f"{_fmt(self.low)}..{_fmt(self.high)}{unit}"


def _fmt(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


SECONDS = "seconds"
LIMITS: dict[str, Limit] = {
    # connection settings (command line, environment, profiles)
    "timeout": Limit(float, 0.001, 60.0, SECONDS,
                 what="reply timeout (--timeout, TMCLSH_TIMEOUT, timeout in a profile)"),
    "retries": Limit(int, 0, 10,
                 what="retries of idempotent commands (--retries, TMCLSH_RETRIES, retries)"),
    "baud": Limit(int, BAUD_RATES[0], BAUD_RATES[-1], choices=BAUD_RATES,
                 what="serial baud rate, one the modules' GP 65 offers (--baud, TMCLSH_BAUD, "
                     "baud)"),
    "address": Limit(int, 0, 255,
                 what="module address (-a, TMCLSH_ADDRESS, address)"),
    "host_address": Limit(int, 0, 255,
                 what="host address (--host-address, TMCLSH_HOST_ADDRESS, host_address)"),
    "can_id": Limit(int, 0, 2047,
                 what="module's CAN id (--can-id, TMCLSH_CAN_ID, can_id)"),
    "reply_id": Limit(int, 0, 2047,
                 what="module's CAN reply id (--reply-id, TMCLSH_REPLY_ID, reply_id)"),
    "bitrate": Limit(int, 10_000, 1_000_000,
                 what="CAN bit rate in bit/s (--bitrate, bitrate in a profile)"),
    # shell settings (config file [settings])
    "history_size": Limit(int, 0, 1_000_000,
                 what="lines of history kept (history_size in [settings])"),
    # subcommands
    "scan_timeout": Limit(float, 0.001, 60.0, SECONDS,
                 what="per-address timeout of scan (scan --timeout)"),
    "origin": Limit(int, 0, 65535,
                 what="program address (asm --at, disasm --at)"),
    # dot-commands
    "sleep": Limit(float, 0.0, DAY, SECONDS,
                 what="a pause (.sleep)"),
    "wait_timeout": Limit(float, 0.0, DAY, SECONDS,
                 what="how long .wait waits (.wait --timeout; none waits forever)"),
    "interval": Limit(float, 0.001, DAY, SECONDS,
                 what="polling interval of .wait (--interval)"),
    "watch_interval": Limit(float, 0.0, DAY, SECONDS,
                 what="time between samples of .watch (0: as fast as the link allows)"),
    "duration": Limit(float, 0.0, DAY, SECONDS,
                 what="other durations given to dot-commands"),
    "count": Limit(int, 1, 1_000_000,
                 what="counts of samples and lines (.watch --count, .history N)"),
    "repeat": Limit(int, 0, 1_000_000,
                 what="repetitions of a block (.repeat N)"),
    "plot_size": Limit(int, 1, 1000,
                 what="size of a plot in characters (.plot --width, --height)"),
}


def _number(text: str, kind: type) -> float | int | None:
    t = text.strip().replace("_", "")
    if not t or len(t) > MAX_DIGITS:
        return None
    try:
        if kind is int:
            return int(t[1:], 16) if t.startswith("$") else int(t, 0)  # $1F as in TMCL
        return float(t)
    except ValueError:
        return None


def check(key: str, value: object, where: str = "", shown: str | None = None) -> int | float:
    """``value`` if it is of the kind and within the range of setting ``key``, else a
    ``SettingError`` naming ``where`` (an option, variable or file and table)."""
    lim = LIMITS[key]
    prefix = f"{where}: " if where else ""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    if ok and lim.kind is int and isinstance(value, float):
        ok = value.is_integer() and math.isfinite(value)
        value = int(value) if ok else value
    if ok:
        ok = math.isfinite(value) and lim.low <= value <= lim.high  # type: ignore[arg-type]
        if ok and lim.choices:
            ok = value in lim.choices
    if not ok:
        got = repr(value) if shown is None else shown
        raise SettingError(f"{prefix}must be {lim.describe()}, got {got}")
    return float(value) if lim.kind is float else int(value)  # type: ignore[arg-type]


def parse(key: str, text: str, where: str = "") -> int | float:
    """A setting typed as text (option, variable, dot-command argument), checked."""
    lim = LIMITS[key]
    value = _number(str(text), lim.kind)
    shown = str(text).strip()
    shown = shown if len(shown) <= MAX_DIGITS else shown[:MAX_DIGITS] + "..."
    if value is None:
        prefix = f"{where}: " if where else ""
        raise SettingError(f"{prefix}must be {lim.describe()}, got {shown!r}")
    return check(key, value, where, repr(shown))


MAX_LIST = 256  # settings one list may name (``1-255`` is the widest useful one)


def parse_list(key: str, text: str, where: str = "") -> tuple[int, ...]:
    """Several values of the whole-number setting ``key`` typed at once: ``1,2,5``, a range
    ``1-8``, or both (``1-3,7``), in the order given; each checked as ``parse`` checks one.
    Duplicates are kept (the simulator serves two modules at one address so); whoever cannot
    use them says so."""
    prefix = f"{where}: " if where else ""
    values: list[int] = []
    for part in str(text).split(","):
        part = part.strip()
        if not part:
            raise SettingError(f"{prefix}an empty item in {str(text).strip()!r} (write 1,2,5 "
                               "or 1-8)")
        low, dash, high = part.partition("-")
        if dash and low.strip():  # (a leading '-' is a sign: parse refuses it with the range)
            first, last = int(parse(key, low, where)), int(parse(key, high, where))
            if first > last:
                raise SettingError(f"{prefix}the range {part!r} runs backwards; write "
                                   f"{last}-{first}")
            values.extend(range(first, last + 1))
        else:
            values.append(int(parse(key, part, where)))
        if len(values) > MAX_LIST:
            raise SettingError(f"{prefix}more than {MAX_LIST} values in {str(text).strip()!r}")
    return tuple(values)
