"""One shell session: the client, the output, variables, and the line runner.

The REPL, ``-c`` and ``-f`` all go through ``Session.run_line``, so a line means the same
wherever it is typed. A dot-command owns the rest of its line; TMCL lines are parsed and
checked against the module's database before anything is sent.
"""

from __future__ import annotations

import re
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from ...tmcl import instructions as isa
from ...client.core import idempotent
from ...client.shared import shared_text
from ...client.text import LineClient as Client
from ...client.text import Result
from ...link.framing import name_of as _name
from ...base.errors import (EXIT_CONNECT, AsmError, ChecksumError, ModuleGoneError, StatusError,
                            TmclError, TmclTimeoutError, TransportError, ValidationError)
from ...tmcl.frames import Request
from ...tmcl.modules import Module
from ...tmcl.status import OK_STATUSES
from . import commands
from .lines import Line, classify, split_text
from ..render import Output

if TYPE_CHECKING:  # (a line is encoded by the client: client/text.py)
    from ...tmcl import asm

_VAR = re.compile(r"\$\{([^}]*)\}")
ANSWERED = 64  # recent replies whose line a later suspect report can name
# --keep-going: lines in a row that get no answer, none coming in between, before the module
# is taken to be gone (Session.failed_unanswered). A link pulled and put back costs a line or
# two (each waits as long as it would for its answer: --timeout times its attempts).
GONE_AFTER = 4



def as_statement(question: str) -> str:
    """``store X in the EEPROM?`` -> ``store X in the EEPROM``: where nobody can answer, the
    question is said as what was not done."""
    return question.strip().removesuffix("?").removesuffix("; continue").strip()


def confirmation(enc: asm.Encoded) -> str | None:
    """The question asked before sending ``enc`` (the instruction set's ``confirm``), or
    None: the one rule, for the session and for a backup checked before it is replayed."""
    p, ins = enc.parameter, enc.instruction
    spec = enc.spec or isa.control(ins.opcode)
    if spec is None:
        return None
    if spec.confirm == "store":
        what = p.name if p is not None else f"parameter {ins.type}"
        return f"store {what} permanently in the module's EEPROM?"
    if spec.confirm == "storable" and p is not None and p.storable and p.bank == 0:
        return f"{spec.mnemonic} {p.name} writes the module's EEPROM; continue?"
    if spec.confirm == "factory":
        return "restore FACTORY DEFAULTS (all settings and the stored program are lost)?"
    return None


def unknown_command(word: str) -> str:
    """The error for a mistyped dot-command, naming the commands it is close to (as a
    mistyped mnemonic gets)."""
    import difflib  # only for a mistyped word: not at start-up

    names = [name for cmd in commands.all_commands() for name in cmd.names()]
    close = difflib.get_close_matches(word.lower(), names, n=3, cutoff=0.6)
    near = f"did you mean {', '.join(close)}? " if close else ""
    return f"unknown shell command {word!r}; {near}type .help for the list"

def encode_typed(client: Client, text: str) -> asm.Encoded:
    """``client.encode(text)`` for a line typed as TMCL; a word that is no TMCL command but a
    dot-command's name without its dot (``clear``) is pointed to that command, rather than to
    the mnemonic nearest in spelling (CLE, which clears a flag on the module)."""
    try:
        return client.encode(text)
    except AsmError as exc:
        raise _dot_command_meant(text, exc) from None


def prepare_typed(client: Client, text: str) -> tuple[asm.Encoded, Request]:
    """``client.prepare(text)``, with :func:`encode_typed`'s pointer to a dot-command."""
    try:
        return client.prepare(text)
    except AsmError as exc:
        raise _dot_command_meant(text, exc) from None


def _dot_command_meant(text: str, exc: AsmError) -> TmclError:
    word = text.split(None, 1)[0] if text.split() else ""
    if word.upper() == isa.ASCII_BIN and exc.message.startswith("unknown command"):
        return ValidationError(f"{word!r} is the module's own ASCII-mode line, not a TMCL "
                               "command; .mode binary sends it")
    cmd = commands.find("." + word.lower()) if word.isalpha() else None
    if cmd is None or not exc.message.startswith("unknown command"):
        return exc
    return ValidationError(f"{word!r} is not a TMCL command; did you mean {cmd.name}? "
                           f"({cmd.help})")


