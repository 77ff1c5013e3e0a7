"""The module's ASCII mode in the shell: ``.ascii`` (a serial terminal in the spirit of tio and
miniterm), ``.mode ascii|binary`` (switch the live link) and ``.ascii-config`` (GP 67).

The terminal shows what the module sends as it arrives. By default input is edited locally
(a prompt_toolkit prompt with history and completion) and each line is sent whole, with the
address character added unless one was typed; the echo of that line is hidden because the
prompt already shows it, and replies are shown with their status decoded
(``BA 100 -5000   ok, value -5000``). ``.ascii --raw`` passes keys through one by one, so the
module's own echo and backspace handling are what the user sees. Ctrl-] returns to the shell;
leaving asks whether to send BIN (``--bin``/``--no-bin`` answer in advance).

The views (``LineView``, ``RawView``) are pure: bytes in, display segments out, so they are
tested on canned byte sequences; the loops around them only move bytes and draw.

All reading goes through ``AsciiLink.read_raw`` under the client's lock: nothing else reads
the transport while the terminal runs.
"""

from __future__ import annotations

import os
import re
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from .. import instructions as isa
from ..ascii import (BS, CR, GP_ASCII_MODE, GP_BANK, ECHO_NAMES, AsciiLink, Echo, LineKind,
                     Mode, address_char, ascii_commands, classify_line, describe_gp67,
                     echo_mode, gp67_value, next_line, reply_part, reply_summary,
                     starts_in_ascii, stop_motors)
from ..errors import StatusError, ValidationError
from ..protocol import Reply, Request, status_ok
from .commands import command

if TYPE_CHECKING:
    from .session import Session

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
        from .style import color_enabled

        self.color = (color_enabled() and sys.stdout.isatty()) if color is None else color
        self._console = None
        if self.color:
            from rich.console import Console

            from .style import rich_theme

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
    opts = TerminalOptions()
    for word in argtext.split():
        if word == "--raw":
            opts.raw = True
        elif word == "--bin":
            opts.send_bin = True
        elif word == "--no-bin":
            opts.send_bin = False
        elif word == "--echo":
            opts.local_echo = True
        else:
            raise ValidationError(f".ascii: unknown option {word!r} "
                                  "(--raw, --echo, --bin, --no-bin)")
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

    # -- output ---------------------------------------------------------------------------
    def write(self, segments: Iterable[Segment]) -> None:
        """What the module sent (stdout)."""
        text = self.paint(segments)
        if text:
            self._emit(0, text)

    def note(self, text: str) -> None:
        """A status line of our own, ``---`` in front (stderr, as miniterm does)."""
        eol = "\r\n" if self.opts.raw else "\n"
        self._emit(1, self.paint([("tmcl.note", f"--- {text}"), ("", eol)]))

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
        from ..errors import TransportError

        while not self._stop.is_set():
            try:
                data = self.link.read_raw(0.05)
            except TransportError as exc:
                self.note(f"link lost: {exc}")
                return
            if data:
                self.show(data)

    def show(self, data: bytes) -> None:
        if self.opts.raw:
            self.write(self.raw_view.feed(data))
            return
        for item in self.line_view.feed(data):
            if item.kind == LineKind.ECHO:
                continue  # the prompt line already shows what was sent
            self.write(item.segments + [("", "\n")])
            if item.kind == LineKind.REPLY:
                self._replied.set()

    # -- line mode ------------------------------------------------------------------------
    def send_line(self, text: str, wait: float | None = None) -> bytes | None:
        """Send one typed line (address character added unless typed); wait up to ``wait``
        seconds for its reply so that output and prompt stay in order."""
        text = text.strip()
        if not text:
            return None
        mod = self.session.client.module
        line = (with_address(text, self.session.client.address, ascii_commands(mod))
                .encode("latin-1", errors="replace") + CR)
        self._replied.clear()
        self.line_view.expect(line)
        self.link.write_raw(line)
        if wait:
            self._replied.wait(wait)
        return line

    def stop_motors(self) -> None:
        mod = self.session.client.module
        stopped = stop_motors(self.link, mod.motors if mod else 1)
        self.note(f"motors stopped: {', '.join(map(str, stopped)) or 'none answered'}")

    def banner(self) -> None:
        c = self.session.client
        self.note(f"ASCII terminal: {c.describe()}, module {c.address} "
                  f"({address_char(c.address)}), host {c.host_address} "
                  f"({address_char(c.host_address)}), {self.link.echo.text}")
        if self.opts.raw:
            if self.link.echo != Echo.CHAR and not self.opts.local_echo:
                self.note("the module does not echo while you type (--echo echoes locally)")
            self.note("keys go to the module as typed; Ctrl-C: stop motors; "
                      "Ctrl-]: back to the shell")
        else:
            self.note(f"'{address_char(c.address)}' goes in front of lines unless typed; "
                      "Ctrl-C: stop motors; Ctrl-]: back to the shell")


# -- loops ---------------------------------------------------------------------------------------

class _Leave(Exception):
    pass


