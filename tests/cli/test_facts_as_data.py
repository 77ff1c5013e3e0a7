"""Facts about TMCL commands are data (tmcl/instructions.toml, the module files), read by
everything above: no module outside tmclsh/tmcl/ and the simulator decides what to do by an
opcode number or a mnemonic string it spells out itself.

The check reads the code (Python's own parser), not the text: a mnemonic string constant, a
comparison of an opcode or mnemonic with a literal or a constant named after a command, and a
constant named after a command bound to a number. The exceptions below are few, each with
its reason; a new one needs one too.
"""

from __future__ import annotations

import ast
from pathlib import Path

from tmclsh.tmcl import instructions as isa
from tmclsh.tmcl.frames import Control

ROOT = Path(__file__).resolve().parents[2] / "tmclsh"
MNEMONICS = {s.mnemonic for s in isa.all_instructions()} | set(isa.ASCII_ONLY_COMMANDS)
COMMAND_NAMES = MNEMONICS | {c.name for c in Control}

# (file, what is found): why it is no decision taken by a spelt-out command
ALLOWED = {
    ("cli/man_guide.py", "'BIN'"): "the man page's text names the ASCII terminal's BIN",
    ("cli/man_reference.py", "'SAP'"): "the man page's text names the lines a backup holds",
    ("cli/man_reference.py", "'SGP'"): "the man page's text names the lines a backup holds",
    ("shell/render.py", "ins.opcode == Control.GET_VERSION"):
        "a raw 136 type 1 typed at the prompt: its value is read by the version decoder "
        "(tmcl/version.py), the one place that knows its layout",
    ("client/ledger.py", "reply.opcode == _GET_VERSION"):
        "136 type 1 names the module's type and firmware, the same every time: two different "
        "answers to it from one address are two modules there (ledger.Doubles)",
    ("client/ledger.py", "last.opcode == _GET_VERSION"):
        "a 136 type 0 answer is a version string, which a second module at the address "
        "follows with its own (ledger.Doubles.asks_version)",
    ("client/ledger.py", "extra.opcode == _GET_VERSION"):
        "the ledger's own resynchronisation marker is a 136: a copy of a marker's reply "
        "proves nothing about the answers before it",
}


def _findings(path: Path) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and node.value in MNEMONICS:
            out.append((node.lineno, repr(node.value)))
        elif isinstance(node, ast.Compare):
            text = ast.unparse(node)
            sides = [e for s in (node.left, *node.comparators)
                     for e in (s.elts if isinstance(s, (ast.Tuple, ast.Set, ast.List)) else [s])]
            if any(word in text for word in ("opcode", "mnemonic", "mnem")) and any(
                    (isinstance(s, ast.Constant) and (isinstance(s.value, int)
                                                      or s.value in MNEMONICS))
                    or (isinstance(s, ast.Attribute) and s.attr in COMMAND_NAMES)
                    or (isinstance(s, ast.Name) and s.id.lstrip("_") in COMMAND_NAMES)
                    for s in sides):
                out.append((node.lineno, text))
        elif isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant) \
                and isinstance(node.value.value, int):
            out += [(node.lineno, f"{t.id} = {node.value.value}") for t in node.targets
                    if isinstance(t, ast.Name) and t.id.lstrip("_") in COMMAND_NAMES]
    return out


def test_no_command_is_spelt_out_to_decide_behaviour_outside_the_protocol_layer():
    found = []
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith(("tmcl/", "sim/")):
            continue
        for line, what in _findings(path):
            if (rel, what) not in ALLOWED:
                found.append(f"tmclsh/{rel}:{line}: {what}")
    assert not found, "\n".join(found)


def test_the_check_finds_what_it_looks_for():
    """The check is no check unless it fails on the code it is there to keep out."""
    sample = ROOT.parent / "tests" / "cli" / "_spelt_out_sample.py"
    sample.write_text('MST = 3\nif spec.mnemonic == "SGP" or req.opcode in (1, 2):\n    pass\n'
                      'if req.opcode == Op.MVP:\n    pass\n')
    try:
        assert sorted(w for _, w in _findings(sample)) == sorted([
            "MST = 3", "spec.mnemonic == 'SGP'", "'SGP'", "req.opcode in (1, 2)",
            "req.opcode == Op.MVP"])
    finally:
        sample.unlink()


def test_every_exception_is_still_needed():
    still = {(path.relative_to(ROOT).as_posix(), what)
             for path in ROOT.rglob("*.py") for _, what in _findings(path)}
    assert set(ALLOWED) <= still, set(ALLOWED) - still
