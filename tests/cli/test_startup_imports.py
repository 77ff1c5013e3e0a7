"""The non-interactive paths (-c, -f, a script on stdin) load no REPL or terminal libraries.

``tmclsh -c`` in a loop or a pipeline starts once per call, so what it imports is start-up
time: prompt_toolkit, rich and pygments are for the REPL and a terminal, asyncio comes with
prompt_toolkit, python-can only for a CAN link, the simulator only with --sim. The check is
the interpreter's own list of loaded modules (sys.modules) after a real run in a subprocess,
with output to a pipe as in a script.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from conftest import ROOT, tmclsh_env

HEAVY = ("prompt_toolkit", "rich", "pygments", "asyncio", "can")

# run tmclsh's main() as `python -m tmclsh` would, then write sys.modules to stderr's last line
RUNNER = """
import atexit, runpy, sys
def dump():
    names = sorted(sys.modules)  # (before json is imported for writing them)
    import json
    print("MODULES " + json.dumps(names), file=sys.stderr)
atexit.register(dump)
sys.argv = ["tmclsh", *sys.argv[1:]]
runpy.run_module("tmclsh", run_name="__main__", alter_sys=True)
"""


def loaded(*args: str, input: str | None = None, env: dict[str, str] | None = None
           ) -> tuple[subprocess.CompletedProcess, set]:
    proc = subprocess.run([sys.executable, "-c", RUNNER, *args], capture_output=True, text=True,
                          input=input, timeout=60, env=tmclsh_env(**(env or {})), cwd=str(ROOT))
    last = proc.stderr.rstrip().splitlines()[-1]
    assert last.startswith("MODULES "), proc.stderr
    return proc, set(json.loads(last[len("MODULES "):]))


def heavy(modules: set) -> list[str]:
    return sorted(m for m in modules if m.split(".")[0] in HEAVY)


@pytest.mark.parametrize("extra", [[], ["--json"]])
def test_port_path_imports_nothing_heavy(make_pty_sim, extra):
    _, path = make_pty_sim()
    proc, modules = loaded("--port", path, "-m", "TMCM-1311", *extra, "-c",
                           "GAP 1, 0; SAP 4, 0, 1000; GAP 4, 0")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    if extra:
        assert [json.loads(line)["reply"] for line in lines] == [0, 1000, 1000]
    else:
        assert lines[0].startswith("ActualPosition") and "1000" in lines[2]
    assert heavy(modules) == []
    assert not any(m.startswith("tmclsh.sim") for m in modules)
    # the dot-command features are not loaded either: no line needed one
    assert not any(m.startswith(("tmclsh.shell.features.help", "tmclsh.shell.features.params",
                                 "tmclsh.shell.features.connection", "tmclsh.shell.repl.completer",
                                 "tmclsh.shell.repl.app", "tmclsh.shell.features.watch")) for m in modules)


def test_sim_script_and_stdin_paths_import_nothing_heavy(tmp_path):
    script = tmp_path / "move.tmcl"
    script.write_text("SAP 4, 0, 500\n.let v = GAP 4, 0\n.expect v == 500\nGAP 4, 0\n")
    proc, modules = loaded("--sim", "-c", "GAP 1, 0")
    assert proc.returncode == 0 and "ActualPosition" in proc.stdout, proc.stderr
    assert heavy(modules) == []
    proc, modules = loaded("--sim", "-f", str(script))
    assert proc.returncode == 0 and "passed" in proc.stdout, proc.stderr
    assert heavy(modules) == []
    proc, modules = loaded("--sim", input="GAP 1, 0\nGAP 4, 0\n")
    assert proc.returncode == 0 and "ActualPosition" in proc.stdout, proc.stderr
    assert heavy(modules) == []


def test_errors_in_a_pipe_are_plain_lines(make_pty_sim):
    _, path = make_pty_sim()
    proc, modules = loaded("--port", path, "-m", "TMCM-1311", "--keep-going", "-c",
                           "GAP 1, ${7}\nGAP 1, 0")  # (checked as it runs: --keep-going)
    assert proc.returncode == 1
    assert "\x1b[" not in proc.stdout + proc.stderr
    assert proc.stderr.splitlines()[0].startswith("error: ") and "motor 7" in proc.stderr
    assert "ActualPosition" in proc.stdout
    assert heavy(modules) == []


# what the -c path used to load before its first request, each now loaded where it is needed:
# the TOML parser (a data file parsed, a config file that has text), platformdirs (a platform
# other than Linux's XDG places), importlib.resources (a package inside a zip file), difflib
# (a mistyped word), ctypes (several units), tempfile and shutil (a file written, help laid out)
ON_DEMAND = ("tomllib", "platformdirs", "importlib.resources", "zipfile", "difflib", "ctypes",
             "tempfile", "shutil")


@pytest.fixture(params=["simulator", "responder"])
def a_1311(request, make_pty_sim):
    """The simulator, or a module written from the manuals answering as a TMCM-1311."""
    if request.param == "simulator":
        yield make_pty_sim()[1]
        return
    from responder import PtyModule

    module = PtyModule(version="1311V111")
    yield module.path
    module.close()


@pytest.mark.skipif(sys.platform != "linux", reason="platformdirs answers elsewhere")
def test_port_path_loads_the_data_cache_not_the_parsers(a_1311, tmp_path):
    path = a_1311
    env = {"XDG_CACHE_HOME": str(tmp_path / "cache")}
    args = ("--port", path, "-m", "TMCM-1311", "-c", "GAP 1, 0")
    first = subprocess.run([sys.executable, "-m", "tmclsh", *args], capture_output=True,
                           text=True, timeout=60, env=tmclsh_env(**env), cwd=str(tmp_path))
    assert first.returncode == 0, first.stderr  # (this run parsed and cached the data files)
    assert list((tmp_path / "cache" / "tmclsh" / "data").glob("tmcm1311-*.marshal"))
    proc, modules = loaded(*args, env=env)
    assert proc.returncode == 0 and proc.stdout.startswith("ActualPosition"), proc.stderr
    assert sorted(m for m in modules if m.startswith(ON_DEMAND)) == []


# loaded where they are used, not at every start: the units' machinery (a command line that
# names several units), logging (something logged), json (a JSON line written)
NOT_FOR_ONE_MODULE = ("tmclsh.ops.units", "tmclsh.shell.features.units", "logging", "json")


def test_a_run_of_one_module_loads_no_units_logging_or_json(a_1311):
    proc, modules = loaded("--port", a_1311, "-m", "TMCM-1311", "-c", "GAP 1, 0")
    assert proc.returncode == 0 and proc.stdout.startswith("ActualPosition"), proc.stderr
    assert sorted(m for m in modules if m in NOT_FOR_ONE_MODULE) == []


def test_several_units_are_still_told_apart(a_1311):
    """A link given twice is a command line naming several units: read as such (here
    refused, as two units on one link), not as a run of one module."""
    proc, _ = loaded("--port", a_1311, "--port", a_1311, "-c", "GAP 1, 0")
    assert proc.returncode == 2 and f"--port {a_1311} is given twice" in proc.stderr


# -- the prompt's start -------------------------------------------------------------------

# run the shell on a terminal; at the moment its first prompt is on the screen (warm_up,
# which prompt_toolkit calls once it has drawn it) write sys.modules to the file named first
PROMPT_RUNNER = """
import json, runpy, sys
from tmclsh.shell.repl import app
out, warm_up = sys.argv.pop(1), app.warm_up
def at_first_prompt(session):
    with open(out + ".tmp", "w") as f:
        json.dump(sorted(sys.modules), f)
    import os
    os.replace(out + ".tmp", out)
    warm_up(session)
