"""The entry point: parse the command line (``options``), run a subcommand or the shell.

Heavy modules (prompt_toolkit, rich, python-can) are imported only by the paths that use them.
"""

from __future__ import annotations

import argparse
import os
import sys

from ..base.errors import EXIT_CONNECT, EXIT_FAILED, EXIT_OK, EXIT_USAGE
# (build_parser and parse_args: names scripts and tests take from here)
from .options import SUBCOMMANDS, build_parser, parse_args, read_command_line  # noqa: F401


# -- subcommands -------------------------------------------------------------------------

def cmd_asm(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..tmcl.asm import assemble_file
    from ..tmcl.modules import load

    prog = assemble_file(args.file, load(args.module), origin=args.at)
    out = Path(args.output) if args.output else Path(args.file).with_suffix(".hex" if args.hex else ".bin")
    data = prog.to_hex().encode() if args.hex else prog.to_binary()
    if str(out) == "-":
        sys.stdout.buffer.write(data)
        return EXIT_OK
    from ..base.files import write_file

    write_file(out, data)  # all or nothing: a failed write leaves OUT as it was
    print(f"{args.file}: {len(prog)} instructions for {prog.module.name} -> {out}", file=sys.stderr)
    return EXIT_OK


def cmd_disasm(args: argparse.Namespace) -> int:
    from ..tmcl.asm import disassemble, read_image_instructions
    from ..tmcl.modules import load

    module = load(args.module)
    image = read_image_instructions(args.file, module)  # bounded by its program memory
    if not image:  # (was an empty line on stdout and nothing said)
        print(f"{args.file}: an empty image: no instructions", file=sys.stderr)
        return EXIT_OK
    sys.stdout.write(disassemble(image, module, origin=args.at))
    return EXIT_OK


def cmd_sim(args: argparse.Namespace) -> int:
    from ..sim.serve import run

    return run(args.module, args.address, pty=args.pty, tcp=args.tcp, can=args.can,
               host_address=args.host_address, bitrate=args.bitrate, faults=args.faults,
               seed=args.faults_seed, bootloader=args.bootloader,
               baud=args.baud)


def cmd_monitor(args: argparse.Namespace) -> int:
    from ..shell.features.monitor import run_monitor

    return run_monitor(args)


def cmd_bridge(args: argparse.Namespace) -> int:
    from ..shell.features.bridge import run_bridge

    return run_bridge(args)


def cmd_replay(args: argparse.Namespace) -> int:
    from .replay import cmd_replay as run

    return run(args)


def cmd_ports(args: argparse.Namespace) -> int:
    """One line per serial port: device, USB vendor:product, description, serial number;
    Trinamic devices first and marked."""
    from serial.tools import list_ports

    from ..base.edges import write_json
    from ..link import TRINAMIC_VID

    ports = sorted(list_ports.comports(), key=lambda p: (p.vid != TRINAMIC_VID, p.device))
    as_json = bool(getattr(args, "json", False))
    if not ports:
        print("no serial ports found", file=sys.stderr)
        return EXIT_OK
    for p in ports:
        trinamic = p.vid == TRINAMIC_VID
        desc = p.description if p.description and p.description != "n/a" else ""
        if as_json:
            write_json({"device": p.device, "vid": p.vid, "pid": p.pid,
                        "description": desc or None, "serial": p.serial_number,
                        "trinamic": trinamic})
            continue
        ids = f"{p.vid:04x}:{p.pid:04x}" if p.vid is not None else "-"
        serial = f"  serial {p.serial_number}" if p.serial_number else ""
        mark = "  [TRINAMIC]" if trinamic else ""
        print(f"{p.device:<20} {ids:<10} {desc}{serial}{mark}".rstrip())
    return EXIT_OK


def cmd_scan(args: argparse.Namespace) -> int:
    """Ask every address in --from..--to who is there (``tmclsh.ops.scan``); with ``--baud auto``
    at each baud rate GP 65 can select. Rows on stdout as modules are found, progress (on a
    terminal) and a summary on stderr."""
    from ..base.edges import write_json
    from ..client.advice import OPTIONS
    from ..client.core import Client
    from ..client.connect import connection_settings, open_transport
    from ..tmcl.modules import baud_rates
    from ..base.errors import ConnectError, TransportError, ValidationError
    from ..ops.scan import ASCII_WIRE_BYTES, address_timeout, answer_at, rate_matters, scan
    from . import inventory as inv

    if args.first > args.last:
        raise ValidationError(f"--from {args.first} is above --to {args.last}")
    inventory = inv.before_scan(args)  # (read and checked before the link is opened)
    auto = args.baud == "auto"
    if auto:
        args.baud = None
    settings = connection_settings(args)
    try:
        transport = open_transport(settings)
    except (TransportError, ValidationError) as exc:  # a port that cannot be opened, a
        raise ConnectError(str(exc)) from exc  # CAN configuration naming none: exit 3 as -c
    client = Client(transport, address=args.first, host_address=settings["host_address"],
                    timeout=1.0, retries=0, can_id=settings.get("can_id"),
                    reply_id=settings.get("reply_id"))
    client.advice = OPTIONS  # (its messages' advice names the command line's options)
    try:
        inv.check_link(inventory, client)
    except ValidationError:
        client.close()
        raise
    ids = "CAN ids" if client.is_can else "addresses"
    usb = bool(settings.get("port") and _is_usb(settings["port"]))
    rates: list[int | None] = [None]
    if auto:
        no_rate = rate_matters(transport, usb=usb)
        if client.is_can:
            raise ValidationError("--baud auto is for a serial line; a CAN bus has a bit "
                                  "rate (--bitrate)")
        if no_rate is None:
            rates = list(baud_rates())
        else:  # every rate would find the same modules again
            auto = False
            print(f"--baud auto: the baud rate has no effect on {client.describe()} "
                  f"({no_rate}): one pass", file=sys.stderr)
    ascii = True if getattr(args, "ascii", None) else None  # (tmclsh --ascii scan: always)
    addresses = range(args.first, args.last + 1)
    found = []
    tried = []
    show_progress = not args.json and sys.stderr.isatty()
    from ..base.interrupts import Terminated, restore, unwind_on

    # SIGTERM and SIGHUP end the scan as Ctrl-C does: through the finally below, so that a
    # module in ASCII mode stepped out of it to be identified is put back first
    previous = unwind_on(("SIGTERM", "SIGHUP"))
    try:
        for i, rate in enumerate(rates):
            if rate is not None:
                transport.set_baudrate(rate)
                client._lifecycle.forget_stale()  # nothing sent at another rate can still arrive
            timeout = args.timeout or address_timeout(transport, usb=usb)
            ascii_timeout = args.timeout or address_timeout(transport, usb=usb,
                                                            nbytes=ASCII_WIRE_BYTES)
            where = client.describe()
            tried.append(f"{ids} {args.first}..{args.last} on {where} "
                         f"({timeout * 1000:.0f} ms each)")
            if not show_progress:
                print(f"scanning {ids} {args.first}..{args.last} on {where}", file=sys.stderr)

            def row(hit) -> None:
                if args.json:
                    write_json(hit.as_json() if auto else
                               {k: v for k, v in hit.as_json().items() if k != "baud"})
                else:
                    at = f"  {hit.baud} baud" if auto else ""
                    mode = "  ASCII mode" if hit.ascii else ""
                    twice = ("  TWO MODULES answer at this address (every reply came twice)"
                             if hit.answers > 1 else "")
                    if hit.bootloader:
                        at += (f"  IN ITS BOOTLOADER (a firmware update did not complete: "
                               f"'tmclsh firmware FILE.hex{_connection_words(args)}' "
                               "completes it)")
                    what = "bootloader" if hit.bootloader else "firmware"
                    print(f"address {hit.address:3d}  {hit.module or 'unknown module':<10}  "
                          f"{what} {hit.version or '?'}{at}{mode}{twice}", flush=True)

            options = {"ascii": ascii, "ascii_timeout": ascii_timeout,
                       "ascii_also": inventory.addresses() if inventory else ()}
            if show_progress:
                hits = _scan_with_progress(client, addresses, timeout,
                                           f"{ids} {args.first}..{args.last} on {where}", row,
                                           **options)
            else:
                shown: set[tuple[int, int]] = set()

                def as_found(addr: int, hit) -> None:
                    if hit is not None:
                        shown.add((addr, hit.answers))
                        row(hit)

                hits = scan(client, addresses, timeout=timeout, progress=as_found, **options)
                for hit in hits:
                    if (hit.address, hit.answers) not in shown:  # found on a later pass
                        row(hit)
            found += hits
            if hits and auto and i + 1 < len(rates) and answer_at(
                    client, [h.address for h in hits], rates[i + 1], timeout):  # type: ignore[arg-type]
                print(f"--baud auto: the modules found at {rate} baud answer at {rates[i + 1]} "
                      f"too: the baud rate has no effect on {transport.url}; stopped",
                      file=sys.stderr)
                break
        if found and inventory is not None:  # (settings are read on the scan's link)
            _scan_summary(found, auto)
            return inv.expect(args, inventory, found, client)
    except (KeyboardInterrupt, Terminated) as exc:
        why = exc.why if isinstance(exc, Terminated) else "interrupted"
        print(f"tmclsh: scan {why} before the last address: only what answered until then "
              "is listed", file=sys.stderr)
        raise
    finally:
        client.close()
        restore(previous)
    if not found:
        _say_error(args, f"nothing answered; tried {'; '.join(tried)}"
                   + ("" if client.is_can else ", in binary and in ASCII mode")
                   + ("" if auto or client.is_can else "; other baud rates: --baud auto"),
                   EXIT_CONNECT, prefix="")
        return EXIT_CONNECT
    _scan_summary(found, auto)
    if args.save is not None:
        inv.save(args, found, client)
    return EXIT_OK


def _scan_summary(found: list, auto: bool) -> None:
    """What a scan found, on standard error: where, and each address two modules share."""
    where = ", ".join(str(f.address) + (" (two)" if f.answers > 1 else "")
                      + (f" ({f.baud} baud)" if auto else "") for f in found)
    n = sum(2 if f.answers > 1 else 1 for f in found)  # (every module, two at one address)
    print(f"{n} module{'s' if n != 1 else ''} found at {where}", file=sys.stderr)
    for hit in found:
        if hit.answers > 1:
            print(f"tmclsh: two modules answer at address {hit.address}: give each its own "
                  "address (one at a time on the line: SGP 66, 0, N), or take one off the line",
                  file=sys.stderr)


def _connection_words(args: argparse.Namespace) -> str:
    """The link options of this run again, as ``tmclsh firmware`` takes them."""
    port = getattr(args, "port", None)
    if port:
        return f" --port {port[0] if isinstance(port, list) else port}"  # (one: scan takes one)
    if getattr(args, "can", None):
        from ..base.canspec import FROM_PYTHON_CAN

        return " --can" if args.can == FROM_PYTHON_CAN else f" --can {args.can}"
    return ""


def _is_usb(port: str) -> bool:
    from ..link import trinamic_ports

    return any(p.device == port for p in trinamic_ports())


def _scan_with_progress(client, addresses: range, timeout: float, what: str, row,
                        **options) -> list:
    """``scan`` under a rich progress bar (stderr is a terminal): addresses done and found so
    far; rows appear above the bar as modules are found (those of the second, slower pass at
    the end). The bar goes where the rows go when stdout is the terminal too."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from ..ops.scan import scan

    found: list[int] = []
    shown: set[tuple[int, int]] = set()
    same_terminal = sys.stdout.isatty()
    with Progress(TextColumn("scanning {task.description}"), BarColumn(),
                  MofNCompleteColumn(), TextColumn("{task.fields[found]}"),
                  console=Console(stderr=not same_terminal), transient=True,
                  redirect_stdout=same_terminal, redirect_stderr=False) as bar:
        task = bar.add_task(what, total=len(addresses), found="")

        def progress(addr: int, hit) -> None:
            if hit is not None:
                found.append(addr)
                shown.add((addr, hit.answers))
                row(hit)
            bar.update(task, advance=1, found=("found " + ", ".join(map(str, found)))
                       if found else "")

        hits = scan(client, addresses, timeout=timeout, progress=progress, **options)
    for hit in hits:
        if (hit.address, hit.answers) not in shown:
            row(hit)
    return hits


def cmd_modules(args: argparse.Namespace) -> int:
    """The known modules and where each comes from, or (``check FILE``) one file validated."""
    from ..base.edges import write_json
    from ..tmcl import modules

    if args.action == "import":
        from .importing import import_modules

        return import_modules(args)
    if args.import_all or args.output:
        print("tmclsh: --all and -o go with 'modules import pytrinamic'", file=sys.stderr)
        return EXIT_USAGE
    if args.action == "check" or args.file:
        if len(args.file) != 1:
            print("tmclsh: modules check wants one FILE", file=sys.stderr)
            return EXIT_USAGE
        path = args.file[0]
        try:
            mod = modules.read_file(path)
        except modules.ModuleFileError as exc:
            print(f"tmclsh: {exc}", file=sys.stderr)
            return EXIT_FAILED
        print(f"{path}: {mod.name} (firmware id {mod.firmware_id}, version "
              f"{mod.version_string}): {len(mod.axis_params)} axis and {len(mod.global_params)} "
              f"global parameters, {'any I/O port' if mod.any_io else f'{len(mod.io)} I/O ports'}"
              f", commands of "
              f"{modules.commands_of(mod)}: OK")
        return EXIT_OK
    built = set(modules.built_in())
    for mod in modules.catalogue():
        source = mod.source
        if source != modules.BUILT_IN and mod.name in built:
            source += " (replaces the built-in)"
        if mod.origin:
            source += f" (data from {mod.origin})"
        if getattr(args, "json", False):
            write_json({"module": mod.name, "firmware_id": mod.firmware_id,
                        "version_string": mod.version_string, "source": source})
        else:
            print(f"{mod.name:<12} {mod.version_string:<10} {source}")
    if not getattr(args, "json", False):
        print(f"{'generic':<12} {'any':<10} built in: numbers only, for any other TMCL module")
    for problem in modules.problems():
        print(f"tmclsh: not loaded: {problem}", file=sys.stderr)
    return EXIT_FAILED if modules.problems() else EXIT_OK


def cmd_firmware(args: argparse.Namespace) -> int:
    from .firmware import cmd_firmware as run

    return run(args)


def cmd_replace(args: argparse.Namespace) -> int:
    from .replace import cmd_replace as run

    return run(args)


# -- entry point -------------------------------------------------------------------------

def show_manual(parser: argparse.ArgumentParser) -> int:
    """The man page, generated now (so an editable install shows the current one), shown
    as man(1) shows it: paged on a terminal, plain text in a pipe (``tmclsh --man | less``,
    ``> tmclsh.txt``). Without man(1) the roff text, said to be that."""
    import shutil
    import subprocess
    import tempfile

    from .docs import manpage

    text = manpage(parser)
    man = shutil.which("man")
    if man is not None:
        with tempfile.TemporaryDirectory() as tmp:
            page = os.path.join(tmp, "tmclsh.1")
            with open(page, "w", encoding="utf-8") as f:
                f.write(text)
            sys.stdout.flush()
            # a path with a slash: man reads that file; in a pipe it writes the plain text
            if subprocess.call([man, page]) == 0:
                return EXIT_OK
    sys.stdout.write(text)
    sys.stdout.flush()
    print("tmclsh: no man(1) to format the manual: this is its roff source "
          "(groff -man -Tutf8 formats it)", file=sys.stderr)
    return EXIT_OK


def _say_error(args: argparse.Namespace, message: str, status: int, prefix: str = "tmclsh: "
               ) -> None:
    """The error a run ends with: a line on stderr, and under --json a record on stdout
    (``edges.error_record``, as every command's) too, so that stdout stays JSON."""
    print(f"{prefix}{message}", file=sys.stderr)
    if getattr(args, "json", False):
        from ..base.edges import error_record, write_json

        write_json(error_record(message, status))


def _user_modules(args: argparse.Namespace) -> None:
    """Take in --module-file; a module file that cannot be used is one warning line and the
    run goes on without it (``tmclsh modules`` reports them itself)."""
    from ..tmcl import modules

    for path in getattr(args, "module_file", None) or ():
        modules.add_file(path)
    if args.subcommand == "modules":
        return
    for problem in modules.problems():
        print(f"tmclsh: warning: {problem}; going on without it", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    from ..base import interrupts, startup

    if argv is None:  # the process's own command line (not a caller's list: a test, a script)
        startup.hold()  # (the collector, while tmclsh starts: base/startup.py)
        interrupts.keep()  # (a signal dropped in a callback is sent again: base/interrupts.py)
    try:
        return _main(sys.argv[1:] if argv is None else argv)
    finally:
        startup.release()


def _main(argv: list[str]) -> int:
    parser, args = read_command_line(argv)
    debug = getattr(args, "debug", False)
    from ..base.edges import reader_gone
    from ..base.errors import TmclError, UsageError, exit_status

    try:
        if getattr(args, "man", False):
            return show_manual(parser)
        if getattr(args, "completions", None):
            from .docs import completion_script

            sys.stdout.write(completion_script(args.completions, parser))
            return EXIT_OK
        _user_modules(args)
        handler = {"asm": cmd_asm, "disasm": cmd_disasm, "sim": cmd_sim, "ports": cmd_ports,
                   "scan": cmd_scan, "modules": cmd_modules, "firmware": cmd_firmware,
                   "replace": cmd_replace, "monitor": cmd_monitor,
                   "bridge": cmd_bridge, "replay": cmd_replay}.get(args.subcommand or "")
        if handler is not None:
            from ..base import startup

            startup.release()
            return handler(args)
        from ..shell.lang.entry import enter

        return enter(args)  # the REPL, -c, -f or several units
    except BrokenPipeError:  # `tmclsh modules | head`: the reader has gone; stop quietly
        return reader_gone()
    except KeyboardInterrupt as exc:
        return exit_status(exc)
    except (TmclError, OSError) as exc:
        if debug:
            raise
        status = exit_status(exc)
        if isinstance(exc, TmclError) and not isinstance(exc, UsageError):
            _say_error(args, str(exc), status)  # (a refused command line: stderr only)
        else:
            print(f"tmclsh: {exc}", file=sys.stderr)
        return status
