"""``scripts/bench.py`` runs (a smoke run with a tiny count; the numbers are not checked:
benchmarks are measurements, not tests)."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys

import pytest

from conftest import ROOT, tmclsh_env

pytestmark = pytest.mark.slow  # benchmark smoke runs: .ci/run runs them after the README's command


def run_bench(*argv: str) -> tuple[list[dict], str]:
    p = subprocess.run([sys.executable, str(ROOT / "scripts" / "bench.py"), *argv, "--json"],
                       capture_output=True, text=True, env=tmclsh_env(), cwd=str(ROOT),
                       timeout=120)
    assert p.returncode == 0, p.stderr
    return [json.loads(line) for line in p.stdout.splitlines()], p.stderr


def check_pairs(result: dict, pairs: int, *prefixes: str) -> None:
    """The row's value is the median of its pair ratios: inside their spread, for each ratio."""
    assert result["pairs"] == pairs
    assert result["ratio_min"] <= result["ratio_q1"] <= result["value"] <= result["ratio_q3"] \
        <= result["ratio_max"]
    for prefix in prefixes:
        assert result[prefix + "ratio_min"] <= result[prefix + "ratio"] \
            <= result[prefix + "ratio_max"], prefix


def test_client_benchmarks_run():
    results, stderr = run_bench("request", "execute", "--count", "50", "--rounds", "2",
                                "--pairs", "4")
    assert [r["benchmark"] for r in results] == ["request", "execute"]
    for result in results:
        for key in ("floor_us", "us", "value", "target", "floor_cpu_us", "cpu_us"):
            assert isinstance(result[key], (int, float)) and result[key] > 0, key
        check_pairs(result, 4, "cpu_")
        assert result["row"].startswith("Client.") and isinstance(result["ok"], bool)
    assert "raw pyserial" in stderr and "median of 4 pair ratios" in stderr


def test_script_benchmark_has_its_floors():
    # 1,000 lines: the raw script's time and CPU per line are differences of two process runs,
    # which a short script leaves to start-up noise (200 lines gave a CPU of -0.8 us in CI)
    (result,), stderr = run_bench("script", "--count", "500", "--rounds", "1", "--pairs", "2")
    assert result["benchmark"] == "script" and result["lines"] == 1000
    for key in ("raw_script_us", "raw_script_cpu_us", "floor_us", "script_floor_us",
                "floor_mean_us", "floor_cpu_us"):
        assert result[key] > 0, key
    # (tmclsh's own time per line is the row's subject, measured elsewhere: not checked here)
    assert isinstance(result["us_per_line"], float) and isinstance(result["cpu_us_per_line"], float)
    check_pairs(result, 2, "gap_", "script_floor_", "mean_", "cpu_", "gap_cpu_")
    assert result["unit"] == "x raw script" and "in-process GAP median" in result["note"]
    assert "raw pyserial script process" in stderr and "the script's own frames" in stderr


def test_script_floor_frames_are_what_the_script_lines_send(fast_client):
    from tmclsh.tmcl.frames import Request

    spec = importlib.util.spec_from_file_location("bench", ROOT / "scripts" / "bench.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    for line, frame in bench.SCRIPT_LINES:
        ins = fast_client.encode(line).instruction
        assert Request(1, ins.opcode, ins.type, ins.motor, ins.value).to_bytes() == frame, line


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


def test_units_benchmark_has_a_row_per_count_against_raw_processes():
    # two small counts (the row's own are 8 and 32): the shape, not the figures
    (result,), stderr = run_bench("units", "--units", "2", "--units", "3", "--rounds", "1")
    assert result["benchmark"] == "units" and result["lines"] == 500
    assert result["units"] == 2 and result["unit"] == "x raw processes"
    assert result["target"] == 1.1 and isinstance(result["ok"], bool)
    (three,) = result["rows"]
    assert three["units"] == 3 and three["target"] == 1.1
    for r in (result, three):
        check_pairs(r, 1, "lines_", "over_one_")
        assert r["raw_s"] > 0 and r["tmclsh_s"] > 0 and r["one_unit_s"] > 0
        assert "start-up left out" in r["note"] and "one unit" in r["note"]
    assert "2 raw processes together" in stderr and "3 raw processes together" in stderr
    assert "3 units over one unit, wall" in stderr


def test_units_counts_must_be_positive():
    p = subprocess.run([sys.executable, str(ROOT / "scripts" / "bench.py"), "units",
                        "--units", "0"], capture_output=True, text=True, env=tmclsh_env(),
                       timeout=30)
    assert p.returncode == 2 and "--units must be at least 1" in p.stderr
