"""``tmclsh replay CAPTURE [CONNECTION] [--as-captured] [--yes] [--json]``: the front end of
a replay (``tmclsh.ops.replay`` reads the capture and sends it again).

What the user sees: the commands that write, store or move, named before anything is sent
(without ``--yes`` that list is the refusal); then a table of every exchange whose reply
differs from the capture, with both latencies, and one line of totals. With ``--json``: one
object per difference, then the result (or the error) as one object with ``"exit"``. Exit 0
no differences, 1 differences (or the link lost), 2 refused before anything was sent, 3 no
module, 130 Ctrl-C. Whatever ends a replay that sent a write, the safety stop runs last.
"""

from __future__ import annotations

import argparse
import sys

from ..base.edges import error_record, write_json
from ..base.errors import (EXIT_CONNECT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE,
                           ConnectError, TmclError, TransportError)

_LISTED = 20  # commands named before the rest are counted


class _Say:
    """Lines on stderr, objects on stdout (``--json``)."""

    def __init__(self, as_json: bool, simulated: bool = False):
        self.json = as_json
        self.simulated = simulated

    def emit(self, obj: dict) -> None:
        if self.simulated:
            obj["simulated"] = True
        write_json(obj)

    def line(self, text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    def error(self, text: str, code: int) -> int:
        if self.json:
            self.emit(error_record(text, code))
        else:
            self.line(f"tmclsh: {text}")
        return code


def _command(c, module) -> str:
    from ..shell.render import describe_instruction

    return describe_instruction(c.instruction, module)


def _writes_json(writes: list) -> list[dict]:
    return [{"index": c.index, "address": c.address, "op": c.instruction.opcode,
             "type": c.instruction.type, "motor": c.instruction.motor,
             "value": c.instruction.signed_value} for c in writes]


def _listed(say: _Say, writes: list, module, head: str) -> None:
    """The commands that write, store or move, named (on stderr)."""
    say.line(f"tmclsh: {head}:")
    for c in writes[:_LISTED]:
        say.line(f"  #{c.index:<5} @{c.address:<4} {_command(c, module)}")
    if len(writes) > _LISTED:
        say.line(f"  ... and {len(writes) - _LISTED} more")


def _commands(n: int) -> str:
    if n == 1:
        return "1 command that writes, stores or moves"
    return f"{n} commands that write, store or move"


def cmd_replay(args: argparse.Namespace) -> int:
    from ..client.connect import connection_settings, open_client
    from ..ops.replay import Result, aim, read_capture, replay

    as_json = bool(getattr(args, "json", False))
    yes = bool(getattr(args, "yes", False))
    say = _Say(as_json)
    try:
        capture = read_capture(args.capture)
        if capture.never():
            c = capture.never()[0]
            return say.error(f"{args.capture}: exchange {c.index}: {_command(c, None)} is "
                             f"not replayed: {c.never}; nothing was sent", EXIT_USAGE)
    except TmclError as exc:
        return say.error(f"{exc}; nothing was sent", EXIT_USAGE)
    writes = capture.writes()
    if writes and not yes:
        why = (f"{args.capture} holds {_commands(len(writes))}; replaying them needs --yes; "
               "nothing was sent")
        if as_json:
            say.emit(error_record(why, EXIT_USAGE, writes=_writes_json(writes)))
            return EXIT_USAGE
        _listed(say, writes, None, f"{args.capture} holds {_commands(len(writes))}")
        return say.error("replaying them needs --yes; nothing was sent", EXIT_USAGE)
    settings = connection_settings(args)
    for key, value in capture.settings().items():  # (-a, --can-id given decide)
        if getattr(args, key, None) is None:
            settings[key] = value
    try:
        client = open_client(settings)
    except (ConnectError, TransportError) as exc:  # (a port that cannot be opened: no module)
        return say.error(str(exc), EXIT_CONNECT)
    say.simulated = bool(settings.get("sim"))
    if writes:
        if as_json:
            say.emit({"replaying": _writes_json(writes)})
        else:
            _listed(say, writes, client.module, f"replaying {_commands(len(writes))}")
    table = _Table(say, client.module)
    code = EXIT_OK
    result = Result(capture)
    from ..base.interrupts import restore, unwind_on

    previous = unwind_on(("SIGTERM", "SIGHUP"))  # (the stop below runs all the same)
    try:
        replay(client, capture, as_captured=args.as_captured, writes=yes, done=table.add,
               into=result)
    except KeyboardInterrupt:
        code = EXIT_INTERRUPTED
    except TmclError as exc:  # (the link lost: what came before is shown below)
        code = say.error(f"{exc}; the replay stopped", EXIT_FAILED)
    finally:
        try:
            if writes:
                from ..shell.features.stop import ToStderr, stop_all

                several = len(capture.addresses) > 1
                for address in capture.written():
                    aim(client, capture.first_at(address))
                    # (each module's stop says whose motors it names when there are several)
                    where = f" ({'CAN id' if client.is_can else 'address'} {address})"
                    stop_all(client, ToStderr(), "replay ended" + (where if several else ""))
        finally:
            client.close()
            restore(previous)
    table.show(result)
    if code == EXIT_OK and result.differences:
        code = EXIT_FAILED
    if as_json:
        say.emit({**result.to_json(), "exit": code})
    return code


class _Table:
    """The differences as they come (JSON), or as a table at the end."""

    def __init__(self, say: _Say, module):
        self.say = say
        self.module = module
        self.rows: list = []

    def add(self, outcome) -> None:
        if not outcome.differs:
            return
        if self.say.json:
            self.say.emit(outcome.to_json())
        else:
            self.rows.append(outcome)

    def show(self, result) -> None:
        n, total = len(result.outcomes), len(result.capture.exchanges)
        diffs = len(result.differences)
        if self.say.json:
            return
        if self.rows:
            from rich.console import Console
            from rich.table import Table

            t = Table(title=f"{diffs} of {n} replies differ from {result.capture.path}")
            for col in ("#", "at", "command", "captured", "now", "differs", "ms then",
                        "ms now"):
                t.add_column(col, justify="right" if col in ("#", "ms then", "ms now")
                             else "left")
            for o in self.rows:
                c = o.captured
                t.add_row(str(c.index), str(c.address), _command(c, self.module),
                          _reply_text(c.reply), _reply_text(o.reply) or o.error,
                          "; ".join(o.differences), _ms(c.latency), _ms(o.latency))
            # (in a pipe or a file, wide enough that a row stays one line)
            Console(width=None if sys.stdout.isatty() else 160).print(t)
        stopped = " (interrupted)" if result.interrupted else ""
        print(f"replayed {n} of {total} exchanges in {result.seconds:.2f} s{stopped}: "
              f"{diffs} difference{'s' if diffs != 1 else ''}", flush=True)


def _reply_text(reply) -> str:
    if reply is None:
        return ""
    if reply.version is not None:
        return f"{reply.status} {reply.version}"
    return f"{reply.status} {reply.value}"


def _ms(seconds: float | None) -> str:
    return "" if seconds is None else f"{seconds * 1000:.1f}"
