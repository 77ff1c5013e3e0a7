"""The module's ASCII mode in the shell: ``.ascii`` (a serial terminal in the spirit of tio and
miniterm), ``.mode ascii|binary`` (switch the live link) and ``.ascii-config`` (GP 67).

The terminal shows what the module sends as it arrives. By default input is edited locally
(a prompt_toolkit prompt with history and completion) and each line is sent whole, with the
address character added unless one was typed; the echo of that line is hidden because the
prompt already shows it, and replies are shown with their status decoded
(``BA 100 -5000   ok, value -5000``). ``.ascii --raw`` passes keys through one by one, so the
module's own echo and backspace handling are what the user sees. Ctrl-] (or ``.quit``)
returns to the shell; leaving asks whether to send BIN (``--bin``/``--no-bin`` answer in
advance). A ``BIN`` the user sends is noticed: the module talks binary frames after it, so the
terminal says so and returns to the shell on the binary link. Ctrl-T opens tio's menu of
conveniences (termtools.py): local echo, hex view, timestamps, a log file, sending a file.

Keys come through prompt_toolkit's input in both modes (its raw mode, its key parser), so the
terminal works wherever prompt_toolkit does.

The views (``LineView``, ``RawView``) are pure: bytes in, display segments out, so they are
tested on canned byte sequences; the loops around them only move bytes and draw.

All reading goes through ``AsciiLink.read_raw`` under the client's lock: nothing else reads
the transport while the terminal runs.
"""

from __future__ import annotations

import re
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ...tmcl import instructions as isa
from ...client.ascii import (BS, CR, GP_ASCII_MODE, GP_BANK, ECHO_NAMES, AsciiLink, Echo, LineKind,
                            Mode, address_char, ascii_commands, classify_line, describe_gp67,
                            echo_mode, gp67_value, next_line, reply_part, reply_summary,
                            starts_in_ascii)
from ...base.errors import StatusError, ValidationError
from ...tmcl.frames import Reply, Request, status_ok
from ..lang import options
from ..lang.commands import command, options_of
from .termtools import (MENU_KEY, MenuState, SessionLog, Stamper, choose, file_lines, hex_hint,
                        hex_lines, is_bin, is_quit, menu_hint, menu_text)

if TYPE_CHECKING:
    from ..lang.session import Session

ESCAPE_KEY = 0x1D  # Ctrl-]
CTRL_C = 0x03
_GGP, _SGP = int(isa.Opcode.GGP), int(isa.Opcode.SGP)

Segment = tuple[str, str]  # (style name from style.py or "", text)


# -- pure views ------------------------------------------------------------------------------

def printable(data: bytes) -> str:
    """Received bytes as text: printable ASCII as is, anything else as ``\\xNN``."""
    return "".join(chr(b) if 32 <= b < 127 or b == 9 else f"\\x{b:02x}" for b in data)


def reply_segments(line: bytes, reply: Reply) -> list[Segment]:
    """``BA 100 -5000`` + ``   ok, value -5000``, styled by status."""
    style = "tmcl.ok" if status_ok(reply.status) else "tmcl.error"
    return [("tmcl.value", printable(line)), ("", "   "), (style, reply_summary(reply))]


@dataclass
class Shown:
    """One line the line-mode terminal received: an echo (hidden), a reply or other text."""

    kind: LineKind
    line: bytes
    reply: Reply | None = None

    @property
    def segments(self) -> list[Segment]:
        if self.reply is not None:
            return reply_segments(self.line, self.reply)
        return [("", printable(self.line))]


@dataclass
class LineView:
    """Line mode: complete lines out; the echo of the line just sent is recognised and
    marked (whatever the echo mode and whether the CR is echoed)."""

    sent: bytes | None = None
    buf: bytearray = field(default_factory=bytearray)

    def expect(self, sent: bytes) -> None:
        self.sent = bytes(sent)

    def feed(self, data: bytes) -> list[Shown]:
        self.buf += data
        out = []
        while True:
            used, line = next_line(self.buf)
            if line is None:
                break
            del self.buf[:used]
            if not line:
                continue
            kind, reply = classify_line(line, self.sent)
            if kind == LineKind.REPLY and reply is not None:
                # show the reply alone even when it ran on from the echo
                out.append(Shown(kind, reply_part(line), reply))
                self.sent = None
            else:
                out.append(Shown(kind, line))
        return out

    def flush(self) -> list[Shown]:
        """What is left without a line end (shown when leaving)."""
        if not self.buf:
            return []
        line = bytes(self.buf)
        self.buf.clear()
        return [Shown(LineKind.OTHER, line)]


