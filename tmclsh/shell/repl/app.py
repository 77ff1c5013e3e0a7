"""The interactive shell: assembles the prompt from its parts and runs the read-eval loop.

Each part lives in its own module (STYLE.md §3-4) and this file only wires them together:
completion (``completer``), highlighting (``lexer``), the bottom toolbar (``toolbar``), keys
(``keys``), styles (``style``) and persistent history. Lines run through
``Session.run_line`` exactly as in ``-c`` and ``-f``.

Behaviour worth knowing:

* Ctrl-C at the prompt or while a command runs sends MST to every motor (keys.py explains
  why always); the shell stays up. Ctrl-D on an empty line, ``.quit`` or ``quit`` leave.
* An empty line repeats ``session.state.repeat_on_empty`` if a feature set it (the
  debugger sets it to ``.step``).
* 138 events and trace lines from other threads appear above the prompt (``patch_stdout``).
* After a link failure (TransportError) the next TMCL line first tries ``client.reconnect()``,
  so a re-plugged USB cable needs no restart; ``.connect`` does the same on demand.
"""

from __future__ import annotations

import errno
import functools
import logging
import os
import sys
from collections.abc import Callable
from contextlib import nullcontext
from typing import TYPE_CHECKING

from ... import __version__
from ...base.edges import terminal_gone
from ...base.errors import TmclError, TransportError
from ...base.interrupts import hung_up
from ..lang.session import Abort, QuitShell, reconnected

if TYPE_CHECKING:
    from prompt_toolkit import PromptSession

    from ..lang.session import Session

log = logging.getLogger(__name__)

# -- parts -------------------------------------------------------------------------------

def history_path():
    from ...base.config import state_dir

    return state_dir() / "history"


def repl_settings() -> dict:
    """The ``[settings]`` of the config file over the packaged defaults (``default.toml``):
    color, editing_mode, history_size. A broken file was reported at start-up already."""
    try:
        from ...base.config import load_settings

        return load_settings()
    except (TmclError, OSError, ImportError):
        return {}


# a history file is read no further back than this, and an entry longer than a script's line
# is dropped: a huge, binary or endless file (a symlink to /dev/zero) must not hold up the start
HISTORY_BYTES = 4 * 1024 * 1024


def make_history(size: int | None = None):
    """Persistent history in the XDG state dir, trimmed to the last ``size`` lines (the
    ``history_size`` setting); in memory if that cannot be read or written, or ``size`` is 0."""
    from prompt_toolkit.history import InMemoryHistory

    if size == 0:
        return InMemoryHistory()
    path = history_path()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.touch(exist_ok=True)
        entries = history_entries(path)  # refuses anything but a regular file
        if size is not None and (len(entries) > size
                                 or path.stat().st_size > HISTORY_BYTES):
            _rewrite_history(path, entries[:size])
        return _bounded_history_class()(str(path))
    except OSError as exc:  # files.FileError too
        log.warning("history not saved: %s", exc)
        return InMemoryHistory()


def history_entries(path) -> list[str]:
    """The entries of a history file in prompt_toolkit's ``FileHistory`` format (an entry is
    its run of ``+`` lines), newest first, from its last ``HISTORY_BYTES`` only; an entry
    longer than ``files.MAX_LINE`` is dropped, bytes that are not UTF-8 are replaced."""
    from ...base import files

    data = files.read_tail(path, HISTORY_BYTES, "history")
    entries: list[str] = []
    lines: list[bytes] = []
    for line in data.split(b"\n") + [b""]:
        if line.startswith(b"+"):
            lines.append(line[1:])
            continue
        if lines:
            entry = b"\n".join(lines)
            if len(entry) <= files.MAX_LINE:
                entries.append(entry.decode("utf-8", errors="replace"))
            lines = []
    entries.reverse()
    return entries


@functools.cache
def _bounded_history_class():
    from prompt_toolkit.history import FileHistory

    class BoundedFileHistory(FileHistory):
        """``FileHistory`` that reads its file with ``history_entries`` (bounded)."""

        def load_history_strings(self):
            try:
                return history_entries(self.filename)
            except OSError as exc:
                log.warning("history not read: %s", exc)
                return []

    return BoundedFileHistory


