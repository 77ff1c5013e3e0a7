"""Adding to tmclsh is what HACKING.md says it is: a dot-command is two hand-edited files (its
entry in the command table, its handler in a feature module), a built-in module is one data
file. Done here to a copy of the tree, exactly so, the new command and module are then found
where users look: ``.help``, completion, the man page, ``tmclsh modules``, the simulator.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest

from conftest import ROOT, tmclsh_env

ENTRY = ("    Command('.hello', 'hello', '.hello [NAME]', 'greet the module (a test command)',\n"
         "            complete=['world'], category='general'),\n")
HANDLER = '''"""A dot-command added the way HACKING.md says."""

from ..lang.commands import command


@command(".hello")
def cmd_hello(session, arg: str) -> None:
    session.out.print(f"hello {arg or 'world'} from the {session.module.name}")
'''
MODULE = '''[module]
name = "TMCM-9999"
summary = "A module added as one data file (a test)"
motors = 2
program_memory = 1024
firmware_id = 9999
version_string = "9999V100"
commands_like = "TMCM-1311"

[[axis]]
number = 4
name = "MaxPositioningSpeed"
access = "RWE"
min = 0
max = 2047
'''


@pytest.fixture(scope="module")
def tree(tmp_path_factory):
    """A copy of the package with a command and a module added as HACKING.md says."""
    root = tmp_path_factory.mktemp("extended")
    shutil.copytree(ROOT / "tmclsh", root / "tmclsh",
                    ignore=shutil.ignore_patterns("__pycache__"))
    table = root / "tmclsh" / "shell" / "lang" / "commands.py"
    text = table.read_text(encoding="utf-8")
    end = "\n)\n\nREGISTRY:"
    assert text.count(end) == 1  # the end of COMMANDS
    table.write_text(text.replace(end, "\n" + ENTRY + ")\n\nREGISTRY:"), encoding="utf-8")
    (root / "tmclsh" / "shell" / "features" / "hello.py").write_text(HANDLER, encoding="utf-8")
    (root / "tmclsh" / "tmcl" / "modules" / "tmcm9999.toml").write_text(MODULE,
                                                                        encoding="utf-8")
    return root


def run(tree, *args: str, code: str | None = None) -> subprocess.CompletedProcess:
    env = tmclsh_env(PYTHONPATH=str(tree))
    argv = [sys.executable, "-c", code] if code else [sys.executable, "-m", "tmclsh", *args]
    p = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=str(tree),
                       timeout=60)
    assert p.returncode == 0, p.stderr
    return p


def test_the_copy_is_what_runs(tree):
    out = run(tree, code="import tmclsh; print(tmclsh.__file__)").stdout
    assert out.startswith(str(tree))


def test_the_new_command_is_in_help_and_runs(tree):
    out = run(tree, "--sim", "-c", ".help").stdout
    assert ".hello [NAME]" in out and "greet the module" in out
    assert run(tree, "--sim", "-c", ".hello bench").stdout.strip() == \
        "hello bench from the TMCM-1311"


def test_the_new_command_completes(tree):
    code = ("from tmclsh.shell.repl.completer import candidates, complete_arg, ranked, suggest\n"
            "names = [c.text for s in suggest('.hel')\n"
            "         for c in ranked('.hel', candidates(s, '.hel', None, None))]\n"
            "print(names[0], [c.text for c in complete_arg(None, '.hello', '')])")
    assert run(tree, code=code).stdout.strip() == ".hello ['world']"


def test_the_man_page_is_generated_with_it(tree):
    run(tree, code=f"from tmclsh.cli import docs; docs.main(['--root', {str(tree)!r}])")
    assert ".hello" in (tree / "man" / "tmclsh.1").read_text(encoding="utf-8")


def test_the_new_module_is_known_and_simulated(tree):
    rows = [json.loads(line) for line in
            run(tree, "modules", "--json").stdout.splitlines() if line.strip()]
    assert {"module": "TMCM-9999", "firmware_id": 9999, "version_string": "9999V100",
            "source": "built in"} in rows
    out = run(tree, "--sim", "TMCM-9999", "-c", "SAP MaxPositioningSpeed, 1, 1000; "
              "GAP MaxPositioningSpeed, 1").stdout
    assert "MaxPositioningSpeed = 1000" in out
