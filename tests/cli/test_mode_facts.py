"""Issue 32, "Library first": no branch on the client's mode (binary frames or the module's
ASCII mode) outside ``client/`` and ``link/``. What differs between the modes is a fact the
mode carries (``tmclsh.link.modes.LinkMode``: the toolbar's word, whether replies carry a
checksum, the instruction set's key for the commands it knows) or the framing's answer to
"can this request go as the link is now" (``Client.refusal``); the front ends read those.

The check reads the code (Python's own parser), not the text. It finds: the client's ASCII
link read at all (``.ascii_link``: whether it is set is the mode, derived again);
``Mode.ASCII``/``Mode.BINARY`` (the ASCII mode's switch, whose decisions are
``client/ascii.py``'s); a comparison that mentions a mode and the name of one ("ascii",
"binary", or a constant so named). The exceptions are few, each with its reason: they read
a wire or a module's data, not the mode the client talks in. A new one needs one too.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2] / "tmclsh"
HOME = ("client/", "link/")  # where the mode is decided
NAMES = {"ascii", "binary"}

# (file, what is found): why it is no branch on the client's mode
ALLOWED = {
    ("ops/scan.py", "probe.mode != Mode.ASCII"):
        "what a probe found the module at another address doing: scan recognises a module "
        "in its ASCII mode on the wire (its client talks binary throughout)",
    ("ops/scan.py", "Mode.ASCII"): "(the same line)",
    ("ops/inventory.py", "mode not in (BINARY, ASCII)"):
        "an inventory file's field checked: the mode a module is expected in",
    ("ops/inventory.py", "want.mode == BINARY"):
        "the mode scan found a module in, compared with the inventory's expectation",
    ("ops/inventory.py", "want.mode == ASCII"): "(the same)",
    ("ops/inventory.py", "mode == ASCII"):
        "an inventory entry may not name a backup for a module it expects in ASCII mode",
}


def _is_name(node: ast.AST) -> bool:
    """``"ascii"``, ``Mode.BINARY``, ``ASCII``: one of the modes named."""
    if isinstance(node, ast.Constant):
        return isinstance(node.value, str) and node.value.lower() in NAMES
    if isinstance(node, ast.Attribute):
        return node.attr.lower() in NAMES
    if isinstance(node, ast.Name):
        return node.id.lstrip("_").lower() in NAMES
    return False


def _findings(source: str) -> list[tuple[int, str]]:
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Attribute) and node.attr == "ascii_link":
            out.append((node.lineno, ast.unparse(node)))
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and node.value.id == "Mode" and node.attr in ("ASCII", "BINARY"):
            out.append((node.lineno, ast.unparse(node)))
        elif isinstance(node, ast.Compare):
            text = ast.unparse(node)
            sides = [e for s in (node.left, *node.comparators)
                     for e in (s.elts if isinstance(s, (ast.Tuple, ast.Set, ast.List)) else [s])]
            if "mode" in text.lower() and any(_is_name(s) for s in sides):
                out.append((node.lineno, text))
    return out


def _sources() -> list[tuple[str, Path]]:
    return [(p.relative_to(ROOT).as_posix(), p) for p in sorted(ROOT.rglob("*.py"))
            if not p.relative_to(ROOT).as_posix().startswith(HOME)]


def test_no_branch_on_the_clients_mode_outside_client_and_link():
    found = [f"tmclsh/{rel}:{line}: {what}" for rel, path in _sources()
             for line, what in _findings(path.read_text(encoding="utf-8"))
             if (rel, what) not in ALLOWED]
    assert not found, ("a branch on the mode outside client/ and link/ (read a fact of "
                       "client.mode, ask client.refusal, or call client/ascii.py):\n"
                       + "\n".join(found))


def test_the_check_finds_what_it_looks_for():
    """The check is no check unless it fails on the code it is there to keep out: each
    shape a branch on the mode had before the facts (shell/repl, ops/replace.py,
    features/scripting.py, features/terminal.py)."""
    sample = ('if c.mode == "ascii":\n    pass\n'
              'if c.mode != "ascii" and module.program_memory:\n    pass\n'
              'twice = getattr(session.client, "mode", "binary") == "ascii"\n'
              'was = client.ascii_link is not None\n'
              'link.on_exit = Mode.BINARY\n'
              'ok = str(client.mode) in ("binary",)\n')
    assert sorted(line for line, _ in _findings(sample)) == [1, 3, 5, 6, 7, 8]
    # a fact read, or a user's word parsed, is no branch on the mode
    assert _findings('if c.mode.marked:\n    pass\n'
                     'ok = words[0].lower() in ("ascii", "binary")\n'
                     'twice = not session.client.mode.checksummed\n') == []


def test_every_exception_is_still_needed():
    still = {(rel, what) for rel, path in _sources()
             for _, what in _findings(path.read_text(encoding="utf-8"))}
    assert set(ALLOWED) <= still, set(ALLOWED) - still