def _rewrite_history(path, entries: list[str]) -> None:
    """The history file replaced by ``entries`` (newest first), as FileHistory writes them."""
    from prompt_toolkit.history import FileHistory

    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)
    keep = FileHistory(str(tmp))
    for line in reversed(entries):
        keep.store_string(line)
    tmp.touch()  # no entries: an empty file
    os.replace(tmp, path)


def prompt_message(session: Session):
    """``TMCM-1311:1> `` (module type and address), with the program state if it runs."""
    from .toolbar import program_state_text

    def message():
        c = session.client
        mod = c.module.name if c.module is not None else "tmcl"
        style = "class:prompt.sim" if c.transport.simulated else "class:prompt"
        parts = [(style, f"{mod}:{c.address}")]
        if c.mode.marked:  # (the usual mode goes unsaid)
            parts.append(("class:prompt.state", f" {c.mode}"))
        text = program_state_text(session) or ""
        if text.startswith(("run", "step")):  # the debugger's "run", "step @12"
            parts.append(("class:prompt.state", f" [{text}]"))
        parts.append((style, "> "))
        return parts

    return message


def build_prompt_session(session: Session, **kw) -> PromptSession:
    """The PromptSession with all parts; ``kw`` goes to PromptSession (tests pass input/output)."""
    from prompt_toolkit import PromptSession
    from prompt_toolkit.auto_suggest import AutoSuggestFromHistory
    from prompt_toolkit.shortcuts import CompleteStyle

    from .keys import tmcl_bindings
    from ..style import prompt_style
    from .toolbar import create_toolbar_tokens_func

    from prompt_toolkit.enums import EditingMode

    settings = repl_settings()
    if "history" not in kw:
        size = settings.get("history_size")
        kw["history"] = make_history(size if isinstance(size, int) else None)
    if settings.get("editing_mode") == "vi":
        kw.setdefault("editing_mode", EditingMode.VI)
    if color_depth(settings) is not None:
        kw.setdefault("color_depth", color_depth(settings))
    return PromptSession(
        message=prompt_message(session),
        auto_suggest=AutoSuggestFromHistory(),
        lexer=lazy_lexer(),
        completer=lazy_completer(session),
        complete_while_typing=False,  # Tab completes; no menu popping up over every number
        complete_style=CompleteStyle.COLUMN,
        reserve_space_for_menu=8,
        bottom_toolbar=create_toolbar_tokens_func(session),
        key_bindings=tmcl_bindings(session),
        style=prompt_style(),
        include_default_pygments_style=False,
        refresh_interval=0.5,  # the toolbar follows trace/program state (no bus I/O)
        **kw,
    )


def lazy_lexer():
    """The TMCL lexer (``lexer.py``, on pygments) made when the line first holds text: an
    empty line has nothing to colour, so the first prompt does not wait for pygments."""
    from prompt_toolkit.lexers import Lexer

    class LazyLexer(Lexer):
        made = None

        def lex_document(self, document):
            if self.made is None:
                if not document.text:
                    return lambda lineno: []
                from prompt_toolkit.lexers import PygmentsLexer

                from .lexer import TmclLexer

                self.made = PygmentsLexer(TmclLexer, sync_from_start=True)
            return self.made.lex_document(document)

    return LazyLexer()


def lazy_completer(session: Session):
    """The completer (``completer.py``) made at the first Tab, not before the first prompt."""
    from prompt_toolkit.completion import Completer

    class LazyCompleter(Completer):
        made = None

        def get_completions(self, document, complete_event):
            if self.made is None:
                from .completer import TmclCompleter

                self.made = TmclCompleter(session)
            return self.made.get_completions(document, complete_event)

    return LazyCompleter()


def _dumb_echo(ps: PromptSession) -> None:
    """On a dumb terminal prompt_toolkit echoes only the last character of each change, so a
    completion (several characters at once) would show as one: echo the rest of it first."""
    buf = ps.default_buffer
    before = {"text": ""}

    def changed(_: object) -> None:
        now = buf.document.text_before_cursor
        old = before["text"]
        if len(now) > len(old) + 1 and now.startswith(old):
            ps.output.write(now[len(old):-1])
        before["text"] = now

    buf.on_text_changed += changed


