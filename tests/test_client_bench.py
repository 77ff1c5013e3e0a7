"""``scripts/bench.py client`` runs (a smoke run with a tiny count; the numbers are not checked:
benchmarks are measurements, not tests)."""

from __future__ import annotations

import json
import subprocess
import sys

from conftest import ROOT, tmclsh_env


def test_client_benchmark_runs():
    p = subprocess.run([sys.executable, str(ROOT / "scripts" / "bench.py"), "client",
                        "--count", "50", "--rounds", "2", "--json"],
                       capture_output=True, text=True, env=tmclsh_env(), cwd=str(ROOT),
                       timeout=60)
    assert p.returncode == 0, p.stderr
    result = json.loads(p.stdout.splitlines()[-1])
    assert result["benchmark"] == "client" and result["count"] == 50
    for key in ("raw_per_s", "client_per_s", "overhead_pct", "fd_floor_us", "sim_us"):
        assert isinstance(result[key], (int, float)) and result[key] == result[key], key
    assert result["raw_per_s"] > 0 and result["client_per_s"] > 0
    assert "client overhead over raw pyserial" in p.stderr


def test_benchmarks_are_listed_and_unknown_names_refused():
    bench = str(ROOT / "scripts" / "bench.py")
    p = subprocess.run([sys.executable, bench, "--list"], capture_output=True, text=True,
                       env=tmclsh_env(), timeout=30)
    assert p.returncode == 0 and "client" in [line.split()[0] for line in p.stdout.splitlines()]
    p = subprocess.run([sys.executable, bench, "nosuch"], capture_output=True, text=True,
                       env=tmclsh_env(), timeout=30)
    assert p.returncode == 2 and "unknown benchmark" in p.stderr