app.warm_up = at_first_prompt
sys.argv = ["tmclsh", *sys.argv[1:]]
runpy.run_module("tmclsh", run_name="__main__", alter_sys=True)
"""


def modules_at_first_prompt(tmp_path, *args: str) -> tuple[set, str]:
    """What the shell had imported when its first prompt was on the (pseudo-)terminal, and
    what the terminal showed by then."""
    import pty
    import select
    import time

    from conftest import patience

    snapshot = tmp_path / "modules.json"
    env = tmclsh_env(TERM="xterm", COLUMNS="100", LINES="30", XDG_STATE_HOME=str(tmp_path))
    pid, fd = pty.fork()
    if pid == 0:  # (the child: the shell on the terminal)
        os.chdir(ROOT)
        os.execve(sys.executable, [sys.executable, "-c", PROMPT_RUNNER, str(snapshot), *args],
                  env)
    screen = b""
    try:
        deadline = time.monotonic() + patience(30)
        while not snapshot.exists() and time.monotonic() < deadline:
            if select.select([fd], [], [], 0.1)[0]:
                try:
                    chunk = os.read(fd, 4096)
                except OSError:
                    break
                if b"\x1b[6n" in chunk:
                    os.write(fd, b"\x1b[1;1R")  # (the cursor position prompt_toolkit asks)
                screen += chunk
        assert snapshot.exists(), f"no prompt; the terminal showed {screen[-400:]!r}"
        os.write(fd, b"\x04")  # Ctrl-D: leave
        deadline = time.monotonic() + patience(30)
        while not os.waitpid(pid, os.WNOHANG)[0]:
            assert time.monotonic() < deadline, "the shell did not end on Ctrl-D"
            if select.select([fd], [], [], 0.1)[0]:
                try:
                    os.read(fd, 4096)  # (what it writes while leaving)
                except OSError:
                    pass
        pid = 0
    finally:
        os.close(fd)
        if pid:
            os.kill(pid, 9)
            os.waitpid(pid, 0)
    return set(json.loads(snapshot.read_text())), screen.decode(errors="replace")


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs a pseudo-terminal")
def test_the_first_prompt_waits_for_no_rich_pygments_stop_or_units(a_1311, tmp_path):
    """The banner is drawn by prompt_toolkit, the prompt's own library; rich (the first
    result), pygments (the lexer: the first key), the completer (the first Tab), the stop
    (the first Ctrl-C) and the units' machinery come after the prompt is on the screen."""
    modules, screen = modules_at_first_prompt(tmp_path, "--port", a_1311, "-m", "TMCM-1311")
    assert "TMCM-1311" in screen and "at address 1" in screen and "Ctrl-D quits" in screen
    assert "prompt_toolkit" in modules
    late = ("rich", "pygments", "tmclsh.shell.repl.completer", "tmclsh.shell.repl.lexer",
            "tmclsh.ops.stop", "tmclsh.ops.units")
    assert sorted(m for m in modules if m.split(".")[0] in late or m in late) == []