def reconnected(client) -> str:
    """The one wording of a link brought back, wherever it is said (the prompt, a script
    with --keep-going, the stop, a watch, .connect)."""
    return f"reconnected to {client.describe()}"


class Abort(TmclError):
    """The user declined a confirmation; nothing was sent."""


class TimeLimitError(TmclTimeoutError):
    """A line ran past the session's ``time_limit`` and was stopped."""


class QuitShell(Exception):
    """``.quit``: leave the shell after this line."""


@dataclass
class SessionState:
    """What the features keep in a session, each slot named and typed here (a feature does
    not guess another's keys; the session imports no feature: their objects are ``Any``)."""

    # the stored program as the prompt and toolbar show it ("run", "stop", "step @12", or
    # {"state": ..., "pc": ...}); None: not known
    program_state: str | dict | None = None
    repeat_on_empty: str | None = None  # what an empty line at the prompt runs (.step)
    pager: bool = False  # long output goes through the pager (the REPL's setting)
    script_depth: int = 0  # scripts (.source, blocks) being run inside one another
    onerror: Any = None  # (node, line) a script runs when a line fails (.onerror)
    record: Any = None  # the scripting.Recorder of .record
    capture: Callable[[Session, str], bool] | None = None  # a block (.repeat/.if) collecting
    debugger: Any = None  # the debugger's DebuggerState
    program: Any = None  # a program whose labels completion offers
    watch_log: Any = None  # the last watch's samples (.plot without a file)
    trace: Callable[[], None] | None = None  # stops the trace (.trace off)
    # ${expression} in any line (the expression engine, imported the first time)
    evaluate: Callable[[Session, str], int | float] | None = None

    def take(self, name: str) -> Any:
        """The slot's value, the slot emptied."""
        value = getattr(self, name)
        setattr(self, name, None)
        return value


@dataclass
class Stats:
    commands: int = 0
    errors: int = 0
    checks_passed: int = 0
    checks_failed: int = 0
    suspects: int = 0  # results reported as possibly another request's answer
    # addresses two modules were found to answer at (Client.take_shared), in the order found
    shared: list[int] = field(default_factory=list)
    # shell commands that sent frames of their own (.upload, .run, .save, ...): not TMCL lines,
    # but a summary saying "0 commands sent" after one would say the module was not touched
    shell_commands: int = 0
    started: float = field(default_factory=time.monotonic)


