"""``scripts/bench.py`` runs (a smoke run with a tiny count; the numbers are not checked:
benchmarks are measurements, not tests)."""

from __future__ import annotations

import json
import subprocess
import sys

from conftest import ROOT, tmclsh_env


def test_client_benchmarks_run():
    p = subprocess.run([sys.executable, str(ROOT / "scripts" / "bench.py"), "request", "execute",
                        "--count", "50", "--rounds", "2", "--json"],
                       capture_output=True, text=True, env=tmclsh_env(), cwd=str(ROOT),
                       timeout=120)
    assert p.returncode == 0, p.stderr
    results = [json.loads(line) for line in p.stdout.splitlines()]
    assert [r["benchmark"] for r in results] == ["request", "execute"]
    for result in results:
        for key in ("floor_us", "us", "value", "target"):
            assert isinstance(result[key], (int, float)) and result[key] > 0, key
        assert abs(result["value"] - result["us"] / result["floor_us"]) < 0.01
        assert result["row"].startswith("Client.") and isinstance(result["ok"], bool)
    assert "raw pyserial" in p.stderr


def test_benchmarks_are_listed_and_unknown_names_refused():
    bench = str(ROOT / "scripts" / "bench.py")
    p = subprocess.run([sys.executable, bench, "--list"], capture_output=True, text=True,
                       env=tmclsh_env(), timeout=30)
    assert p.returncode == 0 and {"request", "execute", "script", "process", "repl",
                                 "upload", "scan"} <= {line.split()[0]
                                                      for line in p.stdout.splitlines()}
    p = subprocess.run([sys.executable, bench, "nosuch"], capture_output=True, text=True,
                       env=tmclsh_env(), timeout=30)
    assert p.returncode == 2 and "unknown benchmark" in p.stderr