@dataclass
class RawView:
    """Raw mode: the module's bytes for the terminal as they arrive (CR and LF become a
    line break, backspace passes through), a decoded status after each reply line, and a
    line break of our own when the module echoed a line the user ended but not its CR (so
    the reply does not run on from the echo)."""

    line: bytearray = field(default_factory=bytearray)  # the current line, backspaces applied
    shown: int = 0  # characters on the current display line
    ended: bytes | None = None  # the line the user ended with Enter, until its echo is over
    last_cr: bool = False
    replies: int = 0  # reply lines seen (a file being sent waits for each)

    def user_enter(self, typed: bytes) -> None:
        """The user pressed Enter after typing ``typed`` (backspaces applied)."""
        self.ended = bytes(typed) if typed else None

    def local(self, data: bytes) -> list[Segment]:
        """Local echo of typed characters (``--echo``, for modules with echo off)."""
        out: list[Segment] = []
        for b in data:
            if b in (0x08, 0x7F):
                if self.shown:
                    self.shown -= 1
                    out.append(("", "\b \b"))
            elif b in (0x0D, 0x0A):
                if self.shown:
                    out.append(("", "\r\n"))
                    self.shown = 0
            else:
                self.shown += 1
                out.append(("tmcl.note", printable(bytes((b,)))))
        return out

    def _end_line(self) -> list[Segment]:
        out: list[Segment] = []
        kind, reply = classify_line(bytes(self.line))
        if reply is not None:
            self.replies += 1
            style = "tmcl.ok" if status_ok(reply.status) else "tmcl.error"
            out += [("", "   "), (style, reply_summary(reply))]
        out.append(("", "\r\n"))
        self.line.clear()
        self.shown = 0
        return out

    def feed(self, data: bytes) -> list[Segment]:
        out: list[Segment] = []
        for b in data:
            if self.ended is not None and self.line and b not in (0x0D, 0x0A) \
                    and bytes(self.line) == self.ended:
                self.ended = None
                out += self._end_line()  # the echo is complete and no CR came
            if b == 0x0A and self.last_cr:
                self.last_cr = False
                continue
            self.last_cr = b == 0x0D
            if b in (0x0D, 0x0A):
                self.ended = None
                out += self._end_line()
            elif b in (0x08, 0x7F):
                if self.line:
                    self.line.pop()
                self.shown = max(0, self.shown - 1)
                out.append(("", "\b"))
            elif 32 <= b < 127:
                self.line.append(b)
                self.shown += 1
                out.append(("", chr(b)))
            else:
                self.line.append(b)
                text = printable(bytes((b,)))
                self.shown += len(text)
                out.append(("tmcl.warn", text))
        return out


def with_address(text: str, address: int, module_commands: Iterable[str] = ()) -> str:
    """The line to send for what the user typed: ``GAP 1, 0`` -> ``AGAP 1, 0``; a line that
    already starts with an address character (``AGAP 1, 0``, ``C MST 0``) is kept."""
    text = text.strip()
    words = {w.upper() for w in (module_commands or ascii_commands())}
    m = re.match(r"([A-Za-z]+)", text)
    if m is None:
        return address_char(address) + text
    word = m.group(1).upper()
    if word in words:
        return address_char(address) + text
    if len(word) == 1 and text[1:].lstrip()[:1].isalpha():
        return text  # `A MST 0`: address character, spaces, command
    if word[1:] in words:
        return text  # `AMST 0`
    return address_char(address) + text


# -- rendering ---------------------------------------------------------------------------------

class Painter:
    """Style names to ANSI sequences (through the rich theme), or plain text."""

    def __init__(self, color: bool | None = None):
        from ..style import color_enabled

        self.color = (color_enabled() and sys.stdout.isatty()) if color is None else color
        self._console = None
        if self.color:
            from rich.console import Console

            from ..style import rich_theme

            self._console = Console(theme=rich_theme(), force_terminal=True,
                                    color_system="standard")

    def __call__(self, segments: Iterable[Segment]) -> str:
        out = []
        for style, text in segments:
            if style and self._console is not None and text.strip():
                from rich.color import ColorSystem

                st = self._console.get_style(style)
                out.append(st.render(text, color_system=ColorSystem.STANDARD))
            else:
                out.append(text)
        return "".join(out)


# -- the terminal ------------------------------------------------------------------------------

@dataclass
class TerminalOptions:
    raw: bool = False
    send_bin: bool | None = None  # None: ask when leaving
    local_echo: bool = False


def parse_options(argtext: str) -> TerminalOptions:
    rest, given = options.parse(argtext, options_of(".ascii"))
    if rest:
        raise ValidationError(f".ascii takes only options, got {rest!r} "
                              "(--raw, --echo, --bin, --no-bin)")
    opts = TerminalOptions(raw="--raw" in given, local_echo="--echo" in given)
    if "--bin" in given or "--no-bin" in given:
        opts.send_bin = "--no-bin" not in given
    return opts