class Session:
    def __init__(self, client: Client, output: Output | None = None, *, interactive: bool = False,
                 yes: bool = False, keep_going: bool = False, settings: dict | None = None):
        self.client = client
        self.out = output or Output()
        if client.on_notice is None:  # what the client does on its own, said on the output
            client.on_notice = self.out.warn
        self.interactive = interactive
        self.yes = yes
        self.keep_going = keep_going
        # a replayed configuration backup writes the module's link identity too (--with-link)
        self.with_link = False
        if keep_going:  # a line that needs the module waits for a lost link to come back
            client._on_link_lost = self.relink
        self.settings = settings or {}
        # numbers; text (a unit's ${port}) only goes into lines as ${name}
        self.variables: dict[str, int | float | str] = {}
        self.history: list[str] = []
        self.stats = Stats()
        self.last_result: Result | None = None
        # hooks: called with (line, result-or-error-text) after every line (used by .record)
        self.recorders: list[Callable[[str, str], None]] = []
        # called once when the session ends (a recording is put in place of its file)
        self.closers: list[Callable[[], None]] = []
        # asks the user; the REPL replaces it with a prompt_toolkit confirm
        self.ask: Callable[[str], bool] | None = None
        # lets the user pick one of (value, label) options (the REPL's: prompt_toolkit choice)
        self.choose: Callable[[str, list[tuple[str, str]]], str] | None = None
        # what features keep in the session (debugger, watch, scripts, ...)
        self.state = SessionState()
        self.location: tuple[str, int] | None = None  # script file and line being run
        # the REPL sets it False before each line; see end_interrupted_line
        self.interrupted_line_ended = True
        # which line each recent reply answered (Client._replies -> line, FILE:LINE), so a
        # reply found suspect later can be named
        # (a ring: the reply numbered n is at n % ANSWERED, with its number)
        self._answered: list[tuple[int, str, tuple[str, int] | None] | None] = [None] * ANSWERED
        self.out.simulated = lambda: bool(getattr(self.client.transport, "simulated", False))
        # seconds one line (with the script or block it starts) may take; None: no limit.
        # For programs that embed the shell and for tests: .sleep, .wait, .watch, blocks and
        # the debugger's stepping end with a TimeLimitError at the deadline.
        self.time_limit: float | None = None
        self._deadline: float | None = None
        self.state.evaluate = _evaluate
        # told (lines done, lines in all) after each line of -c and of a -f script (a unit's
        # live table, shell/features/units.py); None: nobody asks
        self.progress: Callable[[int, int], None] | None = None
        # whether this run of -c/-f has sent anything that starts motion so far (set by the
        # run, main._run_unattended): what a run cut short must stop (a unit's too)
        self.moved: Callable[[], bool] = lambda: False
        # lines failed in a row for want of an answer, and client._replies when the count
        # began (failed_unanswered)
        self._unanswered = 0
        self._unanswered_since = -1

    def close(self) -> bool:
        """End the session: run the closers; a failing one is reported, the rest still run.
        False if one failed."""
        ok = True
        while self.closers:
            fn = self.closers.pop()
            try:
                fn()
            except TmclError as exc:
                ok = False
                self.out.error(None, str(exc))
        return ok

    # -- module -------------------------------------------------------------------------
    @property
    def module(self) -> Module:
        return self.client.require_module()

    def end_interrupted_line(self) -> None:
        """After Ctrl-C during a command the terminal has echoed ``^C`` where the cursor was:
        end that line, once, before anything else is printed."""
        if self.interactive and not self.interrupted_line_ended:
            sys.stdout.write("\n")
            sys.stdout.flush()
        self.interrupted_line_ended = True

    def reconnect(self) -> TmclError | OSError | None:
        """One attempt to bring the link back (``client.reconnect``): None when it is back,
        else the error that says why not. The REPL, a watch, the stop and ``--keep-going``
        scripts all come back this way."""
        try:
            self.client.reconnect()
        except (TmclError, OSError) as exc:
            return exc
        return None

    def ensure_link(self) -> None:
        """Before each line of -c/-f --keep-going after the link was lost: one attempt to
        bring it back. The line runs either way: one that needs no module (``.sleep``,
        ``.echo``) does what it does, one that needs it waits for the link (``relink``)."""
        if self.client.connected:
            return
        if self.reconnect() is None:
            self.out.info(reconnected(self.client))

    def relink(self) -> None:
        """A request found the link down (``Client._on_link_lost``, set with --keep-going):
        wait for it as long as the request would wait for its answer, then bring the module
        up again; TransportError (nothing sent) if it does not come back in that time."""
        client = self.client
        wait = client.timeout * (1 + client.retries)
        try:
            client.reconnect(wait=wait)
        except (TmclError, OSError) as exc:
            raise TransportError(f"still disconnected after waiting {wait:g} s ({exc}); "
                                 "the line was not run") from exc
        self.out.info(reconnected(client))

    def failed_unanswered(self, exc: BaseException) -> None:
        """A line of -c/-f --keep-going failed: after ``GONE_AFTER`` lines in a row that got
        no answer (the link stayed lost, or nothing came back) with no reply from the module
        since, the module is gone: ModuleGoneError, and the run ends as one with no module
        would (exit status 3). Without it a dead module cost every remaining line its full
        wait: half an hour for a long script. Any reply (an error status too, or the 136 of
        a reconnect) starts the count again; errors that are no silence do not count."""
        if not isinstance(exc, (TransportError, TmclTimeoutError)):
            return
        replies = self.client._replies
        if replies != self._unanswered_since:
            self._unanswered, self._unanswered_since = 0, replies
        self._unanswered += 1
        if self._unanswered >= GONE_AFTER:
            gone = ModuleGoneError(
                f"{self._unanswered} lines in a row got no answer from the module on "
                f"{self.client.describe()}: it is taken to be gone, the rest is not run "
                f"(the last: {exc})")
            gone.record = {"exit": EXIT_CONNECT}  # (JSON: as a run that found no module)
            raise gone

    def report_error(self, line: str | None, exc: BaseException) -> None:
        """Say what went wrong with ``line`` (once: an error already shown is not said
        again), with FILE:LINE while a script runs."""
        where = ""
        if self.location is not None:
            where = f"{self.location[0]}:{self.location[1]}: "
        if getattr(exc, "shown", False):
            # (said already, but still this line's error: a unit's "last error" names it)
            self.out.saw_error(f"{where}{exc}")
            return
        self.out.error(line, f"{where}{exc}", getattr(exc, "record", None))

    # -- confirmation -------------------------------------------------------------------
    def confirm(self, question: str) -> None:
        """Raise Abort unless the user agrees (or --yes was given). Scripts need --yes."""
        if self.yes:
            return
        if self.ask is not None and self.interactive:
            # after a question, an empty line must not repeat the last .step (the debugger's
            # repeat_on_empty): the user answered the question, not the debugger
            self.state.repeat_on_empty = None
            if self.ask(question):
                return
            raise Abort("cancelled; nothing was sent")
        raise Abort(f"not done without confirmation: {as_statement(question)}; pass --yes "
                    "to allow it")

    # -- variables ----------------------------------------------------------------------
    def expand(self, line: str) -> str:
        """Replace ``${name}`` (or ``${expression}``) by its value."""
        if "${" not in line:
            return line
        from .expr import format_number

        check_substitutions(line)

        def sub(m: re.Match) -> str:
            inner = m.group(1).strip()
            if inner in self.variables:
                value = self.variables[inner]
                return value if isinstance(value, str) else format_number(value)
            evaluate = self.state.evaluate
            if callable(evaluate):
                return format_number(evaluate(self, inner))
            raise ValidationError(f"unknown variable {inner!r} (set it with .let {inner} = ...)")

        return _VAR.sub(sub, line)

    # -- running lines ------------------------------------------------------------------
    def split(self, text: str) -> list[str]:
        """Lines of typed text: newlines and ';' separate (see lines.py); a command that owns
        its line (``.watch``) takes the rest of it."""
        return split_text(text)

    def time_left(self) -> float | None:
        """Seconds the current line may still take (None: no limit); TimeLimitError once
        the time is up."""
        if self._deadline is None:
            return None
        left = self._deadline - time.monotonic()
        if left <= 0:
            raise TimeLimitError(f"stopped: the line took longer than the session's time "
                                 f"limit of {self.time_limit:g} s")
        return left

    def run_line(self, line: str | Line) -> Result | None:
        """Run one line (text, or a line ``lines.classify`` read already); raises TmclError
        (or Abort) on failure, after counting it."""
        if self.time_limit is None or self._deadline is not None:  # nested: a script's line
            return self._run_line(line)
        self._deadline = time.monotonic() + self.time_limit
        try:
            return self._run_line(line)
        finally:
            self._deadline = None

    def _run_line(self, line: str | Line) -> Result | None:
        if not isinstance(line, Line):
            line = classify(line)  # `GAP 1, 0 # where`, `.let a = 3 // why`
        text = line.text
        if not text:
            return None
        self.history.append(text)
        capture = self.state.capture  # a block (.repeat/.if) collecting its lines
        if callable(capture) and capture(self, text):
            return None
        first = getattr(self.client, "_replies", 0)
        try:
            result = self._dispatch(line)
        except TmclError as exc:
            if not getattr(exc, "counted", False):  # a failed .expect counts as a failure
                self.stats.errors += 1
            self._record(text, f"error: {exc}")
            raise
        finally:
            self._note_answered(first, text)
            self.report_suspects()
        return result

    def _note_answered(self, first: int, text: str) -> None:
        """The replies after ``first`` that no TMCL line claimed (a .wait's or .expect's
        reads, ``${...}``) answered ``text``: a suspect among them names it."""
        last = getattr(self.client, "_replies", 0)
        ring, where = self._answered, self.location
        for seq in range(max(first + 1, last - ANSWERED + 1), last + 1):
            known = ring[seq % ANSWERED]
            if known is None or known[0] != seq:
                ring[seq % ANSWERED] = (seq, text, where)

    def report_suspects(self) -> None:
        """Say which earlier answers may have been another request's (Doubts.take_suspects):
        a result is never silently kept when the link shows it may be wrong."""
        self.report_shared()
        doubts = getattr(self.client, "_doubts", None)
        for s in doubts.take_suspects() if doubts is not None else ():
            known = self._answered[s.seq % ANSWERED]
            line, where = known[1:] if known is not None and known[0] == s.seq else (None, None)
            self.stats.suspects += 1
            what = f"the answer to {line!r}" if line else "an earlier answer"
            if where is not None:
                what += f" ({where[0]}:{where[1]})"
            text = (f"{what} may have been meant for another request (value {s.reply.value}): "
                    "a reply came later that no request was waiting for; run it again "
                    "to be sure")
            if self.out.json:
                self.out.emit({"line": line, "suspect": True, "warning": text})
            else:
                self.out.warn(f"warning: {text}")

    def report_shared(self) -> None:
        """Say once of each address that two modules answer at (Client.take_shared): every
        command reaches both, and no result from there can be trusted. A run that found one
        fails (``Stats.shared``)."""
        take = getattr(self.client, "take_shared", None)
        for address in take() if callable(take) else ():
            self.stats.shared.append(address)
            text = shared_text(address)
            self.out.saw_error(text)  # (a unit's last error: the reason it failed)
            if self.out.json:
                self.out.emit({"address": address, "duplicate": True, "warning": text})
            else:
                self.out.warn(f"warning: {text}")

    def confirm_answers(self) -> None:
        """At the end of a run (-c, -f): give the last answer the chance to show it was
        another request's (``Doubts.confirm_last``), then report the suspects."""
        doubts = getattr(self.client, "_doubts", None)
        if doubts is not None and self.client.connected:
            try:
                doubts.confirm_last()
            except TransportError:
                pass  # the link went: the next command, if any, says so
        self.report_suspects()

    def _dispatch(self, line: Line) -> Result | None:
        text, cmd = line.text, line.command
        if line.unknown:
            raise ValidationError(unknown_command(line.word))
        if cmd is not None:
            args = line.args
            if cmd.expands and "${" in args:
                args = self.expand(args)
            if args and cmd.syntax == cmd.name:  # `.stopall now`: a usage error, nothing sent
                raise ValidationError(f"{cmd.name} takes no arguments (got {args!r})")
            frames, lines = frames_sent(self.client), self.stats.commands
            try:
                cmd.handler(self, args)
            finally:  # (counted when it failed half-way too: what went out went out)
                if frames_sent(self.client) > frames and self.stats.commands == lines:
                    self.stats.shell_commands += 1
            self._record(text, "")
            return None
        return self.run_tmcl(text)

    def run_plain(self, text: str) -> Result:
        """``run_line`` for a script's plain TMCL line: its comment already stripped, no
        ``${...}``, not a command, no block collecting and no time limit (the script runner
        checks those). The layers between are left out, not the checks, counts or hooks: a
        script pays this per line."""
        client = self.client
        try:
            if not client.transport.is_open:  # (client.connected, one call fewer)
                self.ensure_link()  # the link was lost on an earlier line (--keep-going)
            return self.run_tmcl(text)
        except TmclError as exc:
            if not getattr(exc, "counted", False):
                self.stats.errors += 1
            if self.recorders:
                self._record(text, f"error: {exc}")
            raise
        finally:
            # (a client without the list: ask it)
            if getattr(client, "_suspects", True) or getattr(client, "shared_news", False):
                self.report_suspects()

    def run_tmcl(self, text: str, *, show: bool = True) -> Result:
        client = self.client
        enc, req = prepare_typed(client, self.expand(text) if "${" in text else text)
        spec = enc.spec
        if spec is None or spec.confirm:  # may refuse, or ask first
            self._before_sending(enc)
        sent = client.stats["sent"]
        try:
            reply = client._send_encoded(enc, req)
        except (TmclTimeoutError, ChecksumError) as exc:
            if idempotent(req) or isinstance(exc, TimeLimitError):
                raise
            # (the client says whether the frame went out; if it cannot tell, it may have)
            raise _unsure(client, req, exc, getattr(exc, "sent", True)) from exc
        except BaseException:
            # Ctrl-C or SIGTERM before the reply: a command that went out is one the module
            # got, and the summary after it counts it ("at line 1 after 1 command sent")
            if client.stats["sent"] > sent:
                self.stats.commands += 1
            raise
        result = Result(text, enc, reply)
        if reply is not None:
            seq = client._replies
            self._answered[seq % ANSWERED] = (seq, text, self.location)
            doubt = getattr(client, "doubt_on_last", None)
            if doubt is not None and doubt():  # judged, and not settled: said in line
                self.stats.suspects += 1
                result = result._replace(in_doubt=True)
        self.last_result = result
        self.stats.commands += 1
        if show:
            self.out.result(result, client.module)
        if reply is not None and reply.status not in OK_STATUSES:
            self._record(text, f"error: status {reply.status}")
            err = StatusError(reply.status, reply)
            err.shown = show  # type: ignore[attr-defined]  # the result line already said it
            raise err
        if self.recorders:
            self._record(text, "" if reply is None else str(reply.value if reply.version is None
                                                              else reply.version))
        return result

    def _before_sending(self, enc: asm.Encoded) -> None:
        """What the instruction set says of a command before it is sent (``confirm``,
        ``not_a_line``): a question, or a refusal (a raw number: its control's entry)."""
        p, ins = enc.parameter, enc.instruction
        spec = enc.spec or isa.control(ins.opcode)
        if spec is None:
            return
        refusal = getattr(spec, "not_a_line", None)
        if refusal:
            raise ValidationError(f"{ins.opcode} ({spec.name}) is not sent as a line: {refusal}")
        question = confirmation(enc)
        if question is not None:
            self.confirm(question)

    def can_answer(self) -> bool:
        """Would a question be answered (--yes, or someone at the terminal)? Where not, a
        run that would ask is better refused before it sends anything."""
        return self.yes or (self.ask is not None and self.interactive)

    def _record(self, line: str, outcome: str) -> None:
        for fn in list(self.recorders):
            fn(line, outcome)


def _unsure(client: Client, req, exc: TmclError, sent: bool) -> TmclError:
    """A command that is never repeated by itself (MVP REL, RFS START, CALC, ...) got no
    usable answer: say whether the module may have executed it, so it is not typed again
    blindly (a relative move would go twice as far)."""
    name = _name(req)
    if sent:
        more = (f"{name} is not sent again by itself: the module may have executed it; "
                "check (for example GAP ActualPosition) before sending it again")
    else:
        more = f"{name} was not sent"
    err = type(exc)(f"{exc}; {more}")
    err.__dict__.update(exc.__dict__)
    return err


def _evaluate(session: Session, text: str) -> int | float:
    """The expression engine, imported the first time a line holds ``${...}``."""
    from .expr import evaluate

    return evaluate(session, text)




def frames_sent(client) -> int:
    """Frames the client has sent so far (0 for a client that does not count them)."""
    stats = getattr(client, "stats", None)
    return stats.get("sent", 0) if isinstance(stats, dict) else 0


def check_substitutions(text: str) -> None:
    """A ``${`` with no ``}`` after it is an error: it was sent or printed as it stood."""
    if "${" in _VAR.sub("", text):
        raise ValidationError("unterminated ${...}: a '}' is missing")
