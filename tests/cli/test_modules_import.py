"""``tmclsh modules import pytrinamic NAME|--all [-o FILE]``: module files from PyTrinamic's
classes, checked against PyTrinamic itself (every name and number it gives is in the file),
used as tmclsh uses any module file (checked, listed, detected by 136, named in the banner,
completed at the prompt), and safe to run: a missing or changed PyTrinamic is one line, an
edited file is never replaced, PyTrinamic is imported on no other path."""

from __future__ import annotations

import inspect
import subprocess
import sys
import tomllib
import types

import pytest

from conftest import ROOT, tmclsh_env

pytest.importorskip("pytrinamic")

# one of each shape: single axis stepper, three and six axes, a BLDC module, a TMCC
SHAPES = {"TMCM1260": 1, "TMCM3110": 3, "TMCM6110": 6, "TMCM1630": 1, "TMCC160": 1}


@pytest.fixture
def env(tmp_path):
    return tmclsh_env(XDG_CONFIG_HOME=str(tmp_path / "config"))


def modules_dir(tmp_path):
    return tmp_path / "config" / "tmclsh" / "modules"


def _pytrinamic_tables(class_name: str) -> tuple[int, dict[int, str], dict[tuple[int, int], str]]:
    import pytrinamic.modules as pm

    cls = getattr(pm, class_name)
    inst = cls(None)
    axis = {}
    for motor in inst.motors:
        for k, v in vars(motor.AP).items():
            if not k.startswith("_") and isinstance(v, int) and v <= 255:
                axis.setdefault(v, k)
    glob = {}
    for key, table in vars(cls).items():
        if inspect.isclass(table) and key.startswith("GP"):
            for k, v in vars(table).items():
                if not k.startswith("_") and isinstance(v, int):
                    glob.setdefault((int(key[2:] or 0), v), k)
    return len(inst.motors), axis, glob


@pytest.mark.parametrize("class_name", list(SHAPES))
def test_import_writes_a_usable_file_with_pytrinamics_names(run_tmclsh, env, tmp_path,
                                                            class_name):
    r = run_tmclsh("modules", "import", "pytrinamic", class_name, env=env)
    assert r.returncode == 0, r.stderr
    files = list(modules_dir(tmp_path).glob("*.toml"))
    assert len(files) == 1 and str(files[0]) in r.stdout
    data = tomllib.loads(files[0].read_text(encoding="utf-8"))
    motors, axis, glob = _pytrinamic_tables(class_name)
    assert data["module"]["motors"] == motors == SHAPES[class_name]
    got_axis = {p["number"]: p for p in data["axis"]}
    assert set(got_axis) == set(axis)
    for number, name in axis.items():
        got = got_axis[number]
        # the built-in modules' style (MinimumSpeed), PyTrinamic's spelling an alias
        assert got["name"][0].isupper() and "_" not in got["name"].rstrip("0123456789"), got
        assert got["name"] == name or name in got.get("aliases", []) or "_" in got["name"]
        assert got_axis[number]["access"] == "RWE" and "min" not in got_axis[number]
    assert {(p["bank"], p["number"]) for p in data.get("global", [])} == set(glob)
    check = run_tmclsh("modules", "check", str(files[0]), env=env)
    assert check.returncode == 0 and check.stdout.rstrip().endswith(": OK"), check.stderr
    listed = run_tmclsh("modules", env=env)
    name = data["module"]["name"]
    line = next(ln for ln in listed.stdout.splitlines() if ln.startswith(name + " "))
    assert "data from PyTrinamic" in line and str(files[0]) in line


def test_import_to_stdout_a_file_and_all(run_tmclsh, env, tmp_path):
    r = run_tmclsh("modules", "import", "pytrinamic", "tmcm-1161", "-o", "-", env=env)
    assert r.returncode == 0 and r.stdout.startswith("# Written by 'tmclsh modules import")
    assert 'name = "TMCM-1161"' in r.stdout and not modules_dir(tmp_path).exists()
    out = tmp_path / "mine.toml"
    r = run_tmclsh("modules", "import", "pytrinamic", "1161", "-o", str(out), env=env)
    assert r.returncode == 0 and out.is_file()
    folder = tmp_path / "all"
    r = run_tmclsh("modules", "import", "pytrinamic", "--all", "-o", str(folder), env=env)
    assert r.returncode == 0, r.stderr
    written = sorted(p.name for p in folder.glob("*.toml"))
    assert len(written) >= 35 and "tmcm1260.toml" in written
    # the built-in modules (from their manuals): left out, each said in a line
    assert "tmcm1311.toml" not in written and "tmcm1640.toml" not in written
    assert "left out: TMCM-1311 is built in" in r.stderr
    assert len(r.stderr.splitlines()) == 2, r.stderr
    # one class for a family (TMCM123x_0_1, "represents TMCM-1230 and TMCM-1231"): a file each
    assert {"tmcm1230.toml", "tmcm1231.toml"} <= set(written)
    from tmclsh.tmcl.modules import read_file  # what `modules check` runs, in this process

    for path in folder.glob("*.toml"):
        assert read_file(path).origin.startswith("PyTrinamic"), path