class Terminal:
    """The ``.ascii`` terminal. ``write`` draws text (already styled) for the user."""

    def __init__(self, session: Session, link: AsciiLink, opts: TerminalOptions,
                 write: Callable[[str], None], painter: Painter | None = None,
                 write_note: Callable[[str], None] | None = None):
        self.session = session
        self.link = link
        self.opts = opts
        self.paint = painter or Painter()
        self._write = write
        self._write_note = write_note or write
        self._write_lock = threading.Lock()
        # line mode: while no prompt is shown, output is held and written in order by the
        # main thread before the next prompt; while the prompt is shown it goes through the
        # (patch_stdout) writers, which print above the prompt
        self._held: list[tuple[Callable[[str], None], str]] | None = None
        self._direct: tuple[Callable[[str], None], Callable[[str], None]] | None = None
        self._stop = threading.Event()
        self._reader: threading.Thread | None = None
        self._replied = threading.Event()
        self.line_view = LineView()
        self.raw_view = RawView()
        self.menu = MenuState(local_echo=opts.local_echo)
        self._lines = Stamper()  # where lines start in the module's output (timestamps)
        self.left_ascii = False  # the user sent BIN: the module talks binary frames now

    # -- output ---------------------------------------------------------------------------
    def write(self, segments: Iterable[Segment]) -> None:
        """What the module sent (stdout), with timestamps at line starts if they are on."""
        stamped: list[Segment] = []
        for style, text in segments:
            for is_stamp, piece in self._lines.pieces(text, self.menu.timestamps):
                stamped.append(("tmcl.note" if is_stamp else style, piece))
        self.log("".join(t for _, t in stamped))
        text = self.paint(stamped)
        if text:
            self._emit(0, text)

    def note(self, text: str) -> None:
        """A status line of our own, ``---`` in front (stderr, as miniterm does)."""
        eol = self.eol
        text = f"--- {text}"
        if self.opts.raw and not self._lines.at_line_start:
            text = eol + text  # in the middle of the module's line: a line of its own
            self._lines.at_line_start = True
        self.log(text + eol)
        self._emit(1, self.paint([("tmcl.note", text), ("", eol)]))

    def log(self, text: str) -> None:
        """Into the session's log file, if one is open (Ctrl-T f)."""
        if self.menu.log is not None and text:
            self.menu.log.write(text)

    @property
    def eol(self) -> str:
        return "\r\n" if self.opts.raw else "\n"

    def _emit(self, stream: int, text: str) -> None:
        with self._write_lock:
            if self._held is not None and self._direct is not None:
                self._held.append((self._direct[stream], text))
            else:
                (self._write, self._write_note)[stream](text)

    def hold(self, direct_out: Callable[[str], None], direct_err: Callable[[str], None]) -> None:
        """Line mode, prompt gone: hold output for ``release`` (written with the direct
        writers then, in order, before the prompt comes back)."""
        with self._write_lock:
            self._direct = (direct_out, direct_err)
            if self._held is None:
                self._held = []

    def release(self) -> None:
        """Write what was held; until the next ``hold`` output goes to the normal writers."""
        with self._write_lock:
            held, self._held = self._held or [], None
            for write, text in held:
                write(text)

    # -- the reader thread ----------------------------------------------------------------
    def start_reader(self) -> None:
        self._stop.clear()
        self._reader = threading.Thread(target=self._read_loop, name="tmclsh-ascii-term",
                                        daemon=True)
        self._reader.start()

    def stop_reader(self) -> None:
        self._stop.set()
        if self._reader is not None:
            self._reader.join(1)
            self._reader = None

    def _read_loop(self) -> None:
        from ...base.errors import TransportError

        while not self._stop.is_set():
            try:
                data = self.link.read_raw(0.05)
            except TransportError as exc:
                self.note(f"link lost: {exc}")
                return
            if data:
                self.show(data)

    def show(self, data: bytes) -> None:
        if self.menu.hex_view:
            self._show_hex(data)
            return
        if self.opts.raw:
            before = self.raw_view.replies
            self.write(self.raw_view.feed(data))
            if self.raw_view.replies != before:
                self._replied.set()
            return
        for item in self.line_view.feed(data):
            if item.kind == LineKind.ECHO:
                continue  # the prompt line already shows what was sent
            self.write(item.segments + [("", "\n")])
            if item.kind == LineKind.REPLY:
                self._replied.set()

    def _show_hex(self, data: bytes) -> None:
        """The bytes as they arrived, in hex; the views still follow the lines (a sent line
        still waits for its reply), but what they would show is not shown."""
        if self.opts.raw:
            before = self.raw_view.replies
            self.raw_view.feed(data)
            self.raw_view.shown = 0
            replied = self.raw_view.replies != before
        else:
            replied = any(i.kind == LineKind.REPLY for i in self.line_view.feed(data))
        segments: list[Segment] = [] if self._lines.at_line_start else [("", self.eol)]
        for line in hex_lines(data):
            segments += [("tmcl.value", line), ("", self.eol)]
        self.write(segments)
        if replied:
            self._replied.set()

    # -- line mode ------------------------------------------------------------------------
    def send_line(self, text: str, wait: float | None = None) -> bytes | None:
        """Send one typed line (address character added unless typed); wait up to ``wait``
        seconds for its reply so that output and prompt stay in order. A BIN for this
        module sets ``left_ascii``."""
        text = text.strip()
        if not text:
            return None
        mod = self.session.client.module
        line = (with_address(text, self.session.client.address, ascii_commands(mod))
                .encode("latin-1", errors="replace") + CR)
        self._replied.clear()
        self.line_view.expect(line)
        if self.opts.raw:
            self.raw_view.user_enter(line[:-1])
        if self.menu.local_echo and not self.opts.raw:
            self.write([("tmcl.note", line[:-1].decode("latin-1")), ("", "\n")])
        self.link.write_raw(line)
        if is_bin(line[:-1], self.session.client.address):
            self.left_ascii = True
        if wait:
            self._replied.wait(wait)
        return line

    def send_file(self, name: str, between: Callable[[], None] | None = None) -> None:
        """Ctrl-T u: each line of the file (blank and comment lines left out) sent and its
        reply waited for; stops after a BIN. ``between`` runs after each line (line mode
        writes out what arrived)."""
        try:
            lines = file_lines(name)
        except ValidationError as exc:
            self.note(str(exc))
            return
        self.note(f"sending {len(lines)} line{'s' if len(lines) != 1 else ''} from "
                  f"{name.strip()}")
        sent = 0
        for text in lines:
            self.send_line(text, wait=self.session.client.timeout)
            sent += 1
            if between is not None:
                between()
            if self.left_ascii:
                break
        self.note(f"sent {sent} of {len(lines)} lines from {name.strip()}")

    def toggle_log(self, name: str | None) -> None:
        """Ctrl-T f: stop the log that is open, else start one in file ``name``."""
        if self.menu.log is not None:
            path = self.menu.log.path
            self.note(f"log closed: {path}")
            self.menu.log.close()
            self.menu.log = None
            return
        try:
            self.menu.log = SessionLog.open(name or "")
        except ValidationError as exc:
            self.note(str(exc))
            return
        self.note(f"logging the session to {self.menu.log.path} (Ctrl-T f stops)")

    def menu_key(self, key: str) -> str | None:
        """A key after Ctrl-T. Switches flip here (and say so); for ``f`` and ``u`` the key
        is returned: the loop asks for the file name first (f while logging stops it)."""
        picked = choose(key)
        if picked is None:
            self.note(f"Ctrl-T {printable(key.encode('latin-1', 'replace'))}: no such menu "
                      "entry (Ctrl-T ? lists them)")
            return None
        if picked == "?":
            for line in menu_text(self.menu):
                self.note(line)
            return None
        if picked == "f" and self.menu.log is not None:
            self.toggle_log(None)
            return None
        if picked in ("f", "u"):
            return picked
        said = self.menu.toggle(picked)
        if picked == "e" and not self.opts.raw:
            said += " (the line as sent, address character included)"
        if picked == "h":
            said += hex_hint(self.menu.hex_view)
        self.note(str(said))
        return None

    def back_to_binary(self) -> None:
        """After the user's BIN: the link is binary frames again; tmclsh leaves it so."""
        from ...base.errors import TmclError
        from ...tmcl.frames import Control

        client = self.session.client
        self.link.detach(send_bin=False)
        client._resync_next()
        self.link.on_exit = Mode.BINARY
        try:
            client.request(Request(client.address, Control.GET_VERSION, 1, 0, 0))
        except TmclError as exc:
            self.note(f"BIN sent, but the module does not answer binary commands ({exc})")
            return
        self.note("module left ASCII mode (BIN): back to the shell on the binary link")

    def stop_motors(self) -> None:
        """The shell's one stop (the stored program first: MST alone is undone by a program
        that runs), said as the shell says it: only a motor whose speed reads 0 is stopped."""
        from .stop import ToNotes, stop_all

        stop_all(self.session.client, ToNotes(self.note), session=self.session)

    def banner(self) -> None:
        c = self.session.client
        self.note(f"ASCII terminal: {c.describe()}, module {c.address} "
                  f"({address_char(c.address)}), host {c.host_address} "
                  f"({address_char(c.host_address)}), {self.link.echo.text}")
        if self.opts.raw:
            if self.link.echo != Echo.CHAR and not self.opts.local_echo:
                self.note("the module does not echo while you type (--echo or Ctrl-T e "
                          "echoes locally)")
            self.note("keys go to the module as typed; Ctrl-C: stop motors; Ctrl-T: menu; "
                      "Ctrl-]: back to the shell")
        else:
            self.note(f"'{address_char(c.address)}' goes in front of lines unless typed; "
                      "Ctrl-C: stop motors; Ctrl-T: menu; Ctrl-] or .quit: back to the shell")


