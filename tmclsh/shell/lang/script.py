"""Scripts: files of shell lines, replayed with ``-f FILE``/``.source FILE``: read, checked,
cut into blocks and run (the dot-commands that make them useful, variables, checks, waits,
recording, are the feature ``features/scripting.py``).

A script is read whole and checked before anything is sent (block structure, unknown
commands, expressions, and every TMCL line without ``${...}`` against the module), so a typo
on line 40 cannot leave the motor half-way through lines 1-39. Stdin (``-f -``, or a pipe)
is run as it arrives, block by block, so a program can drive the shell through a pipe.

Blocks::

    .repeat COUNT [as NAME]     lines until the matching .end, COUNT times (NAME = 0..COUNT-1)
    .if EXPR / .elif EXPR / .else / .end

They nest, and also work typed at the prompt or in ``-c``: the lines are collected until the
block's ``.end`` and then run.

Errors stop the script with ``FILE:LINE: message`` (``--keep-going`` continues after runtime
errors, never after syntax errors). Exit status: 0 all well, 1 a command, check or wait
failed, 2 the script could not be read or has a syntax error (nothing was sent).
"""

from __future__ import annotations

import re
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ...base import files, limits
from ...base.edges import error_record
from ...base.interrupts import Terminated
from ...base.errors import (EXIT_CONNECT, EXIT_FAILED, EXIT_OK, EXIT_USAGE, AsmError,
                            ModuleGoneError, RangeError, TmclError, ValidationError)
from . import commands, expr, options
from .commands import options_of
from .lines import classify, split_line
from .session import QuitShell, check_substitutions, encode_typed, unknown_command

if TYPE_CHECKING:
    from .session import Session

STDIN = "<stdin>"
PROGRESS_MIN_STEPS = 20  # scripts with fewer steps run without a progress bar


# What stopped a script before anything was sent, as the summary names it
SYNTAX, RANGE, CHECK, NO_FILE, UNREADABLE = ("syntax", "range", "check", "no such file",
                                             "unreadable")
UNANSWERED = "unanswered"  # a backup's line would ask, and nobody can answer (no --yes)
_KIND_TEXT = {SYNTAX: "syntax error", RANGE: "a value out of range",
              CHECK: "a line the module would refuse", NO_FILE: "no such file",
              UNREADABLE: "cannot read the file",
              UNANSWERED: "a line that asks first, and no --yes"}


class ScriptError(TmclError):
    """A script problem that is not the module's: unreadable file, bad block structure."""

    def __init__(self, message: str, kind: str = SYNTAX):
        self.kind = kind
        super().__init__(message)


class CheckFailed(TmclError):
    """``.expect`` found the condition false."""

    counted = True  # in checks_failed, not also in errors


class ScriptSyntaxError(ScriptError):
    def __init__(self, file: str, line: int, message: str, kind: str = SYNTAX,
                 text: str | None = None):
        self.file, self.line, self.message = file, line, message
        self.text = text  # the line refused (--json's "line"), when one line is to blame
        super().__init__(f"{file}:{line}: {message}", kind)


def error_kind(exc: TmclError) -> str:
    """Why a line was refused before the run: syntax, a value out of range, or a check."""
    if isinstance(exc, (ScriptError, AsmError)):
        return exc.kind
    if isinstance(exc, RangeError):
        return RANGE
    return SYNTAX


# -- the parsed script -------------------------------------------------------------------

@dataclass
class Node:
    file: str
    line: int
    text: str


@dataclass
class Step(Node):
    """One line, run through ``Session.run_line``; or, for a plain TMCL line (``plain``: its
    text without the comment; no ``${...}``, not a command), through ``Session.run_plain``."""

    plain: str | None = None


@dataclass
class Repeat(Node):
    count: expr.Expression | None = None
    var: str | None = None
    body: list[Node] = field(default_factory=list)


@dataclass
class If(Node):
    # (condition, body); condition None is the .else branch
    branches: list[tuple[expr.Expression | None, list[Node]]] = field(default_factory=list)


@dataclass
class Include(Node):
    path: str = ""
    body: list[Node] = field(default_factory=list)


