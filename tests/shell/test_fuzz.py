"""Random and hostile input against the shell, the assembler and the disassembler.

Property: whatever a user types, ``Session.run_line`` either works or raises a ``TmclError``
(``QuitShell`` for ``.quit``) within a time bound, in text and in --json mode, and nothing
reaches the wire that the instruction set and the module data do not allow. The frames are
checked as the simulator received them, against the manuals' tables (``instructions.toml``,
``modules/*.toml``), not against the encoder that made them.

Fixed budget and derandomized (the same examples every run), so CI is repeatable and quick.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tmclsh.tmcl import instructions as isa
from tmclsh.tmcl.asm import assemble, disassemble, parse_line, read_image
from tmclsh.client.text import LineClient

pytestmark = pytest.mark.slow  # a fuzzer: .ci/run runs it after the README's command
from tmclsh.base.errors import TmclError
from tmclsh.tmcl.modules import load
from tmclsh.tmcl.frames import Control
from tmclsh.shell.lang import commands
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import QuitShell, Session
from tmclsh.link import open_sim

# TMCLSH_FUZZ_EXAMPLES=5000 TMCLSH_FUZZ_RANDOM=1 for a longer hunt than CI's
FUZZ = settings(max_examples=int(os.environ.get("TMCLSH_FUZZ_EXAMPLES", "250")), deadline=None,
                derandomize=not os.environ.get("TMCLSH_FUZZ_RANDOM"), database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow, HealthCheck.data_too_large])
TIME_LIMIT = 0.3  # the session's time limit: .sleep 1e6, .wait, .watch cannot block the test
BOUND = TIME_LIMIT + 3.0  # seconds one line may take, with room for a loaded CI machine

# Commands that leave the sandbox of one in-process module on binary frames: another link,
# another address, ASCII text on the wire, a terminal on stdin. Raw command numbers (a line
# starting with a digit or '$') are sent as typed by design, so they are not generated.
LEAVE = {".connect", ".ascii", ".mode", ".ascii-config", ".address", ".module", ".onerror"}

MODULE = load("TMCM-1311")
NUMBERS = ["0", "1", "-1", "3", "255", "256", "2147483647", "2147483648", "-2147483649",
           "4294967295", "$FF", "0x1F", "0b101", "1e3", "1e999", "-1e999", "nan", "inf",
           "1.5", ".5", "9" * 50, "9" * 5000, "0" * 3000 + "1", "1e300", "-0", "0x" + "F" * 60]
HOSTILE = ["[/]", "[bold]", "[/bold]", "[link=x]", "${", "}", "${x}", "${1/0}", "\\", "'",
           '"', ";", ",", "(", ")", "((((", "))))", "==", "=", ">", ">>", "//", "#", "\x00",
           "\x1b[2J", "\t", "é", "∞", "🙂", "\u202e", "--", "--count", "--interval",
           "--timeout", "--until", "--csv", "--at", "--yes", "as", "off", "all", "@", ":",
           "/dev/zero", "/dev/full", "/nonexistent/x", ".", "..", "-", "min(5)", "max()",
           "bit(1.5, 2)", "round(1, 2)", "abs(", "not", "and", "or"]
MNEMONICS = sorted({s.mnemonic for s in isa.all_instructions()}) + ["FOO", "gap", "sap"]
PARAMS = sorted({p.name for name in ("TMCM-1311", "TMCM-351", "TMCM-1640")
                 for p in load(name).axis_params[:20] + load(name).global_params[:10]})
DOTS = sorted(c.name for c in commands.all_commands() if c.name not in LEAVE) + ["help", "?",
                                                                               "quit"]

number = st.sampled_from(NUMBERS) | st.integers(-2**40, 2**40).map(str) | \
    st.floats(allow_nan=True, allow_infinity=True).map(repr)
word = number | st.sampled_from(HOSTILE + MNEMONICS + PARAMS + ["ABS", "REL", "STATUS",
                                                                 "TICKS", "i", "x"])
nested = st.integers(1, 400).map(lambda n: "(" * n + "1" + ")" * n)
long_sum = st.integers(100, 1200).map(lambda n: "+".join(["1"] * n))
operand = number | word | nested | long_sum
args = st.lists(operand, max_size=6).map(lambda xs: " ".join(xs)) | \
    st.lists(operand, max_size=4).map(lambda xs: ", ".join(xs))
tmcl_line = st.tuples(st.sampled_from(MNEMONICS), args).map(lambda t: f"{t[0]} {t[1]}")
dot_line = st.tuples(st.sampled_from(DOTS), args).map(lambda t: f"{t[0]} {t[1]}")
let_line = st.tuples(st.sampled_from(["x", "i", "[/]", "min"]), args).map(
    lambda t: f".let {t[0]} = {t[1]}")
free_text = st.text(st.characters(blacklist_categories=("Cs",)), max_size=80)
# plausible lines, so that much of what is generated is sent and has to be checked
small = st.integers(-3, 300).map(str) | st.sampled_from(PARAMS + ["ABS", "REL", "COORD",
                                                                  "STATUS", "x"])
value = st.integers(-2**33, 2**33).map(str) | st.sampled_from(NUMBERS) | st.sampled_from(
    ["x", "x + 1", "${x}", "-x", "GAP 1, 0", "(1+2)*3"])
plausible_tmcl = st.tuples(st.sampled_from(MNEMONICS), small, st.integers(0, 3), value).map(
    lambda t: f"{t[0]} {t[1]}, {t[2]}, {t[3]}") | st.tuples(
    st.sampled_from(["GAP", "GGP", "GIO", "SAP", "RFS", "ROR", "MST"]), small,
    st.integers(0, 2)).map(lambda t: f"{t[0]} {t[1]}, {t[2]}")
expression = st.tuples(st.sampled_from(["GAP 1, 0", "x", "GIO 0, 0", "min(1, x)", "bit(x, 3)",
                                        "GGP 0, 2", "abs(-x)", "RFS STATUS, 0", "1/0"]),
                       st.sampled_from(["==", "!=", ">=", "+", "*", "and", "or", "%"]),
                       value).map(" ".join)
templates = st.sampled_from([
    ".let x = {e}", ".expect {e}", ".wait {e} --timeout 0.05", ".wait {e} --interval {v}",
    ".sleep {v}", ".sleep 0.01", ".repeat {v}", ".repeat 2 as i", ".end", ".if {e}", ".else",
    ".elif {e}", ".watch {e} --count 2 --interval 0", ".watch --count {v}",
    ".watch a={e}; b=GAP 1, 0 --until \"a > {v}\" --interval 0.01", ".param {v}",
    ".params axis {v}", ".params global", ".vars {v}", ".vars 0..{v}", ".history {v}",
    ".echo {e}", ".echo {e} > out.txt", ".record rec.tmcl", ".record off", ".plot",
    ".plot --width {v}", ".dump --count {v}", ".dump dump.tmc --count 3", ".status", ".stop",
    ".step {v}", ".continue {v}", ".break @{v}", ".delete", ".run", ".reset", ".where",
    ".list", ".display {e}", ".undisplay", ".decode {v}", ".help {v}", ".trace on",
    ".trace off", ".stopall", ".version", "help {v}", ".source rec.tmcl", ".upload out.txt",
    ".exit",
])
plausible_dot = st.tuples(templates, expression, value).map(
    lambda t: t[0].replace("{e}", t[1]).replace("{v}", t[2]))
line = plausible_tmcl | plausible_dot | tmcl_line | dot_line | let_line | free_text | \
    st.sampled_from(HOSTILE)


def _first_word(text: str) -> str:
    parts = text.split(None, 1)
    return parts[0] if parts else ""


def allowed(text: str) -> bool:
    t = text.strip()
    if not t or t[0].isdigit() or t[0] == "$":  # raw command numbers are sent as typed
        return False
    cmd = commands.find(_first_word(t))
    return cmd is None or cmd.name not in LEAVE


lines = st.lists(line.filter(allowed), min_size=1, max_size=6)


# -- the wire, checked against the tables ---------------------------------------------------

def check_frames(data: bytes, module=MODULE) -> None:
    """Every byte the simulator received is a binary request the tables allow."""
    assert len(data) % 9 == 0, f"{len(data)} bytes are not whole 9-byte frames"
    download = False
    for i in range(0, len(data), 9):
        f = data[i:i + 9]
        assert sum(f[:8]) & 0xFF == f[8], f"bad checksum in {f.hex(' ')}"
        assert f[0] == 1, f"frame to address {f[0]}: {f.hex(' ')}"
        op, typ, motor = f[1], f[2], f[3]
        value = int.from_bytes(f[4:8], "big", signed=True)
        if op == Control.START_DOWNLOAD:
            download = True
            continue
        if op == Control.QUIT_DOWNLOAD:
            download = False
            continue
        if 128 <= op <= 139:
            assert op != Control.FACTORY_DEFAULT, "137 sent without confirmation"
            assert op != Control.ENTER_ASCII, "139 sent (ASCII mode was not asked for)"
            continue
        spec = isa.by_opcode(op)
        assert spec is not None, f"unknown command {op} sent: {f.hex(' ')}"
        assert module.name in spec.modules, f"{spec.mnemonic} is not a {module.name} command"
        if download:
            continue  # a stored program's instruction: checked by the assembler's tests
        assert spec.direct, f"{spec.mnemonic} is not allowed in direct mode"
        assert not spec.persists, f"{spec.mnemonic} (EEPROM) sent without confirmation"
        if spec.mnemonic in ("SAP", "GAP", "RSAP"):
            assert motor < module.motors, f"{spec.mnemonic} to motor {motor}"
            p = module.axis(typ)
            assert p is not None, f"{spec.mnemonic} of axis parameter {typ}, which does not exist"
            if spec.mnemonic == "SAP":
                _check_write(p, value, f)
        elif spec.mnemonic in ("SGP", "GGP", "RSGP"):
            p = module.glob(typ, motor)
            assert p is not None, f"{spec.mnemonic} of global parameter {typ} bank {motor}"
            if spec.mnemonic == "SGP":
                _check_write(p, value, f)
                assert not (p.storable and p.bank == 0), "SGP to EEPROM without confirmation"
        elif spec.mnemonic in ("ROR", "ROL", "MST", "MVP"):
            assert motor < module.motors, f"{spec.mnemonic} to motor {motor}"


def _check_write(p, value: int, frame: bytes) -> None:
    assert p.writable, f"{p.name} is read-only but was written: {frame.hex(' ')}"
    if p.choices:
        assert value in p.choices, f"{p.name} = {value} is not one of {p.choices}"
        return
    unsigned = value & 0xFFFFFFFF
    if p.min is not None and p.max is not None:
        assert p.min <= value <= p.max or p.min <= unsigned <= p.max, \
            f"{p.name} = {value} outside {p.min}..{p.max}"


@pytest.fixture
def sandbox(tmp_path, monkeypatch):
    """Files the fuzz text names (.record x, .echo y > z) land in a scratch folder."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("TMCLSH_CONFIG", "/dev/null")
    return tmp_path