def ask_choice(question: str, options: list[tuple[str, str]]) -> str:
    """``session.choose`` in the REPL: one of ``options`` (value, label), by arrows and Enter
    or by its number; Ctrl-C or Ctrl-D picks the last one (cancel)."""
    try:
        from prompt_toolkit.shortcuts import choice
    except ImportError:  # prompt_toolkit before 3.0.52: a typed answer
        from prompt_toolkit import prompt

        keys = "/".join(f"{v[0]}={v}" for v, _ in options)
        try:
            answer = prompt(f"{question} [{keys}] ").strip().lower()
        except (KeyboardInterrupt, EOFError):
            return options[-1][0]
        return next((v for v, _ in options if answer and v.startswith(answer)), options[-1][0])
    from prompt_toolkit.key_binding import KeyBindings

    keys = KeyBindings()
    for number, (value, _label) in enumerate(options[:9], 1):
        # a number chooses, as the numbers beside the options say (prompt_toolkit's only
        # moves the selection there, and Enter then takes it)
        keys.add(str(number), eager=True)(lambda event, v=value: event.app.exit(result=v))
    try:
        # a fresh copy each time, the first (safe) option the default: what was chosen last
        # time is never where the selection starts
        return choice(question, options=list(options), default=options[0][0],
                      key_bindings=keys)
    except (KeyboardInterrupt, EOFError):
        return options[-1][0]


LEAVE_OPTIONS = [("stop", "stop everything first, then leave"),
                 ("leave", "leave it running and quit"),
                 ("cancel", "cancel: stay in the shell")]


def may_leave(session: Session) -> bool:
    """Leaving while a motor turns or the stored program runs: ask (stop first / leave
    running / cancel). True when the shell may end."""
    from ...ops.stop import activity_everywhere
    from ..features.stop import stop_everywhere

    client = session.client
    choose = getattr(session, "choose", None)
    if not client.connected and choose is not None and client.motion:
        # the link went down while a motor tmclsh set moving may still move (a USB cable
        # pulled from a powered module): one attempt to bring it back and ask; else say so
        why = session.reconnect()
        if why is not None:
            told = "; ".join(f"motor {m}: {c.line}" for m, c in
                             sorted(client.motion.motors().items()))
            session.out.warn(f"leaving with the link down ({why}): tmclsh could not ask the "
                             f"module or stop it, and last set {told}")
            return True
        session.out.ok(reconnected(client))
    if not client.connected or choose is None:
        return True
    if getattr(client, "bring_up_pending", False):  # (its answers are waited for: say so)
        session.out.info(f"leaving: first asking the module at address {client.address} "
                         "whether a motor turns or its program runs; it has not answered "
                         "since the link came back, so this waits a few seconds for it")
    try:
        found = activity_everywhere(client)  # (each address left with a motor told to move)
    except (TmclError, OSError):
        return True
    busy = [(address, act, why) for address, act, why in found if not act.idle]
    if not busy:
        return True
    what = "; ".join((f"address {address}: " if len(found) > 1 else "") + str(act)
                     + (f" ({why})" if why else "") for address, act, why in busy)
    answer = choose(f"{what[:1].upper()}{what[1:]}. Leave the shell?", LEAVE_OPTIONS)
    if answer == "stop":
        if not stop_everywhere(client, session.out, "leaving", session=session):
            session.out.warn("not everything stopped: staying in the shell "
                             "(leave again to quit anyway)")
            session.choose = None  # the next Ctrl-D or .quit leaves without asking
            return False
        return True
    return answer == "leave"


def ask_yes_no(question: str) -> bool:
    """``session.ask`` in the REPL: ``[y/N]`` and Enter, as everywhere (ask.py)."""
    from .ask import ask_yes_no as ask

    return ask(question, default=False)


