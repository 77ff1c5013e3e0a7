"""The TMCL lexer: one Pygments lexer for the prompt and for listings."""

from __future__ import annotations

from pygments.token import Comment, Error, Keyword, Name, Number, Punctuation

from tmclsh.tmcl.modules import load
from tmclsh.shell.repl.lexer import TmclLexer, highlight


def tokens(text: str, module=None) -> list[tuple[object, str]]:
    return [(tok, val) for _, tok, val in TmclLexer(module).get_tokens_unprocessed(text)
            if val.strip()]


def test_a_command_line():
    assert tokens("SAP MaxPositioningSpeed, 0, $1F // fast") == [
        (Keyword, "SAP"), (Name.Attribute, "MaxPositioningSpeed"), (Punctuation, ","),
        (Number.Integer, "0"), (Punctuation, ","), (Number.Hex, "$1F"),
        (Comment.Single, "// fast")]


def test_labels_types_constants_and_jumps():
    assert tokens("Loop: MVP ABS, 0, 0x10")[:4] == [
        (Name.Label, "Loop"), (Punctuation, ":"), (Keyword, "MVP"), (Name.Builtin, "ABS")]
    assert tokens("Speed = 1000")[0] == (Name.Constant, "Speed")
    assert tokens("    JA Loop") == [(Keyword, "JA"), (Name.Label, "Loop")]
    assert tokens("EI TI_TIMER0") == [(Keyword, "EI"), (Name.Builtin, "TI_TIMER0")]


def test_mnemonics_are_case_insensitive_and_only_in_command_position():
    assert tokens("gap 4, 0")[0] == (Keyword, "gap")
    assert tokens("FOO 1")[0] == (Name, "FOO")


def test_shell_commands():
    assert tokens(".help SAP") == [(Keyword.Pseudo, ".help"), (Keyword, "SAP")]
    assert tokens("help 140") == [(Keyword.Pseudo, "help"), (Number.Integer, "140")]
    assert tokens("#include tmclparam.tmc") == [(Comment.Preproc, "#include tmclparam.tmc")]


def test_module_restricts_parameter_names():
    assert tokens("GAP ActualPosition")[1] == (Name.Attribute, "ActualPosition")
    m1640 = load("TMCM-1640")
    assert tokens("GAP MicrostepResolution", m1640)[1][0] is not Name.Attribute
    assert tokens("GAP MicrostepResolution", load("TMCM-1311"))[1][0] is Name.Attribute


def test_bad_characters_are_errors():
    assert (Error, "@") in tokens("GAP 4, 0 @")


def test_every_character_is_covered_and_positions_add_up():
    text = "Loop: SAP 4, 0, 1000  // x\n  JA Loop\n.help\n"
    pos = 0
    for index, _, value in TmclLexer().get_tokens_unprocessed(text):
        assert index == pos
        pos += len(value)
    assert pos == len(text)


def test_highlight_for_listings():
    text = highlight("MVP ABS, 0, 100\n")
    assert text.plain == "MVP ABS, 0, 100\n"
