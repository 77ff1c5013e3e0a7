"""In a pipe or a file the shell writes plain lines without rich; they must be the characters
rich writes there (rich is the reference: it is what a terminal shows, less the colour)."""

from __future__ import annotations

import io
import sys

import pytest

from tmclsh.tmcl import asm
from tmclsh.client.text import Result
from tmclsh.tmcl.modules import load
from tmclsh.tmcl.frames import Reply
from tmclsh.shell.render import Output, _console, render_event, render_result

M = load("TMCM-1311")


class Pipe(io.StringIO):
    def isatty(self) -> bool:
        return False


def result(line: str, status: int = 100, value: int = 0, **kw) -> Result:
    enc = asm.encode(asm.parse_line(line), M, direct=True)
    ins = enc.instruction
    return Result(line, enc, Reply(2, 1, status, ins.opcode, value, **kw))


CASES = [
    ("GAP 1, 0", 100, -5000, {}),
    ("SAP 4, 0, 1000", 100, 1000, {}),
    ("SAP 4, 0, 1000", 4, 0, {}),
    ("GAP StatusWord, 0", 100, 0b1001, {}),  # bits on the lines below
    ("GIO 255, 0", 100, 5, {}),  # all inputs
    ("GIO 8, 1", 100, 240, {}),  # a scaled analogue input
    ("ROR 0, 500", 100, 0, {}),
    ("136 0, 0, 0", 100, 0, {"version": "1311V111"}),
    ("136 1, 0, 0", 100, 0x051F_6F00, {}),
]


@pytest.fixture
def pipes(monkeypatch):
    """``pipes()`` -> (stdout, stderr), both pipes from now on (called in the test: pytest
    puts its own capture back between a fixture and the test)."""
    for var in ("FORCE_COLOR", "TTY_COMPATIBLE"):
        monkeypatch.delenv(var, raising=False)

    def make() -> tuple[Pipe, Pipe]:
        out, err = Pipe(), Pipe()
        monkeypatch.setattr(sys, "stdout", out)
        monkeypatch.setattr(sys, "stderr", err)
        return out, err
    return make


def rich_text(write) -> str:
    """What rich writes to a pipe for ``write(console)``."""
    real = sys.stdout
    sys.stdout = buf = Pipe()
    try:
        write(_console())
    finally:
        sys.stdout = real
    return buf.getvalue()


@pytest.mark.parametrize("line, status, value, kw", CASES)
def test_a_result_is_what_rich_writes(pipes, line, status, value, kw):
    out, _ = pipes()
    r = result(line, status, value, **kw)
    Output().result(r, M)
    assert out.getvalue() == rich_text(lambda c: c.print(render_result(r, M)))
    assert "\x1b" not in out.getvalue()


def test_messages_and_events_are_what_rich_writes(pipes):
    out, err = pipes()
    o = Output()
    o.info("  (collecting lines until .end)")
    o.ok("motors 0 stopped")
    o.print("x = 5\twith a tab  ", markup=False)
    o.event(Reply(2, 1, 128, 138, 1))
    o.warn("watch: a value is late")
    o.error("GAP 1, 7", "no motor 7")
    assert out.getvalue() == rich_text(lambda c: (
        c.print("  (collecting lines until .end)", style="tmcl.note", markup=False),
        c.print("motors 0 stopped", style="tmcl.ok", markup=False),
        c.print("x = 5\twith a tab  ", markup=False),
        c.print(render_event(Reply(2, 1, 128, 138, 1)), style="tmcl.event", markup=False)))
    assert err.getvalue() == "watch: a value is late\nerror: no motor 7\n"


def test_rich_writes_when_a_console_is_put_in_place(pipes):
    from rich.console import Console

    from tmclsh.shell.style import rich_theme

    out, _ = pipes()
    o = Output()
    o.console = Console(force_terminal=True, file=io.StringIO(), color_system="standard",
                        theme=rich_theme())
    o.result(result("SAP 4, 0, 1000"), M)
    assert out.getvalue() == ""
    assert "\x1b[" in o.console.file.getvalue()
    assert o.is_terminal


def test_a_result_line_kept_for_one_stream_is_not_written_to_another(monkeypatch):
    """The memo of result lines goes by stream, mode and console: a line made for a pipe is
    not sent to the stream put in its place, nor kept as text once JSON is asked for."""
    out = Output()
    r = result("GAP 1, 0", value=-5000)
    first, second = Pipe(), Pipe()
    monkeypatch.setattr(sys, "stdout", first)
    out.result(r, M)
    out.result(r, M)
    monkeypatch.setattr(sys, "stdout", second)
    out.result(r, M)
    out.json = True
    out.result(r, M)
    assert first.getvalue().splitlines() == ["ActualPosition = -5000 µsteps"] * 2
    text, obj = second.getvalue().splitlines()
    assert text == "ActualPosition = -5000 µsteps" and obj.startswith("{")
    from rich.console import Console

    console = Console(file=io.StringIO(), width=100)  # a console put in place: rich writes
    out.json = False
    out.console = console
    out.result(r, M)
    assert console.file.getvalue().strip() == "ActualPosition = -5000 µsteps"
    assert second.getvalue().count("\n") == 2
    # stdout becomes a terminal: the line made for a pipe is not written there plainly,
    # rich writes it (a console made for the terminal)
    out = Output()
    monkeypatch.setattr(sys, "stdout", Pipe())
    out.result(r, M)
    terminal = Tty()
    monkeypatch.setattr(sys, "stdout", terminal)
    out.result(r, M)
    assert out._console is not None and "ActualPosition" in terminal.getvalue()


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True