MODULES = ("TMCM-1311", "TMCM-351", "TMCM-1640")


def _session(json_mode: bool, module: str = "TMCM-1311") -> tuple[Session, list[bytes]]:
    client = LineClient(open_sim(module, 1, speed=20), module=module, timeout=0.3, retries=0)
    sim = client.transport.simulator
    received: list[bytes] = []
    write = sim.write

    def recording(data: bytes) -> None:
        received.append(bytes(data))
        write(data)

    sim.write = recording  # what the module received, byte for byte
    session = Session(client, Output(json_mode=json_mode))
    session.time_limit = TIME_LIMIT
    return session, received


class Hung(Exception):
    pass


@contextlib.contextmanager
def watchdog(seconds: float):
    """A line that blocks far past the bound fails the example (with the line and where it
    hung) instead of hanging the test run."""
    def bark(signum, frame):
        raise Hung(f"still running after {seconds:g} s")

    old = signal.signal(signal.SIGALRM, bark)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _run(texts: list[str], json_mode: bool, capsys, module: str = "TMCM-1311") -> None:
    session, received = _session(json_mode, module)
    try:
        for text in texts:
            began = time.monotonic()
            try:
                with watchdog(BOUND * 3):
                    session.run_line(text)
            except (TmclError, QuitShell):
                pass
            # anything else propagates and fails the example with its traceback
            took = time.monotonic() - began
            assert took < BOUND, f"{text[:60]!r} took {took:.1f} s"
    finally:
        session.close()
        session.client.close()
    check_frames(b"".join(received), load(module))
    out = capsys.readouterr().out
    if json_mode:
        for row in out.splitlines():
            json.loads(row)  # stdout stays one JSON object per line, whatever was typed


