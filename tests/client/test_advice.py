"""Advice in messages is in the words its reader can give: the command line's options after
the command line connected, the shell's own commands at the prompt and in scripts where the
shell has one (``.address N``: ``-a N`` is no line the prompt takes), the option where it
has none (no shell command sets the timeout or the baud rate), ``connect()``'s keywords to a
program. Against modules written from the manual (tests/responder.py)."""

from __future__ import annotations

import subprocess
import sys
from types import SimpleNamespace

import pytest

from conftest import ROOT, patience, tmclsh_env
from responder import Responder
from tmclsh.client.advice import KEYWORDS, OPTIONS, SHELL, more_time, setting


def test_each_reader_is_given_its_own_words():
    shell = SimpleNamespace(advice=SHELL, timeout=1.0)
    assert setting(shell, "address", "N") == ".address N"
    assert setting(shell, "can_id", 5) == ".address 5"  # (on CAN .address sets the CAN id)
    assert setting(shell, "ascii", True) == ".mode ascii"
    assert setting(shell, "baud", 115200) == "--baud 115200"  # (no shell command for it)
    assert more_time(shell) == "--timeout 2"
    assert setting(shell, "address", 5, later=True) == "-a 5"  # (for the next run)
    cli = SimpleNamespace(advice=OPTIONS)
    assert [setting(cli, "address", "N"), setting(cli, "ascii", True)] == ["-a N", "--ascii"]
    program = SimpleNamespace(advice=KEYWORDS)
    assert setting(program, "address", 5, later=True) == "address=5"


class AtFive(Responder):
    """A TMCM-1311 at address 5 (no module answers at the factory address 1)."""

    addresses = frozenset({5})


@pytest.fixture
def modules():
    made = [Responder(), AtFive()]
    yield made
    for m in made:
        m.close()


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tmclsh", "--timeout", "0.3", *args],
                          capture_output=True, text=True, timeout=patience(60),
                          env=tmclsh_env(), cwd=str(ROOT))


def test_a_script_line_is_told_the_shell_s_command(modules):
    first, other = modules
    p = run("--port", first.path, "-c", f".connect {other.path}; .address 5; GAP 1, 0")
    assert "; then .address N" in p.stderr, p.stderr
    assert "then -a N" not in p.stderr
    assert "  - a slow link: --timeout 2" in p.stderr.splitlines(), p.stderr
    assert "try --baud 115200" in p.stderr  # (the shell has no command for the baud rate)
    assert "address 5: TMCM-1311" in p.stdout, p.stdout + p.stderr  # (as advised)


def test_the_command_line_is_still_told_its_option(modules):
    _, other = modules
    p = run("--port", other.path, "-c", "GAP 1, 0")
    assert p.returncode == 3, p.stderr
    assert "; then -a N" in p.stderr, p.stderr
    assert ".address" not in p.stderr
