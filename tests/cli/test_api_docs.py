"""The Python API reference: ``scripts/api-docs`` builds it with pdoc from the docstrings of
what ``import tmclsh`` exports, lists exactly those names, and refuses an undocumented one."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import tmclsh

from conftest import ROOT, tmclsh_env


def api_docs(root: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(root / "scripts" / "api-docs"), "-o", str(out)],
                          capture_output=True, text=True, timeout=300,
                          env=tmclsh_env(PYTHON=sys.executable, PYTHONPATH=str(root)))


def test_the_reference_builds_and_lists_only_the_api(tmp_path):
    run = api_docs(ROOT, tmp_path / "api")
    assert run.returncode == 0, run.stderr
    page = (tmp_path / "api" / "tmclsh.html").read_text()
    assert (tmp_path / "api" / "index.html").exists()
    # every top-level entry is an anchor of its own: id="NAME" (members are NAME.member)
    listed = set(re.findall(r'<section id="([A-Za-z_]\w*)">', page))
    assert listed == set(tmclsh.__all__)
    assert 'id="LineClient.execute"' in page and 'id="LineClient._ledger"' not in page
    assert not (tmp_path / "api" / "tmclsh").exists()  # no private module's page


def test_an_undocumented_name_fails_the_build(tmp_path):
    tree = tmp_path / "tree"
    shutil.copytree(ROOT / "tmclsh", tree / "tmclsh",
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "scripts", tree / "scripts",
                    ignore=shutil.ignore_patterns("__pycache__", "programs"))
    core = tree / "tmclsh" / "client" / "core.py"
    text = core.read_text()
    doc = '        """Where the module is, in words'
    assert doc in text
    core.write_text(text.replace(doc, "        # Where the module is, in words"))
    run = api_docs(tree, tmp_path / "api")
    assert run.returncode == 1
    assert run.stderr.strip() == "api-docs: no docstring: LineClient.describe"
    assert not (tmp_path / "api").exists()
