"""What programs read from --json: events as their own objects in order with the results, and
results from the simulator marked as such."""

from __future__ import annotations

import json
import subprocess
import sys

from conftest import ROOT, tmclsh_env

MOVE = "SAP 4, 0, 50000\nMVP ABS, 0, 2000\n138 0, 0, 0\n.sleep 1.5\nGAP 1, 0\n"


def objects(text: str) -> list[dict]:
    return [json.loads(x) for x in text.splitlines() if x.strip()]


def test_events_come_in_order_with_the_results_over_a_pty(pty_sim, tmp_path):
    sim, path = pty_sim
    script = tmp_path / "move.tmcl"
    script.write_text(MOVE)
    for how in (["-f", str(script)], ["-c", MOVE]):
        p = subprocess.run([sys.executable, "-m", "tmclsh", "--port", path, "-m", "TMCM-1311",
                            "--json", *how], capture_output=True, text=True, timeout=30,
                           env=tmclsh_env(), cwd=str(ROOT))
        assert p.returncode == 0, p.stderr
        objs = objects(p.stdout)
        kinds = [o.get("line") or o.get("event") for o in objs]
        assert kinds == ["SAP 4, 0, 50000", "MVP ABS, 0, 2000", "138 0, 0, 0", 138, "GAP 1, 0"]
        event = objs[3]
        assert set(event) == {"event", "motors", "t"} and event["motors"] == [0]
        assert 0.1 < event["t"] < 1.5  # when it came, not when the next line ran
        assert objs[4]["reply"] == 2000
        sim.axes[0].set_position(0)


def test_simulated_results_say_so(run_tmclsh, tmp_path):
    p = run_tmclsh("--sim", "--json", "-c", "GAP 4, 0; SAP 140, 0, ${99}")
    objs = objects(p.stdout)
    assert len(objs) == 2 and all(o["simulated"] is True for o in objs)
    assert "error" in objs[1]
    script = tmp_path / "s.tmcl"
    script.write_text("GAP 4, 0\n")
    text = run_tmclsh("--sim", "-f", str(script))
    (summary,) = [x for x in text.stdout.splitlines() if "commands sent" in x
                  or "command sent" in x]
    assert "SIMULATED" in summary
    quiet = run_tmclsh("--sim", "--json", "-f", str(script))
    assert "SIMULATED" in quiet.stderr and all(o["simulated"] for o in objects(quiet.stdout))


def test_a_real_link_has_no_simulated_field(pty_sim, tmp_path):
    _, path = pty_sim
    script = tmp_path / "s.tmcl"
    script.write_text("GAP 4, 0\n")
    p = subprocess.run([sys.executable, "-m", "tmclsh", "--port", path, "-m", "TMCM-1311",
                        "--json", "-f", str(script)], capture_output=True, text=True, timeout=30,
                       env=tmclsh_env(), cwd=str(ROOT))
    assert p.returncode == 0
    assert all("simulated" not in o for o in objects(p.stdout))
    assert "SIMULATED" not in p.stderr