def test_built_in_modules_are_not_replaced_unless_asked(run_tmclsh, env, tmp_path):
    r = run_tmclsh("modules", "import", "pytrinamic", "TMCM1311", env=env)
    assert r.returncode == 2 and "built in, from its manual" in r.stderr
    assert not modules_dir(tmp_path).exists()
    r = run_tmclsh("modules", "import", "pytrinamic", "TMCM1311", "-o", str(tmp_path / "x.toml"),
                   env=env)
    assert r.returncode == 0


def test_an_edited_file_is_not_overwritten(run_tmclsh, env, tmp_path):
    assert run_tmclsh("modules", "import", "pytrinamic", "TMCM1260", env=env).returncode == 0
    path = modules_dir(tmp_path) / "tmcm1260.toml"
    assert run_tmclsh("modules", "import", "pytrinamic", "TMCM1260", env=env).returncode == 0
    path.write_text("# mine now\n" + path.read_text(encoding="utf-8"), encoding="utf-8")
    r = run_tmclsh("modules", "import", "pytrinamic", "TMCM1260", env=env)
    assert r.returncode == 2 and "was not written by an import" in r.stderr
    assert path.read_text(encoding="utf-8").startswith("# mine now")


@pytest.mark.parametrize("words, message", [
    (["TMCM1260"], "modules import takes where to import from"),
    (["pytrinamic"], "takes one NAME (TMCM1260) or --all"),
    (["pytrinamic", "TMCM9999"], "has no module class 'TMCM9999'; it has TMCC160"),
    (["pytrinamic", "TMCM123x_0_1"], "stands for TMCM-1230 and TMCM-1231: name one of them"),
])
def test_bad_words_are_one_line(run_tmclsh, env, words, message):
    r = run_tmclsh("modules", "import", *words, env=env)
    assert r.returncode == 2 and message in r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.splitlines()) == 1


def _main(argv, monkeypatch, capsys, tmp_path) -> tuple[int, str]:
    from tmclsh.cli.main import main

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    rc = main(argv)
    return rc, capsys.readouterr().err


def test_a_missing_pytrinamic_is_one_clear_line(monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, "pytrinamic", None)  # import pytrinamic: ImportError
    monkeypatch.setitem(sys.modules, "pytrinamic.modules", None)
    rc, err = _main(["modules", "import", "pytrinamic", "TMCM1260"], monkeypatch, capsys,
                    tmp_path)
    assert rc == 1
    assert "PyTrinamic is not installed" in err and "pip install 'tmclsh[pytrinamic]'" in err


def _fake_pytrinamic(monkeypatch, modules: types.ModuleType) -> None:
    top = types.ModuleType("pytrinamic")
    top.modules = modules  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "pytrinamic", top)
    monkeypatch.setitem(sys.modules, "pytrinamic.modules", modules)


def test_a_changed_pytrinamic_is_one_clear_line(monkeypatch, capsys, tmp_path):
    _fake_pytrinamic(monkeypatch, types.ModuleType("pytrinamic.modules"))  # no TMCLModule
    rc, err = _main(["modules", "import", "pytrinamic", "TMCM1260"], monkeypatch, capsys,
                    tmp_path)
    assert rc == 1 and "has no pytrinamic.modules.TMCLModule" in err

    class TMCLModule:
        def __init__(self, connection, module_id=1):
            self.motors = []

    class TMCM1260(TMCLModule):  # a motor without an AP class
        def __init__(self, connection):
            self.motors = [object()]

    class TMCM1261(TMCLModule):  # its constructor wants more than PyTrinamic 0.2's did
        def __init__(self, connection, interface_kind):
            pass

    fake = types.ModuleType("pytrinamic.modules")
    fake.TMCLModule, fake.TMCM1260, fake.TMCM1261 = TMCLModule, TMCM1260, TMCM1261
    _fake_pytrinamic(monkeypatch, fake)
    rc, err = _main(["modules", "import", "pytrinamic", "TMCM1260"], monkeypatch, capsys,
                    tmp_path)
    assert rc == 1 and "has a motor without an AP class" in err
    rc, err = _main(["modules", "import", "pytrinamic", "TMCM1261"], monkeypatch, capsys,
                    tmp_path)
    assert rc == 1 and "TMCM1261 could not be read: TypeError" in err
    rc, err = _main(["modules", "import", "pytrinamic", "--all"], monkeypatch, capsys,
                    tmp_path)
    assert rc == 0 and err.count("left out:") == 2  # each one line, the run goes on
    assert not (tmp_path / "config").exists()