def _word(text: str) -> tuple[str, str]:
    parts = text.split(None, 1)
    return parts[0].lower(), (parts[1].strip() if len(parts) > 1 else "")


_AS = re.compile(r"^(.*\S)\s+as\s+([A-Za-z_][A-Za-z0-9_]*)$", re.IGNORECASE | re.DOTALL)


def parse_repeat(args: str) -> tuple[expr.Expression, str | None]:
    if not args:
        raise ValidationError(".repeat needs a count: .repeat COUNT [as NAME]")
    var = None
    m = _AS.match(args)
    if m:
        args, var = m.group(1), m.group(2)
        check_var_name(var)
    return expr.parse(args), var


def parse_condition(word: str, args: str) -> expr.Expression:
    if not args:
        raise ValidationError(f"{word} needs a condition: {word} EXPR")
    return expr.parse(args)


MAX_BLOCK_DEPTH = 32  # .repeat/.if blocks inside one another


_AGAIN_LINES = 4096  # distinct plain lines Parser.nodes keeps (a file is bounded, stdin not)


class Parser:
    """Lines in, nodes out; a node is yielded as soon as it is complete (for stdin)."""

    def __init__(self, session: Session, file: str, base: Path | None,
                 stack: tuple[str, ...] = ()):
        self.session = session
        self.file = file
        self.base = base
        self.stack = stack + (file,)
        self.precheck = True
        self.outer_blocks = 0  # blocks open around the .source that includes this file
        self.seen: dict[str, str | None] = {}  # TMCL lines checked: Step.plain of each

    def fail(self, line: int, message: str, kind: str = SYNTAX,
             text: str | None = None) -> ScriptSyntaxError:
        return ScriptSyntaxError(self.file, line, message, kind, text)

    def nodes(self, lines: Iterable[str]) -> Iterator[Node]:
        open_: list[tuple[Node, list[Node]]] = []  # open blocks and the body being filled
        held = 0  # lines inside open blocks: a block without .end on stdin is bounded too
        # a physical line met before that was one plain TMCL line, and what it was: what a
        # long script mostly is, taken without splitting and checking it again
        again: dict[str, tuple[str, str]] = {}
        file = self.file
        for number, raw in enumerate(lines, 1):
            if not open_:
                hit = again.get(raw)
                if hit is not None:
                    yield Step(file, number, hit[0], hit[1])
                    continue
            texts = split_line(raw)  # `GAP 1, 0; GAP 2, 0` is two lines
            if len(texts) == 1 and not open_ and self.seen.get(texts[0]):
                if len(again) >= _AGAIN_LINES:
                    again.clear()
                again[raw] = (texts[0], self.seen[texts[0]])  # type: ignore[assignment]
            for text in texts:
                held = held + 1 if open_ else 0
                if held > files.MAX_LINES:
                    raise self.fail(open_[-1][0].line, f"{_word(open_[-1][0].text)[0]} has no "
                                    f".end within {files.MAX_LINES:,} lines")
                node = self.line(number, text, open_)
                if node is None:
                    continue
                if open_:
                    open_[-1][1].append(node)
                else:
                    yield node
        if open_:
            node = open_[-1][0]
            raise self.fail(node.line, f"{_word(node.text)[0]} has no matching .end",
                            text=node.text)

    def line(self, number: int, text: str, open_: list[tuple[Node, list[Node]]]) -> Node | None:
        """Parse one line into a complete node, or None while a block is still open."""
        try:
            return self._line(number, text, open_)
        except ScriptSyntaxError as exc:
            if exc.text is None and exc.file == self.file:  # (an included file's says its own)
                exc.text = text
            raise
        except TmclError as exc:
            raise self.fail(number, str(exc), error_kind(exc), text) from None

    def _line(self, number: int, text: str, open_: list[tuple[Node, list[Node]]]) -> Node | None:
        # ``text`` is one shell line, its comment off (split_line took it)
        file = self.file
        if "${" in text:
            check_substitutions(text)
        if not text.startswith("."):
            # a line seen before passed the same checks (parsing sends nothing, so the
            # module and mode cannot change between); a long script repeats its lines
            seen = self.seen.get(text, False)
            if seen is not False:
                return Step(file, number, text, seen)
            if len(self.seen) >= _AGAIN_LINES:
                self.seen.clear()  # (stdin may bring any number of distinct lines)
            if classify(text).command is not None:  # bare help/quit
                self.seen[text] = None
                return Step(file, number, text)
            if self.precheck and "${" not in text:
                encode_typed(self.session.client, text)
            # what Session.run_line would send as it is (see Step.plain)
            plain = self.seen[text] = text if "${" not in text else None
            return Step(file, number, text, plain)
        word, args = _word(text)
        if word in (".repeat", ".if") and len(open_) + self.outer_blocks >= MAX_BLOCK_DEPTH:
            raise self.fail(number, f"blocks nested more than {MAX_BLOCK_DEPTH} deep")
        if word == ".repeat":
            count, var = parse_repeat(args)
            expr.validate(self.session, count)
            node: Node = Repeat(file, number, text, count, var)
            open_.append((node, node.body))  # type: ignore[attr-defined]
            return None
        if word == ".if":
            cond = parse_condition(word, args)
            expr.validate(self.session, cond)
            node = If(file, number, text)
            node.branches.append((cond, []))  # type: ignore[attr-defined]
            open_.append((node, node.branches[-1][1]))  # type: ignore[attr-defined]
            return None
        if word in (".elif", ".else"):
            if not open_ or not isinstance(open_[-1][0], If):
                raise self.fail(number, f"{word} without .if")
            node = open_[-1][0]
            assert isinstance(node, If)
            if node.branches[-1][0] is None:
                raise self.fail(number, f"{word} after .else")
            cond = None
            if word == ".elif":
                cond = parse_condition(word, args)
                expr.validate(self.session, cond)
            elif args:
                raise self.fail(number, ".else takes no argument (use .elif EXPR)")
            node.branches.append((cond, []))
            open_[-1] = (node, node.branches[-1][1])
            return None
        if word == ".end":
            if args:
                raise self.fail(number, ".end takes no argument")
            if not open_:
                raise self.fail(number, ".end without .repeat or .if")
            return open_.pop()[0]
        if word == ".source":
            return self.include(number, text, args, len(open_))
        cmd = commands.find(word)
        if cmd is None:
            raise self.fail(number, unknown_command(word))
        check = cmd.checker()  # (the entry names it; its feature module is imported)
        if check is not None:
            check(self.session, args)
        if cmd.changes_link:
            self.precheck = False
        return Step(file, number, text)

    def include(self, number: int, text: str, args: str, blocks: int = 0) -> Include:
        if not args:
            raise self.fail(number, ".source needs a file name")
        if "${" in args:
            raise self.fail(number, ".source takes a plain file name (no ${...})")
        path = resolve(args, self.base)
        if str(path) in self.stack:
            raise self.fail(number, f"{args} includes itself")
        if len(self.stack) > 16:
            raise self.fail(number, "includes nested more than 16 deep")
        lines = as_replayed(self.session, path,
                            read_lines(path, lambda msg, kind: self.fail(number, msg, kind)))
        sub = Parser(self.session, str(path), path.parent, self.stack)
        sub.precheck = self.precheck
        sub.outer_blocks = self.outer_blocks + blocks + 1  # an include nests like a block
        body = list(sub.nodes(lines))
        self.precheck = sub.precheck
        return Include(self.file, number, text, str(path), body)