# -- loops ---------------------------------------------------------------------------------------

class _Leave(Exception):
    pass


def _history():
    from prompt_toolkit.history import FileHistory, InMemoryHistory

    from ...base.config import state_dir

    try:
        d = state_dir()
        d.mkdir(parents=True, exist_ok=True)
        return FileHistory(str(d / "ascii-history"))
    except OSError:
        return InMemoryHistory()


def _completer(session: Session):
    from prompt_toolkit.completion import Completer, Completion

    class AsciiCompleter(Completer):
        def get_completions(self, document, complete_event) -> Iterator[Completion]:
            for c in ascii_completions(session, document.text_before_cursor):
                yield Completion(c.text, start_position=-len(c.word), display=c.display,
                                 display_meta=c.meta)

    return AsciiCompleter()


@dataclass(frozen=True)
class AsciiCompletion:
    text: str
    word: str
    display: str
    meta: str = ""


def ascii_completions(session: Session, text: str) -> list[AsciiCompletion]:
    """Completions for the terminal's line: the commands ASCII mode accepts, symbolic types,
    and parameters, motors and ports *by number* (the module's ASCII parser knows no names;
    typing a name finds its number)."""
    from ..repl.completer import (AxisParam, Candidate, GlobalParam, Mnemonic, candidates, current_word,
                            param_meta, ranked, suggest)

    mod = session.client.module
    body = text
    m = re.match(r"\s*([A-Za-z])( +|(?=[A-Za-z]{2}))", text)
    if m is not None:
        rest = text[m.end():]
        first = rest.split(None, 1)[0].upper() if rest.split() else ""
        typed_addr = not (text.strip().upper() in {c.upper() for c in ascii_commands(mod)})
        if typed_addr and (not first or any(c.startswith(first) for c in ascii_commands(mod))):
            body = rest
    word = current_word(text)
    out: list[AsciiCompletion] = []
    seen: set[str] = set()
    for s in suggest(body, mod):
        if isinstance(s, Mnemonic):
            specs = {sp.mnemonic: sp.summary for sp in isa.all_instructions()}
            cands = [Candidate(n, specs.get(n, isa.ASCII_ONLY.get(n, "")))
                     for n in ascii_commands(mod)]
        elif isinstance(s, (AxisParam, GlobalParam)) and mod is not None:
            params = mod.axis_params if isinstance(s, AxisParam) else mod.global_params
            cands = [Candidate(str(p.number), param_meta(p), f"{p.number} {p.name}",
                               also=(p.name, p.manual_name))
                     for p in params if s.access in p.access]
        elif type(s).__name__ in ("ShellCommand", "CommandArg", "Label"):
            continue
        else:
            cands = candidates(s, word, mod, session)
        for c in ranked(word, cands):
            if c.text not in seen:
                seen.add(c.text)
                out.append(AsciiCompletion(c.text, word, c.display or c.text, c.meta))
    return out


