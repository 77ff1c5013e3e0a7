"""Cloning a module as a person does it at the prompt (tmux): .save, a change, .diff shows
it, .restore asks [y/N] and writes it back. Skipped where tmux is missing."""

from __future__ import annotations

from tmux import needs_tmux

pytestmark = needs_tmux


def test_save_diff_restore_at_the_prompt(terminal, tmp_path):
    t = terminal(cwd=tmp_path)
    t.start("--sim")
    t.wait("TMCM-1311:1>")
    t.run(".save axis1.tmcl", "saved 155 parameters of the TMCM-1311 to axis1.tmcl")
    assert (tmp_path / "axis1.tmcl").read_text(encoding="utf-8").startswith("// tmclsh")
    t.run("SAP MaxCurrent, 0, 128", "ok: MaxCurrent set to 128")
    # the 11 of the module's own place on its line (address, baud rate, CAN) are not compared
    screen = t.run(".diff axis1.tmcl", "1 of 144 parameters differ from axis1.tmcl")
    assert "left alone, the module's own place on its line" in screen
    row = next(ln for ln in screen.splitlines() if ln.startswith("MaxCurrent"))
    assert row.split() == ["MaxCurrent", "│", "AP", "6", "│", "motor", "0", "│", "0", "│",
                           "128", "│", "1/255", "of", "module", "max.", "current"]
    t.run(".restore axis1.tmcl", "write 1 parameter from axis1.tmcl to the TMCM-1311")
    t.line("n")  # answers end with Enter, as everywhere ([y/N])
    t.wait("cancelled; nothing was sent")
    t.run("GAP MaxCurrent, 0", "MaxCurrent = 128")
    t.run(".restore axis1.tmcl", "write 1 parameter from axis1.tmcl to the TMCM-1311")
    t.line("y")
    t.wait("restored 1 parameter from axis1.tmcl")
    t.run(".diff axis1.tmcl", "no differences: the TMCM-1311 matches axis1.tmcl")
    t.run(".save axis1.tmcl", "axis1.tmcl (a backup of a TMCM-1311, ")  # the golden one
    t.wait("exists; overwrite it? [y/N]")
    t.line("")  # Enter alone: no
    t.wait("cancelled; nothing was sent")
    t.run(".help .restore", "--store")
    t.quit()