def resolve(name: str, base: Path | None) -> Path:
    path = Path(name.strip().strip("\"'")).expanduser()
    if not path.is_absolute() and base is not None:
        path = base / path
    return path


def read_lines(path: Path, fail: Callable[[str, str], Exception]) -> list[str]:
    """A script's lines: at most ``files.MAX_FILE`` bytes, ``files.MAX_LINES`` lines and
    ``files.MAX_LINE`` characters a line (``/dev/zero`` is refused, not read to the end);
    ``fail(message, kind)`` makes the error when it cannot be read."""
    try:
        exists = path.exists()
    except OSError as exc:  # a name the system refuses (too long)
        raise fail(f"cannot read {path}: {exc.strerror or exc}", UNREADABLE) from None
    if not exists:
        raise fail(f"no such file: {path}", NO_FILE)
    try:
        lines = files.read_lines(path, "script")
    except files.FileError as exc:
        raise fail(str(exc), UNREADABLE) from None
    except (OSError, ValueError) as exc:
        raise fail(f"cannot read {path}: {getattr(exc, 'strerror', None) or exc}",
                   UNREADABLE) from None
    for no, line in enumerate(lines, 1):
        if len(line) > files.MAX_LINE:
            raise fail(f"{path}:{no}: line longer than {files.MAX_LINE:,} characters",
                       UNREADABLE)
    return lines


