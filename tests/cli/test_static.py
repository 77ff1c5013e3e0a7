"""Names that do not exist are found before a user runs into them.

Nine branches were merged into one tree this round; one merge dropped ``import os`` from
cli.py, where only ``tmclsh --man`` and a closed pipe would have raised the NameError. pyflakes
reads every file and names each undefined name, so such a loss fails here instead.
"""

from __future__ import annotations

from pathlib import Path

import pytest

pyflakes = pytest.importorskip("pyflakes.api")
from pyflakes import messages  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


class _Collect:
    def __init__(self) -> None:
        self.found: list[str] = []

    def flake(self, message) -> None:
        if isinstance(message, (messages.UndefinedName, messages.UndefinedLocal,
                                messages.UndefinedExport)):
            self.found.append(str(message))

    def unexpectedError(self, filename, msg) -> None:  # noqa: N802 (pyflakes' interface)
        self.found.append(f"{filename}: {msg}")

    def syntaxError(self, filename, msg, lineno, offset, text) -> None:  # noqa: N802
        self.found.append(f"{filename}:{lineno}: {msg}")


@pytest.mark.parametrize("folder", ["tmclsh", "tests", "scripts"])
def test_no_undefined_names(folder):
    report = _Collect()
    files = sorted((ROOT / folder).rglob("*.py"))
    if folder == "scripts":
        files.append(ROOT / "scripts" / "bench.py")
    for path in dict.fromkeys(files):
        pyflakes.checkPath(str(path), report)
    assert not report.found, "\n".join(report.found)


def test_no_merge_left_its_conflict_markers():
    """A merge once left ``<<<<<<< HEAD`` in HACKING.md's table, where a reader took both
    sides for the truth; no tracked text file may keep a marker line."""
    import subprocess
    names = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                           check=False).stdout.split()
    if not names:
        pytest.skip("not a git checkout: no list of tracked files")
    found = [f"{name}:{n}" for name in names if name.endswith((".md", ".py", ".toml", ".txt"))
             for n, line in enumerate((ROOT / name).read_text(encoding="utf-8",
                                                               errors="replace").splitlines(), 1)
             if line.startswith(("<<<<<<< ", ">>>>>>> ")) or line == "======="]
    assert not found, "conflict markers: " + ", ".join(found)


def test_hacking_names_every_source_file():
    """HACKING.md is where a newcomer finds each file's job: a file it does not name is a
    file nobody can place (the old import paths at the package's top are one row)."""
    text = (ROOT / "HACKING.md").read_text(encoding="utf-8")
    package = ROOT / "tmclsh"
    shims = {p.name for p in package.glob("*.py")
             if "_moved" in p.read_text(encoding="utf-8")}

    def named(p: Path) -> bool:  # as `x.py`, `folder/x.py`, or `folder/x.thing` / `x.thing`
        return any(word in text for word in (f"`{p.name}`", f"/{p.name}`", f"{p.parent.name}/"
                                             f"{p.stem}.", f"`{p.stem}."))

    missing = [p.relative_to(package).as_posix() for p in sorted(package.rglob("*.py"))
               if p.name != "__init__.py" and p.name not in shims and not named(p)]
    assert not missing, "HACKING.md names no job for: " + ", ".join(missing)
