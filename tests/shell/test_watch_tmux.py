"""A watch tried the way a person does it: in a real terminal (tmux), while the simulated
motor moves; 's' stops the motor, 'q' ends the watch, the terminal comes back intact.

Skipped when tmux is not installed.
"""

from __future__ import annotations

import re
import sys
import time
from pathlib import Path

from tmux import needs_tmux

pytestmark = needs_tmux

ROOT = Path(__file__).resolve().parents[2]


def value(screen: str, name: str) -> int:
    m = re.search(rf"│ {name}\s+│\s+(-?\d+) │", screen)
    assert m, screen
    return int(m.group(1))


def test_watch_while_the_motor_moves(terminal, tmp_path):
    run = tmp_path / "run.sh"
    run.write_text(
        f"cd {ROOT}\n"
        f"PYTHONPATH={ROOT} NO_COLOR=1 {sys.executable} -m tmclsh --sim -c 'ROR 0, 20000\n"
        ".watch pos=GAP 1, 0; speed=GAP 3, 0; in0=GIO 0, 0 --interval 0.05'\n"
        "echo EXIT=$?\nstty -a | grep -o ' -\\?icanon'\nsleep 30\n")
    term = terminal(width=110, height=30, timeout=10.0)
    term.shell(f"sh {run}")
    first = term.wait_for(re.compile(r"samples.*\n(.*\n)*│ pos .*\n(.*\n)*s/space: stop all"))
    time.sleep(0.4)
    second = term.screen()
    assert value(second, "pos") > value(first, "pos")  # live: the motor moves on screen
    assert value(second, "speed") > 0
    assert "q: end (motors keep running)" in second

    term.keys("s")
    stopped = term.wait_for(re.compile(r"stopped motor 0 \(MST; speed reads 0\) at"))
    deadline = time.monotonic() + 5
    while value(stopped, "speed") != 0 and time.monotonic() < deadline:
        time.sleep(0.1)
        stopped = term.screen()
    assert value(stopped, "speed") == 0  # the ramp down, seen in the table
    term.keys("q")
    done = term.wait_for(re.compile(r"EXIT=\d+\n.*icanon"))
    assert "EXIT=0" in done
    assert re.search(r"watch: \d+ samples in [\d.]+ s", done)
    assert "stopped motor 0 (MST; speed reads 0) at" in done  # the table's last caption
    assert " icanon" in done  # the terminal is back in line mode (cbreak undone)