def check_var_name(name: str) -> None:
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise ValidationError(f"{name!r} is not a variable name (letters, digits, _)")
    low = name.lower()
    if low in expr.KEYWORDS or low in expr.FUNCTIONS or name.upper() in expr.read_mnemonics():
        raise ValidationError(f"{name!r} is a reserved word; choose another variable name")


def parse_let(args: str) -> tuple[str, expr.Expression]:
    name, sep, rest = args.partition("=")
    name = name.strip()
    if not sep or rest.startswith("="):
        raise ValidationError(".let wants NAME = EXPRESSION (e.g. .let speed = 1000)")
    check_var_name(name)
    return name, expr.parse(rest)


# Syntax checks run before a script starts: (session, argtext) -> None, raising on error.
# Other features add theirs (watch.py registers ".watch").
def _check_let(session: Session, args: str) -> None:
    if args:
        expr.validate(session, parse_let(args)[1])


def _check_expr_options(command: str) -> Callable[[Session, str], None]:
    def check(session: Session, args: str) -> None:
        rest, opts = options.parse(args, options_of(command))
        for name in opts:
            options.float_value(opts, name, None, allow_none=name == "--timeout",
                                limit="wait_timeout" if name == "--timeout" else "interval")
        if not rest:
            raise ValidationError("an expression is needed")
        expr.validate(session, expr.parse(rest))
    return check


def check_sleep(session: Session, args: str) -> None:
    if not args:
        raise ValidationError(".sleep needs seconds: .sleep 0.5")
    expr.validate(session, expr.parse(blank_substitutions(args)))


def blank_substitutions(text: str) -> str:
    """``${...}`` cannot be checked before the run; check the rest with a placeholder."""
    return re.sub(r"\$\{[^}]*\}", "0", text)


def check_onerror(session: Session, args: str) -> None:
    if not args:
        raise ValidationError(".onerror needs a line to run (e.g. .onerror MST 0) or 'off'")
    if args.lower() == "off":
        return
    if args.startswith("."):
        if commands.find(_word(args)[0]) is None:
            raise ValidationError(f"unknown shell command {_word(args)[0]!r}")
    elif "${" not in args:
        session.client.encode(args)


def check_let(session: Session, args: str) -> None:
    _check_let(session, blank_substitutions(args))


def check_expect(session: Session, args: str) -> None:
    _check_expr_options(".expect")(session, blank_substitutions(args))


def check_wait(session: Session, args: str) -> None:
    _check_expr_options(".wait")(session, blank_substitutions(args))


# -- running -----------------------------------------------------------------------------

class _Stop(Exception):
    """Unwinds a script after its first error (already reported)."""


@dataclass
class Counts:
    commands: int
    passed: int
    failed: int
    errors: int
    suspects: int = 0
    shell: int = 0  # shell commands that sent frames of their own (Stats.shell_commands)
    shared: int = 0  # addresses found shared (Stats.shared)


def _counts(session: Session) -> Counts:
    s = session.stats
    return Counts(s.commands, s.checks_passed, s.checks_failed, s.errors, s.suspects,
                  s.shell_commands, len(s.shared))