@dataclass(frozen=True)
class _MenuFile:
    """The line-mode prompt left for a menu entry that needs a file name; ``text`` is what
    was typed on the prompt meanwhile (it comes back)."""

    key: str
    text: str


_ASK = {"f": "--- log the session to file: ", "u": "--- send the lines of file: "}


def _ask_file(question: str, **kw) -> str:
    from prompt_toolkit import PromptSession
    from prompt_toolkit.completion import PathCompleter

    try:
        return PromptSession(**kw).prompt(question, completer=PathCompleter(expanduser=True))
    except (EOFError, KeyboardInterrupt):
        return ""


def _menu_bindings(term: Terminal, kb) -> Callable[[object], None]:
    """Ctrl-T and the key after it, on the line-mode prompt. Returns the hook for the key
    processor's ``after_key_press``: a key with a binding of its own (Enter, Tab, an arrow)
    does its usual job and closes the menu, so a later letter is typed, not taken for it."""
    from prompt_toolkit.filters import Condition

    menu = {"state": None}  # None, "opened" (Ctrl-T just pressed), "waiting"

    @kb.add("c-t", eager=True)
    def _(event) -> None:
        menu["state"] = "opened"
        term.note(menu_hint(term.menu))

    # not eager: the terminal's own reports (cursor position) keep their bindings
    @kb.add("<any>", filter=Condition(lambda: menu["state"] is not None))
    def _(event) -> None:
        menu["state"] = None
        key = term.menu_key(event.data)
        if key is not None:
            event.app.exit(result=_MenuFile(key, event.app.current_buffer.text))

    def after_key(_processor: object) -> None:
        menu["state"] = "waiting" if menu["state"] == "opened" else None

    return after_key


def run_line_mode(term: Terminal) -> None:
    """Prompt, send, repeat; what arrives is printed above the prompt by the reader."""
    from prompt_toolkit import PromptSession
    from prompt_toolkit.key_binding import KeyBindings
    from prompt_toolkit.patch_stdout import patch_stdout

    from ..style import prompt_style

    session = term.session
    kb = KeyBindings()

    @kb.add("c-]", eager=True)  # eager: c-] is also the prefix of emacs character search
    def _(event) -> None:
        event.app.exit(exception=_Leave())

    after_key = _menu_bindings(term, kb)
    prompt = PromptSession(history=_history(), completer=_completer(session), key_bindings=kb,
                           style=prompt_style(), complete_while_typing=False)
    prompt.app.key_processor.after_key_press += after_key
    message = [("class:prompt", f"ascii {address_char(session.client.address)}> ")]
    # between prompts nothing is drawn by prompt_toolkit: write to the terminal itself
    direct = (_real_write(sys.__stdout__), _real_write(sys.__stderr__))

    def between() -> None:  # what arrived for one line of a file, before the next is sent
        term.release()
        term.hold(*direct)

    term.hold(*direct)
    typed = ""
    with patch_stdout(raw=True):
        term.start_reader()
        try:
            while not term.left_ascii:
                term.release()
                try:
                    text = prompt.prompt(message, default=typed)
                except KeyboardInterrupt:
                    term.hold(*direct)
                    typed = ""
                    term.stop_motors()
                    continue
                except (EOFError, _Leave):
                    term.hold(*direct)
                    break
                typed = ""
                if isinstance(text, _MenuFile):
                    typed = text.text
                    name = _ask_file(_ASK[text.key])
                    term.hold(*direct)
                    if text.key == "f":
                        term.toggle_log(name)
                    else:
                        try:
                            term.send_file(name, between)
                        except KeyboardInterrupt:  # Ctrl-C while a file is being sent
                            term.stop_motors()
                    continue
                term.hold(*direct)
                if is_quit(text):
                    break
                term.log(f"{message[0][1]}{text}\n")
                try:
                    term.send_line(text, wait=session.client.timeout)
                except KeyboardInterrupt:  # Ctrl-C while waiting for the reply
                    term.stop_motors()
            time.sleep(0.05)  # let a last reply arrive before the reader stops
        finally:
            term.stop_reader()
            for item in term.line_view.flush():
                term.write(item.segments + [("", "\n")])
            term.release()


