"""The small ecosystem promises: color = "always", tmclsh --man, --json after a subcommand."""

from __future__ import annotations

import json

from conftest import tmclsh_env


def _with_color(tmp_path, value: str, **env):
    cfg = tmp_path / "config.toml"
    cfg.write_text(f'[settings]\ncolor = "{value}"\n')
    return tmclsh_env(TMCLSH_CONFIG=str(cfg), **env)


def test_color_always_colours_a_pipe_despite_no_color(tmp_path, run_tmclsh):
    r = run_tmclsh("--sim", "-c", "GAP 1, 0", env=_with_color(tmp_path, "always", NO_COLOR="1",
                                                             TERM="dumb"))
    assert r.returncode == 0 and "\x1b[" in r.stdout and "ActualPosition" in r.stdout
    err = run_tmclsh("--sim", "-c", "GAP 999, 0", env=_with_color(tmp_path, "always",
                                                                  NO_COLOR="1"))
    assert "\x1b[" in err.stderr  # the error line too


def test_color_auto_and_never_leave_a_pipe_plain(tmp_path, run_tmclsh):
    for value in ("auto", "never"):
        r = run_tmclsh("--sim", "-c", "GAP 1, 0", env=_with_color(tmp_path, value))
        assert r.returncode == 0 and "ActualPosition" in r.stdout
        assert "\x1b[" not in r.stdout, value


def test_man_prints_the_current_manual(run_tmclsh, tmp_path):
    """Issue 35: in a pipe it printed the raw roff; it is the text man shows now."""
    import shutil

    from tmclsh.cli.docs import manpage

    if shutil.which("man") is not None:
        r = run_tmclsh("--man")
        assert r.returncode == 0
        assert ".SH" not in r.stdout and "\\f" not in r.stdout  # formatted, not roff
        assert "MODULE FILES" in r.stdout and "PROGRAM IMAGES" in r.stdout
    # no man(1) to format it: the roff as generated now, said to be that
    r = run_tmclsh("--man", env=tmclsh_env(PATH=str(tmp_path)))
    assert r.returncode == 0
    assert r.stdout == manpage()
    assert ".SH MODULE FILES" in r.stdout and ".SH PROGRAM IMAGES" in r.stdout
    assert "roff source" in r.stderr


def test_json_before_or_after_the_subcommand(tmp_path, run_tmclsh):
    env = tmclsh_env(XDG_CONFIG_HOME=str(tmp_path))
    before = run_tmclsh("--json", "modules", env=env)
    after = run_tmclsh("modules", "--json", env=env)
    assert before.returncode == after.returncode == 0
    assert before.stdout == after.stdout
    assert {json.loads(x)["module"] for x in after.stdout.splitlines()} >= {"TMCM-1311",
                                                                            "TMCM-351"}