@FUZZ
@given(texts=lines, module=st.sampled_from(MODULES))
def test_shell_lines_text_mode(texts, module, sandbox, capsys):
    _run(texts, False, capsys, module)


@FUZZ
@given(texts=lines, module=st.sampled_from(MODULES))
def test_shell_lines_json_mode(texts, module, sandbox, capsys):
    _run(texts, True, capsys, module)


def test_the_checker_catches_what_it_should():
    """The wire check is not vacuous: a bad checksum, an unknown parameter, an out-of-range
    write and an EEPROM store are each refused."""
    def frame(op, typ, motor, value, addr=1):
        body = bytes([addr, op, typ, motor]) + value.to_bytes(4, "big", signed=True)
        return body + bytes([sum(body) & 0xFF])

    check_frames(frame(6, 1, 0, 0))  # GAP ActualPosition: fine
    for bad in (frame(6, 1, 0, 0)[:8] + b"\x00", frame(6, 250, 0, 0), frame(5, 4, 0, 2**30),
                frame(7, 4, 0, 0), frame(6, 1, 7, 0), frame(6, 1, 0, 0, addr=9),
                frame(137, 0, 0, 1234), frame(6, 1, 0, 0)[:5]):
        with pytest.raises(AssertionError):
            check_frames(bad)