class Runner:
    def __init__(self, session: Session, on_step: Callable[[], None] | None = None):
        self.session = session
        self.failed = False
        self.stopped = False  # a failed line ended the run (no --keep-going)
        self.on_step = on_step
        # told each node before it runs (its file and line), for a unit's "line reached"
        self.on_node: Callable[[Node], None] | None = None
        self.interrupted_at: tuple[str, int] | None = None  # where Ctrl-C came (file, line)

    def run(self, nodes: Iterable[Node]) -> None:
        session = self.session
        state = session.state
        depth = state.script_depth
        state.script_depth = depth + 1
        saved = session.location
        try:
            for node in nodes:
                if self.on_node is not None:
                    self.on_node(node)
                # the fast path: a plain TMCL line, what most of a long script is (see step)
                plain = node.plain if type(node) is Step else None  # type: ignore[attr-defined]
                if plain is None or session.time_limit is not None or state.capture is not None:
                    session.out.flush()  # a command may wait, ask or read: show what was held
                    self.node(node)
                    continue
                session.location = (node.file, node.line)
                try:
                    session.run_plain(plain)
                except TmclError as exc:  # as guard
                    self.failed = True
                    report(session, node, exc)
                    if not session.keep_going:
                        raise _Stop() from exc
                    session.failed_unanswered(exc)  # (ModuleGoneError: the run is over)
                if self.on_step is not None:
                    self.on_step()
        except (KeyboardInterrupt, Terminated):  # (Ctrl-C, SIGTERM, SIGHUP)
            if self.interrupted_at is None:  # (the innermost: a .source's own line)
                self.interrupted_at = session.location
            raise
        finally:
            state.script_depth = depth
            session.location = saved

    def node(self, node: Node) -> None:
        if isinstance(node, Step):
            self.guard(node, lambda: self.step(node))
            if self.on_step is not None:
                self.on_step()
        elif isinstance(node, Repeat):
            count = self.guard(node, lambda: repeat_count(self.session, node.count))
            for i in range(count or 0):
                if node.var is not None:
                    self.session.variables[node.var] = i
                self.run(node.body)
        elif isinstance(node, If):
            for cond, body in node.branches:
                hit = True if cond is None else self.guard(
                    node, lambda c=cond: bool(c.evaluate(expr.SessionContext(self.session))))
                if hit is None:  # the condition failed to evaluate (and was reported)
                    return
                if hit:
                    self.run(body)
                    return
        elif isinstance(node, Include):
            self.run(node.body)

    def step(self, node: Step) -> None:
        session = self.session
        word, args = _word(node.text)
        if word == ".onerror":
            set_onerror(session, args, node)
            return
        typed = len(session.history)
        session.time_left()  # a long .repeat stops at the session's time limit
        try:
            if session.client is not None and node.text:
                session.ensure_link()  # the link was lost on an earlier line (--keep-going)
            session.run_line(node.text)
        finally:
            del session.history[typed:]  # the history is what was typed, not what a script ran

    def on_error(self) -> None:
        """The script stopped at an error: run its ``.onerror`` line, if it set one."""
        pending = self.session.state.take("onerror")
        if pending is None:
            return
        node, line = pending  # type: ignore[misc]
        self.session.out.info(f"{node.file}:{node.line}: .onerror: {line}")
        try:
            self.session.run_line(line)
        except TmclError as exc:
            report(self.session, node, exc)

    def guard(self, node: Node, fn: Callable[[], object]):
        self.session.location = (node.file, node.line)
        try:
            return fn()
        except QuitShell:
            raise
        except TmclError as exc:
            self.failed = True
            report(self.session, node, exc)
            if not self.session.keep_going:
                raise _Stop() from exc
            self.session.failed_unanswered(exc)  # (ModuleGoneError: the run is over)
            return None


def repeat_count(session: Session, count: expr.Expression | None) -> int:
    assert count is not None
    value = count.evaluate(expr.SessionContext(session))
    return int(limits.check("repeat", value, ".repeat count"))


def report(session: Session, node: Node, exc: TmclError) -> None:
    """``FILE:LINE: message``; under --json an error object (once per error)."""
    where = f"{node.file}:{node.line}: "
    session.out.saw_error(f"{where}{exc}")
    if session.out.json:
        if getattr(exc, "shown", False):
            session.out.warn(f"{where}{exc}")  # its result object already says "error"
        else:  # (a check's record: its fields, then the error)
            session.out.emit(error_record(f"{where}{exc}", line=node.text,
                                          **getattr(exc, "record", {})))
    else:
        session.out.err.print(f"{where}{exc}", style="tmcl.error", markup=False)