def banner(session: Session) -> list[tuple[str, str]]:
    """The lines above the first prompt, as prompt_toolkit's (style, text) pieces: the
    prompt's own library draws them, as it draws the toolbar, so the first prompt does not
    wait for rich (imported when a result is first shown)."""
    c = session.client
    out = [("class:banner.title", f"tmclsh {__version__}"), ("", " · ")]
    mod = c.module.label if c.module is not None else "unknown module"
    out += [("class:banner.name", mod), ("", f" at address {c.address}")]
    if c.transport.simulated:
        out += [("", " · "), ("class:banner.sim", "SIMULATED"),
                ("", " (built-in simulator, no hardware)")]
    else:
        out.append(("", f" on {c.describe()}"))
    if c.mode.marked:
        out.append(("", f" · {c.mode.label} mode"))
    if c.version:
        out.append(("", f" · firmware {c.version}"))
    out.append(("", "\n"))
    for i, word in enumerate((".help", "help SAP", "help 140")):
        out += [("", " · " if i else ""), ("class:banner.name", word)]
    out.append(("", " · Tab completes · Ctrl-C stops all motors · Ctrl-D quits"))
    return out


def show_banner(session: Session, settings: dict) -> None:
    """The banner, in the colours the prompt takes (the ``color`` setting, NO_COLOR)."""
    from prompt_toolkit import print_formatted_text
    from prompt_toolkit.formatted_text import FormattedText

    from ..style import prompt_style

    session.out.flush()
    print_formatted_text(FormattedText(banner(session)), style=prompt_style(),
                         color_depth=color_depth(settings),
                         file=session.out.stdout or sys.stdout,
                         include_default_pygments_style=False)


def color_depth(settings: dict):
    """prompt_toolkit's colour depth for the ``color`` setting (None: its own choice, which
    follows NO_COLOR and the terminal)."""
    from prompt_toolkit.output import ColorDepth

    if settings.get("color") == "never":
        return ColorDepth.DEPTH_1_BIT
    if settings.get("color") == "always":  # prompt_toolkit would follow NO_COLOR itself
        return ColorDepth.DEPTH_8_BIT
    return None


# -- the loop ----------------------------------------------------------------------------

def run_repl(session: Session, prompt_session: PromptSession | None = None) -> int:
    """The interactive shell; returns the exit status (0)."""
    from prompt_toolkit.patch_stdout import patch_stdout

    from ..features.stop import stop_everywhere

    session.interactive = True
    session.ask = ask_yes_no
    session.choose = ask_choice
    settings = repl_settings()
    session.state.pager = settings.get("pager", True) is not False
    if settings.get("color") == "never":
        session.out.set_color("never")
    from prompt_toolkit.utils import is_dumb_terminal

    ps = prompt_session or build_prompt_session(session)
    client = session.client
    dumb = prompt_session is None and is_dumb_terminal()
    if dumb:
        _dumb_echo(ps)
    _quiet_when_the_terminal_goes()
    show_banner(session, settings)
    _after_first_prompt(ps, lambda: warm_up(session))
    unlisten = client.add_listener(session.out.event)
    client.poll()  # (the last answer of the bring-up may have come twice: said now)
    session.report_shared()
    client.start_event_poller()
    try:
        while True:
            try:
                # output from other threads goes above the prompt while it is shown (a dumb
                # terminal has no prompt to redraw: straight away). The proxy is closed after
                # each line, which writes out all it holds: a command's output comes before
                # the next prompt, also when several lines are pasted at once.
                with nullcontext() if dumb else patch_stdout(raw=True):
                    try:
                        text = ps.prompt()
                    except EOFError:
                        text = None
                    if (text is None or not run_text(session, text)) and may_leave(session):
                        break
            except KeyboardInterrupt:
                # Ctrl-C where the key binding is not active: a dumb terminal, or the
                # moment between two prompts when the terminal is in cooked mode
                stop_everywhere(session.client, session.out, "Ctrl-C", session=session)
            except OSError as exc:
                if not _terminal_gone(exc):
                    raise
                # (it said "[Errno 5] Input/output error" and left the motors turning)
                raise hung_up() from exc
    finally:
        unlisten()
        client.stop_event_poller()
    return 0


def _terminal_gone(exc: OSError) -> bool:
    """Is ``exc`` the REPL's terminal hanging up (the window closed, the SSH session gone)?
    The link's and files' errors are tmclsh's own (TmclError); a hung-up terminal fails
    reads and writes with EIO and is no terminal any more."""
    if isinstance(exc, TmclError) or exc.errno not in (errno.EIO, errno.ENXIO):
        return False
    return any(terminal_gone(fd) for fd in (0, 1))