# -- the assembler and the disassembler -------------------------------------------------

source_line = tmcl_line | free_text | st.tuples(st.sampled_from(["L", "Main", "x"]), args).map(
    lambda t: f"{t[0]}: {t[1]}") | st.tuples(st.sampled_from(["N", "Speed"]), operand).map(
    lambda t: f"{t[0]} = {t[1]}") | st.sampled_from(["#include x", "#include /dev/zero",
                                                     "#define", "// comment", ""])


@FUZZ
@given(text=st.lists(source_line, max_size=12).map("\n".join))
def test_assembler_on_random_text(text, sandbox):
    began = time.monotonic()
    for raw in text.splitlines():
        try:
            parse_line(raw)
        except TmclError:
            pass
    try:
        prog = assemble(text, MODULE, "fuzz.tmc", base=sandbox)
    except TmclError:
        pass
    else:
        again = assemble(disassemble(prog.instructions, MODULE), MODULE)
        assert again.instructions == prog.instructions
    assert time.monotonic() - began < BOUND


@FUZZ
@given(data=st.binary(max_size=600) | st.lists(
    st.lists(st.integers(0, 255), min_size=7, max_size=7).map(
        lambda b: " ".join(f"{x:02x}" for x in b)), max_size=20).map(
    lambda rows: "\n".join(rows).encode()))
def test_disassembler_on_random_bytes(data):
    try:
        image = read_image(data)
    except TmclError:
        return
    text = disassemble(image, MODULE)
    assert isinstance(text, str)
