"""The simulator of a module imported from PyTrinamic (``tmclsh modules import pytrinamic``),
driven by PyTrinamic's own class for that module over ``tmclsh sim --pty``.

Such a file holds PyTrinamic's names (``MaxVelocity``, ``PositionReachedFlag``), not the
manuals' (``MaxPositioningSpeed``, ``TargetPositionReached``) the simulator's rules are written
for; ``sim/model.py``'s ``ALSO_CALLED`` says which is which, and the simulator's own start
values (``START_VALUES``) let a motor move. What these tests hold is what a PyTrinamic user
sees: a move reaches its target and says so through the flag PyTrinamic reads (AP 8, or bit 14
of AP 156 on a BLDC module, named by PyTrinamic's ``FLAG_POSITION_END``), a rotation reaches
its speed, a stop stops; an output of a module whose ports are not known reads back; a
PyTrinamic example program for an imported module runs to its end.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import ROOT, tmclsh_env

pytest.importorskip("pytrinamic")

# one of each shape: single-axis stepper; the last motor of six; a BLDC module (its position
# end is a status bit); a family class standing for two modules (TMCM123x_0_1)
SHAPES = [("TMCM1260", "TMCM-1260", 0), ("TMCM6110", "TMCM-6110", 5),
          ("TMCM1630", "TMCM-1630", 0), ("TMCM123x_0_1", "TMCM-1231", 0)]


@pytest.fixture
def imported(tmp_path):
    """``imported(class, name)``: the module file written as the import writes it, in a
    private config directory; returns the environment a tmclsh process finds it with."""
    from tmclsh.tmcl.modules import from_pytrinamic as fp

    folder = tmp_path / "config" / "tmclsh" / "modules"
    folder.mkdir(parents=True)

    def write(class_name: str, name: str) -> dict[str, str]:
        imp = fp.convert(class_name, name)
        (folder / fp.file_name(imp.name)).write_text(imp.text, encoding="utf-8")
        return tmclsh_env(XDG_CONFIG_HOME=str(tmp_path / "config"))

    return write


def _until(pred, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, "not within the time"
        time.sleep(0.02)


@pytest.mark.parametrize("class_name, name, axis", SHAPES, ids=[s[1] for s in SHAPES])
def test_pytrinamics_class_moves_the_simulated_imported_module(imported, class_name, name,
                                                               axis):
    from pytrinamic.connections import ConnectionManager
    import pytrinamic.modules

    env = imported(class_name, name)
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "sim", "-m", name, "--pty"],
                            stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
                            env=env, cwd=ROOT)
    try:
        path = proc.stdout.readline().strip()
        assert path, "the simulator did not start"
        with ConnectionManager(
                f"--interface serial_tmcl --port {path} --data-rate 9600").connect() as iface:
            module = getattr(pytrinamic.modules, class_name)(iface)
            motor = module.motors[axis]
            motor.actual_position = 0
            module.move_to(axis, 3000, 20000)
            _until(lambda: motor.get_position_reached())
            assert (motor.actual_position, motor.target_position) == (3000, 3000)
            module.move_by(axis, -1000)
            _until(lambda: motor.get_position_reached() and motor.actual_position == 2000)
            module.rotate(axis, -5000)
            _until(lambda: motor.actual_velocity == -5000)
            assert not motor.get_position_reached()
            module.stop(axis)
            _until(lambda: motor.actual_velocity == 0)
    finally:
        proc.terminate()
        proc.wait(5)


def test_an_output_of_a_module_whose_ports_are_not_known_reads_back(imported, run_tmclsh):
    """any_io: the file lists no ports, so tmclsh sends GIO/SIO for any port and the module
    answers; the simulated one takes an output and reads it back, inputs read 0."""
    env = imported("TMCM1260", "TMCM-1260")
    r = run_tmclsh("-m", "TMCM-1260", "--sim", "-c", "SIO 3, 2, 1; GIO 3, 2; GIO 1, 0", env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == ["ok: port 3 set to 1", "port 3 = 1", "port 1 = 0"]


def test_help_says_which_start_values_are_the_simulators(imported, run_tmclsh):
    """PyTrinamic carries no defaults: what the simulated module starts at is the simulator's
    choice, and help on it says so (the module's own note says what is not known)."""
    env = imported("TMCM1260", "TMCM-1260")
    r = run_tmclsh("-m", "TMCM-1260", "--sim", "-c", "help MaxVelocity; help TargetPosition",
                   env=env)
    assert r.returncode == 0, r.stderr
    text = " ".join(r.stdout.split())
    assert "simulator Starts at 51200 in the simulator, a start value of its own" in text
    assert "range, unit and access are not known" in text
    assert text.count("Starts at") == 1  # TargetPosition: nothing the simulator chose


def test_the_built_in_modules_are_simulated_by_their_own_names_only():
    """ALSO_CALLED only fills in a name a module lacks: the built-in files (from the manuals)
    gain no second name, so nothing the manuals' rules do changes for them."""
    from tmclsh.sim.model import known_as
    from tmclsh.tmcl.modules import built_in, load

    for name in built_in():
        mod = load(name)
        assert all(n == p.name for (_, n), p in known_as(mod).items()), name


def test_a_pytrinamic_example_for_an_imported_module_runs_to_its_end(imported, request):
    """PyTrinamic's TMCM-1260 rotate_demo.py (rotate, stop, double the distance, back to 0,
    each until PyTrinamic's own 'position reached') on the simulated imported module, its
    clock 20x real time as in test_pytrinamic_clients.py."""
    from pytrinamic_examples import cache_folder, examples_dir
    from test_pytrinamic_clients import RUNNER, SPEED

    from tmclsh.sim import Simulator
    from tmclsh.sim.serve import serve_pty
    from tmclsh.tmcl import modules

    examples = examples_dir(cache_folder(request))
    script = examples / "modules" / "TMCM1260" / "TMCL" / "rotate_demo.py"
    env = imported("TMCM1260", "TMCM-1260")
    modules.add_file(Path(env["XDG_CONFIG_HOME"]) / "tmclsh" / "modules" / "tmcm1260.toml")
    try:
        with Simulator("TMCM-1260", speed=SPEED) as sim, serve_pty(sim) as server:
            r = subprocess.run(
                [sys.executable, "-c", RUNNER, str(SPEED), str(script), "--interface",
                 "serial_tmcl", "--port", server.path, "--data-rate", "9600"],
                capture_output=True, text=True, timeout=60, cwd=script.parent)
    finally:
        modules.forget_user_files()
    assert r.returncode == 0, r.stderr[-2000:]
    out = r.stdout
    assert "Furthest point reached." in out and out.rstrip().endswith("Ready."), out[-2000:]
    assert "Reached position 0." in out
