"""The ASCII terminal's loops: line mode (a prompt_toolkit prompt with history, completion and
tio's Ctrl-T menu, each line sent whole), plain lines from a pipe, and raw mode (keys passed
through one by one). They only move bytes between the keyboard and ``Terminal``
(``terminal.py``) and draw.
"""

from __future__ import annotations

import re
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, TextIO

from ...tmcl import instructions as isa
from ...client.ascii import BS, CR, address_char, ascii_commands
from .termtools import MENU_KEY, is_bin, is_quit, menu_hint

if TYPE_CHECKING:
    from ..lang.session import Session
    from .terminal import Terminal

ESCAPE_KEY = 0x1D  # Ctrl-]
CTRL_C = 0x03


def real_write(stream: TextIO) -> Callable[[str], None]:
    """A writer to the terminal itself (``sys.__stdout__``), past the prompt's patched stdout:
    between prompts, and in raw mode, nothing else draws."""
    def write(text: str) -> None:
        stream.write(text)
        stream.flush()

    return write


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
    from ..repl.completer import (AxisParam, Candidate, GlobalParam, Mnemonic, candidates,
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
    direct = (real_write(sys.__stdout__), real_write(sys.__stderr__))

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
