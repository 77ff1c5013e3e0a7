"""Completion: the pure ``suggest()`` and what the completer offers for a typed line.

No terminal, no device: the completer reads the module database only.
"""

from __future__ import annotations

import dataclasses

import pytest
from prompt_toolkit.completion import CompleteEvent
from prompt_toolkit.document import Document

from tmclsh.link.modes import ASCII, BINARY
from tmclsh.tmcl.modules import load
from tmclsh.shell.lang import commands
from tmclsh.shell.lang.session import SessionState
from tmclsh.shell.repl.completer import (AxisParam, CommandArg, GlobalParam, Interrupt, IoBank, IoPort,
                                    Label, Mnemonic, MotorNumber, ParamBank, ParamValue,
                                    ShellCommand, SymbolicType, TmclCompleter, current_word,
                                    suggest)

M1311 = load("TMCM-1311")
M351 = load("TMCM-351")
M1640 = load("TMCM-1640")

commands.load_all()


# -- suggest() ---------------------------------------------------------------------------

@pytest.mark.parametrize("text, expected", [
    ("", [Mnemonic(), ShellCommand(dotted=True)]),
    ("G", [Mnemonic(), ShellCommand(dotted=False)]),
    ("  gap", [Mnemonic(), ShellCommand(dotted=False)]),
    ("GAP ", [AxisParam("GAP", "R")]),
    ("GAP MaxPos", [AxisParam("GAP", "R")]),
    ("gap maxpos", [AxisParam("GAP", "R")]),
    ("SAP ", [AxisParam("SAP", "W")]),
    ("STAP ", [AxisParam("STAP", "E")]),
    ("RSAP Max", [AxisParam("RSAP", "E")]),
    ("GAP 4, ", [MotorNumber("GAP")]),
    ("GAP 4,", [MotorNumber("GAP")]),
    ("SAP 140, 0, ", [ParamValue("SAP", "axis", "140", "0")]),
    ("GGP ", [GlobalParam("GGP", "R")]),
    ("SGP Serial", [GlobalParam("SGP", "W")]),
    ("STGP ", [GlobalParam("STGP", "E")]),
    ("GGP SerialAddress, ", [ParamBank("GGP", "SerialAddress")]),
    ("SGP 66, 0, ", [ParamValue("SGP", "global", "66", "0")]),
    ("MVP ", [SymbolicType("MVP")]),
    ("MVP A", [SymbolicType("MVP")]),
    ("MVP ABS, ", [MotorNumber("MVP")]),
    ("MVP ABS, 0, ", []),  # a position: nothing to offer
    ("RFS ", [SymbolicType("RFS")]),
    ("GIO ", [IoPort("GIO", outputs=False)]),
    ("SIO ", [IoPort("SIO", outputs=True)]),
    ("GIO 1, ", [IoBank("GIO", "1", outputs=False)]),
    ("EI ", [Interrupt("EI")]),
    ("EI, ", [Interrupt("EI")]),  # the manuals' comma after the mnemonic
    ("JA ", [Label("JA")]),
    ("Loop: MV", [Mnemonic(), ShellCommand(dotted=False)]),
    ("Loop: ", [Mnemonic()]),
    ("Loop: GAP ", [AxisParam("GAP", "R")]),
    ("GAP 4, 0 // comm", []),
    ("GAP 4, 0, 0, ", []),
    ("FOO ", []),
    ("136 ", []),
    (".", [ShellCommand(dotted=True)]),
    (".pa", [ShellCommand(dotted=True)]),
    (".param ", [CommandArg(".param", "")]),
    (".param max", [CommandArg(".param", "max")]),
    (".help S", [CommandArg(".help", "S")]),
    ("help ", [CommandArg(".help", "")]),
    ("help GA", [CommandArg(".help", "GA")]),
])
def test_suggest(text, expected):
    assert suggest(text, M1311) == expected


def test_suggest_does_not_need_a_module():
    assert suggest("GAP ", None) == [AxisParam("GAP", "R")]


@pytest.mark.parametrize("text, word", [
    ("GAP MaxPos", "MaxPos"), ("GAP ", ""), ("SAP 4, 0, $1F", "$1F"), (".par", ".par"),
    ("GAP 4,0", "0"),
])
def test_current_word(text, word):
    assert current_word(text) == word


# -- the completer -----------------------------------------------------------------------

def complete(text: str, module=M1311, session=None):
    c = TmclCompleter(session=session, module=module)
    return list(c.get_completions(Document(text), CompleteEvent(completion_requested=True)))


def texts(text: str, module=M1311) -> list[str]:
    return [c.text for c in complete(text, module)]


def test_gap_maxpos_offers_both_speed_and_current_speed_first():
    got = complete("GAP MaxPos")
    assert [c.text for c in got][:2] == ["MaxPositioningSpeed", "MaxPossibleCurrent"]
    first = got[0]
    assert first.start_position == -len("MaxPos")
    # the meta text a user sees: number, range with unit, access, the manual's name
    meta = first.display_meta_text
    assert "AP 4" in meta and "0..327679999 pps" in meta and "Maximum positioning speed" in meta
    assert "AP 15" in got[1].display_meta_text