def count_steps(nodes: Iterable[Node]) -> tuple[int, bool]:
    """Steps a run will take (constant repeat counts multiplied) and whether it shows views."""
    total, views = 0, False
    for node in nodes:
        if isinstance(node, Step):
            total += 1
            views = views or _word(node.text)[0] in (".watch", ".plot")
        elif isinstance(node, Repeat):
            n, v = count_steps(node.body)
            root = node.count.root if node.count is not None else None
            times = int(root.value) if isinstance(root, expr.Num) and root.value >= 0 else 1
            total += n * times
            views = views or v
        elif isinstance(node, If):
            for _, body in node.branches:
                n, v = count_steps(body)
                total += n
                views = views or v
        elif isinstance(node, Include):
            n, v = count_steps(node.body)
            total += n
            views = views or v
    return total, views


def _progress(session: Session, name: str, nodes: list[Node]):
    """A rich progress bar for long scripts on a terminal (None otherwise)."""
    if session.out.json or not session.out.is_terminal:
        return None
    total, views = count_steps(nodes)
    if total < PROGRESS_MIN_STEPS or views:
        return None
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                               TimeElapsedColumn)

    progress = Progress(TextColumn("{task.description}", markup=False), BarColumn(), MofNCompleteColumn(),
                        TimeElapsedColumn(), console=session.out.console, transient=True)
    task = progress.add_task(Path(name).name, total=total)

    def advance() -> None:
        t = progress.tasks[0]
        if t.completed + 1 > (t.total or 0):
            progress.update(task, total=t.completed + 1)
        progress.advance(task)

    return progress, advance


def _line_counter(progress: Callable[[int, int], None], path: str,
                  total: int) -> Callable[[Node], None]:
    """A runner's ``on_node`` telling ``progress`` the line of ``path`` being run and the
    file's line count: the numbers its errors' FILE:LINE use, so the two never disagree."""
    progress(0, total)

    def at(node: Node) -> None:
        if node.file == path:  # (an included file's lines count as the line including it)
            progress(node.line, total)
    return at


def run_file(session: Session, path: str) -> int:
    """Run a script file (``-`` = stdin) in ``session``; returns the exit status."""
    start = time.monotonic()
    before = _counts(session)
    name = STDIN if path == "-" else path
    written: list[str] = []
    runner = Runner(session)
    status, kind = EXIT_OK, SYNTAX
    try:
        if path == "-":
            parser = Parser(session, STDIN, Path.cwd())
            _run_nodes(runner, parser.nodes(_stdin_lines()))
        else:
            file = Path(path)
            written = read_lines(file, ScriptError)
            lines = as_replayed(session, path, written)
            nodes = list(Parser(session, path, file.resolve().parent).nodes(lines))
            bar = _progress(session, path, nodes)
            if bar is None and session.progress is not None:
                runner.on_node = _line_counter(session.progress, path, len(written))
            if bar is None:
                # results are written in batches, not flushed line by line (see Output.hold);
                # not for stdin, whose writer may wait for each result before the next line
                held = session.out.hold
                session.out.hold = True
                try:
                    _run_nodes(runner, nodes)
                finally:
                    session.out.hold = held
                    session.out.flush()
            else:
                progress, runner.on_step = bar
                with progress:
                    _run_nodes(runner, nodes)
    except ScriptError as exc:
        _report_plain(session, exc)
        status, kind = EXIT_USAGE, exc.kind
        if kind != UNANSWERED:  # (which says what to do itself)
            _backup_hint(session, path, written, stopped=True)
    except ModuleGoneError as exc:  # (--keep-going: line after line went unanswered)
        session.report_error(None, exc)
        status = EXIT_CONNECT
    except (KeyboardInterrupt, Terminated) as exc:
        # how far it got, before the Ctrl-C policy (stop everything) says what it stopped
        # (SIGTERM and SIGHUP say so: ``why``)
        where = runner.interrupted_at
        try:
            summary(session, name, before, time.monotonic() - start, EXIT_FAILED,
                    interrupted=where[1] if where is not None else 0,
                    stopped=getattr(exc, "why", "interrupted (Ctrl-C)"),
                    in_file=where[0] if where is not None and where[0] != name else None)
        except Exception:  # (a summary must not hide the interrupt)
            pass
        raise
    finally:
        session.location = None
    session.confirm_answers()  # (the last answer may show only now to be another's)
    if runner.failed and status == EXIT_OK:
        _backup_hint(session, path, written, stopped=runner.stopped)
    if status == EXIT_OK and (runner.failed or session.stats.suspects > before.suspects
                              or len(session.stats.shared) > before.shared):
        # a result that may be another request's is no pass, nor a run on an address two
        # modules answer at
        status = EXIT_FAILED
    summary(session, name, before, time.monotonic() - start, status, kind)
    if status == EXIT_USAGE and (session.stats.commands > before.commands
                                  or session.stats.shell_commands > before.shell):
        # stdin runs each line as it arrives: a bad line after others were sent is a run
        # that failed (as in -c), not a script refused with nothing sent
        status = EXIT_FAILED
    return status


