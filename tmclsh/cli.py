"""The command line: argument parsing and the entry point.

The parser is the single source of the command-line contract (DESIGN.md): the man page and
the shell completions are checked against ``build_parser()`` so they cannot drift from it.
Heavy modules (prompt_toolkit, rich, python-can) are imported only by the paths that use them.
"""

from __future__ import annotations

import argparse
import os
import sys

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


def add_connection(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("connection (default: the one attached Trinamic USB module, "
                             "else --sim TMCM-1311)")
    x = g.add_mutually_exclusive_group()
    x.add_argument("--port", metavar="PORT",
                   help="serial device or pyserial URL (socket://, rfc2217://, loop://, spy://, hwgrep://)")
    x.add_argument("--can", metavar="IFACE:CHANNEL",
                   help="python-can bus, e.g. socketcan:can0, pcan:PCAN_USBBUS1, virtual:bench")
    x.add_argument("--sim", metavar="MODULE", nargs="?", const="TMCM-1311",
                   help="the built-in simulator, in process (default module TMCM-1311)")
    g.add_argument("--baud", type=_int, metavar="N", help="baud rate (default 9600, the factory setting)")
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
    add_connection(sc)
    sc.add_argument("--from", dest="first", type=_address, default=1, metavar="N")
    sc.add_argument("--to", dest="last", type=_address, default=255, metavar="N")
    sc.add_argument("--timeout", type=_positive, default=0.05, metavar="S",
                    help="per-address timeout (default 0.05)")
    sc.add_argument("--json", action="store_true")
    return p


# -- subcommands -------------------------------------------------------------------------

def cmd_asm(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .asm import assemble_file
    from .modules import load

    prog = assemble_file(args.file, load(args.module), origin=args.at)
    out = Path(args.output) if args.output else Path(args.file).with_suffix(".hex" if args.hex else ".bin")
    data = prog.to_hex().encode() if args.hex else prog.to_binary()
    if str(out) == "-":
        sys.stdout.buffer.write(data)
        return EXIT_OK
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, out)  # never leave a partial file behind
    print(f"{args.file}: {len(prog)} instructions for {prog.module.name} -> {out}", file=sys.stderr)
    return EXIT_OK


def cmd_disasm(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .asm import disassemble, read_image
    from .errors import AsmError
    from .modules import load

    try:
        data = sys.stdin.buffer.read() if args.file == "-" else Path(args.file).read_bytes()
    except OSError as exc:
        raise AsmError(f"cannot read {args.file}: {exc.strerror}") from None
    sys.stdout.write(disassemble(read_image(data), load(args.module), origin=args.at))
    return EXIT_OK


def cmd_sim(args: argparse.Namespace) -> int:
    from .sim.serve import run

    return run(args.module, args.address, pty=args.pty, tcp=args.tcp, can=args.can,
               host_address=args.host_address)


def trinamic_ports() -> list:
    """Serial ports whose USB vendor is Trinamic (0x2A3C), sorted by device name."""
    from serial.tools import list_ports

    return sorted((p for p in list_ports.comports() if p.vid == TRINAMIC_VID),
                  key=lambda p: p.device)


TRINAMIC_VID = 0x2A3C


def cmd_ports(args: argparse.Namespace) -> int:
    """One line per serial port: device, USB vendor:product, description, serial number;
    Trinamic devices first and marked."""
    import json

    from serial.tools import list_ports

    ports = sorted(list_ports.comports(), key=lambda p: (p.vid != TRINAMIC_VID, p.device))
    as_json = bool(getattr(args, "json", False))
    if not ports:
        print("no serial ports found", file=sys.stderr)
        return EXIT_OK
    for p in ports:
        trinamic = p.vid == TRINAMIC_VID
        desc = p.description if p.description and p.description != "n/a" else ""
        if as_json:
            print(json.dumps({"device": p.device, "vid": p.vid, "pid": p.pid,
                              "description": desc or None, "serial": p.serial_number,
                              "trinamic": trinamic}))
            continue
        ids = f"{p.vid:04x}:{p.pid:04x}" if p.vid is not None else "-"
        serial = f"  serial {p.serial_number}" if p.serial_number else ""
        mark = "  [TRINAMIC]" if trinamic else ""
        print(f"{p.device:<20} {ids:<10} {desc}{serial}{mark}".rstrip())
    return EXIT_OK


def cmd_scan(args: argparse.Namespace) -> int:
    """Ask every address in --from..--to for its version.

    Presence is tested with 136 type 1, whose serial reply names the module address and
    opcode, so a slow module's late answer is never credited to the next address (the 136
    type 0 string reply names neither). A module that answered is then asked for its version
    string. On CAN the --from..--to range is the CAN ids (GP 71) and every module answers on
    the one --reply-id; a CAN reply names no sender the client can rely on, so there the
    per-id timeout must outlast the modules' answer time (a few ms).
    """
    import json

    from .client import Client
    from .errors import ChecksumError, TmclError, TmclTimeoutError, ValidationError
    from .modules import by_firmware_id, from_version_string
    from .protocol import Control, Request

    if args.first > args.last:
        raise ValidationError(f"--from {args.first} is above --to {args.last}")
    settings = connection_settings(args)
    transport = open_transport(settings)
    client = Client(transport, address=args.first, host_address=settings["host_address"],
                    timeout=args.timeout, retries=0, can_id=settings.get("can_id"),
                    reply_id=settings.get("reply_id"))
    ids = "CAN ids" if client.is_can else "addresses"
    print(f"scanning {ids} {args.first}..{args.last} on {client.describe()}", file=sys.stderr)
    found = 0
    try:
        for addr in range(args.first, args.last + 1):
            client.address = addr
            if client.is_can:
                client.can_id = addr
            try:
                binary = client.request(Request(addr, Control.GET_VERSION, 1, 0, 0))
            except (TmclTimeoutError, ChecksumError):
                continue
            assert binary is not None
            version = None
            try:  # it is there: give it time and a retry for the string
                reply = client.request(Request(addr, Control.GET_VERSION, 0, 0, 0),
                                       timeout=max(args.timeout, 0.2), retries=1)
                version = reply.version if reply is not None else None
            except TmclError:
                pass
            mod = from_version_string(version) if version else None
            if mod is None and binary.status == 100:
                mod = by_firmware_id((binary.value >> 16) & 0xFFFF)
            found += 1
            row = {"address": addr, "module": mod.name if mod else None, "version": version}
            if args.json:
                print(json.dumps(row), flush=True)
            else:
                print(f"address {addr:3d}  {row['module'] or 'unknown module':<10}  "
                      f"firmware {version or '?'}", flush=True)
    finally:
        client.close()
    if not found:
        print(f"no module answered on {ids} {args.first}..{args.last}", file=sys.stderr)
    return EXIT_OK if found else EXIT_ERROR


# -- connection --------------------------------------------------------------------------

def connection_settings(args: argparse.Namespace) -> dict:
    from .config import load_config, resolve

    cli = {k: getattr(args, k, None) for k in
           ("port", "baud", "can", "sim", "can_id", "reply_id", "module", "address",
            "host_address", "ascii", "timeout", "retries", "profile")}
    return resolve(cli, load_config())


def _setting(settings: dict, key: str, default):
    value = settings.get(key)
    return default if value is None else value  # address 0 is an address


def open_transport(settings: dict):
    """The transport the settings name: port, CAN bus, the one attached Trinamic module, or
    else the in-process simulator (``settings["port"]``/``["sim"]`` record which)."""
    from . import transport as tr

    baud = _setting(settings, "baud", 9600)
    if settings.get("port"):
        return tr.open_serial(settings["port"], baud)
    if settings.get("can"):
        return tr.open_can(settings["can"])
    if not settings.get("sim"):
        found = trinamic_ports()
        if len(found) == 1:
            settings["port"] = found[0].device
            return tr.open_serial(found[0].device, baud)
        if len(found) > 1:
            print(f"tmclsh: {len(found)} Trinamic modules attached "
                  f"({', '.join(p.device for p in found)}); pick one with --port. "
                  "Starting the simulator.", file=sys.stderr)
    module = settings.get("sim") or settings.get("module") or "TMCM-1311"
    settings["sim"] = module
    return tr.open_sim(module, _setting(settings, "address", 1),
                       host_address=_setting(settings, "host_address", 2))


def open_client(settings: dict):
    """A client on ``open_transport(settings)``, in ASCII mode if asked, module identified."""
    from .client import Client, start

    transport = open_transport(settings)
    module = settings.get("module") or settings.get("sim")
    client = Client(transport, address=_setting(settings, "address", 1),
                    host_address=_setting(settings, "host_address", 2), module=module,
                    timeout=_setting(settings, "timeout", 1.0),
                    retries=_setting(settings, "retries", 2),
                    can_id=settings.get("can_id"), reply_id=settings.get("reply_id"))
    return start(client, ascii=bool(settings.get("ascii")))


# -- entry point -------------------------------------------------------------------------

def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser()
    args = parser.parse_args(argv)
    debug = getattr(args, "debug", False)
    from .errors import TmclError

    try:
        if getattr(args, "completions", None):
            from .docs import completion_script

            sys.stdout.write(completion_script(args.completions, parser))
            return EXIT_OK
        handler = {"asm": cmd_asm, "disasm": cmd_disasm, "sim": cmd_sim, "ports": cmd_ports,
                   "scan": cmd_scan}.get(args.subcommand or "")
        if handler is not None:
            return handler(args)
        from .shell.main import run_shell

        return run_shell(args)
    except KeyboardInterrupt:
        return 130
    except TmclError as exc:
        if debug:
            raise
        print(f"tmclsh: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except OSError as exc:
        if debug:
            raise
        print(f"tmclsh: {exc}", file=sys.stderr)
        return EXIT_ERROR