def test_parameter_completion_is_case_insensitive_and_fuzzy():
    assert texts("GAP maxpos")[0] == "MaxPositioningSpeed"
    assert texts("SAP microstep")[0] == "MicrostepResolution"
    assert "MaxPositioningSpeed" in texts("GAP mxpsp")  # letters in order


def test_completion_respects_access():
    assert "MaxPossibleCurrent" not in texts("SAP MaxPos")  # read-only: SAP would be refused
    assert "MaxPositioningSpeed" in texts("STAP MaxPos")
    assert "ActualPosition" not in texts("STAP Actual")  # RW, not storable


def test_number_in_parameter_slot_completes_numbers():
    got = complete("GAP 14")
    assert [c.text for c in got][:3] == ["14", "140", "141"]
    assert all(c.text.startswith("14") for c in got)
    assert "MicrostepResolution" in got[1].display_text


def test_mnemonics_are_the_modules_and_direct_only():
    all_1311 = texts("", M1311)
    assert "SAP" in all_1311 and "MVP" in all_1311
    assert "JA" not in all_1311  # program-only: refused at the prompt
    assert "RFS" in texts("R", M1311)
    assert "RFS" not in texts("R", M1640)  # the TMCM-1640 has no reference search
    meta = {c.text: c.display_meta_text for c in complete("MV")}
    assert "Move to position" in meta["MVP"]


def test_symbolic_types_per_module():
    assert texts("MVP ", M1311) == ["ABS", "REL", "COORD"]
    assert texts("MVP ", M1640) == ["ABS", "REL"]
    assert texts("MVP co", M1311) == ["COORD"]


def test_motor_numbers():
    assert texts("ROR ", M1311) == ["0"]
    assert texts("SAP 4, ", M351) == ["0", "1", "2"]


def test_global_parameters_and_banks():
    got = complete("GGP Serial")
    names = [c.text for c in got]
    assert names[0] in ("SerialAddress", "SerialHeartbeat", "SerialHostAddress")
    assert "GP 66" in {c.text: c.display_meta_text for c in got}["SerialAddress"]
    assert texts("GGP SerialAddress, ") == ["0"]
    assert texts("GGP 0, ") == ["2", "3"]  # GP 0 exists in banks 2 (user var) and 3 (timer)
    assert "Timer0Period" in texts("GGP Timer")


def test_io_ports_and_banks():
    ports = complete("GIO ")
    assert [c.text for c in ports][:8] == [str(n) for n in range(8)]
    assert "255" in [c.text for c in ports]
    assert "IN_1" in {c.text: c.display_meta_text for c in ports}["1"]
    outs = {c.text: c.display_meta_text for c in complete("SIO ")}
    assert "OUT_3" in outs["3"] and "IN_3" not in outs["3"]
    assert texts("SIO 3, ") == ["2"]
    assert texts("GIO 8, ") == ["1"]  # supply voltage: analog bank only


def test_parameter_values():
    got = complete("SAP MicrostepResolution, 0, ")
    assert [c.text for c in got][:2] == ["0", "1"]
    assert got[8].display_meta_text == "256 microsteps"
    assert texts("SAP 4, 0, ") == []  # a plain number: nothing to offer


def test_interrupt_names():
    assert "TI_TIMER0" in texts("EI TI_T")


def test_dot_commands_with_meta():
    got = {c.text: c.display_meta_text for c in complete(".pa")}
    assert ".param" in got and ".params" in got
    assert "parameter" in got[".param"]
    assert ".help" in texts(".he")


def test_bare_words_at_line_start():
    assert "help" in texts("he")
    assert "quit" in texts("qu")


def test_dot_command_arguments():
    assert texts(".trace ") == ["on", "off"]
    assert texts(".trace o") == ["on", "off"]
    assert texts(".param maxpos")[0] == "MaxPositioningSpeed"
    assert texts(".params ")[:2] == ["axis", "global"]
    assert texts(".module 351") == ["TMCM-351"]
    assert "sim" in texts(".connect ")
    assert "TMCM-1640" in texts(".connect sim ")


def test_help_argument_offers_commands_mnemonics_and_parameters():
    got = texts("help ")
    assert "SAP" in got and ".param" in got and "MicrostepResolution" in got
    assert texts("help SA")[0] == "SAP"
    assert "--source" in texts("help --s")
    assert texts("help --source RO")[:2] == ["ROR", "ROL"]
    assert "--source" not in texts("help --source ")


class _FakeProgram:
    labels = {"Loop": 3, "Start": 0}


class _FakeSession:
    def __init__(self):
        self.state = SessionState(program=_FakeProgram())
        self.client = type("C", (), {"module": M1311, "mode": BINARY})()


def test_labels_come_from_the_debuggers_program():
    s = _FakeSession()
    got = [c.text for c in complete("JA ", session=s)]
    assert got == ["Start", "Loop"]
    assert [c.text for c in complete("JA Lo", session=s)] == ["Loop"]


