"""`.upload` on a line that loses a reply, tried as a person sees it: tmclsh in a real terminal
(tmux) on a simulated module behind a pty. The program is stored again from 132, and what the
upload says about that stands on a line of its own above the progress bar (it ran on from the
bar's line, written beside it on the other stream). Skipped when tmux is not installed."""

from __future__ import annotations

import threading
import time

from tmux import needs_tmux

pytestmark = needs_tmux


def test_a_lost_reply_is_said_above_the_bar_and_the_program_stored_again(make_pty_sim,
                                                                       terminal, tmp_path):
    sim, path = make_pty_sim()
    prog = tmp_path / "long.tmc"
    prog.write_text("".join(f"    SGP {i % 56}, 2, {i}\n" for i in range(1500)) + "    STOP\n")
    term = terminal(width=110, height=30, timeout=20.0, env={"NO_COLOR": "1"})
    term.start("--port", path, "-m", "TMCM-1311")
    term.wait("TMCM-1311:1>")

    def lose_one() -> None:
        # one reply lost once a few hundred frames are stored (the bar is drawn by then)
        deadline = time.monotonic() + 60
        while not (sim.vm.download and sim.vm.download_addr >= 400):
            if time.monotonic() > deadline:
                return
            time.sleep(0.001)
        sim.faults.drop_next = 1

    threading.Thread(target=lose_one, daemon=True).start()
    term.line(f".upload {prog} --yes")
    screen = term.wait("verified: read back identical", timeout=60)
    said = [ln for ln in screen.splitlines() if "storing the program again" in ln]
    assert len(said) == 1 and said[0].startswith("upload: no reply to SGP from address 1")
    assert not sim.vm.download