def run_plain_lines(term: Terminal, lines: Iterable[str]) -> None:
    """Line mode without a terminal (stdin is a pipe): send each line, show what comes."""
    term.start_reader()
    try:
        for text in lines:
            if text.strip() == "\x1d" or is_quit(text):
                break
            term.send_line(text, wait=term.session.client.timeout)
            if term.left_ascii:
                break
        time.sleep(0.05)
    finally:
        term.stop_reader()
        for item in term.line_view.flush():
            term.write(item.segments + [("", "\n")])


_ESC_SEQ = re.compile(rb"\x1b(?:\[[0-?]*[ -/]*[@-~]|O.|.)?", re.S)


def translate_keys(data: bytes) -> list[bytes | int]:
    """Keys typed in raw mode to what the module gets: DEL becomes BS, Enter a CR, escape
    sequences (arrows, function keys) are dropped; Ctrl-], Ctrl-C and Ctrl-T come back as
    ints."""
    data = _ESC_SEQ.sub(b"", data)
    out: list[bytes | int] = []
    for b in data:
        if b in (ESCAPE_KEY, CTRL_C, MENU_KEY):
            out.append(b)
        elif b == 0x7F:
            out.append(BS)
        elif b == 0x0A:
            out.append(CR)
        else:
            out.append(bytes((b,)))
    return out


def key_bytes(key_press) -> bytes:
    """What a prompt_toolkit KeyPress typed, as bytes for the module (pasted text whole;
    arrows, function keys and terminal reports nothing)."""
    from prompt_toolkit.keys import Keys

    data = key_press.data or ""
    if key_press.key == Keys.BracketedPaste:
        return data.replace("\r\n", "\r").replace("\n", "\r").encode("latin-1", "replace")
    if data.startswith("\x1b") and len(data) > 1:
        return b""
    return data.encode("latin-1", "replace")


class RawKeys:
    """Raw mode's keys: each goes to the module as typed, except Ctrl-] (leave), Ctrl-C (erase
    the line, or stop the motors), Ctrl-T (the menu) and Enter after ``.quit`` (leave).
    ``press`` returns "leave", a menu key that needs a file name ("f", "u"), or None."""

    def __init__(self, term: Terminal):
        self.term = term
        self.typed = bytearray()  # the line typed so far (for Ctrl-C, .quit and BIN)
        self.menu_open = False

    def press(self, key: bytes | int) -> str | None:
        term = self.term
        if self.menu_open:
            self.menu_open = False
            if key == MENU_KEY:  # Ctrl-T twice: the module gets one
                term.link.write_raw(bytes((MENU_KEY,)))
                return None
            char = key if isinstance(key, bytes) else bytes((key,))
            return term.menu_key(char.decode("latin-1"))
        if key == ESCAPE_KEY:
            return "leave"
        if key == MENU_KEY:
            self.menu_open = True
            term.note(menu_hint(term.menu))
            return None
        if key == CTRL_C:
            if self.typed:
                term.link.write_raw(BS * len(self.typed))
                self.typed.clear()
                term.note("line erased; Ctrl-C again stops the motors")
            else:
                term.stop_motors()
            return None
        assert isinstance(key, bytes)
        if key == CR and is_quit(self.typed.decode("latin-1")):
            term.link.write_raw(BS * len(self.typed))  # the module forgets the typed word
            self.typed.clear()
            return "leave"
        term.link.write_raw(key)
        if key == CR:
            term.raw_view.user_enter(bytes(self.typed))
            if is_bin(bytes(self.typed), term.session.client.address):
                term.left_ascii = True
            self.typed.clear()
        elif key == BS:
            if self.typed:
                self.typed.pop()
        else:
            self.typed += key
        if term.menu.local_echo:
            term.write(term.raw_view.local(key))
        return "leave" if term.left_ascii else None


