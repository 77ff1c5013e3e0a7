"""The command-line contract as an argparse parser, and the exit statuses.

``build_parser()`` is the single source of the command line: the entry point (``cli``) parses
with it, and the man page and shell completions (``docs``) are generated from it, so neither
can drift from the other. It imports nothing heavy.
"""

from __future__ import annotations

import argparse

from . import __version__

SUBCOMMANDS = ("asm", "disasm", "sim", "ports", "scan")
EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_CONNECT = 0, 1, 2, 3


def _int(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def _address(text: str) -> int:
    n = _int(text)
    if not 0 <= n <= 255:
        raise argparse.ArgumentTypeError(f"address must be 0..255, got {n}")
    return n


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if v <= 0:
        raise argparse.ArgumentTypeError("must be positive")
    return v


def _baud_or_auto(text: str) -> int | str:
    return "auto" if text.strip().lower() == "auto" else _int(text)


def add_connection(p: argparse.ArgumentParser, *, auto_baud: bool = False) -> None:
    g = p.add_argument_group("connection (default: the one attached Trinamic USB module; "
                             "else --sim at the prompt, exit 3 elsewhere)")
    x = g.add_mutually_exclusive_group()
    x.add_argument("--port", metavar="PORT",
                   help="serial device or pyserial URL (socket://, rfc2217://, loop://, spy://, hwgrep://)")
    x.add_argument("--can", metavar="IFACE:CHANNEL",
                   help="python-can bus, e.g. socketcan:can0, pcan:PCAN_USBBUS1, virtual:bench")
    x.add_argument("--sim", metavar="MODULE", nargs="?", const="TMCM-1311",
                   help="the built-in simulator, in process (default module TMCM-1311)")
    if auto_baud:
        g.add_argument("--baud", type=_baud_or_auto, metavar="N|auto",
                       help="baud rate (default 9600, the factory setting); auto: each rate "
                            "GP 65 can select, in turn")
    else:
        g.add_argument("--baud", type=_int, metavar="N",
                       help="baud rate (default 9600, the factory setting)")
    g.add_argument("--can-id", type=_int, metavar="N", help="module's CAN id (GP 71, default 1)")
    g.add_argument("--reply-id", type=_int, metavar="N", help="module's CAN reply id (GP 70, default 2)")
    g.add_argument("--profile", metavar="NAME", help="connection profile from the config file")


def add_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("options")
    g.add_argument("-m", "--module", metavar="NAME", help="module type (default: detected with command 136)")
    g.add_argument("-a", "--address", type=_address, metavar="N", help="module address (default 1)")
    g.add_argument("--host-address", type=_address, metavar="N", help="host address (default 2)")
    g.add_argument("--ascii", action="store_true", default=None,
                   help="talk to the module through its ASCII mode instead of binary frames")
    g.add_argument("--json", action="store_true", help="one JSON object per result on stdout")
    g.add_argument("--trace", action="store_true", help="every frame in hex, decoded, on stderr")
    g.add_argument("--timeout", type=_positive, metavar="S", help="reply timeout in seconds (default 1)")
    g.add_argument("--retries", type=_int, metavar="N", help="retries of idempotent commands (default 2)")
    g.add_argument("--keep-going", action="store_true", help="scripts: continue after an error")
    g.add_argument("-y", "--yes", action="store_true",
                   help="do not ask before EEPROM writes, factory reset or program download")
    g.add_argument("--debug", action="store_true", help="show tracebacks instead of one-line errors")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="tmclsh",
        description="Interactive shell for Trinamic TMCL modules (TMCM-1311, TMCM-351, TMCM-1640).",
        epilog="Subcommands: asm, disasm, sim, ports, scan ('tmclsh SUBCOMMAND --help').")
    add_connection(p)
    add_options(p)
    run = p.add_mutually_exclusive_group()
    run.add_argument("-c", metavar="LINES", dest="command",
                     help="run shell lines (separated by ';' or newlines), print results, exit")
    run.add_argument("-f", metavar="SCRIPT", dest="script", help="replay a script file ('-' = stdin), exit")
    p.add_argument("--completions", metavar="SHELL", choices=("bash", "zsh", "fish"),
                   help="print the completion script for bash, zsh or fish")
    p.add_argument("--version", action="version", version=f"tmclsh {__version__}")
    sub = p.add_subparsers(dest="subcommand", metavar="SUBCOMMAND")

    a = sub.add_parser("asm", help="assemble a TMCL program")
    a.add_argument("file", metavar="FILE")
    a.add_argument("-m", "--module", metavar="NAME", default="TMCM-1311", help="target module (default TMCM-1311)")
    a.add_argument("-o", "--output", metavar="OUT", help="output file (default FILE with .bin, or .hex with --hex)")
    a.add_argument("--hex", action="store_true", help="hex text: one instruction per line, 7 bytes")
    a.add_argument("--at", type=_int, metavar="ADDR", default=0, help="start address (default 0)")

    d = sub.add_parser("disasm", help="disassemble a binary or hex image")
    d.add_argument("file", metavar="FILE")
    d.add_argument("-m", "--module", metavar="NAME", default="TMCM-1311", help="module for symbolic names")
    d.add_argument("--at", type=_int, metavar="ADDR", default=0, help="address of the first instruction")

    s = sub.add_parser("sim", help="serve a simulated module on a pty, TCP or CAN")
    s.add_argument("-m", "--module", metavar="NAME", default="TMCM-1311")
    s.add_argument("--address", type=_address, default=1, metavar="N", help="module address (default 1)")
    s.add_argument("--host-address", type=_address, default=2, metavar="N")
    how = s.add_mutually_exclusive_group(required=True)
    how.add_argument("--pty", action="store_true", help="serve on a pseudo-terminal (path on the first line)")
    how.add_argument("--tcp", metavar="HOST:PORT", help="serve on TCP, for socket:// URLs")
    how.add_argument("--can", metavar="IFACE:CHANNEL", help="serve on a python-can bus")

    sub.add_parser("ports", help="list serial ports (Trinamic USB devices marked)")

    sc = sub.add_parser("scan", help="find modules on a bus (address, type, firmware)")
    add_connection(sc, auto_baud=True)
    sc.add_argument("--from", dest="first", type=_address, default=1, metavar="N")
    sc.add_argument("--to", dest="last", type=_address, default=255, metavar="N")
    sc.add_argument("--timeout", type=_positive, metavar="S",
                    help="per-address timeout (default: from the link, the wire time of a "
                         "request and its reply at the baud rate plus a margin)")
    sc.add_argument("--json", action="store_true")
    return p