def _quiet_when_the_terminal_goes() -> None:
    """A thread that writes to the terminal (prompt_toolkit's ``patch_stdout`` flushes
    from one, under the prompt, a watch and the ASCII terminal) meets the terminal's going
    away first, and printed its traceback there as the shell ended (with the hang-up's
    stop said right below). The main thread acts on the hang-up (SIGHUP, or its own read
    failing); such a thread ends quietly. Every other error in a thread goes on to the
    hook there was."""
    import threading

    before = threading.excepthook
    if getattr(before, "terminal_gone_quiet", False):
        return

    def hook(args) -> None:
        exc = args.exc_value
        if isinstance(exc, OSError) and _terminal_gone(exc):
            return
        before(args)

    hook.terminal_gone_quiet = True  # type: ignore[attr-defined]
    threading.excepthook = hook


def _after_first_prompt(ps: PromptSession, work: Callable[[], None]) -> None:
    """``work`` once, as soon as the first prompt is on the screen (prompt_toolkit has drawn
    and flushed it): what it costs falls in the moment the user reads the prompt."""
    done = False

    def once(_app: object) -> None:
        nonlocal done  # (a flag, not the handler taken off: the event is being fired)
        if not done:
            done = True
            work()

    ps.app.after_render += once


def warm_up(session: Session) -> None:
    """What the first commands need and the start did not wait for: the safety stop Ctrl-C
    sends (``ops/stop.py``, so the first Ctrl-C does not wait for an import), rich for the
    first result, the lexer for the first key, the completer for the first Tab; then the
    garbage collector held off during the start runs again."""
    from ...base import startup
    from ...ops import stop  # noqa: F401
    from ..render import load_rich
    from . import completer, lexer  # noqa: F401

    load_rich()
    startup.release()  # (the start is over: base/startup.py)


def run_text(session: Session, text: str) -> bool:
    """Run what was typed (one or more lines); False when the shell should end."""
    lines = session.split(text)
    if not lines:
        if text.strip():  # only a comment
            return True
        repeat = session.state.repeat_on_empty
        if not repeat:
            return True
        lines = [str(repeat)]
    for line in lines:
        if not run_one(session, line):
            return False
    return True


def run_one(session: Session, text: str) -> bool:
    """One line with every failure turned into a message; False after ``.quit``."""
    from ..lang.lines import classify
    from ..features.stop import stop_everywhere

    line = classify(text)
    # a lost link (also one a .watch met) is brought back before the next TMCL line
    lost = not session.client.connected
    if lost and line.tmcl:
        if not _try_reconnect(session):
            return True
    elif lost and (line.command is None or line.command.reconnects):
        _try_reconnect(session, quiet=True)  # a shell command that fails says why itself
    session.interrupted_line_ended = False
    try:
        session.run_line(line)
    except QuitShell:
        return False
    except Abort as exc:
        session.out.info(str(exc))
    except TransportError as exc:
        session.report_error(text, exc)
        if not session.client.connected:  # (a failed .connect PORT leaves the old link up)
            session.out.info("the link is down: the next command tries to reconnect "
                             "(or .connect [PORT])")
    except TmclError as exc:
        session.report_error(text, exc)
    except KeyboardInterrupt:
        session.end_interrupted_line()  # the terminal echoed ^C on the command's line
        stop_everywhere(session.client, session.out, "interrupted", session=session)
    except Exception as exc:  # a bug must not take the motor shell down with it
        log.debug("internal error", exc_info=True)
        session.out.error(text, f"internal error ({type(exc).__name__}: {exc}); "
                                "please report it" + ("" if os.environ.get("TMCLSH_DEBUG")
                                                      else " (TMCLSH_DEBUG=1 shows the traceback)"))
        if os.environ.get("TMCLSH_DEBUG"):
            import traceback

            traceback.print_exc(file=sys.stderr)
    return True




def _try_reconnect(session: Session, quiet: bool = False) -> bool:
    why = session.reconnect()
    if why is None:
        session.out.ok(reconnected(session.client))
        return True
    if not quiet:
        switch = ". .connect [PORT] to switch" if isinstance(why, TmclError) else ""
        # (the link may have gone while nobody was typing: nothing said so yet but the
        # toolbar, so "still" would refer to nothing)
        session.out.error(None, f"the link is down and did not come back ({why}); nothing "
                                f"was sent{switch}")
    return False
