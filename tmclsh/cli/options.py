"""The command-line contract as an argparse parser, and the exit statuses.

``build_parser()`` is the single source of the command line: the entry point (``cli``) parses
with it, and the man page and shell completions (``docs``) are generated from it, so neither
can drift from the other. It imports nothing heavy.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

from .. import __version__
from ..base import limits
from ..base.canspec import FROM_PYTHON_CAN, LINK_DEFAULTS as _D


SUBCOMMANDS = ("asm", "disasm", "sim", "ports", "scan", "modules", "firmware", "replace",
               "monitor", "bridge", "replay")


def setting(key: str):
    """An argparse type that checks a value against ``limits.LIMITS[key]``, so an option
    takes exactly what the same setting takes from a variable or a profile."""
    def convert(text: str) -> int | float:
        try:
            return limits.parse(key, text)
        except limits.SettingError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    convert.__name__ = key  # argparse names it in "invalid <name> value"
    return convert


def _range(key: str) -> str:
    return limits.LIMITS[key].short()


_address = setting("address")
_baud = setting("baud")


def _faults(text: str) -> dict[str, float]:
    from ..sim.faults import parse_rates  # only when --faults is given

    try:
        return parse_rates(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _seed(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None


def id_list(key: str):
    """An argparse type for several values of setting ``key`` at once: ``1,2,5``, ranges
    ``1-8``, or both (``limits.parse_list``, each checked against ``limits.LIMITS[key]``)."""
    def convert(text: str) -> tuple[int, ...]:
        try:
            return limits.parse_list(key, text)
        except limits.SettingError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    convert.__name__ = f"{key} list"
    return convert


def _ops(text: str) -> list[int]:
    """``--op GAP,SAP,136``: mnemonics the instruction set knows, or command numbers."""
    from ..tmcl import instructions as isa

    out = []
    for word in (w.strip() for w in text.split(",")):
        spec = isa.by_mnemonic(word) if word else None
        if spec is not None:
            out.append(spec.opcode)
            continue
        try:
            number = int(word, 0)
        except ValueError:
            number = -1
        if not 0 <= number <= 255:
            raise argparse.ArgumentTypeError(
                f"{word!r} is no command: a mnemonic (GAP, SAP, MVP, ...) or a command "
                "number 0..255 (136)")
        out.append(number)
    return out


def _params(text: str) -> list[str | int]:
    """``--param ActualPosition,4``: parameter names (checked against the module data) or
    numbers."""
    from ..ops.filter import parameter_known

    out: list[str | int] = []
    for word in (w.strip() for w in text.split(",")):
        if word.isdigit():
            out.append(int(word))
        elif word and parameter_known(word):
            out.append(word)
        else:
            raise argparse.ArgumentTypeError(
                f"{word!r} is no parameter name of any module tmclsh has data for "
                "('tmclsh -c \".params\"' lists them); or give the number")
    return out


def _host_port(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"--tcp wants HOST:PORT (PORT 0..65535; 0: any free "
                                         f"port), got {text!r}")
    return host, int(port)


def _add_view(p: argparse.ArgumentParser) -> None:
    """What monitor and bridge show, and how long they run."""
    g = p.add_argument_group("what is shown")
    g.add_argument("-m", "--module", metavar="NAME", default=argparse.SUPPRESS,
                   help="module type for parameter names at every address (default: learnt "
                        "from each module's 136 answers in the traffic; numbers until then)")
    g.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                   help="one JSON object per frame (op, type, motor, value; status and "
                        "latency on replies), a summary object at the end")
    g.add_argument("--hex", action="store_true", help="also the bytes of every frame")
    table = g.add_mutually_exclusive_group()
    table.add_argument("--table", dest="table", action="store_true", default=None,
                       help="a live table per module at the bottom of the terminal (exchanges, "
                            "per second, errors by name, the slowest exchange, the last value "
                            "of each parameter) while the lines scroll above it (default: on "
                            "when stdout is a terminal, without --json)")
    table.add_argument("--no-table", dest="table", action="store_false",
                       help="only the lines, also on a terminal")
    g.add_argument("--address", type=id_list("can_id"), metavar="LIST",
                   help="only these module addresses or CAN ids (1,2,5 or 1-8)")
    g.add_argument("--op", type=_ops, metavar="LIST",
                   help="only these commands (GAP,SAP or numbers: 136)")
    g.add_argument("--param", type=_params, metavar="LIST",
                   help="only these parameters (ActualPosition, or numbers)")
    g.add_argument("--count", type=setting("count"), metavar="N",
                   help=f"stop after N lines or objects shown ({_range('count')})")
    g.add_argument("--duration", type=setting("duration"), metavar="S",
                   help="stop after S seconds (of the log's own time when reading a log)")
    g.add_argument("--timeout", type=setting("timeout"), metavar="S", default=argparse.SUPPRESS,
                   help="a request with no reply after S seconds is unanswered (default 1)")
    g.add_argument("-o", "--output", metavar="FILE",
                   help="also write every frame heard, as heard: a python-can log on CAN "
                        "(its format from the suffix: .asc, .blf, .trc, .log, .csv), hex "
                        "lines on serial; 'tmclsh monitor --log FILE' replays it")


def _baud_or_auto(text: str) -> int | str:
    return "auto" if text.strip().lower() == "auto" else _baud(text)


def _add_timeout(p: argparse.ArgumentParser) -> None:
    """A subcommand's own --timeout (left out of the namespace when not given, so the
    settings' and the profile's value stands)."""
    p.add_argument("--timeout", type=setting("timeout"), metavar="S", default=argparse.SUPPRESS,
                   help=f"reply timeout in seconds (default 1; {_range('timeout')})")


def add_connection(p: argparse.ArgumentParser, *, auto_baud: bool = False,
                   nested: bool = False) -> None:
    """The connection options; ``nested`` (a subcommand's copy): an option not given leaves
    what was given before the subcommand (``tmclsh --can scan``) instead of resetting it."""
    first = len(p._actions)
    g = p.add_argument_group("connection (default: the one attached Trinamic USB module; "
                             "else --sim at the prompt, exit 3 elsewhere)")
    x = g.add_mutually_exclusive_group()
    x.add_argument("--port", metavar="PORT", action="append",
                   help="serial device (/dev/ttyACM0, COM3) or pyserial URL (socket://, "
                        "rfc2217://, loop://, spy://, hwgrep://); give it again for more "
                        "modules, each on its own port (-c and -f run on every one)")
    x.add_argument("--can", metavar="IFACE:CHANNEL", nargs="?", const=FROM_PYTHON_CAN,
                   help="python-can bus, e.g. socketcan:can0 (Linux; vcan0 for a virtual bus "
                        "other programs can join), pcan:PCAN_USBBUS1, kvaser:0, "
                        "slcan:/dev/ttyACM0 or slcan:COM5; alone: the bus python-can's own "
                        "configuration names (~/can.conf, CAN_INTERFACE, CAN_CHANNEL, "
                        "CAN_BITRATE). python-can's virtual interface works inside one "
                        "process only, so it cannot reach a 'tmclsh sim'")
    # a bare --sim is "" here: the -m module, else a TMCM-1311 (client/connect.py decides)
    x.add_argument("--sim", metavar="MODULE", nargs="?", const="",
                   help="the built-in simulator, in process, of MODULE (default: the -m "
                        "module, else a TMCM-1311)")
    if auto_baud:
        g.add_argument("--baud", type=_baud_or_auto, metavar="N|auto",
                       help=f"baud rate (default {_D['baud']}, the factory setting); auto: each rate "
                            f"GP 65 can select, in turn ({_range('baud')})")
    else:
        g.add_argument("--baud", type=setting("baud"), metavar="N",
                       help=f"baud rate (default {_D['baud']}, the factory setting; {_range('baud')})")
    g.add_argument("--bitrate", type=setting("bitrate"), metavar="N",
                   help="CAN bit rate in bit/s; the modules' factory setting is 1000000 "
                        "(GP 69 = 8); without it the adapter's own default or configuration "
                        f"applies, which is often lower ({_range('bitrate')})")
    g.add_argument("--can-id", type=id_list("can_id"), metavar="N[,N...]",
                   help=f"module's CAN id (GP 71, default {_D['can_id']}; {_range('can_id')}); several "
                        "(1,2,5 or 1-8): a module at each on the bus")
    g.add_argument("--reply-id", type=id_list("reply_id"), metavar="N[,N...]",
                   help=f"module's CAN reply id (GP 70, default {_D['reply_id']}; {_range('reply_id')}); "
                        "several: one for each --can-id, in the same order")
    g.add_argument("--profile", metavar="NAME", help="connection profile from the config file")
    if not nested:  # (several modules at once: -c and -f, not a subcommand)
        g.add_argument("--all", action="store_true", dest="all_modules",
                       help="every Trinamic USB module attached, one unit each (-c, -f)")
    if nested:
        for action in p._actions[first:]:
            action.default = argparse.SUPPRESS


def add_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("options")
    g.add_argument("-m", "--module", metavar="NAME",
                   help="module type (default: detected with command 136; a type without data "
                        "runs in generic mode, numbers only; \"generic\" forces it)")
    g.add_argument("--module-file", metavar="PATH", action="append", dest="module_file",
                   help="a module data file of your own (same format as the built-in ones; "
                        "files in the config directory's modules/ are read too)")
    g.add_argument("-a", "--address", type=id_list("address"), metavar="N[,N...]",
                   help=f"module address (default {_D['address']}; {_range('address')}); several (1,2,5 or "
                        "1-8): a module at each on the line, one unit each (-c, -f)")
    g.add_argument("--host-address", type=_address, metavar="N",
                   help=f"host address (default {_D['host_address']}; {_range('host_address')})")
    g.add_argument("--ascii", action="store_true", default=None,
                   help="talk to the module through its ASCII mode instead of binary frames "
                        "(its replies carry no checksum: settings are read twice)")
    g.add_argument("--json", action="store_true", help="one JSON object per result on stdout")
    g.add_argument("--trace", action="store_true",
                   help="every frame in hex, decoded, on stderr (the connect's own too)")
    g.add_argument("--timeout", type=setting("timeout"), metavar="S",
                   help=f"reply timeout in seconds (default 1; {_range('timeout')})")
    g.add_argument("--retries", type=setting("retries"), metavar="N",
                   help=f"retries of idempotent commands (default 2; {_range('retries')})")
    g.add_argument("--keep-going", action="store_true", help="scripts: continue after an error")
    g.add_argument("--with-link", action="store_true",
                   help="-f of a configuration backup: write the module's link identity too "
                        "(address, baud rate, CAN, ASCII start-up; left alone otherwise)")
    g.add_argument("--log-dir", metavar="DIR",
                   help="several units: one transcript per unit in DIR (every frame sent and "
                        "answered and every line shown, with times)")
    g.add_argument("-y", "--yes", action="store_true",
                   help="do not ask before EEPROM writes, factory reset or program download")
    g.add_argument("--debug", action="store_true", help="show tracebacks instead of one-line errors")


def _columns() -> int:
    """The terminal's width as argparse reads it (``COLUMNS``, else the terminal on stdout,
    else 80), without importing shutil for it: 2 ms of every start, for help text that a
    run which is not asking for help never lays out."""
    try:
        columns = int(os.environ.get("COLUMNS", ""))
    except ValueError:
        columns = 0
    if columns <= 0:
        try:
            columns = os.get_terminal_size(sys.__stdout__.fileno()).columns
        except (AttributeError, ValueError, OSError):
            columns = 0
    return columns if columns > 0 else 80


class _Formatter(argparse.HelpFormatter):
    def __init__(self, prog: str, indent_increment: int = 2, max_help_position: int = 24,
                 width: int | None = None, **kw) -> None:
        super().__init__(prog, indent_increment, max_help_position,
                         _columns() - 2 if width is None else width, **kw)


class _Parser(argparse.ArgumentParser):
    """argparse's parser with ``_Formatter`` (its subcommands' parsers too: argparse makes
    them of the same class)."""

    def __init__(self, *args, formatter_class: type = _Formatter, **kw) -> None:
        super().__init__(*args, formatter_class=formatter_class, **kw)


class _WholeParserNeeded(Exception):
    """What the shell's parser cannot answer alone: help, an error (a subcommand's name is
    one to it), the man page or the completions."""


class _ShellParser(_Parser):
    """The parser without the subcommands' parsers (``build_parser(subcommands=False)``):
    whatever it would say, the whole parser says instead."""

    def print_help(self, file=None) -> None:
        raise _WholeParserNeeded

    def error(self, message: str):  # type: ignore[override]
        raise _WholeParserNeeded


def read_command_line(argv: Sequence[str]) -> tuple[argparse.ArgumentParser,
                                                    argparse.Namespace]:
    """The parser and what it read from ``argv``. A run of the shell (the prompt, ``-c``,
    ``-f``) is read without building the eleven subcommands' parsers, which are most of the
    parser's cost at every start; anything else (a subcommand, help, an error, ``--man``,
    ``--completions``) is read by the whole parser, so it says what it always said."""
    try:
        parser = build_parser(subcommands=False)
        args = parse_args(parser, argv)
        if not (args.man or args.completions):
            return parser, args
    except _WholeParserNeeded:
        pass
    parser = build_parser()
    return parser, parse_args(parser, argv)


def build_parser(subcommands: bool = True) -> argparse.ArgumentParser:
    """The command line; ``subcommands=False``: without the subcommands' own parsers (for
    ``read_command_line``, which turns to the whole one for anything that names one)."""
    p = (_Parser if subcommands else _ShellParser)(
        prog="tmclsh",
        description="Interactive shell for Trinamic TMCL modules (TMCM-1311, TMCM-351, TMCM-1640).",
        epilog="Subcommands: asm, disasm, sim, ports, scan, modules, firmware, replace, "
               "monitor, bridge, replay ('tmclsh SUBCOMMAND --help').")
    add_connection(p)
    add_options(p)
    run = p.add_mutually_exclusive_group()
    run.add_argument("-c", metavar="LINES", dest="command",
                     help="run shell lines (separated by ';' or newlines), print results, exit")
    run.add_argument("-f", metavar="SCRIPT", dest="script", help="replay a script file ('-' = stdin), exit")
    p.add_argument("--completions", metavar="SHELL", choices=("bash", "zsh", "fish"),
                   help="print the completion script for bash, zsh or fish")
    p.add_argument("--man", action="store_true",
                   help="show this manual as man shows it, plain text in a pipe (also "
                        "where 'man tmclsh' cannot find it: an editable install has none)")
    p.add_argument("--version", action="version", version=f"tmclsh {__version__}")
    sub = p.add_subparsers(dest="subcommand", metavar="SUBCOMMAND")
    if not subcommands:
        return p

    a = sub.add_parser("asm", help="assemble a TMCL program")
    a.add_argument("file", metavar="FILE")
    a.add_argument("-m", "--module", metavar="NAME", default="TMCM-1311", help="target module (default TMCM-1311)")
    a.add_argument("-o", "--output", metavar="OUT",
                   help="output file (default FILE with .bin, or .hex with --hex; \"-\" = stdout); "
                        "binary output is the TMCL-IDE image: 8-byte records (command, type, "
                        "motor, value MSB first, checksum = 8-bit sum of the seven)")
    a.add_argument("--hex", action="store_true",
                   help="hex text instead: one instruction per line, its 7 bytes in hex")
    a.add_argument("--at", type=setting("origin"), metavar="ADDR", default=0,
                   help=f"start address (default 0; {_range('origin')})")

    d = sub.add_parser("disasm", help="disassemble a TMCL-IDE binary image (.bin) or hex text")
    d.add_argument("file", metavar="FILE")
    d.add_argument("-m", "--module", metavar="NAME", default="TMCM-1311", help="module for symbolic names")
    d.add_argument("--at", type=setting("origin"), metavar="ADDR", default=0,
                   help=f"address of the first instruction (default 0; {_range('origin')})")

    s = sub.add_parser("sim", help="serve a simulated module on a pty, TCP or CAN")
    s.add_argument("-m", "--module", metavar="NAME", default="TMCM-1311",
                   help="module to simulate (default TMCM-1311; 'tmclsh modules' lists them)")
    s.add_argument("--address", type=id_list("address"), default=(_D["address"],),
                   metavar="N[,N...]",
                   help=f"module address (default {_D['address']}); several (1,2,3 or 1-3): a module at each "
                        "on one line, as on an RS485 bus (each answers its own address; an "
                        "address given twice answers twice); --pty and --tcp only")
    s.add_argument("--host-address", type=_address, default=_D["host_address"], metavar="N",
                   help=f"address its replies are sent to (default {_D['host_address']})")
    how = s.add_mutually_exclusive_group(required=True)
    how.add_argument("--pty", action="store_true",
                     help="serve on a pseudo-terminal (path on the first line; Linux and "
                          "macOS only: use --tcp on Windows)")
    how.add_argument("--tcp", metavar="HOST:PORT", help="serve on TCP, for socket:// URLs")
    how.add_argument("--can", metavar="IFACE:CHANNEL",
                     help="serve on a python-can bus, IFACE:CHANNEL as the client reads it "
                          "(socketcan:vcan0 to test on Linux; python-can's virtual interface "
                          "cannot be reached from another process)")
    s.add_argument("--bitrate", type=setting("bitrate"), metavar="N",
                   help=f"CAN bit rate in bit/s ({_range('bitrate')})")
    s.add_argument("--baud", type=_baud, metavar="N",
                   help="pace the line at this baud rate, as a real serial line is: every "
                        "byte, request or reply, takes 10 bits' time (default: no pacing; "
                        f"--pty and --tcp only; {_range('baud')})")
    s.add_argument("--faults", type=_faults, metavar="KIND=P,...",
                   help="misbehave at random: for each reply, the probability P (0..1) of each "
                        "fault: drop (not sent), corrupt (a bit flipped), truncate (half sent), "
                        "delay (held back 0.2..2 s), garbage (noise before it), dup (sent "
                        "twice), dup-late (a copy after the next request); e.g. "
                        "drop=0.1,corrupt=0.05,dup=0.05")
    s.add_argument("--faults-seed", type=_seed, metavar="N",
                   help="seed for --faults, so a run misbehaves the same way again")
    s.add_argument("--bootloader", action="store_true",
                   help="start in the module's bootloader with no valid firmware, as after a "
                        "firmware update that broke off (it answers at address 1; 'tmclsh "
                        "firmware FILE.hex' completes the update)")

    po = sub.add_parser("ports", help="list serial ports (Trinamic USB devices marked)")
    # SUPPRESS: `tmclsh --json ports` and `tmclsh ports --json` both work
    po.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                    help="one JSON object per port")

    mo = sub.add_parser("modules", help="known modules and where each comes from; "
                                        "'modules check FILE' validates a module file; "
                                        "'modules import pytrinamic NAME' writes one from "
                                        "PyTrinamic's tables")
    mo.add_argument("action", nargs="?", choices=("check", "import"), metavar="check|import",
                    help="check FILE: exit 0 if tmclsh can use it, else 1 naming the line; "
                         "import pytrinamic NAME (or --all): write a module file from the "
                         "installed PyTrinamic's class for NAME (TMCM1260): its motors and "
                         "parameter names and numbers")
    mo.add_argument("file", nargs="*", metavar="FILE|pytrinamic NAME",
                    help="the module file to check, or where to import from and what")
    mo.add_argument("--all", dest="import_all", action="store_true",
                    help="import: every module PyTrinamic has a class for (except those "
                         "tmclsh has built in)")
    mo.add_argument("-o", "--output", metavar="FILE",
                    help="import: write here instead of the config directory's modules/ "
                         "('-' = standard output; with --all a folder)")
    mo.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                    help="one JSON object per module")

    sc = sub.add_parser("scan", help="find modules on a bus (address, type, firmware)")
    add_connection(sc, auto_baud=True, nested=True)
    sc.add_argument("--from", dest="first", type=_address, default=1, metavar="N")
    sc.add_argument("--to", dest="last", type=_address, default=255, metavar="N")
    # (SUPPRESS: ``tmclsh --timeout S scan`` keeps the S given before the subcommand)
    sc.add_argument("--timeout", type=setting("scan_timeout"), metavar="S",
                    default=argparse.SUPPRESS,
                    help="per-address timeout (default: from the link, the wire time of a "
                         f"request and its reply at the baud rate plus a margin; "
                         f"{_range('scan_timeout')})")
    sc.add_argument("--ascii", action="store_true", default=argparse.SUPPRESS,
                    help="also look for modules in ASCII mode at every address that did not "
                         "answer in binary (without it, only when none did: the ASCII pass "
                         "takes as long as the first)")
    sc.add_argument("--save", metavar="INVENTORY", default=None,
                    help="write what answered as an inventory (TOML): each module's address "
                         "or CAN id, type, firmware and mode (a file that exists is not "
                         "replaced)")
    sc.add_argument("--expect", metavar="INVENTORY", default=None,
                    help="compare the line with an inventory and name every difference "
                         "(missing, extra, another type, other firmware, in its bootloader, "
                         "in ASCII mode, two modules at one address, settings that differ "
                         "from a backup): exit 0 match, 1 differences, 3 nothing answered")
    sc.add_argument("--json", action="store_true", default=argparse.SUPPRESS)

    fw = sub.add_parser("firmware", help="update the module's firmware over its TMCL "
                                         "bootloader; completes an update that broke off")
    fw.add_argument("file", metavar="FILE.hex",
                    help="the firmware image, an Intel HEX file as the vendor ships it")
    add_connection(fw, nested=True)
    fw.add_argument("-a", "--address", type=_address, metavar="N", default=argparse.SUPPRESS,
                    help=f"module address (default 1; {_range('address')}); a module in its "
                         "bootloader is also looked for at address 1, 115200 baud")
    _add_timeout(fw)
    fw.add_argument("--check", action="store_true",
                    help="say what would happen (module type and firmware now, image type and "
                         "version, whether it fits) and write nothing")
    fw.add_argument("-y", "--yes", action="store_true", default=argparse.SUPPRESS,
                    help="do not ask before erasing (needed where nobody can answer)")
    fw.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                    help="one JSON object per step, then the result")

    rp = sub.add_parser("replace", help="replace a module: the old one's firmware version, "
                                        "settings and stored program onto a new one, read "
                                        "back; the old module is only read")
    rp.add_argument("--from", dest="source", metavar="CONNECTION|BACKUP", required=True,
                    help="the old module: a serial port or pyserial URL, can:IFACE:CHANNEL, or "
                         "a backup file .save wrote (its .program.tmcl beside it, if named)")
    rp.add_argument("--to", dest="target", metavar="CONNECTION", required=True,
                    help="the new module: a serial port or pyserial URL, or can:IFACE:CHANNEL")
    rp.add_argument("--from-address", type=_address, metavar="N", default=1,
                    help=f"the old module's address (default 1; {_range('address')})")
    rp.add_argument("--to-address", type=_address, metavar="N", default=1,
                    help=f"the new module's address (default 1; {_range('address')})")
    rp.add_argument("--firmware", metavar="FILE.hex",
                    help="the image of the old module's firmware version (Intel HEX), written "
                         "when the new module runs another version; without it, the step "
                         "says which image is needed and stops")
    rp.add_argument("--with-link", action="store_true",
                    help="carry the old module's link identity too (address, baud rate, CAN "
                         "ids, ASCII start-up): the new module moves to the old one's place")
    rp.add_argument("--force", action="store_true",
                    help="replace a module of another type: settings carried by parameter "
                         "name where the units agree (as .restore --force), firmware left alone")
    rp.add_argument("--baud", type=setting("baud"), metavar="N", default=argparse.SUPPRESS,
                    help=f"baud rate of both serial links (default 9600; {_range('baud')})")
    _add_timeout(rp)
    rp.add_argument("-y", "--yes", action="store_true", default=argparse.SUPPRESS,
                    help="do not ask before writing to the new module (needed where nobody "
                         "can answer)")
    rp.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                    help="the report as one JSON object")

    mon = sub.add_parser("monitor", help="decode TMCL traffic tmclsh does not send: a CAN "
                                         "bus, a serial tap, a log file (sends nothing)")
    src = mon.add_argument_group("where to listen (one of)")
    where = src.add_mutually_exclusive_group(required=True)
    where.add_argument("--can", metavar="IFACE:CHANNEL", nargs="?", const=FROM_PYTHON_CAN,
                       default=argparse.SUPPRESS,
                       help="a python-can bus, as for the shell (alone: python-can's own "
                            "configuration); every frame on it")
    where.add_argument("--log", metavar="FILE",
                       help="a python-can log of any format it reads (.asc, .blf, .trc, .log, "
                            ".csv, .db, ...), or a serial capture written by -o")
    where.add_argument("--port", metavar="TAP", default=argparse.SUPPRESS,
                       help="a serial port that hears a bus (an RS485 adapter on the line): "
                            "the master's requests and the modules' replies")
    src.add_argument("--baud", type=setting("baud"), metavar="N", default=argparse.SUPPRESS,
                     help=f"the tap's baud rate (default {_D['baud']}; {_range('baud')})")
    src.add_argument("--bitrate", type=setting("bitrate"), metavar="N",
                     default=argparse.SUPPRESS, help=f"CAN bit rate ({_range('bitrate')})")
    src.add_argument("--can-id", type=id_list("can_id"), metavar="LIST",
                     help="CAN ids requests go to (GP 71; default 1, and ids learnt from "
                          "frames that answer each other)")
    src.add_argument("--reply-id", type=id_list("reply_id"), metavar="LIST",
                     help="CAN ids replies come on (GP 70; default 2, and learnt)")
    src.add_argument("--host-address", type=id_list("host_address"), metavar="LIST",
                     default=argparse.SUPPRESS,
                     help="serial host addresses replies go to (GP 76; default 2, and any "
                          "that answers a request)")
    _add_view(mon)

    rp = sub.add_parser("replay", help="send a captured session to a module again and "
                                       "report every reply that differs")
    rp.add_argument("capture", metavar="CAPTURE",
                    help="what was captured: a serial capture (monitor -o, bridge -o), a "
                         "python-can log (.asc, .blf, .trc, .log, .csv, ...), candump's "
                         "screen lines, or a --log-dir transcript")
    add_connection(rp, nested=True)
    _add_timeout(rp)
    rp.add_argument("--as-captured", action="store_true",
                    help="send each request at its time in the capture (default: each as "
                         "soon as the one before is answered)")
    rp.add_argument("-y", "--yes", action="store_true", default=argparse.SUPPRESS,
                    help="also send the commands that write, store or move (named first; "
                         "without it such a capture is refused, nothing sent)")
    rp.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                    help="one JSON object per difference, then the result")

    br = sub.add_parser("bridge", help="forward another program's frames to a module, "
                                       "decoding each")
    side = br.add_argument_group("where the other program connects (one of)")
    serve = side.add_mutually_exclusive_group(required=True)
    serve.add_argument("--pty", action="store_true",
                       help="a pseudo-terminal (its path is the first line on stdout; Linux "
                            "and macOS): for PyTrinamic and programs that open a device path")
    serve.add_argument("--tcp", type=_host_port, metavar="HOST:PORT",
                       help="a TCP port, for socket:// URLs (the endpoint is the first line)")
    mod = br.add_argument_group("the module (one of)")
    link = mod.add_mutually_exclusive_group(required=True)
    link.add_argument("--port", metavar="PORT", default=argparse.SUPPRESS,
                      help="the module's serial port or pyserial URL: bytes forwarded "
                           "unchanged")
    link.add_argument("--can", metavar="IFACE:CHANNEL", nargs="?", const=FROM_PYTHON_CAN,
                      default=argparse.SUPPRESS,
                      help="the module on a python-can bus: the program's serial frames go "
                           "to it as CAN frames, its replies come back as serial frames")
    mod.add_argument("--baud", type=setting("baud"), metavar="N", default=argparse.SUPPRESS,
                     help=f"the module's baud rate (default {_D['baud']}; {_range('baud')})")
    mod.add_argument("--bitrate", type=setting("bitrate"), metavar="N",
                     default=argparse.SUPPRESS, help=f"CAN bit rate ({_range('bitrate')})")
    mod.add_argument("--can-id", type=setting("can_id"), metavar="N", default=argparse.SUPPRESS,
                     help="CAN id every request goes to (default: each request's address)")
    mod.add_argument("--reply-id", type=setting("reply_id"), metavar="N",
                     default=argparse.SUPPRESS,
                     help=f"CAN id replies come on (GP 70, default {_D['reply_id']}; {_range('reply_id')})")
    mod.add_argument("--host-address", type=_address, metavar="N", default=argparse.SUPPRESS,
                     help="on CAN: the address byte of the serial replies (default 2)")
    _add_view(br)
    return p


def parse_args(parser: argparse.ArgumentParser, argv: Sequence[str]) -> argparse.Namespace:
    """``parser.parse_args``, except that an option whose value is optional (``--can``,
    ``--sim``) right before a subcommand's name takes no value: ``tmclsh --can scan`` scans
    python-can's configured bus (no CAN spec or module is called ``scan``)."""
    optional = {s: a.const for a in parser._actions if a.nargs == argparse.OPTIONAL
                for s in a.option_strings if a.const is not None}
    argv = list(argv)
    for i, word in enumerate(argv[:-1]):
        if word == "--":
            break
        if word in optional and argv[i + 1] in SUBCOMMANDS:
            argv[i] = f"{word}={optional[word]}"
    return parser.parse_args(argv)
