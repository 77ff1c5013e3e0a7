"""The README's recipes for the technician's three jobs (issue 33) work as written: each
command is taken from the README, its placeholders (OLD, NEW, PTY, BRIDGE, the device paths)
given simulated modules' pseudo-terminals, and run as a user runs it."""

from __future__ import annotations

import re
import shlex
import signal
import subprocess
import sys

from conftest import patience, tmclsh_env
from test_readme import README, block_after, code_spans


def span(start: str) -> str:
    """The one inline command of the README that starts so."""
    found = [s for s in code_spans() if s.startswith(start)]
    assert len(found) == 1, (start, found)
    return found[0]


def run(command: str, cwd, **names: str) -> subprocess.CompletedProcess:
    """A README command line, its placeholders replaced, run in ``cwd``."""
    words = [names.get(w, w) for w in shlex.split(command)]
    assert words[0] == "tmclsh", command
    return subprocess.run([sys.executable, "-m", "tmclsh", *words[1:]], capture_output=True,
                          text=True, env=tmclsh_env(), cwd=str(cwd), timeout=patience(120),
                          stdin=subprocess.DEVNULL)


def test_the_replace_recipe(make_pty_sim, tmp_path):
    old, old_path = make_pty_sim()
    new, new_path = make_pty_sim()
    names = {"OLD": old_path, "NEW": new_path}
    (tmp_path / "prog.tmcl").write_text("SAP 4, 0, 500\nWAIT TICKS, 0, 10\nJA 0\n")
    for start in ('tmclsh --port OLD -c', "tmclsh --port OLD --yes -c"):
        done = run(span(start), tmp_path, **names)
        assert done.returncode == 0, done.stderr
    done = run(span("tmclsh replace --from OLD --to NEW --yes"), tmp_path, **names)
    assert done.returncode == 0, done.stdout + done.stderr
    assert re.search(r"^program\s+done\s+3 instructions uploaded", done.stdout, re.M)
    assert f"replaced: {old_path} -> {new_path}" in done.stdout
    assert new.store.get("axis", "MaxPositioningSpeed") == 1234


def test_the_replay_recipe(make_pty_sim, tmp_path):
    sim, path = make_pty_sim()
    bridge = shlex.split(span("tmclsh bridge --pty --port PTY -o"))
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh",
                             *[path if w == "PTY" else w for w in bridge[1:]]],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=tmclsh_env(), cwd=str(tmp_path))
    try:
        endpoint = proc.stdout.readline().strip()
        assert endpoint, proc.stderr.read()
        done = run(span("tmclsh --port BRIDGE -c"), tmp_path, BRIDGE=endpoint)
        assert done.returncode == 0, done.stderr
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=patience(30))
        assert proc.returncode == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    replay = span("tmclsh replay plc.txt --port PTY")
    same = run(replay, tmp_path, PTY=path)
    assert same.returncode == 0 and "0 differences" in same.stdout, same.stdout + same.stderr
    done = run(span('tmclsh --port PTY -c "SAP 6'), tmp_path, PTY=path)
    assert done.returncode == 0, done.stderr
    differs = run(replay, tmp_path, PTY=path)
    assert differs.returncode == 1, differs.stdout + differs.stderr
    assert "value 0 -> 100" in differs.stdout and "GAP 6, 0" in differs.stdout


def test_the_inventory_recipe(make_pty_sim, tmp_path):
    """The README's block: a line saved, then a module at 3 with another firmware and the
    TMCM-351 at 5 gone: the same lines the README shows."""
    from tmclsh.sim import SimBus, Simulator

    sims = [Simulator("TMCM-1311", 1), Simulator("TMCM-1311", 3), Simulator("TMCM-351", 5)]
    bus, path = make_pty_sim(target=SimBus(sims))
    block = block_after("**Knowing what is on the line.**")
    lines = block.splitlines()
    save, expect = (ln.removeprefix("$ ") for ln in lines[:2])
    done = run(save, tmp_path, **{"/dev/ttyUSB0": path})
    assert done.returncode == 0, done.stderr
    assert "type = \"TMCM-351\"" in (tmp_path / "line.toml").read_text()
    sims[1].version_string, sims[1].firmware_version = "1311V100", 100
    bus.simulators.remove(sims[2])
    done = run(expect, tmp_path, **{"/dev/ttyUSB0": path})
    assert done.returncode == 1, done.stdout + done.stderr
    assert done.stdout.splitlines() == lines[2:]
    for sim in sims:
        sim.close()
    # the try-it line names a line the same scan finds
    assert "`tmclsh sim --pty --address 1,3`" in README