async def _raw_loop(term: Terminal, inp) -> None:
    import asyncio

    queue: asyncio.Queue = asyncio.Queue()

    def ready() -> None:
        for key_press in inp.read_keys():
            queue.put_nowait(key_press)

    keys = RawKeys(term)
    with inp.raw_mode(), inp.attach(ready):
        while True:
            key_press = await queue.get()
            for key in translate_keys(key_bytes(key_press)):
                action = keys.press(key)
                if action == "leave":
                    if term.left_ascii:
                        await asyncio.sleep(min(term.session.client.timeout, 0.3))  # its reply
                    return
                if action in _ASK:
                    name = await _ask_file_async(inp, _ASK[action])
                    if action == "f":
                        term.toggle_log(name)
                    else:
                        await asyncio.to_thread(term.send_file, name)
                        if term.left_ascii:
                            return


async def _ask_file_async(inp, question: str) -> str:
    """A file name, asked on the raw terminal's own input (prompt_toolkit restores raw mode
    and our key reader afterwards)."""
    from prompt_toolkit import PromptSession
    from prompt_toolkit.completion import PathCompleter

    try:
        return await PromptSession(input=inp).prompt_async(
            question, completer=PathCompleter(expanduser=True))
    except (EOFError, KeyboardInterrupt):
        return ""


def run_raw_mode(term: Terminal) -> None:
    import asyncio

    from prompt_toolkit.input import create_input

    inp = create_input()
    term.start_reader()
    try:
        asyncio.run(_raw_loop(term, inp))
    finally:
        term.stop_reader()
        term.write([("", "\r\n")] if not term._lines.at_line_start else [])
        inp.close()


def _ask_yes_no(question: str, default: bool) -> bool:
    from ..repl.ask import ask_yes_no

    return ask_yes_no(question, default)


# -- shell commands ------------------------------------------------------------------------------

def _complete_ascii(session: Session, text: str) -> list[tuple[str, str]]:
    return [("--raw", "pass keys through one by one"),
            ("--echo", "with --raw: echo typed keys locally"),
            ("--bin", "send BIN when leaving"), ("--no-bin", "stay in ASCII mode when leaving")]


@command(".ascii")
def cmd_ascii(session: Session, argtext: str) -> None:
    opts = parse_options(argtext)
    client = session.client
    tty_in = sys.stdin.isatty() and sys.stdout.isatty()
    if opts.raw and not tty_in:
        raise ValidationError(".ascii --raw needs a terminal")
    was_ascii = client.ascii_link is not None
    link = client.ascii_link or AsciiLink.attach(client, tell=not opts.raw)
    if opts.raw:  # straight to the terminal: no prompt to draw around, no proxy's delay
        term = Terminal(session, link, opts, _real_write(sys.__stdout__),
                        write_note=_real_write(sys.__stderr__))
    else:
        term = Terminal(session, link, opts, _stdout_write, write_note=_stderr_write)
    if not was_ascii:
        term.note("module entered ASCII mode (command 139)" if link.entered
                  else "module was already in ASCII mode")
    term.banner()
    try:
        if opts.raw:
            run_raw_mode(term)
        elif tty_in:
            run_line_mode(term)
        else:
            run_plain_lines(term, sys.stdin)
    finally:
        if term.menu.log is not None:
            term.toggle_log(None)
    if term.left_ascii:
        term.back_to_binary()
        return
    _leave(term, tty_in)


def _stdout_write(text: str) -> None:
    sys.stdout.write(text)
    sys.stdout.flush()


def _real_write(stream) -> Callable[[str], None]:
    def write(text: str) -> None:
        stream.write(text)
        stream.flush()

    return write


def _stderr_write(text: str) -> None:
    sys.stderr.write(text)
    sys.stderr.flush()


def _leave(term: Terminal, interactive: bool) -> None:
    link = term.link
    send_bin = term.opts.send_bin
    if send_bin is None:
        default = link.found == Mode.BINARY
        send_bin = _ask_yes_no("--- send BIN (module back to binary mode)?", default) \
            if interactive else default
    # the answer also decides the mode tmclsh leaves the module in when it exits
    if send_bin:
        link.detach(send_bin=True)
        link.on_exit = Mode.BINARY
        term.note("BIN sent: module in binary mode")
    else:
        link.on_exit = Mode.ASCII
        term.note("module stays in ASCII mode, also when tmclsh exits (the shell talks to "
                  "it in ASCII; .mode binary switches back)")


def _complete_mode(session: Session, text: str) -> list[tuple[str, str]]:
    return [("ascii", "drive the module through its ASCII command line"),
            ("binary", "binary TMCL frames (sends BIN if in ASCII mode)"),
            ("--keep", "leave the module in this mode when tmclsh exits")]


@command(".mode")
def cmd_mode(session: Session, argtext: str) -> None:
    words, given = options.parse_words(argtext, options_of(".mode"))
    keep = "--keep" in given
    client = session.client
    if len(words) > 1 or (words and words[0].lower() not in ("ascii", "binary")):
        raise ValidationError(".mode takes ascii or binary (and --keep)")
    if words:
        want = Mode(words[0].lower())
        if want == Mode.ASCII and client.ascii_link is None:
            AsciiLink.attach(client)
        elif want == Mode.BINARY and client.ascii_link is not None:
            client.ascii_link.detach(send_bin=True)
        link = AsciiLink.for_client(client)
        if keep and link is not None:
            link.on_exit = want
    _show_mode(session)


