"""--keep-going concludes that a module is gone: after a few lines in a row got no answer,
the run (or the unit) ends as one with no module (exit status 3) instead of spending every
remaining line's full wait on it (a 300-line script: minutes)."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time

import pytest

from conftest import ROOT, tmclsh_env
from responder import Responder

LINES = 300  # a long script: with no conclusion it took 300 waits of --timeout x 3


def script(tmp_path) -> str:
    path = tmp_path / "long.tmcl"
    path.write_text("GAP 4, 0\n.sleep 0.02\n" * (LINES // 2))
    return str(path)


def serve_sim() -> tuple[subprocess.Popen, str]:
    """A simulated module in a process of its own, on TCP (its first line: the endpoint)."""
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "sim", "-m", "TMCM-1311",
                             "--tcp", "127.0.0.1:0"], stdout=subprocess.PIPE, text=True,
                            env=tmclsh_env(), cwd=str(ROOT))
    return proc, "socket://" + proc.stdout.readline().strip()


@pytest.fixture
def two_sims():
    procs = [serve_sim() for _ in range(2)]
    yield procs
    for proc, _ in procs:
        proc.kill()
        proc.wait(10)


def test_a_unit_whose_module_dies_ends_as_gone_and_the_other_finishes(two_sims, tmp_path):
    (dying, url1), (_, url2) = two_sims
    run = subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", url1, "--port", url2,
                            "-f", script(tmp_path), "--keep-going", "--json", "--timeout", "0.3"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           env=tmclsh_env(), cwd=str(ROOT))
    killed_at, ended_at, summaries, answered = None, {}, {}, 0
    run_out = []
    for line in run.stdout:  # (read as it comes: when each unit ends is part of the test)
        run_out.append(line)
        obj = json.loads(line)
        if obj.get("unit") == 1 and "reply" in obj:
            answered += 1
            if answered == 10:  # mid-run: the module's process dies
                dying.kill()
                killed_at = time.monotonic()
        if obj.get("summary"):
            summaries[obj["unit"]], ended_at[obj["unit"]] = obj, time.monotonic()
    err = run.stderr.read()
    assert run.wait(60) == 3, err  # a unit had no module
    assert killed_at is not None, err
    # far under the old 300 x 0.9 s: a few lines' waits (generous for a busy machine)
    assert ended_at[1] - killed_at < 10, (ended_at[1] - killed_at, err)
    gone, other = summaries[1], summaries[2]
    assert gone["result"] == "no module" and gone["exit"] == 3, gone
    assert "got no answer from the module" in gone["error"] and "taken to be gone" in \
        gone["error"], gone
    assert gone["line"] < LINES
    assert other["result"] == "passed" and other["line"] == LINES, other
    assert f"tmclsh: no module for unit 1 {url1}" in err, err
    said = [o for o in map(json.loads, run_out) if o.get("unit") == 1 and o.get("exit") == 3
            and not o.get("summary")]
    assert said and said[0]["line"] is None and "taken to be gone" in said[0]["error"]


class FallsSilent(Responder):
    """tests/responder.py's TMCM-1311 that stops answering once ``silent`` is set (its
    power cut while the line stays up)."""

    def __init__(self, **kw):
        self.silent = threading.Event()
        super().__init__(**kw)

    def answer(self, raw: bytes) -> bytes | None:
        return None if self.silent.is_set() else super().answer(raw)


@pytest.mark.parametrize("given", ["-f", "-c"])
def test_a_module_that_falls_silent_is_concluded_gone(tmp_path, given):
    module = FallsSilent(tcp=True)
    try:
        path = tmp_path / "s.tmcl"
        path.write_text("GAP 4, 0\n.sleep 0.02\n" * 100)
        lines = str(path) if given == "-f" else path.read_text()
        run = subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", module.url,
                                "-m", "TMCM-1311", given, lines, "--keep-going",
                                "--timeout", "0.3"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, env=tmclsh_env(),
                               cwd=str(ROOT))
        deadline = time.monotonic() + 30
        while module.commands().count(6) < 10 and time.monotonic() < deadline:
            time.sleep(0.02)
        module.silent.set()
        silenced = time.monotonic()
        out, err = run.communicate(timeout=120)
        took = time.monotonic() - silenced
        assert run.returncode == 3, err
        assert "4 lines in a row got no answer from the module" in err, err
        assert took < 15, took  # (100 lines at 0.9 s each before)
        heard = module.commands()
        assert heard.count(6) < 100 * 3  # the rest was not sent
    finally:
        module.close()


def test_a_line_answered_in_between_starts_the_count_again(tmp_path):
    """Lines that fail for a module's refusal or a reply coming in between are no silence:
    a module that answers every other line is not concluded gone."""
    class EveryOther(Responder):
        n = 0

        def answer(self, raw: bytes) -> bytes | None:
            if raw[1] == 6:
                self.n += 1
                if self.n % 2 == 0:
                    return None
            return super().answer(raw)

    module = EveryOther(tcp=True)
    try:
        path = tmp_path / "s.tmcl"
        path.write_text("GAP 4, 0\n" * 12)
        p = subprocess.run([sys.executable, "-m", "tmclsh", "--port", module.url, "-m",
                            "TMCM-1311", "-f", str(path), "--keep-going", "--timeout", "0.3",
                            "--retries", "0"], capture_output=True, text=True, timeout=120,
                           env=tmclsh_env(), cwd=str(ROOT))
        assert p.returncode == 1, p.stderr  # lines failed; the module is there
        assert "taken to be gone" not in p.stderr
        assert p.stdout.count("MaxPositioningSpeed = ") >= 5
    finally:
        module.close()