def _backup_hint(session: Session, path: str, lines: list[str], *, stopped: bool) -> None:
    """After a configuration backup's replay failed: what would do better (shell/features/clone.py)."""
    if not lines or not lines[0].startswith("//"):
        return
    from ..features.clone import replay_hint

    hint = replay_hint(session, path, lines, stopped=stopped)
    if hint is not None:
        session.out.info(hint)


def _run_nodes(runner: Runner, nodes: Iterable[Node]) -> None:
    try:
        runner.run(nodes)
    except _Stop:
        runner.stopped = True
        runner.on_error()
    except QuitShell:
        pass
    finally:
        runner.session.state.onerror = None


def _stdin_lines() -> Iterator[str]:
    """``-f -``: each line run as it arrives, none longer than ``files.MAX_LINE``."""
    try:
        yield from files.stream_lines(sys.stdin, STDIN)
    except files.FileError as exc:
        raise ScriptError(str(exc)) from None


def _report_plain(session: Session, exc: TmclError) -> None:
    session.out.saw_error(str(exc))
    if session.out.json:
        # (the line refused; null when no one line is to blame: an unreadable file)
        session.out.emit(error_record(str(exc), line=getattr(exc, "text", None)))
    else:
        session.out.err.print(str(exc), style="tmcl.error", markup=False)


def summary(session: Session, name: str, before: Counts, elapsed: float, status: int,
            kind: str = SYNTAX, *, interrupted: int | None = None,
            in_file: str | None = None, stopped: str = "interrupted (Ctrl-C)") -> None:
    """The last line of a script run; ``interrupted``: the line Ctrl-C came at (0: none),
    ``in_file`` when that is in a file the script included, ``stopped`` what stopped it (a
    unit stopped by SIGTERM says so)."""
    now = _counts(session)
    sent = now.commands - before.commands
    shell = now.shell - before.shell
    also = (f" and {shell} shell command{'s' if shell != 1 else ''} that talked to the module"
            if shell else "")
    passed, failed = now.passed - before.passed, now.failed - before.failed
    errors = now.errors - before.errors
    why = _KIND_TEXT.get(kind, kind)
    if interrupted is not None:
        at = f" at line {interrupted}" if interrupted else ""
        if interrupted and in_file is not None:
            at += f" of {in_file}"
        text = (f"{name}: {stopped}{at} after {sent} "
                f"command{'s' if sent != 1 else ''} sent{also}, {passed} check"
                f"{'s' if passed != 1 else ''} passed, {failed} failed, {errors} "
                f"error{'s' if errors != 1 else ''}, {elapsed:.2f} s")
    elif status == EXIT_USAGE and sent == 0 and not shell:
        text = f"{name}: not run ({why}; nothing was sent)"
    elif status == EXIT_USAGE:  # stdin runs each line as it arrives, up to the bad one
        text = (f"{name}: stopped ({why}) after {sent} "
                f"command{'s' if sent != 1 else ''} sent{also}, {elapsed:.2f} s")
    else:
        text = (f"{name}: {sent} command{'s' if sent != 1 else ''} sent{also}, "
                f"{passed} check{'s' if passed != 1 else ''} passed, {failed} failed, "
                f"{errors} error{'s' if errors != 1 else ''}, {elapsed:.2f} s")
        suspects = now.suspects - before.suspects
        if suspects:
            text += f"; {suspects} answer{'s' if suspects != 1 else ''} in doubt (see the warnings)"
        shared = session.stats.shared[before.shared:]
        if shared:
            text += ("; two modules answer at address "
                     + ", ".join(str(a) for a in shared))
    if session.out.simulated():
        text += "  [SIMULATED: built-in simulator, no module]"
    if session.out.json:
        session.out.err.print(text, style="tmcl.note", markup=False)
    else:
        session.out.print(text, style="tmcl.error" if status else "tmcl.note", markup=False)