def test_pytrinamic_is_imported_on_no_other_path():
    from test_startup_imports import loaded

    for args in (["--sim", "-c", "help 153; .module; GAP 1, 0"], ["modules"],
                 ["modules", "check", str(ROOT / "tmclsh/tmcl/modules/tmcm1311.toml")]):
        proc, modules = loaded(*args)
        assert proc.returncode == 0, proc.stderr
        assert not any(m.split(".")[0] == "pytrinamic" for m in modules), args


def test_an_imported_module_is_detected_named_and_completed(run_tmclsh, env, tmp_path,
                                                            terminal):
    """A simulated TMCM-1260 (simulated from the imported file) on a pty: the shell finds its
    type by 136, says where the data comes from, and completes PyTrinamic's names."""
    import shutil

    assert run_tmclsh("modules", "import", "pytrinamic", "TMCM1260", env=env).returncode == 0
    sim = subprocess.Popen([sys.executable, "-m", "tmclsh", "sim", "-m", "TMCM-1260", "--pty"],
                           stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
                           env=env, cwd=ROOT)
    try:
        path = sim.stdout.readline().strip()
        r = run_tmclsh("--port", path, "-c", "SAP MaxVelocity, 0, 1234\nGAP MaxVelocity, 0",
                       env=env)
        assert r.returncode == 0, r.stderr
        assert r.stdout.splitlines()[-1] == "MaxVelocity = 1234"
        if shutil.which("tmux") is None:
            pytest.skip("tmux is not installed: the completion half needs a terminal")
        term = terminal(env={"XDG_CONFIG_HOME": str(tmp_path / "config")})
        term.start("--port", path)
        screen = term.wait("TMCM-1260:1>")
        assert "TMCM-1260 (data from PyTrinamic" in screen
        term.type("GAP MaxVel")
        term.keys("Tab")
        term.wait("TMCM-1260:1> GAP MaxVelocity")
        term.type(", 0")
        term.keys("Enter")
        term.wait("MaxVelocity = 1234")
    finally:
        sim.terminate()
        sim.wait(5)


def test_a_family_class_and_status_bits(run_tmclsh, env):
    """TMCM123x_0_1 stands for two modules: each is its own file, found by its own type
    number. A BLDC class's ENUM names status bits (FLAG_POSITION_END = 0x4000), which its
    get_position_reached tests AP StatusFlags against: they are the parameter's bits."""
    r = run_tmclsh("modules", "import", "pytrinamic", "TMCM-1231", "-o", "-", env=env)
    assert r.returncode == 0, r.stderr
    data = tomllib.loads(r.stdout)
    assert (data["module"]["name"], data["module"]["version_string"]) == ("TMCM-1231",
                                                                          "1231V000")
    assert any("stands for TMCM-1230 and TMCM-1231" in n for n in data["module"]["notes"])
    r = run_tmclsh("modules", "import", "pytrinamic", "TMCM1630", "-o", "-", env=env)
    status = next(p for p in tomllib.loads(r.stdout)["axis"] if p["name"] == "StatusFlags")
    assert status["number"] == 156 and status["bits"] == {"14": "position end"}



def test_imported_names_read_like_the_built_in_ones_and_pytrinamics_still_work(
        run_tmclsh, env, tmp_path):
    r = run_tmclsh("modules", "import", "pytrinamic", "TMCM1161", env=env)
    assert r.returncode == 0, r.stderr
    data = tomllib.loads(next(modules_dir(tmp_path).glob("*.toml")).read_text("utf-8"))
    by_number = {p["number"]: p for p in data["axis"]}
    assert by_number[130]["name"] == "MinimumSpeed"  # PyTrinamic: minimumSpeed
    assert by_number[130]["aliases"] == ["minimumSpeed"]
    assert by_number[4]["name"] == "MaxVelocity" and "aliases" not in by_number[4]
    from tmclsh.tmcl.modules import read_file

    mod = read_file(next(modules_dir(tmp_path).glob("*.toml")))
    assert mod.lookup("axis", "minimumSpeed").number == 130
    assert mod.lookup("axis", "MinimumSpeed").aliases == ("minimumSpeed",)
