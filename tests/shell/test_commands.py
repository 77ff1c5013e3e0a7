"""The dot-command table (commands.COMMANDS) and the handlers in the feature modules agree.

The table is read without importing the features, so a handler nobody described, or a
description nobody handles, would only show when a user types the command: these tests say
which one and where it belongs.
"""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys

import pytest

import tmclsh.shell
from conftest import ROOT, tmclsh_env
from tmclsh.shell.lang import commands


def _import_every_shell_module() -> None:
    for info in pkgutil.walk_packages(tmclsh.shell.__path__, "tmclsh.shell."):
        importlib.import_module(info.name)


def test_every_handler_has_an_entry_in_the_table() -> None:
    _import_every_shell_module()
    described = {c.name: c for c in commands.COMMANDS}
    for name, module in commands.HANDLERS.items():
        if not module.startswith("tmclsh.shell."):
            continue  # a test's own command
        feature = module.rsplit(".", 1)[1]
        assert name in described, (
            f"{module} has a handler for {name} but COMMANDS in tmclsh/shell/lang/commands.py has "
            f"no entry for it: add Command({name!r}, {feature!r}, SYNTAX, HELP, ...) there and "
            f"register the handler with @command({name!r}) only")
        assert described[name].feature == feature, (
            f"{name} is handled in {module} but its COMMANDS entry names the feature "
            f"{described[name].feature!r}")


def test_every_entry_has_a_handler_and_its_completion() -> None:
    for cmd in commands.COMMANDS:
        module = importlib.import_module(f"{commands.FEATURE_PACKAGE}.{cmd.feature}")
        assert commands.HANDLERS.get(cmd.name) == module.__name__, (
            f"COMMANDS describes {cmd.name} in the feature {cmd.feature!r}, but "
            f"{module.__name__} has no @command({cmd.name!r}) handler")
        assert callable(cmd.handler)
        if isinstance(cmd.complete, str):
            assert callable(getattr(module, cmd.complete, None)), (
                f"{cmd.name}: completion {cmd.complete!r} is not a function in {module.__name__}")
        if cmd.same_as:
            assert cmd.handler is commands.find(cmd.same_as).handler, cmd.name


def test_names_and_aliases_are_unique() -> None:
    names = [n for c in commands.COMMANDS for n in c.names()]
    assert len(names) == len(set(names)), sorted(n for n in names if names.count(n) > 1)
    for c in commands.COMMANDS:
        assert c.name.startswith(".") and c.syntax.startswith(c.name) and c.help, c.name


def test_the_table_is_read_without_importing_a_feature() -> None:
    """.help's list, the completer's words and the man page need no feature module; running a
    command imports its own feature and no other."""
    code = (
        "import sys\n"
        "from tmclsh.shell.lang import commands\n"
        "names = [c.name for c in commands.all_commands()]\n"
        "assert '.watch' in names and commands.find('help').bare\n"
        "features = [f'{commands.FEATURE_PACKAGE}.{f}' for f in commands.FEATURES]\n"
        "print(sorted(f for f in features if f in sys.modules))\n"
        "commands.find('.sleep').handler\n"
        "print(sorted(f for f in features if f in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.splitlines()
    assert out == ["[]", "['tmclsh.shell.features.scripting']"]


def test_an_undescribed_handler_is_refused_with_a_clear_message() -> None:
    with pytest.raises(LookupError, match=r"'\.frobnicate'.*no entry in COMMANDS"):
        commands.command(".frobnicate")(lambda session, arg: None)


def test_a_script_checks_a_feature_command_before_the_feature_ran(tmp_path) -> None:
    """.watch's options are checked when the script is read (nothing sent yet), though its
    module is imported only then."""
    script = tmp_path / "bad.tmcl"
    script.write_text("MVP ABS, 0, 1000\n.watch pos=GAP 1, 0 --intervall 1\n")
    proc = subprocess.run([sys.executable, "-m", "tmclsh", "--sim", "-f", str(script)],
                          capture_output=True, text=True, timeout=60,
                          env=tmclsh_env(), cwd=str(ROOT))
    assert proc.returncode != 0
    assert f"{script}:2: " in proc.stderr and "--intervall" in proc.stderr, proc.stderr
    assert "moving" not in proc.stdout and "nothing was sent" in proc.stdout  # no MVP ran
