"""The dot-commands' options: declared once in the command table, read by one parser
(shell/lang/options.py) for every command, offered by the completer, and named in the syntax line
that ``.help`` and the man page show."""

from __future__ import annotations

import re

import pytest

from tmclsh.base.errors import ValidationError
from tmclsh.shell.lang import commands, options
from tmclsh.shell.repl.completer import complete_arg
from tmclsh.shell.lang.options import Option

WATCH = (Option("--interval", "S"), Option("--until", "EXPR"), Option("--csv", "FILE"))


def test_options_come_out_of_the_text_the_rest_stays_as_typed():
    rest, opts = options.parse('pos=GAP 1, 0; b=GIO 0, 0 --interval 0.1 --until "pos >= 5000"'
                               " --csv x.csv", WATCH)
    assert rest == "pos=GAP 1, 0; b=GIO 0, 0"
    assert opts == {"--interval": "0.1", "--until": "pos >= 5000", "--csv": "x.csv"}
    # a minus inside an expression is no option; quotes protect their content
    rest, opts = options.parse("GAP 1, 0 - -5 '--flag' --flag", (Option("--flag"),))
    assert rest == "GAP 1, 0 - -5 '--flag'" and opts == {"--flag": True}
    assert options.parse("x --interval=2", WATCH) == ("x", {"--interval": "2"})


def test_short_spellings_and_words():
    yes = (Option("--yes", aliases=("-y",)), Option("--at", "ADDR"))
    assert options.parse_words('"my file.tmc" -y --at 8', yes) == (
        ["my file.tmc"], {"--yes": True, "--at": "8"})


@pytest.mark.parametrize("text, message", [
    ("x --timout 3", "unknown option --timout \\(options: --interval, --until, --csv\\)"),
    ("x --interval", "--interval needs a value \\(S\\)"),
    ('x --until "a > 1', "unclosed quote in the value of --until"),
    ("x 'open", "unclosed quote"),
])
def test_mistakes_are_one_clear_line(text, message):
    with pytest.raises(ValidationError, match=message):
        options.parse(text, WATCH)
    with pytest.raises(ValidationError, match="--flag takes no value"):
        options.parse("--flag=1", (Option("--flag"),))


def test_option_numbers():
    assert options.float_value({"--timeout": "2.5"}, "--timeout", 30) == 2.5
    assert options.float_value({}, "--timeout", 30) == 30
    assert options.float_value({"--timeout": "none"}, "--timeout", 30, allow_none=True) is None
    with pytest.raises(ValidationError, match="seconds"):
        options.float_value({"--timeout": "soon"}, "--timeout", 30)
    with pytest.raises(ValidationError, match="from 0 to 86400, got '-1'"):
        options.float_value({"--timeout": "-1"}, "--timeout", 30)
    with pytest.raises(ValidationError, match="from 0 to 86400, got '1e300'"):
        options.float_value({"--timeout": "1e300"}, "--timeout", 30)
    with pytest.raises(ValidationError, match="got 'nan'"):
        options.float_value({"--timeout": "nan"}, "--timeout", 30)
    assert options.int_value({"--count": "0x10"}, "--count", None) == 16
    with pytest.raises(ValidationError, match="from 1 to 1000000, got .0."):
        options.int_value({"--count": "0"}, "--count", None)


@pytest.mark.parametrize("cmd", [c for c in commands.COMMANDS if c.options], ids=str)
def test_the_syntax_line_names_exactly_the_declared_options(cmd):
    """What .help and the man page show of a command is what its parser takes."""
    shown = set(re.findall(r"(?<![\w-])-{1,2}[a-z][a-z-]*", cmd.syntax))
    assert shown == {o.name for o in cmd.options}, cmd.syntax


def test_every_option_in_a_syntax_line_is_declared():
    for cmd in commands.COMMANDS:
        shown = set(re.findall(r"(?<![\w-])--[a-z][a-z-]*", cmd.syntax))
        assert shown <= {o.name for o in cmd.options}, cmd.name


def test_the_completer_offers_the_declared_options_not_given_yet():
    offered = [c.text for c in complete_arg(None, ".upload", "prog.tmc --yes -")]
    assert offered == ["--at", "--no-verify"]
    assert [c.text for c in complete_arg(None, ".wait", "GAP 1, 0 == 1 --")] == [
        "--timeout", "--interval"]
