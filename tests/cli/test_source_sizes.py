"""Issue 32, "Library first": no source file of tmclsh over 900 lines and no class over 45
methods, so that each part can be read, tested and used from Python on its own.

The code is read, not imported: every ``.py`` under ``tmclsh/`` (the man page and completion
generator included), each ``def`` directly in a class body counted as a method (a property's
getter and setter are two). None is excepted: the last one, the client, was split into its
components (tmclsh/client/taps.py, doubt.py, shared.py, lifecycle.py).
"""

from __future__ import annotations

import ast
from pathlib import Path


ROOT = Path(__file__).resolve().parents[2] / "tmclsh"
MAX_LINES = 900
MAX_METHODS = 45



def _sources() -> list[Path]:
    return sorted(ROOT.rglob("*.py"))


def _name(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def _classes(path: Path) -> list[tuple[str, int]]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return [(node.name, sum(isinstance(b, (ast.FunctionDef, ast.AsyncFunctionDef))
                            for b in node.body))
            for node in ast.walk(tree) if isinstance(node, ast.ClassDef)]


def test_no_source_file_is_over_900_lines():
    new = {_name(p): n for p in _sources() if (n := _lines(p)) > MAX_LINES}
    assert not new, (f"over {MAX_LINES} lines: " + ", ".join(
        f"tmclsh/{name} ({n})" for name, n in sorted(new.items()))
        + "; split it by what each part does (HACKING.md's layers)")


def test_no_class_has_over_45_methods():
    new = {(_name(p), cls): n for p in _sources() for cls, n in _classes(p)
           if n > MAX_METHODS}
    assert not new, (f"over {MAX_METHODS} methods: " + ", ".join(
        f"{cls} in tmclsh/{name} ({n})" for (name, cls), n in sorted(new.items()))
        + "; move methods into the component they belong to")


def test_the_counts_read_what_they_say(tmp_path):
    """The reading itself: a file of 901 lines is long, a class of 46 defs (a property's
    setter counted) is big, a nested function is no method."""
    long = tmp_path / "long.py"
    long.write_text("x = 1\n" * (MAX_LINES + 1), encoding="utf-8")
    assert _lines(long) == MAX_LINES + 1
    body = "".join(f"    def m{i}(self):\n        def inner():\n            pass\n"
                   for i in range(MAX_METHODS - 1))
    body += ("    @property\n    def p(self):\n        return 1\n"
             "    @p.setter\n    def p(self, v):\n        pass\n")
    big = tmp_path / "big.py"
    big.write_text("class Big:\n" + body, encoding="utf-8")
    assert _classes(big) == [("Big", MAX_METHODS + 1)]