# -- the collector while tmclsh starts ------------------------------------------------------

# count the collector's runs from the moment the start holds it; at each release say how
# many there were and whether it was held
GC_RUNNER = """
import gc, runpy, sys
from tmclsh.base import startup
runs = []
gc.callbacks.append(lambda phase, info: runs.append(info) if phase == "start" else None)
hold, release = startup.hold, startup.release
def held():
    hold()
    runs.clear()
def released():
    print(f"RELEASED {len(runs)} {gc.isenabled()}", file=sys.stderr)
    release()
    print(f"AFTER {gc.isenabled()}", file=sys.stderr)
startup.hold, startup.release = held, released
sys.argv = ["tmclsh", *sys.argv[1:]]
runpy.run_module("tmclsh", run_name="__main__", alter_sys=True)
"""


def test_the_collector_waits_while_tmclsh_starts_and_runs_for_the_lines(a_1311):
    """From the first import to the first line the garbage collector does not run (it walked
    the start's objects again and again: 5 ms of a -c run); the lines run with it on."""
    proc = subprocess.run([sys.executable, "-c", GC_RUNNER, "--port", a_1311, "-m",
                           "TMCM-1311", "-c", "GAP 1, 0"], capture_output=True, text=True,
                          timeout=60, env=tmclsh_env(), cwd=str(ROOT))
    assert proc.returncode == 0 and proc.stdout.startswith("ActualPosition"), proc.stderr
    said = [line.split() for line in proc.stderr.splitlines()
            if line.startswith(("RELEASED", "AFTER"))]
    assert said[:2] == [["RELEASED", "0", "False"], ["AFTER", "True"]], proc.stderr


def test_the_collector_runs_again_whatever_way_the_command_line_ends(capsys):
    """In a process that calls the entry (a test, a script): on again after a subcommand, an
    error and the completions."""
    import gc

    from tmclsh.cli import main as cli

    assert gc.isenabled()
    assert cli.main(["--completions", "bash"]) == 0 and gc.isenabled()
    with pytest.raises(SystemExit):
        cli.main(["bogus"])
    assert gc.isenabled()
    assert cli.main(["modules"]) == 0 and gc.isenabled()
    capsys.readouterr()