def test_completer_never_asks_the_device():
    class Boom:
        def __getattr__(self, name):
            raise AssertionError(f"completion touched the client: {name}")

    s = _FakeSession()
    s.client = type("C", (), {"module": M1311, "mode": BINARY,
                              "request": Boom(), "send": Boom(), "identify": Boom()})()
    for text in ("", "GAP ", "GAP MaxPos", "GGP 0, ", "SIO ", ".param ", "help 1"):
        complete(text, module=None, session=s)


def test_ascii_mode_hides_commands_the_ascii_interface_refuses(monkeypatch):
    """Which commands the module's ASCII mode knows is the instruction set's (``ascii``),
    read through the mode's facts: a direct command marked otherwise is not offered there,
    and is in binary mode. (Every direct command of the manuals is marked ascii today, so
    the data is changed for the test: the completer must read it, not know it.)"""
    changed = [dataclasses.replace(sp, ascii=False) if sp.mnemonic in ("ROR", "GGP") else sp
               for sp in M1311.instructions]
    monkeypatch.setitem(vars(M1311), "instructions", changed)  # (a cached property)
    s = _FakeSession()
    s.client.mode = ASCII
    got = [c.text for c in complete("", module=M1311, session=s)]
    assert "SAP" in got and "GAP" in got and "ROL" in got
    assert "ROR" not in got and "GGP" not in got
    reads = [c.text for c in complete(".expect ", module=M1311, session=s)]
    assert "GAP" in reads and "GGP" not in reads
    s.client.mode = BINARY
    got = [c.text for c in complete("", module=M1311, session=s)]
    assert "ROR" in got and "GGP" in got
    assert "GGP" in [c.text for c in complete(".expect ", module=M1311, session=s)]


# -- inside expressions --------------------------------------------------------------------

def menu(text: str, session=None) -> list[tuple[str, str]]:
    return [(c.text, c.display_meta_text) for c in complete(text, session=session)]


@pytest.mark.parametrize("prefix", [
    ".watch pos=", ".watch a=GAP 1, 0; b=", ".watch p=GAP 1, 0 --until \"", ".wait ",
    ".expect ", ".if ", ".elif ", ".display ", ".let x = ", "SAP 4, 0, ${", ".expect 5 < ",
    ".wait abs(", ".if not ", ".expect GAP 1, 0 > 3 and ",
])
@pytest.mark.parametrize("tmcl", ["GAP MaxPos", "GAP 4, ", "GGP ", "GGP SerialAddress, ",
                                  "GIO ", "GIO 1, "])
def test_a_read_inside_an_expression_completes_as_at_the_prompt(prefix, tmcl):
    at_prompt = menu(tmcl)
    assert at_prompt  # each read has something to offer at the prompt
    assert menu(prefix + tmcl) == at_prompt


def test_where_a_value_is_expected_the_reads_variables_and_functions():
    s = _FakeSession()
    s.variables = {"target": 5000}
    got = [c.text for c in complete(".expect ", module=None, session=s)]
    # the module's read commands (RFS only as RFS STATUS), not commands that move
    assert {"GAP", "GGP", "GIO", "GCO", "RFS"} <= set(got)
    assert not {"SAP", "MVP", "ROR", "MST"} & set(got)
    assert "target" in got and "abs(" in got
    assert [c.text for c in complete(".expect GAP 1, 0 == t", module=None, session=s)][0] \
        == "target"
    assert [c.text for c in complete(".wait RFS ", module=None, session=s)] == ["STATUS"]


def test_watch_until_offers_the_watched_names():
    got = texts(".watch pos=GAP 1, 0; v=GAP 3, 0 --until \"")
    assert got[:2] == ["pos", "v"]


def test_after_a_value_or_outside_the_expression_nothing_from_it():
    assert texts(".expect GAP 1, 0 ") == []  # an operator comes next
    assert texts(".let x") == []  # the variable's name, before =
    assert texts(".wait GAP 8, 0 == 1 --time") == ["--timeout"]  # the command's options
    assert "GAP" not in texts(".watch pos=GAP 1, 0 --interval ")
    assert "GAP" not in texts('.watch p=GAP 1, 0 --until "p > 5" ')  # the quoted value ended
    assert "GAP" in texts('.watch p=GAP 1, 0 --until "p > ')
    # a closed ${...} is over: the line's own slot completes again
    assert texts("SAP 140, ${m}, ") == texts("SAP 140, 0, ") != []


def test_a_computed_operand_keeps_the_read_going():
    assert texts(".expect GAP (GGP 0, 2), ") == texts("GAP 1, ")
    assert texts(".if GAP 1, (m) == GGP ") == texts("GGP ")


def test_nothing_is_offered_inside_a_comment():
    """A comment runs to the end of the line (`#` at a word's start, or `//`), as the shell
    reads it; inside quotes a `#` is text."""
    assert suggest("GAP 1, 0 # Max") == [] and suggest("GAP 1, 0 // Max") == []
    assert suggest("GAP Max") != [] and suggest('.echo "a # b') != []