def _history():
    from prompt_toolkit.history import FileHistory, InMemoryHistory

    from ..config import state_dir

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
    from .completer import (AxisParam, Candidate, GlobalParam, Mnemonic, candidates,
                            current_word, param_meta, ranked, suggest)

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
            cands = [Candidate(n, specs.get(n, {"BIN": "leave ASCII mode (binary mode again)",
                                                 "RUN": "start the stored TMCL program",
                                                 "STOP": "stop the running TMCL program"}
                                            .get(n, ""))) for n in ascii_commands(mod)]
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


def run_line_mode(term: Terminal) -> None:
    """Prompt, send, repeat; what arrives is printed above the prompt by the reader."""
    from prompt_toolkit import PromptSession
    from prompt_toolkit.key_binding import KeyBindings
    from prompt_toolkit.patch_stdout import patch_stdout

    from .style import prompt_style

    session = term.session
    kb = KeyBindings()

    @kb.add("c-]", eager=True)  # eager: c-] is also the prefix of emacs character search
    def _(event) -> None:
        event.app.exit(exception=_Leave())

    prompt = PromptSession(history=_history(), completer=_completer(session), key_bindings=kb,
                           style=prompt_style(), complete_while_typing=False)
    message = [("class:prompt", f"ascii {address_char(session.client.address)}> ")]
    # between prompts nothing is drawn by prompt_toolkit: write to the terminal itself
    direct = (_real_write(sys.__stdout__), _real_write(sys.__stderr__))
    term.hold(*direct)
    with patch_stdout(raw=True):
        term.start_reader()
        try:
            while True:
                term.release()
                try:
                    text = prompt.prompt(message)
                except KeyboardInterrupt:
                    term.hold(*direct)
                    term.stop_motors()
                    continue
                except (EOFError, _Leave):
                    term.hold(*direct)
                    break
                term.hold(*direct)
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
            if text.strip() == "\x1d":
                break
            term.send_line(text, wait=term.session.client.timeout)
        time.sleep(0.05)
    finally:
        term.stop_reader()
        for item in term.line_view.flush():
            term.write(item.segments + [("", "\n")])


_ESC_SEQ = re.compile(rb"\x1b(?:\[[0-?]*[ -/]*[@-~]|O.|.)?", re.S)


def translate_keys(data: bytes) -> list[bytes | int]:
    """Keys typed in raw mode to what the module gets: DEL becomes BS, Enter a CR, escape
    sequences (arrows, function keys) are dropped; Ctrl-] and Ctrl-C come back as ints."""
    data = _ESC_SEQ.sub(b"", data)
    out: list[bytes | int] = []
    for b in data:
        if b in (ESCAPE_KEY, CTRL_C):
            out.append(b)
        elif b == 0x7F:
            out.append(BS)
        elif b == 0x0A:
            out.append(CR)
        else:
            out.append(bytes((b,)))
    return out


def run_raw_mode(term: Terminal) -> None:
    import select
    import termios
    import tty

    fd = sys.stdin.fileno()
    old = termios.tcgetattr(fd)
    typed = bytearray()  # the line the user has typed so far (for Ctrl-C)
    tty.setraw(fd)
    term.start_reader()
    try:
        while True:
            ready, _, _ = select.select([fd], [], [], 0.1)
            if not ready:
                continue
            keys = os.read(fd, 256)
            if not keys:
                break
            for key in translate_keys(keys):
                if key == ESCAPE_KEY:
                    return
                if key == CTRL_C:
                    if typed:
                        term.link.write_raw(BS * len(typed))
                        typed.clear()
                        term.note("line erased; Ctrl-C again stops the motors")
                    else:
                        term.stop_motors()
                    continue
                assert isinstance(key, bytes)
                term.link.write_raw(key)
                if key == CR:
                    term.raw_view.user_enter(bytes(typed))
                    typed.clear()
                elif key == BS:
                    if typed:
                        typed.pop()
                else:
                    typed += key
                if term.opts.local_echo:
                    term.write(term.raw_view.local(key))
    finally:
        term.stop_reader()
        termios.tcsetattr(fd, termios.TCSADRAIN, old)
        term.write([("", "\r\n")] if term.raw_view.shown else [])


def _ask_yes_no(question: str, default: bool) -> bool:
    from prompt_toolkit import prompt

    hint = "[Y/n]" if default else "[y/N]"
    try:
        answer = prompt(f"{question} {hint} ").strip().lower()
    except (EOFError, KeyboardInterrupt):
        return default
    if not answer:
        return default
    return answer in ("y", "yes", "j", "ja")


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
    link = client.ascii_link or AsciiLink.attach(client)
    if opts.raw:  # straight to the terminal: no prompt to draw around, no proxy's delay
        term = Terminal(session, link, opts, _real_write(sys.__stdout__),
                        write_note=_real_write(sys.__stderr__))
    else:
        term = Terminal(session, link, opts, _stdout_write, write_note=_stderr_write)
    if not was_ascii:
        term.note("module entered ASCII mode (command 139)" if link.entered
                  else "module was already in ASCII mode")
    term.banner()
    if opts.raw:
        run_raw_mode(term)
    elif tty_in:
        run_line_mode(term)
    else:
        run_plain_lines(term, sys.stdin)
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
    words = argtext.split()
    keep = "--keep" in words
    words = [w for w in words if w != "--keep"]
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


def _complete_config(session: Session, text: str) -> list[tuple[str, str]]:
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

    from .render import render_bits

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