def _show_mode(session: Session) -> None:
    client = session.client
    link = AsciiLink.for_client(client)
    if session.out.json:
        obj: dict = {"mode": client.mode}
        if link is not None:
            obj.update(echo=link.echo.name.lower(), found=link.found.value,
                       on_exit=link.on_exit.value)
        session.out.emit(obj)
        return
    if client.ascii_link is not None:
        session.out.print(f"mode: {client.ascii_link.describe()}", markup=False)
    else:
        extra = ""
        if link is not None and link.on_exit == Mode.ASCII:
            extra = (" (module was found in ASCII mode: 139 is sent at exit)"
                     if link.found == Mode.ASCII else
                     " (back to ASCII mode at exit, as chosen when leaving .ascii)")
        session.out.print(f"mode: binary{extra}", markup=False)


def _no_ascii_interface(session: Session) -> str | None:
    """Why this module has no GP 67 to show or set, from its data (a module known by number
    only is asked: the module decides), or None."""
    module = session.client.module
    if module is None or module.generic:
        return None
    if not module.ascii_mode:
        return f"the {module.name} has no ASCII interface (its data: no GP 67, no command 139)"
    if module.glob(GP_ASCII_MODE, GP_BANK) is None:
        return f"the {module.name}'s data lists no GP 67 (ASCIIMode)"
    return None


def _complete_config(session: Session | None, text: str) -> list[tuple[str, str]]:
    if session is not None and _no_ascii_interface(session) is not None:
        return []  # nothing to offer: the module has no GP 67
    return [("startup=ascii", "start up in ASCII mode (GP 67 bit 0)"),
            ("startup=binary", "start up in binary mode"),
            ("echo=char", "echo each character (bits 5/4 = 00)"),
            ("echo=line", "echo the whole line after CR (01)"),
            ("echo=none", "no echo, reply only (10)")]


@command(".ascii-config")
def cmd_ascii_config(session: Session, argtext: str) -> None:
    changes: dict[str, str] = {}
    for word in argtext.split():
        key, sep, val = word.partition("=")
        key, val = key.lower(), val.lower()
        if not sep or key not in ("startup", "echo"):
            raise ValidationError(f".ascii-config: {word!r}: use startup=ascii|binary and/or "
                                  "echo=char|line|none")
        if key == "startup" and val not in ("ascii", "binary"):
            raise ValidationError(f"startup must be ascii or binary, got {val!r}")
        if key == "echo" and val not in ECHO_NAMES:
            raise ValidationError(f"echo must be one of {'|'.join(ECHO_NAMES)}, got {val!r}")
        changes[key] = val
    lacking = _no_ascii_interface(session)
    if lacking is not None:
        raise ValidationError(f"{lacking}: nothing to show or set; nothing sent")
    client = session.client
    current = _read_gp67(session)
    if not changes:
        _show_gp67(session, current, None)
        return
    new = gp67_value(current, startup=changes.get("startup"), echo=changes.get("echo"))
    param = client.require_module().glob(GP_ASCII_MODE, GP_BANK)
    if param is not None:
        param.check(new)
    if new == current:
        _show_gp67(session, current, "unchanged")
        return
    session.confirm(f"write GP 67 = {new} ({describe_gp67(new)}) to the module's EEPROM "
                    f"(now {current})?")
    reply = client.request(Request(client.address, _SGP, GP_ASCII_MODE, GP_BANK, new))
    session.stats.commands += 1
    if reply is not None and not status_ok(reply.status):
        raise StatusError(reply.status, reply)
    if client.ascii_link is not None:
        client.ascii_link.refresh_echo()
    value = _read_gp67(session)
    _show_gp67(session, value, f"was {current}")
    if not session.out.json:
        session.out.info("stored: SGP writes GP 67 to EEPROM itself (bank-0 parameters "
                         "64..128, manual §10.1), STGP 67, 0 is not needed; the start-up "
                         "mode applies from the next power-up")


def _read_gp67(session: Session) -> int:
    client = session.client
    reply = client.request(Request(client.address, _GGP, GP_ASCII_MODE, GP_BANK, 0))
    session.stats.commands += 1
    assert reply is not None
    if not status_ok(reply.status):
        raise StatusError(reply.status, reply)
    return reply.value


def _show_gp67(session: Session, value: int, note: str | None) -> None:
    if session.out.json:
        obj = {"gp67": value, "startup": "ascii" if starts_in_ascii(value) else "binary",
               "echo": echo_mode(value).name.lower()}
        if note:
            obj["note"] = note
        session.out.emit(obj)
        return
    from rich.text import Text

    from ..render import render_bits

    text = Text()
    text.append("GP 67 ASCIIMode", style="tmcl.name")
    text.append(" = ")
    text.append(str(value), style="tmcl.value")
    text.append(f"  ({describe_gp67(value)})")
    if note:
        text.append(f"  [{note}]", style="tmcl.note")
    session.out.print(text)
    param = session.client.module.glob(GP_ASCII_MODE, GP_BANK) if session.client.module else None
    if param is not None and param.bits:
        session.out.print(render_bits(value, param))
