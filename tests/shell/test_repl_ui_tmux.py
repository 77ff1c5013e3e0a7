"""The REPL a technician lives in, tried in a real terminal (tmux): completion inside
expressions, long output through the pager, the toolbar in narrow terminals. Skips without
tmux."""

from __future__ import annotations

import re
import shutil

import pytest

from tmux import needs_tmux

pytestmark = needs_tmux

PROMPT = "TMCM-1311:1>"
NO_USER_PAGER = ("PAGER", "MANPAGER", "LESS", "TMCLSH_CONFIG", "TMCLSH_PORT", "TMCLSH_CAN",
                 "TMCLSH_PROFILE", "TMCLSH_MODULE", "TMCLSH_ADDRESS")


def last_prompt(screen: str) -> str:
    lines = [ln.rstrip() for ln in screen.splitlines() if ln.startswith(PROMPT)]
    return lines[-1] if lines else ""


@pytest.fixture
def shell(terminal):
    """``shell(width, height, **env)``: the REPL on the simulator, at its first prompt."""

    def start(width: int = 100, height: int = 30, env: dict[str, str] | None = None):
        t = terminal(width=width, height=height, env={"NO_COLOR": "1", **(env or {})},
                     unset=NO_USER_PAGER)
        t.start("--sim")
        t.wait("trace off")
        return t

    return start


# -- completion inside expressions ----------------------------------------------------------

def test_completion_menu_inside_a_watch_expression(shell):
    t = shell()
    t.type(".watch pos=GAP ActualPos")
    t.keys("Tab")
    t.wait_for(lambda s: last_prompt(s) == f"{PROMPT} .watch pos=GAP ActualPosition")
    t.type(", ")
    t.keys("Tab")  # the motor slot, as at the prompt: the module's one motor
    t.wait_for(lambda s: last_prompt(s) == f"{PROMPT} .watch pos=GAP ActualPosition, 0")
    t.keys("C-u")
    t.type(".expect GGP Serial")
    t.keys("Tab")
    screen = t.wait("SerialHostAddress")
    assert last_prompt(screen) == f"{PROMPT} .expect GGP SerialAddress"  # the best match
    menu = [ln.split() for ln in screen.splitlines() if re.search(r" GP \d+ · ", ln)]
    assert [m[:3] for m in menu[:3]] == [["SerialAddress", "GP", "66"],
                                         ["SerialHeartbeat", "GP", "68"],
                                         ["SerialHostAddress", "GP", "76"]]
    t.keys("C-u")
    t.type("SAP 4, 0, ${G")
    t.keys("Tab")  # inside ${...}: the read commands, not SAP/MVP
    screen = t.wait("Get coordinate")
    menu = [ln.split()[0] for ln in screen.splitlines() if ln.strip().startswith("G")
            and "Get " in ln]
    assert menu == ["GAP", "GGP", "GIO", "GCO"]
    assert "Move to position" not in screen and "Set axis parameter" not in screen
    t.keys("C-u")
    t.type(".watch p=GAP 1, 0; v=GAP 3, 0 --until \"")
    t.keys("Tab")  # the watched names first, then the reads and the functions
    screen = t.wait("round()")
    assert "watched value" in screen and "Get axis parameter" in screen
    t.keys("C-u")
    t.quit()


# -- the pager ------------------------------------------------------------------------------

needs_less = pytest.mark.skipif(shutil.which("less") is None, reason="less is not installed")


@needs_less
def test_long_output_is_paged_and_q_leaves_the_pager(shell):
    t = shell(width=80, height=24)
    t.line(".params")
    screen = t.wait_for(lambda s: s.rstrip().endswith(":") or "(END)" in s,
                        what="less did not show")
    assert "MaxPositioningSpeed" in screen
    assert "trace off" not in screen  # the pager owns the screen, not the prompt
    t.keys("Space")  # the next page
    t.wait("I2tLimit")
    t.keys("q")
    t.wait_for(lambda s: last_prompt(s) == PROMPT and "trace off" in s)
    # short output is not paged
    t.line(".help trace")
    screen = t.wait("bytes and what they mean")
    t.wait_for(lambda s: last_prompt(s) == PROMPT)
    t.quit()


def test_the_pager_is_the_users_pager(shell, tmp_path):
    got = tmp_path / "paged.txt"
    t = shell(width=80, height=24, env={"PAGER": f"cat > {got}; echo PAGER-RAN"})
    t.line(".help")
    t.wait("PAGER-RAN")
    text = got.read_text()
    assert ".params" in text and ".watch" in text and "Keys" in text
    t.wait_for(lambda s: last_prompt(s) == PROMPT)
    t.line(".help trace")  # fits: no pager
    t.wait("bytes and what they mean")
    assert t.screen().count("PAGER-RAN") == 1
    t.quit()


def test_no_pager_with_c_or_when_the_setting_is_off(terminal, tmp_path):
    marker = tmp_path / "paged.txt"
    pager = f"cat > {marker}; echo PAGER-RAN"
    t = terminal(width=80, height=24, env={"NO_COLOR": "1", "PAGER": pager},
                 unset=NO_USER_PAGER[1:])
    t.start("--sim", "-c", ".params")
    screen = t.wait("EXIT=0")
    assert "PAGER-RAN" not in screen and not marker.exists()
    t.kill()
    config = tmp_path / "config" / "tmclsh"
    config.mkdir(parents=True)
    (config / "config.toml").write_text("[settings]\npager = false\n")
    t = terminal(width=80, height=24, env={"NO_COLOR": "1", "PAGER": pager},
                 unset=NO_USER_PAGER[1:])
    t.start("--sim")
    t.wait("trace off")
    t.line(".params")
    # the end of the table, straight on the screen, and the prompt after it
    screen = t.wait_for(re.compile(r"Input7EdgeType.*\n" + PROMPT))
    assert "PAGER-RAN" not in screen and not marker.exists()
    t.quit()


# -- the toolbar ----------------------------------------------------------------------------

def toolbar(screen: str) -> str:
    bars = [ln.rstrip() for ln in screen.splitlines() if ln.startswith(" SIMULATED ")]
    return bars[-1] if bars else ""


@pytest.mark.parametrize("width, hints", [(80, "^C stop motors  ^D quit"), (60, "^C stop")])
def test_the_toolbar_fits_narrow_terminals_in_whole_words(shell, width, hints):
    t = shell(width=width, height=20)
    bar = toolbar(t.screen())
    assert bar.startswith(" SIMULATED  | TMCM-1311 @1")
    assert bar.endswith(hints) and len(bar) <= width
    t.line(".trace on")
    screen = t.wait_for(lambda s: "trace on" in toolbar(s))
    bar = toolbar(screen)
    assert len(bar) <= width and bar.endswith(hints)
    t.line(".trace off")
    t.wait_for(lambda s: "trace off" in toolbar(s))
    t.quit()


# -- the program state after .connect ------------------------------------------------------

def test_connect_shows_the_new_links_program_state_at_once(shell, tmp_path):
    prog = tmp_path / "loop.tmcl"
    prog.write_text("Loop: WAIT TICKS, 0, 100\nJA Loop\n")
    t = shell()
    t.line(f".upload {prog} --yes")
    t.wait("verified: read back identical")
    t.line(".run")
    t.wait(f"{PROMPT.rstrip('>')} [run]>")
    t.wait("program run")  # the toolbar
    t.line(".connect sim TMCM-1311")
    screen = t.wait("connected:")
    screen = t.wait_for(lambda s: last_prompt(s) == PROMPT and "program stop" in toolbar(s))
    assert "[run]" not in last_prompt(screen)
    t.quit()
