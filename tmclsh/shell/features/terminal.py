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

import sys
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ...tmcl import instructions as isa
from ...client.ascii import (CR, GP_ASCII_MODE, GP_BANK, ECHO_NAMES, AsciiLink, Echo, LineKind,
                             address_char, ascii_commands, describe_gp67, drive, echo_mode,
                             echo_written, mode_record, mode_text, padded, switch,
                             gp67_value, starts_in_ascii, tell_no_checksum)
from ...base.errors import StatusError, ValidationError
from ...tmcl.frames import Request, status_ok
from ..lang import options
from ..lang.commands import command, options_of
from .termtools import (MenuState, SessionLog, Stamper, choose, file_lines, hex_hint, hex_lines,
                        is_bin, menu_text)
from .termloops import real_write, run_line_mode, run_plain_lines, run_raw_mode
from .termview import LineView, Painter, RawView, Segment, printable, with_address

if TYPE_CHECKING:
    from ..lang.session import Session

_GGP, _SGP = int(isa.Opcode.GGP), int(isa.Opcode.SGP)


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
        if not self.opts.raw:  # (raw mode: the keys as typed)
            # whole nine-byte blocks, as tmclsh's own lines: a binary module on the line
            # that frames in nines stays in step
            line = padded(line)
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

        try:
            self.link.after_bin()
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
    link, news = drive(client, tell=False)  # (the terminal reads nothing twice: _leave)
    if opts.raw:  # straight to the terminal: no prompt to draw around, no proxy's delay
        term = Terminal(session, link, opts, real_write(sys.__stdout__),
                        write_note=real_write(sys.__stderr__))
    else:
        term = Terminal(session, link, opts, _stdout_write, write_note=_stderr_write)
    if news is not None:
        term.note(news)
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


def _stderr_write(text: str) -> None:
    sys.stderr.write(text)
    sys.stderr.flush()


def _leave(term: Terminal, interactive: bool) -> None:
    link = term.link
    send_bin = term.opts.send_bin
    if send_bin is None:
        default = link.found_in_binary
        send_bin = _ask_yes_no("--- send BIN (module back to binary mode)?", default) \
            if interactive else default
    # the answer also decides the mode tmclsh leaves the module in when it exits
    link.settle(to_binary=send_bin)
    if send_bin:
        term.note("BIN sent: module in binary mode")
    else:
        term.note("module stays in ASCII mode, also when tmclsh exits (the shell talks to "
                  "it in ASCII; .mode binary switches back)")
        tell_no_checksum(term.session.client)  # (from here the shell reads through it)


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
        switch(client, words[0].lower(), keep=keep)
    _show_mode(session)


def _show_mode(session: Session) -> None:
    client = session.client
    if session.out.json:
        session.out.emit(mode_record(client))
        return
    session.out.print(f"mode: {mode_text(client)}", markup=False)


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
    echo_written(client)
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