def as_replayed(session: Session, path: Path | str, lines: list[str]) -> list[str]:
    """A configuration backup replayed leaves the module's link identity alone unless
    --with-link (shell/features/clone.py: replay_lines); any other script is run as written."""
    if not lines or not lines[0].startswith("//") or session.client is None:
        return lines
    from ..features.clone import needs_yes, replay_lines
    from .session import as_statement

    lines = replay_lines(session, path, lines)
    asks = needs_yes(session, lines)
    if asks is not None:
        number, question = asks
        raise ScriptSyntaxError(
            str(path), number, f"{as_statement(question)}, and nobody can answer here: "
            f"replay the configuration backup with --yes (or write what differs: .restore "
            f"{path} --yes); nothing was sent", UNANSWERED)
    return lines


def run_source(session: Session, path: str) -> bool:
    """``.source`` typed at the prompt or in -c: run a file in this session.

    Returns True if all went well. Errors inside are reported with FILE:LINE; the caller
    gets one ScriptError marked as shown.
    """
    file = resolve(path, None)  # relative to the current folder
    lines = as_replayed(session, file, read_lines(file, ScriptError))
    try:
        nodes = list(Parser(session, str(file), file.parent).nodes(lines))
    except ScriptSyntaxError as exc:
        # (the file is checked whole before its first line runs, as -f checks it: the
        # error says so, as -f's summary does, so nobody wonders what ran before it)
        raise ScriptSyntaxError(exc.file, exc.line, f"{exc.message} ({path} not run: "
                                "nothing was sent)", exc.kind, exc.text) from None
    runner = Runner(session)
    _run_nodes(runner, nodes)
    return not runner.failed


# -- blocks typed at the prompt (or in -c) -------------------------------------------------

class BlockCollector:
    """Collects lines typed after ``.repeat``/``.if`` until the matching ``.end``, then runs
    them. Installed as ``session.state.capture`` (consulted by ``Session.run_line``)."""

    def __init__(self, first: str):
        self.lines = [first]
        self.depth = 1

    def __call__(self, session: Session, text: str) -> bool:
        self.lines.append(text)
        for fn in list(session.recorders):
            fn(text, "")
        word = _word(text or "#")[0]
        if word in (".repeat", ".if"):
            self.depth += 1
        elif word == ".end":
            self.depth -= 1
        if self.depth == 0:
            session.state.capture = None
            self.run(session)
        return True

    def run(self, session: Session) -> None:
        try:
            nodes = list(Parser(session, "<input>", Path.cwd()).nodes(self.lines))
        except ScriptSyntaxError as exc:
            raise ValidationError(str(exc)) from None
        runner = Runner(session)
        _run_nodes(runner, nodes)
        if runner.failed:
            err = ScriptError("block stopped by an error")
            err.shown = True  # type: ignore[attr-defined]
            raise err


# -- the commands ------------------------------------------------------------------------

def set_onerror(session: Session, args: str, node: Node | None = None) -> None:
    check_onerror(session, args)
    if args.lower() == "off":
        session.state.onerror = None
    else:
        session.state.onerror = (node or Node("<input>", 0, args), args)
