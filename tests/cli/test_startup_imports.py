"""The non-interactive paths (-c, -f, a script on stdin) load no REPL or terminal libraries.

``tmclsh -c`` in a loop or a pipeline starts once per call, so what it imports is start-up
time: prompt_toolkit, rich and pygments are for the REPL and a terminal, asyncio comes with
prompt_toolkit, python-can only for a CAN link, the simulator only with --sim. The check is
the interpreter's own list of loaded modules (sys.modules) after a real run in a subprocess,
with output to a pipe as in a script.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from conftest import ROOT, tmclsh_env

HEAVY = ("prompt_toolkit", "rich", "pygments", "asyncio", "can")

# run tmclsh's main() as `python -m tmclsh` would, then write sys.modules to stderr's last line
RUNNER = """
import atexit, json, runpy, sys
atexit.register(lambda: print("MODULES " + json.dumps(sorted(sys.modules)), file=sys.stderr))
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
