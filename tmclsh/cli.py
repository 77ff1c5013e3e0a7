"""The entry point: parse the command line (``options``), run a subcommand or the shell.

Heavy modules (prompt_toolkit, rich, python-can) are imported only by the paths that use them.
"""

from __future__ import annotations

import argparse
import os
import sys

from .options import (EXIT_CONNECT, EXIT_ERROR, EXIT_OK, EXIT_USAGE,  # noqa: F401
                      SUBCOMMANDS, build_parser)


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


def cmd_ports(args: argparse.Namespace) -> int:
    """One line per serial port: device, USB vendor:product, description, serial number;
    Trinamic devices first and marked."""
    import json

    from serial.tools import list_ports

    from .connection import TRINAMIC_VID

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
    from .connection import connection_settings, open_transport
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
        from .errors import ConnectError

        return EXIT_CONNECT if isinstance(exc, ConnectError) else EXIT_ERROR
    except OSError as exc:
        if debug:
            raise
        print(f"tmclsh: {exc}", file=sys.stderr)
        return EXIT_ERROR
