"""The dot-commands of scripts: blocks typed at the prompt, ``.onerror``, ``.source``,
variables, checks and waits on certain answers, ``.sleep``, ``.echo``, recording and history.

The language they belong to (reading, checking and running a script, the blocks' parser) is
``lang/script.py``; these are its commands, imported the first time one of them runs.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

from ...base import clock, files
from ...base.errors import ChecksumError, FrameError, TmclTimeoutError, ValidationError
from ...client.ledger import CONFIRM_ROUNDS
from ...ops.certain import read_until_certain
from ..lang import expr, options
from ..lang.commands import command, options_of
from ..lang.script import (BlockCollector, CheckFailed, ScriptError, _word, parse_condition,
                           parse_let, parse_repeat, run_source, set_onerror)
# the checks before a script runs, named by the commands' entries (Command.check)
from ..lang.script import (check_expect, check_let, check_onerror, check_sleep,  # noqa: F401
                           check_wait)

if TYPE_CHECKING:
    from ..lang.session import Session

WAIT_TIMEOUT = 30.0  # .wait default, seconds
WAIT_INTERVAL = 0.05
_VIEWS = {".watch", ".plot", ".history", ".help", ".record"}  # not replayed by .record


# -- blocks typed at the prompt (or in -c) -------------------------------------------------

def _open_block(session: Session, word: str, args: str) -> None:
    if word == ".repeat":
        expr.validate(session, parse_repeat(args)[0])
    else:
        expr.validate(session, parse_condition(word, args))
    session.state.capture = BlockCollector(f"{word} {args}")
    if session.interactive:
        session.out.info("  (collecting lines until .end)")


@command(".repeat")
def cmd_repeat(session: Session, args: str) -> None:
    _open_block(session, ".repeat", args)


@command(".if")
def cmd_if(session: Session, args: str) -> None:
    _open_block(session, ".if", args)


def _outside_block(word: str) -> Callable[[Session, str], None]:
    def handler(session: Session, args: str) -> None:
        raise ValidationError(f"{word} without an open .repeat or .if block")
    return handler


command(".elif")(
    _outside_block(".elif"))
command(".else")(_outside_block(".else"))
command(".end")(
    _outside_block(".end"))


@command(".onerror")
def cmd_onerror(session: Session, args: str) -> None:
    if session.state.script_depth == 0:
        raise ValidationError(".onerror works inside scripts (-f, .source)")
    set_onerror(session, args)


@command(".source")
def cmd_source(session: Session, args: str) -> None:
    if not args:
        raise ValidationError(".source needs a file name")
    ok = run_source(session, args)
    if not ok:
        err = ScriptError(f"{args} stopped by an error")
        err.shown = True  # type: ignore[attr-defined]  # reported with FILE:LINE already
        raise err


@command(".let")
def cmd_let(session: Session, args: str) -> None:
    if not args:
        _show_variables(session)
        return
    name, expression = parse_let(session.expand(args))
    value = expression.evaluate(expr.SessionContext(session))
    session.variables[name] = value
    if session.out.json and session.interactive:
        session.out.emit({"let": name, "value": value})
    elif session.interactive:
        session.out.print(f"{name} = {expr.format_number(value)}", markup=False)


def _show_variables(session: Session) -> None:
    if session.out.json:
        session.out.emit({"variables": dict(session.variables)})
        return
    if not session.variables:
        session.out.info("no variables (set one with .let NAME = EXPR)")
    for name, value in sorted(session.variables.items()):
        shown = repr(value) if isinstance(value, str) else expr.format_number(value)
        session.out.print(f"{name} = {shown}", markup=False)


def check(expression: expr.Expression, ctx: expr.SessionContext) -> tuple[bool, str, str]:
    """Evaluate a condition: (holds, what the left side was, what the right side was).

    For ``a OP b`` the sides are described as read (``GIO 3, 2 is 1``); for any other
    condition the reads it made (or its value) stand on the left.
    """
    root = expression.root
    if isinstance(root, expr.Binary) and root.op in expr.COMPARISONS:
        left, right = root.left.evaluate(ctx), root.right.evaluate(ctx)
        ok = expr.COMPARISONS[root.op](left, right)
        rhs = "" if isinstance(root.right, expr.Num) else \
            f"{_side(root.right, ctx)} is {expr.format_number(right)}"
        return ok, f"{_side(root.left, ctx)} is {expr.format_number(left)}", rhs
    value = expression.evaluate(ctx)
    seen = [f"{k} is {expr.format_number(v)}" for k, v in ctx.trace.items()]
    return bool(value), ", ".join(seen) or f"value {expr.format_number(value)}", ""


@dataclass
class Judged:
    """A condition checked on certain answers (``judge``): ``doubt`` names the reads whose
    answer stayed in doubt (the sides are then not to be stated as read)."""

    ok: bool
    left: str
    right: str
    doubt: list[str]
    answered: dict[int, str]  # every reply the check took (Client._replies -> read)
    tries: int = 1  # times the condition was evaluated
    disagreed: bool = False  # (ASCII) two evaluations in a row never came out the same
    values: dict[str, expr.Number] = field(default_factory=dict)  # each read, as read

    def record(self, expression: expr.Expression, passed: bool) -> dict[str, object]:
        """The JSON fields of a check (.expect, .wait): the same keys, passed or not; the
        values read are left out while in doubt (not stated as read)."""
        obj: dict[str, object] = {"check": expression.text, "passed": passed}
        if self.doubt:
            obj["in_doubt"] = list(self.doubt)
        else:
            obj["values"] = dict(self.values)
        return obj

    def seen(self) -> str:
        return f"{self.left}{', ' + self.right if self.right else ''}"

    def in_doubt(self) -> str:
        times = f" (read {self.tries} times)" if self.tries > 1 else ""
        if self.disagreed:
            return (f"it came out differently on every two evaluations in a row{times}, and "
                    "an ASCII reply carries no checksum to tell a changed digit")
        reads = " and ".join(self.doubt)
        return (f"the answer to {reads} is in doubt{times}: the line brought a reply nothing "
                "was waiting for, so it may have been another request's")


def judge(session: Session, expression: expr.Expression, *, again: bool = True,
          confirm: bool = True) -> Judged:
    """``check`` on answers known to be the module's own. On a line that brings a reply
    twice, a read may take a copy of the reply before it (same command, same layout); the
    client finds that out when the real answer comes while nothing waits for it, which one
    more exchange (136 type 1, ``confirm``) gives the chance to. A read in doubt is read
    again (the whole condition, ``CONFIRM_ROUNDS`` times at most, if ``again``).
    The suspects a check dealt with are taken from the client (not reported again)."""
    # replies without a checksum (ASCII): the client reads settings twice, but motion state
    # and inputs once, so the condition itself must come out the same on two evaluations
    twice = not session.client.mode.checksummed
    answered: dict[int, str] = {}
    seen: list[tuple[bool, str, str, dict[str, expr.Number]]] = []  # each evaluation
    outcome: bool | None = None

    def evaluate(_doubt: set[str] | None) -> dict[int, str]:
        ctx = expr.TrackedContext(session)
        try:
            ok, left, right = check(expression, ctx)
            seen.append((ok, left, right, dict(ctx.trace)))
        finally:
            answered.update(ctx.answered)
        return ctx.answered

    def settled(doubt: set[str]) -> bool:
        nonlocal outcome
        if doubt:
            outcome = None
            return False
        ok = seen[-1][0]
        if twice and outcome is not ok:
            outcome = ok
            return False
        return True

    found = read_until_certain(session.client, evaluate, confirm=confirm,
                               confirm_again=confirm, accept=settled,
                               again=(CONFIRM_ROUNDS if again else 0) + twice)
    ok, left, right, values = seen[-1]
    session.client._doubts.settle(answered)
    if twice and not found.accepted and not found.doubt:  # never agreed twice in a row
        return Judged(ok, left, right, [expression.text], answered, found.again + 1,
                      values=values, disagreed=True)
    return Judged(ok, left, right, sorted(found.doubt), answered, found.again + 1,
                  values=values)


def _side(node: expr.Node, ctx: expr.SessionContext) -> str:
    """A read by the TMCL it sent (``GIO 3, 2`` for ``GIO (port), 2``), else as written."""
    return node.tmcl(ctx) if isinstance(node, expr.Read) else node.text


@command(".expect")
def cmd_expect(session: Session, args: str) -> None:
    if not args:
        raise ValidationError(".expect needs a condition: .expect GAP 1, 0 == 5000")
    expression = expr.parse(session.expand(args))
    judged = judge(session, expression)
    if judged.doubt or not judged.ok:  # in doubt: judged on no certain value, not a pass
        session.stats.checks_failed += 1
        err = CheckFailed(f"expectation in doubt: {expression.text} ({judged.in_doubt()})"
                          if judged.doubt else
                          f"expectation failed: {expression.text} ({judged.seen()})")
        err.record = judged.record(expression, False)  # type: ignore[attr-defined]
        raise err
    session.stats.checks_passed += 1
    if session.out.json:
        session.out.emit({"line": f".expect {args}", **judged.record(expression, True)})
    else:
        session.out.print(f"passed: {expression.text} ({judged.left})", style="tmcl.ok",
                          markup=False)




# what a poll of .wait may meet and still poll again: no answer, or none intact (the module
# refusing the read, a StatusError, is an answer and ends the wait)
_UNREAD = (TmclTimeoutError, ChecksumError, FrameError)


@command(".wait")
def cmd_wait(session: Session, args: str) -> None:
    rest, opts = options.parse(args, options_of(".wait"))
    timeout = options.float_value(opts, "--timeout", WAIT_TIMEOUT, allow_none=True,
                                limit="wait_timeout")
    interval = options.float_value(opts, "--interval", WAIT_INTERVAL, limit="interval")
    assert interval is not None
    if not rest:
        raise ValidationError(".wait needs a condition: .wait GAP 8, 0 == 1")
    expression = expr.parse(session.expand(rest))
    last: Judged | None = None
    start = time.monotonic()
    last_at = 0.0  # seconds into the wait when ``last`` was read
    unread: str | None = None  # why the polls since ``last`` read nothing

    def holds() -> bool:
        nonlocal last, last_at, unread
        try:
            judged = judge(session, expression, again=False, confirm=False)
        except _UNREAD as exc:  # no answer, or none intact: the next poll may get one
            unread = str(exc)
            return False
        before, last, last_at, unread = last, judged, time.monotonic() - start, None
        if before is not None:  # (judged by this poll's requests)
            session.client._doubts.settle(before.answered)
        if not last.ok or last.doubt:
            return False  # a "not yet" in doubt costs one more poll: a condition met is confirmed
        last.doubt = sorted(session.client.in_doubt(last.answered, confirm=True))
        session.client._doubts.settle(last.answered)
        return not last.doubt

    left = session.time_left()
    capped = left is not None and (timeout is None or timeout > left)
    try:
        session.client.wait_until(holds, left if capped else timeout, interval)
    except TmclTimeoutError:
        if capped:
            time.sleep(0.001)
            session.time_left()
        elapsed = time.monotonic() - start
        record: dict[str, object] = {"check": expression.text, "passed": False,
                                     "timed_out": True, "values": None}
        if last is None:
            seen = f"no value could be read: {unread}"
        else:
            # the last answer judged, so it is not stated as read when it was in doubt
            doubt = sorted(session.client.in_doubt(last.answered, confirm=True)) or last.doubt
            session.client._doubts.settle(last.answered)
            last.doubt = doubt
            seen = last.in_doubt() if doubt else last.seen()
            record.update(last.record(expression, False), read_at=round(last_at, 3))
            if unread is not None:
                seen += (f", read at {last_at:.2f} s; the reads after it failed: {unread}")
        if unread is not None:
            record["read_error"] = unread
        record["elapsed"] = round(elapsed, 3)
        err = TmclTimeoutError(f"timed out after {timeout:g} s waiting for {expression.text} "
                               f"({seen})")
        err.record = record  # type: ignore[attr-defined]
        raise err from None
    assert last is not None
    elapsed = time.monotonic() - start
    if session.out.json:
        session.out.emit({"line": f".wait {args}", **last.record(expression, True),
                          "elapsed": round(elapsed, 3)})
    else:  # said as .expect says a pass, with how long it took
        session.out.print(f"reached after {elapsed:.2f} s: {expression.text} ({last.left})",
                          style="tmcl.ok", markup=False)


@command(".sleep")
def cmd_sleep(session: Session, args: str) -> None:
    if not args:
        raise ValidationError(".sleep needs seconds: .sleep 0.5")
    seconds = expr.seconds("sleep", expr.evaluate(session, args), ".sleep")
    left = session.time_left()
    if left is not None and seconds > left:
        clock.sleep(left)
        session.time_left()  # raises: the time is up
    clock.sleep(seconds)


def _split_redirect(text: str) -> tuple[str, str | None, str]:
    """``TEXT > FILE`` / ``TEXT >> FILE`` (outside quotes and ${...}): (text, mode, file)."""
    quote, brace, cut = None, 0, None
    for i, ch in enumerate(text):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif text.startswith("${", i):
            brace += 1
        elif ch == "}" and brace:
            brace -= 1
        elif ch == ">" and not brace and cut is None:
            cut = i
    if cut is None:
        return text, None, ""
    mode = "a" if text.startswith(">>", cut) else "w"
    target = text[cut + (2 if mode == "a" else 1):].strip()
    if not target:
        raise ValidationError(".echo: a file name is needed after '>'")
    return text[:cut].rstrip(), mode, target


def _unquote(text: str) -> str:
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "\"'":
        return text[1:-1]
    return text


@command(".echo")
def cmd_echo(session: Session, args: str) -> None:
    text, mode, target = _split_redirect(args)
    line = _unquote(session.expand(text))
    if mode is None:
        if session.out.json:
            session.out.emit({"echo": line})
        else:
            session.out.print(line, markup=False)
        return
    path = Path(_unquote(session.expand(target))).expanduser()
    before = ""
    if mode == "a" and path.is_file():  # appended all or nothing, like any write
        before = files.read_text(path, what="file")
        if before and not before.endswith("\n"):
            before += "\n"
    files.write_file(path, before + line + "\n")


# -- recording and history ---------------------------------------------------------------

class Recorder:
    """Writes typed lines to a script that replays as-is; results become ``//`` comments.

    Failed lines are written commented out (replaying them would fail again), views such as
    ``.watch`` too (a script would wait in them forever).
    """

    def __init__(self, session: Session, path: Path, fh: files.AtomicWriter):
        self.session = session
        self.path = path
        self.fh = fh
        self.lines = 0
        self._last: tuple[int, str] | None = None

    def __call__(self, line: str, outcome: str) -> None:
        s = self.session
        if s.state.script_depth:
            return  # lines of a running script or block: the line that started it is recorded
        word = _word(line)[0]
        if word == ".record":
            return
        key = (len(s.history), line)
        if key == self._last:
            return  # the same line reported twice (an error reply, then its exception)
        self._last = key
        if outcome.startswith("error"):
            text = f"# {line}    // {outcome}"
        elif word in _VIEWS:
            text = f"# {line}    // view, not replayed"
        elif outcome and _is_read(s, line):
            text = f"{line}    // = {outcome}"
        else:
            text = line
        try:
            self.fh.write(text + "\n")
            self.fh.flush()
        except files.FileError as exc:  # disk full: stop recording, say so, keep the old file
            self.stop()
            self.session.out.error(None, f"{exc}; recording stopped, {self.path} unchanged")
            return
        self.lines += 1

    def stop(self) -> None:
        """Forget the recording: the file keeps what it held before ``.record``."""
        self.fh.abort()
        self._detach()

    def _detach(self) -> None:
        s = self.session
        if self in s.recorders:
            s.recorders.remove(self)
        if s.state.record is self:
            s.state.record = None
        if self.close in s.closers:
            s.closers.remove(self.close)

    def close(self) -> None:
        """Put the recording in place of the file (``.record off``, or the session ends)."""
        self._detach()
        self.fh.commit()


def _is_read(session: Session, line: str) -> bool:
    r = session.last_result
    return (r is not None and r.line == line and r.encoded.spec is not None
            and r.encoded.spec.reads)


# the words that end a recording; they are never taken as a file name (a file called
# `stop` is `./stop`)
RECORD_OFF = ("off", "stop")


@command(".record")
def cmd_record(session: Session, args: str) -> None:
    current: Recorder | None = session.state.record  # type: ignore[assignment]
    if not args:
        if current is None:
            session.out.info("not recording (.record FILE starts)")
        else:
            session.out.info(f"recording to {current.path} ({current.lines} lines)")
        return
    if current is not None:
        current.close()
        session.out.info(f"recorded {current.lines} lines to {current.path}")
    if args.strip().lower() in RECORD_OFF:
        if current is None:
            session.out.info("not recording")
        return
    path = Path(_unquote(args.strip())).expanduser()
    # written beside PATH and moved over it at '.record off' or the end of the session, so
    # a full disk or a crash never leaves half a script where a good one was
    fh = files.atomic_writer(path)
    client = session.client
    module = client.module.name if client.module else "unknown module"
    fh.write(f"# recorded by tmclsh {datetime.now():%Y-%m-%d %H:%M} "
             f"({module}, address {client.address})\n# replay: tmclsh -f {path}\n")
    fh.flush()
    rec = Recorder(session, path, fh)
    session.state.record = rec
    session.recorders.append(rec)
    session.closers.append(rec.close)
    session.out.info(f"recording to {path} (.record off to stop)")


@command(".history")
def cmd_history(session: Session, args: str) -> None:
    lines = session.history[:-1] if session.history[-1:] and \
        _word(session.history[-1])[0] == ".history" else list(session.history)
    first = 1
    if args:
        n = options.int_value({"N": args.strip()}, "N", None, minimum=1)
        assert n is not None
        first = max(1, len(lines) - n + 1)
        lines = lines[-n:]
    if session.out.json:
        session.out.emit({"history": lines})
        return
    for i, line in enumerate(lines, first):
        session.out.print(f"{i:4d}  {line}", markup=False)
