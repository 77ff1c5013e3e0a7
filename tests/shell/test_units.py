"""Many modules at once (issue 25): units on their own ports, on one RS485 line, on a CAN
bus; what each says, how they fail alone, and how Ctrl-C stops them all. Through real bytes:
simulated modules served on ptys (each its own line) and on python-can's virtual bus."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import threading
import time
import uuid

import pytest

from conftest import ROOT, patience, read_until, tmclsh_env
from tmclsh.cli import main as cli
from tmclsh.sim import SimBus, Simulator
from tmclsh.sim.model import AXIS

TYPES = ("TMCM-1311", "TMCM-351", "TMCM-1640", "TMCM-1311")


@pytest.fixture
def run(capsys, monkeypatch):
    """``run(*argv)`` -> (exit status, stdout, stderr) of tmclsh's main in this process (the
    virtual CAN bus reaches no other)."""
    monkeypatch.setenv("TMCLSH_CONFIG", "/dev/null")
    for var in ("TMCLSH_PORT", "TMCLSH_CAN", "TMCLSH_PROFILE", "TMCLSH_ADDRESS"):
        monkeypatch.delenv(var, raising=False)

    def go(*argv: str) -> tuple[int, str, str]:
        capsys.readouterr()
        rc = cli.main(list(argv))
        out, err = capsys.readouterr()
        return rc, out, err
    return go


@pytest.fixture
def four(make_pty_sim):
    """Four modules, each on its own pty: a TMCM-1311, a TMCM-351, a TMCM-1640, a TMCM-1311."""
    return [make_pty_sim(module) for module in TYPES]


def _ports(sims) -> list[str]:
    return [arg for _, path in sims for arg in ("--port", path)]


def _objects(out: str) -> list[dict]:
    return [json.loads(line) for line in out.splitlines()]


def test_four_units_on_four_ports_each_its_own_session(four, run, tmp_path):
    script = tmp_path / "check.tmcl"
    script.write_text(".let mine = ${unit} * 10\n"
                      "GGP 66, 0\n"
                      ".expect GGP 66, 0 == ${address}\n"
                      ".echo unit ${unit} on ${port}: ${mine}\n")
    rc, out, err = run(*_ports(four), "--json", "-f", str(script))
    assert rc == 0, err
    objects = _objects(out)
    paths = [path for _, path in four]
    for obj in objects:  # every object says which unit, port and address it is
        assert obj["port"] == paths[obj["unit"] - 1] and obj["address"] == 1, obj
    summaries = {o["unit"]: o for o in objects if o.get("summary")}
    assert sorted(summaries) == [1, 2, 3, 4]
    assert [summaries[n]["module"] for n in (1, 2, 3, 4)] == list(TYPES)
    assert all(s["result"] == "passed" and s["exit"] == 0 and s["checks_passed"] == 1
               and s["line"] == s["of"] == 4 for s in summaries.values())
    echoes = sorted(o["echo"] for o in objects if "echo" in o)
    assert echoes == [f"unit {n} on {paths[n - 1]}: {n * 10}" for n in (1, 2, 3, 4)]
    # each unit's summary object comes after its own results
    for n in (1, 2, 3, 4):
        mine = [i for i, o in enumerate(objects) if o["unit"] == n]
        assert objects[mine[-1]].get("summary")
    assert "summary" not in out.splitlines()[0]
    assert re.search(r"^ +4 +\S+ +TMCM-1311 +1311V111 +4/4 .* passed", err, re.M), err


def test_a_line_one_type_refuses_fails_that_unit_before_its_run(four, run):
    """AP 17 (VelocityReachedWindow) exists on the TMCM-1311 only here: the other types
    refuse the line before anything is sent to them; the 1311s run it."""
    sims = [sim for sim, _ in four]
    before = [sim.param(AXIS, 17) if sim.module.name == "TMCM-1311" else None for sim in sims]
    rc, out, err = run(*_ports(four), "-c", "SAP 17, 0, 1234; GAP 17, 0")
    assert rc == 1
    lines = out.splitlines()
    assert "[1 " in out and "[4 " in out
    for n, sim in enumerate(sims, 1):
        mine = [line for line in lines if line.startswith(f"[{n} ")]
        if sim.module.name == "TMCM-1311":
            assert sim.param(AXIS, 17) == 1234 != before[n - 1]
            assert re.search(rf"^ +{n} .* 2/2 .* passed", err + out, re.M)
        else:
            assert not [m for m in mine if "= 1234" in m]
            assert re.search(rf"^ +{n} .* refused", out, re.M), out
    assert "nothing was sent" in err


def test_three_addresses_on_one_line_take_turns(make_pty_sim, run):
    bus, path = make_pty_sim(target=SimBus([Simulator("TMCM-1311", a) for a in (1, 2, 3)]))
    rc, out, err = run("--port", path, "--address", "1-3", "-c",
                       "SAP 4, 0, ${address} * 100; GAP 4, 0")
    assert rc == 0, err
    results = [line.split("] ", 1) for line in out.splitlines() if line.startswith("[")]
    assert results == [[f"[{a} {path} @{a}", text] for a in (1, 2, 3) for text in (
        f"ok: MaxPositioningSpeed set to {a * 100} pps", f"MaxPositioningSpeed = {a * 100} pps")]
    # in turn: each unit's lines before the next unit's
    assert [sim.param(AXIS, 4) for sim in bus.simulators] == [100, 200, 300]


def test_units_on_a_python_can_virtual_bus(run):
    from tmclsh.sim.serve import serve_can
    from tmclsh.tmcl.frames import Reply, Request

    channel = f"units-{uuid.uuid4().hex[:8]}"
    sims = [Simulator("TMCM-1311", 1), Simulator("TMCM-351", 1)]
    sims[1].write(Request(1, 9, 71, 0, 3).to_bytes())  # its own CAN id first (GP 71 = 3)
    assert Reply.from_bytes(sims[1].read(1.0)).ok
    servers = [serve_can(s, "virtual", channel) for s in sims]
    try:
        rc, out, err = run("--can", f"virtual:{channel}", "--can-id", "1,3", "--json", "-c",
                           "GGP 71, 0")
    finally:
        for server, sim in zip(servers, sims):
            server.close()
            sim.close()
    assert rc == 0, err
    reads = [o for o in _objects(out) if "reply" in o]
    assert [(o["unit"], o["can"], o["can_id"], o["reply"]) for o in reads] == [
        (1, f"virtual:{channel}", 1, 1), (2, f"virtual:{channel}", 3, 3)]


def test_a_unit_unplugged_mid_run_fails_alone(make_pty_sim, run, tmp_path):
    from tmclsh.sim.serve import serve_pty

    keep = make_pty_sim("TMCM-1311")
    gone_sim = Simulator("TMCM-351")
    gone = serve_pty(gone_sim)
    script = tmp_path / "long.tmcl"
    script.write_text(".repeat 40\nGAP 1, 0\n.sleep 0.01\n.end\n")
    threading.Timer(0.3, gone.close).start()  # the cable pulled out
    try:
        rc, out, err = run("--port", keep[1], "--port", gone.path, "-f", str(script))
    finally:
        gone.close()
        gone_sim.close()
    assert rc == 1, out + err
    assert re.search(r"^ +1 .* 4/4 .* passed", out, re.M), out  # the file's lines
    assert re.search(r"^ +2 .* failed +[0-9.]+ s  long.tmcl:2: lost ", out, re.M), out
    assert f"[2 {gone.path}] " in err and "lost" in err


def test_no_module_at_a_unit_is_exit_3_naming_it(make_pty_sim, run):
    _, path = make_pty_sim("TMCM-1311")
    rc, out, err = run("--port", path, "--address", "1,4", "--timeout", "0.1", "--retries", "0",
                       "--json", "-c", "GAP 1, 0")
    assert rc == 3
    summaries = {o["unit"]: o for o in _objects(out) if o.get("summary")}
    assert summaries[1]["result"] == "passed" and summaries[2]["result"] == "no module"
    assert summaries[2]["exit"] == 3 and "address 4" in summaries[2]["error"]
    assert err.splitlines()[-1] == f"tmclsh: no module for unit 2 {path} @4"


def test_the_log_dir_keeps_a_transcript_per_unit(four, run, tmp_path):
    logs = tmp_path / "logs"
    rc, out, err = run(*_ports(four[:2]), "--log-dir", str(logs), "-c", "GAP 4, 0")
    assert rc == 0, err
    files = sorted(p.name for p in logs.iterdir())
    assert [f[:8] for f in files] == ["unit-01-", "unit-02-"]
    text = (logs / files[1]).read_text()
    stamp = r"\d\d:\d\d:\d\d\.\d{3}"
    assert re.search(rf"^{stamp} tx> 01 88 00 00 00 00 00 00 89", text, re.M)  # 136, at connect
    assert re.search(rf"^{stamp} tx> 01 06 04 00 .*GAP 4, 0", text, re.M)
    assert re.search(rf"^{stamp} <rx 02 01 64 06 ", text, re.M)
    assert re.search(rf"^{stamp} out +MaxPositioningSpeed = ", text, re.M)
    assert "passed (exit status 0)" in text.splitlines()[-1]


def test_all_takes_every_attached_module(four, run, monkeypatch):
    import tmclsh.link as link

    class Port:
        def __init__(self, device):
            self.device = device

    monkeypatch.setattr(link, "trinamic_ports", lambda: [Port(p) for _, p in four[:3]])
    rc, out, err = run("--all", "--json", "-c", "GGP 66, 0")
    assert rc == 0, err
    assert sorted(o["port"] for o in _objects(out) if o.get("summary")) == sorted(
        p for _, p in four[:3])
    monkeypatch.setattr(link, "trinamic_ports", lambda: [])
    rc, out, err = run("--all", "-c", "GGP 66, 0")
    assert rc == 3 and "--all: no Trinamic USB module is attached" in err


@pytest.mark.parametrize("argv, says", [
    (["--address", "1,1"], "--address 1 is given twice"),
    (["--can", "virtual:x", "--can-id", "1,2,3", "--reply-id", "5,6"],
     "--reply-id names 2 ids for 3 CAN ids"),
    (["--address", "1-2"], "standard input is read once; 2 units given"),
    (["--address", "1-2", "-f", "-"], "-f - reads standard input once"),
])
def test_what_cannot_be_is_a_usage_error(make_pty_sim, run, argv, says):
    _, path = make_pty_sim()
    if "--can" not in argv:
        argv = ["--port", path, *argv]
    if "-f" not in argv and "--reply-id" in argv:
        argv = [*argv, "-c", "GAP 1, 0"]
    rc, out, err = run(*argv)
    assert rc == 2 and says in err, err


# -- Ctrl-C and signals stop every unit --------------------------------------------------------

@pytest.mark.parametrize("sig, status, why", [(signal.SIGINT, 130, "interrupted"),
                                              (signal.SIGTERM, 143, "terminated (SIGTERM)")])
def test_a_signal_stops_every_unit(make_pty_sim, tmp_path, sig, status, why):
    sims = [make_pty_sim(m) for m in ("TMCM-1311", "TMCM-351")]
    script = tmp_path / "turn.tmcl"
    script.write_text("ROR 0, 500\n.sleep 30\n")
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", *_ports(sims), "-f", str(script)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=tmclsh_env(), cwd=str(ROOT))
    try:
        turning = [sim for sim, _ in sims]
        # both units have taken in their ROR's answer (the motors turning alone came before
        # that: a unit still on line 1 when the signal landed); then their .sleep
        shown = read_until(proc, lambda text: text.count("ok: motor 0 rotating") == 2
                           and text.endswith("\n"))
        assert all(s.param(AXIS, 3) for s in turning)
        time.sleep(0.3)  # (from the ROR's result to the .sleep: a few steps)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=patience(15))
        out = shown + out
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == status, err
    assert all(s.param(AXIS, 3) == 0 for s in turning)
    for n, (_, path) in enumerate(sims, 1):
        assert f"[{n} {path}] {why}: stopped motor" in err, err
    assert re.search(r"^ +1 .* 2/2 .* stopped .*" + re.escape(why), out, re.M), out
    # each unit's last line names what stopped it (not "Ctrl-C" for a SIGTERM)
    assert len(re.findall(r"turn\.tmcl: " + re.escape(why) + r"( \(Ctrl-C\))? at line 2",
                          out)) == 2, out


def test_a_reader_gone_stops_what_each_unit_set_moving(tmp_path):
    """`tmclsh --port A --port B -f turn.tmcl | head -1`: as a run of one module does, the
    run is cut short where its reader went away: the unit that set a motor turning stops it
    and says so on stderr, the unit that moved nothing is sent nothing more, and the run
    ends 1 (it ran to its end unheard, exit 0, the motor turning). Modules written from the
    manuals (tests/responder.py), not the simulator."""
    from responder import PtyModule

    turning, still = PtyModule(version="1311V111"), PtyModule(version="1311V111")
    script = tmp_path / "turn.tmcl"
    script.write_text(".if unit == 1\nROR 0, 500\n.end\n"
                      ".repeat 100\nGAP 1, 0\n.sleep 0.1\n.end\n")
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", turning.path,
                             "--port", still.path, "-f", str(script)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=tmclsh_env(), cwd=str(ROOT))
    try:
        read_until(proc, lambda text: "rotating" in text and text.count("\n") >= 3)
        proc.stdout.close()  # (`| head`: the reader has what it wanted and goes)
        err = proc.stderr.read()
        proc.wait(timeout=patience(30))
    finally:
        if proc.poll() is None:
            proc.kill()
        turning.close()
        still.close()
    assert proc.returncode == 1, err
    assert 1 in turning.commands()  # ROR
    after_ror = turning.commands()[turning.commands().index(1):]
    assert 3 in after_ror, turning.got  # MST: the one stop
    assert f"[1 {turning.path}] the output's reader went away: stopped motor 0" in err, err
    assert 3 not in still.commands(), still.got
    assert f"[2 {still.path}] the output's reader went away: stopped" not in err, err
    assert "Traceback" not in err and "Exception ignored" not in err, err



def test_a_reader_gone_found_as_the_units_end_still_stops_what_they_set_moving(tmp_path):
    """`| head -1` whose reader went while the units slept, a unit's last lines a read and a
    ROL: the read's line is the first write to find the reader gone, and the unit ends (the
    ROL sent) before the run's next look at the units; that look was never taken, so the
    run ended 1 with no word of the reader and both motors turning. Now the run looks once
    more as the units end and stops what each set moving. Modules from the manuals."""
    from responder import PtyModule

    modules = [PtyModule(version="1311V111"), PtyModule(version="1311V111")]
    script = tmp_path / "turn.tmcl"
    script.write_text("ROR 0, 500\n.sleep 2\nGAP 1, 0\nROL 0, 300\n")
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", modules[0].path,
                             "--port", modules[1].path, "-f", str(script)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=tmclsh_env(), cwd=str(ROOT))
    try:
        read_until(proc, lambda text: text.count("rotating") == 2)
        proc.stdout.close()  # (`| head -1`: the reader has its lines and goes)
        err = proc.stderr.read()
        proc.wait(timeout=patience(30))
    finally:
        if proc.poll() is None:
            proc.kill()
        for module in modules:
            module.close()
    assert proc.returncode == 1, err
    for module in modules:
        sent = module.commands()
        last_move = max(i for i, op in enumerate(sent) if op in (1, 2))  # ROR or ROL
        assert 3 in sent[last_move:], module.got  # an MST after it: not left turning
        said = f"{module.path}] the output's reader went away: stopped motor 0"
        assert said in err, err
    assert "Traceback" not in err and "Exception ignored" not in err, err


def _interrupt_once_turning(script, path: str, sim, *extra: str,
                            then=lambda: None, timeout: float = 20) -> tuple[int, str, str]:
    """Run ``script`` on the units at 1-3 on ``path``; once ``sim``'s motor turns, ``then()``
    and Ctrl-C (SIGINT); returns (status, stdout, stderr)."""
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", path, "--address",
                             "1-3", *extra, "-f", str(script)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=tmclsh_env(), cwd=str(ROOT))
    try:
        deadline = time.monotonic() + patience(timeout)
        while not sim.param(AXIS, 3):
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.05)
        then()
        time.sleep(0.3)  # (in the loop: the main thread waits for the line's thread)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=patience(timeout))
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, out, err


def test_ctrl_c_on_a_shared_line_stops_the_unit_running_and_starts_no_other(make_pty_sim,
                                                                           tmp_path):
    """One thread runs the three units of one line in turn: Ctrl-C while the first runs
    stops its motor, and the run waits for that stop before it ends (the others never
    start)."""
    bus, path = make_pty_sim(target=SimBus([Simulator("TMCM-1311", a) for a in (1, 2, 3)]))
    script = tmp_path / "turn.tmcl"
    script.write_text("ROR 0, 500\n.repeat 300\nGAP 1, 0\n.sleep 0.1\n.end\n")
    first = bus.simulators[0]
    status, out, err = _interrupt_once_turning(script, path, first, "--json", timeout=15)
    assert status == 130, err
    assert first.param(AXIS, 3) == 0
    assert f"[1 {path} @1] interrupted: stopped motor 0" in err, err
    summaries = {o["unit"]: o for o in _objects(out) if o.get("summary")}
    assert [summaries[n]["result"] for n in (1, 2, 3)] == ["stopped", "not run", "not run"]
    assert all(sim.param(AXIS, 3) == 0 for sim in bus.simulators[1:])


# -- on a terminal: the live table ---------------------------------------------------------------

def test_the_live_table_in_a_terminal(make_pty_sim, terminal, tmp_path):
    from tmux import needs_tmux

    if needs_tmux.args[0]:
        pytest.skip("tmux is not installed")
    slow = make_pty_sim("TMCM-1311")
    fast = make_pty_sim("TMCM-351")
    script = tmp_path / "line.tmcl"
    script.write_text(".repeat 30\nGAP 1, 0\n.sleep (2 - ${unit}) * 0.05\n.end\n"
                      ".expect GGP 66, 0 == 2\n")
    term = terminal(width=150)
    term.start("--port", slow[1], "--port", fast[1], "-f", str(script))
    live = term.wait_for(re.compile(r"│ +1 │.*running.*\n.*│ +2 │.*(passed|failed)"), timeout=20)
    assert re.search(r"│ +1 │ \S+ +│ TMCM-1311 │ 1311V111 │ +[1-5]/5 │", live), live
    screen = term.wait("EXIT=", timeout=30)
    assert "EXIT=1" in screen
    assert "summary" in screen and "units" not in screen  # the live table made way for it
    # the line column numbers the file's lines, as the error's FILE:LINE does
    assert re.search(r"│ +1 │.* 5/5 .*│ failed .*│ line.tmcl:5: expectation failed", screen)
    assert re.search(r"│ +2 │.*│ TMCM-351 .* 5/5 .*│ failed", screen)
    # what a unit says on stderr is above the table, with the unit in front
    assert f"[1 {slow[1]}] {script}:5: expectation failed" in screen.replace("\n", "")
    # the results themselves are not on the screen: where to find them is
    assert "ActualPosition =" not in screen and "results are not shown beside the table" in \
        screen.replace("\n", "")


def test_the_prompt_takes_one_module(make_pty_sim, terminal):
    from tmux import needs_tmux

    if needs_tmux.args[0]:
        pytest.skip("tmux is not installed")
    _, path = make_pty_sim()
    term = terminal()
    term.start("--port", path, "--address", "1,2")
    screen = term.wait("EXIT=")
    assert "EXIT=2" in screen
    assert f"the prompt talks to one module; 2 units given ({path} @1, {path} @2)" in \
        screen.replace("\n", "")


def test_ctrl_c_stops_the_motor_a_unit_that_had_ended_left_turning(make_pty_sim, tmp_path):
    """A unit's script may end with its motor turning (said, "left running"); Ctrl-C while
    the next unit runs stops every motor of the run, that one too (it was left turning)."""
    bus, path = make_pty_sim(target=SimBus([Simulator("TMCM-1311", a) for a in (1, 2, 3)]))
    script = tmp_path / "turn.tmcl"
    script.write_text("ROR 0, 500\n.sleep 1.5\n")
    first, second = bus.simulators[:2]

    def unit_1_left_it_turning() -> None:
        assert first.param(AXIS, 3)  # unit 1 ended with its motor turning

    status, out, err = _interrupt_once_turning(script, path, second,
                                               then=unit_1_left_it_turning)
    assert status == 130, err
    assert [sim.param(AXIS, 3) for sim in bus.simulators] == [0, 0, 0], err
    assert f"[1 {path} @1] interrupted: stopped motor 0" in err, err
    assert f"[2 {path} @2] interrupted: stopped motor 0" in err, err


def test_a_units_line_is_the_files_line_as_its_errors_say(make_pty_sim, run, tmp_path):
    """Issue 35: the `line` column counted lines without comments (3/19) while the error
    beside it said eol.tmcl:4; both number the file's lines now, JSON too."""
    sims = [make_pty_sim("TMCM-1311") for _ in range(2)]
    script = tmp_path / "eol.tmcl"
    script.write_text("// set up\n"
                      "GAP 4, 0\n"
                      "\n"
                      ".expect GAP 4, 0 == -7   // fails: never negative\n"
                      "GAP 5, 0\n"
                      "// the end\n")
    rc, out, err = run(*_ports(sims), "--json", "-f", str(script))
    assert rc != 0
    summaries = [o for o in _objects(out) if o.get("summary")]
    assert len(summaries) == 2
    for s in summaries:
        assert "eol.tmcl:4:" in s["error"], s
        assert (s["line"], s["of"]) == (4, 6), s
    rc, out, err = run(*_ports(sims), "-f", str(script))
    assert re.search(r"^ +1 .* 4/6 ", out + err, re.M), out + err
    script.write_text("// only comments and one line\nGAP 4, 0\n// end\n")
    rc, out, err = run(*_ports(sims), "--json", "-f", str(script))
    assert rc == 0, err
    assert all((o["line"], o["of"]) == (3, 3) for o in _objects(out) if o.get("summary"))


def test_the_units_lines_are_written_by_one_writer(run, monkeypatch):
    """Each unit's lines wait in its own buffer; the main thread alone writes them (issue 34:
    no lock of the whole process taken for each line a unit shows)."""
    writers: set[str] = set()

    class Recording:
        def __init__(self):
            self.text = []

        def write(self, text: str) -> int:
            writers.add(threading.current_thread().name)
            self.text.append(text)
            return len(text)

        def flush(self) -> None:
            pass

        def isatty(self) -> bool:
            return False

    out, err = Recording(), Recording()
    monkeypatch.setattr(sys, "stdout", out)
    monkeypatch.setattr(sys, "stderr", err)
    rc = cli.main(["--sim", "TMCM-1311", "--address", "1,2,3", "-c",
                   "GAP 1, 0; .echo done ${unit}"])
    assert rc == 0
    shown = "".join(out.text)
    for n in (1, 2, 3):
        assert f"[{n} sim TMCM-1311 @{n}] done {n}" in shown
    assert writers == {threading.main_thread().name}


def test_what_the_units_said_since_a_tick_goes_out_in_one_write(monkeypatch):
    """32 units' lines of one tick are one write and one flush of the real stream, not one
    per unit (each a system call the units' threads wait on); a line to the other stream
    between them keeps its place."""
    from tmclsh.ops.units import Unit
    from tmclsh.shell.features.unitview import PrefixView

    calls: list[tuple[str, str]] = []

    class Counting:
        def __init__(self, name: str):
            self.name = name

        def write(self, text: str) -> int:
            calls.append((self.name, text))
            return len(text)

        def flush(self) -> None:
            calls.append((self.name, "<flush>"))

        def isatty(self) -> bool:
            return False

    monkeypatch.setattr(sys, "stdout", Counting("out"))
    monkeypatch.setattr(sys, "stderr", Counting("err"))
    units = [Unit(n, "port", f"/dev/ttyX{n}", 1) for n in range(1, 33)]
    view = PrefixView(units, None)
    for unit in units:
        view.record(unit).write("out", f"GAP 1, 0 -> {unit.number}\nsecond\n")
    view.drain()
    writes = [text for name, text in calls if text != "<flush>"]
    assert [name for name, _ in calls] == ["out", "out"] and len(writes) == 1
    assert writes[0].splitlines()[:3] == ["[1 /dev/ttyX1 @1] GAP 1, 0 -> 1",
                                          "[1 /dev/ttyX1 @1] second",
                                          "[2 /dev/ttyX2 @1] GAP 1, 0 -> 2"]
    assert len(writes[0].splitlines()) == 64
    calls.clear()
    view.record(units[0]).write("out", "a\n")
    view.record(units[1]).write("err", "warning: b\n")
    view.record(units[2]).write("out", "c\n")
    view.record(units[3]).write("out", "d\n")
    view.drain()
    assert [(name, text) for name, text in calls if text != "<flush>"] == [
        ("out", "[1 /dev/ttyX1 @1] a\n"), ("err", "[2 /dev/ttyX2 @1] warning: b\n"),
        ("out", "[3 /dev/ttyX3 @1] c\n[4 /dev/ttyX4 @1] d\n")]


FEATURES = (".let x = GAP 1, 0\n.expect GAP 1, 0 == ${x}\nROR 0, 100\n.sleep 0.01\nMST 0\n"
            ".watch GAP 1, 0 --count 1\n")


@pytest.mark.parametrize("config, lines", [
    (None, FEATURES),
    ('[settings]\ncolor = "never"\n', "GAP 1, 0\n"),
    (None, "// a jig's test, first line a comment (as a backup's)\nGAP 1, 0\nGAP 250, 0\n"),
], ids=["features", "a config file", "a comment first"])
def test_nothing_is_imported_in_a_units_thread(tmp_path, config, lines):
    """A stop lands at a unit's next bytecode: inside an import it would leave a module half
    made for every unit after it. What the lines and the links need is imported first; the
    config file is read once, before (parsing it imports a TOML parser)."""
    probe = (
        "import sys, threading\n"
        "seen = []\n"
        "class Finder:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if threading.current_thread().name.startswith('unit-line'):\n"
        "            seen.append(name)\n"
        "sys.meta_path.insert(0, Finder())\n"
        "from tmclsh.cli import main as cli\n"
        "rc = cli.main(sys.argv[1:])\n"
        "print('IMPORTED', rc, sorted(set(seen)), file=sys.__stderr__)\n")
    script = tmp_path / "s.tmcl"
    script.write_text(lines)
    env = tmclsh_env()
    if config is not None:
        (tmp_path / "config.toml").write_text(config)
        env["TMCLSH_CONFIG"] = str(tmp_path / "config.toml")
        # the module data cached as a user's machine has it (else parsing the module files
        # imports the TOML parser first, in the main thread, and hides the config file's)
        warm = subprocess.run([sys.executable, "-m", "tmclsh", "--sim", "TMCM-1311", "-c",
                               "GAP 1, 0"], capture_output=True, text=True, env=env,
                              timeout=120)
        assert warm.returncode == 0, warm.stderr
    proc = subprocess.run([sys.executable, "-c", probe, "--sim", "TMCM-1311", "--address",
                           "1,2", "-f", str(script)], capture_output=True, text=True,
                          env=env, timeout=120)
    said = [line for line in proc.stderr.splitlines() if line.startswith("IMPORTED")]
    status = 2 if "GAP 250" in lines else 0  # (refused: the module has no parameter 250)
    assert said == [f"IMPORTED {status} []"], proc.stderr


def test_tmcl_lines_alone_start_no_temporary_files_module(tmp_path):
    """Only a command writes a file: a run of TMCL lines alone does not import tempfile (and
    shutil, random, bz2, lzma) before its units start; one with a command does."""
    probe = ("import sys\n"
             "from tmclsh.cli import main as cli\n"
             "rc = cli.main(sys.argv[1:])\n"
             "print('TEMPFILE', rc, 'tempfile' in sys.modules, file=sys.__stderr__)\n")
    for lines, loaded in (("GAP 1, 0\nSAP 4, 0, 1000\n", False),
                          ("GAP 1, 0\n.echo ${unit}\n", True)):
        script = tmp_path / "s.tmcl"
        script.write_text(lines)
        proc = subprocess.run([sys.executable, "-c", probe, "--sim", "TMCM-1311", "--address",
                               "1,2", "-f", str(script)], capture_output=True, text=True,
                              env=tmclsh_env(), timeout=120)
        said = [line for line in proc.stderr.splitlines() if line.startswith("TEMPFILE")]
        assert said == [f"TEMPFILE 0 {loaded}"], proc.stderr


def test_a_unit_whose_diff_differs_names_it_as_its_last_error(run, tmp_path):
    """``.diff --exit-code`` fails a unit whose module differs; its table said so, and the
    unit's "last error" said nothing (errors 1, result failed, and an empty column)."""
    from responder import PtyModule

    same, other = PtyModule(version="1311V111"), PtyModule(version="1311V111")
    try:
        same.values[(4, 0, False)], other.values[(4, 0, False)] = 1000, 5
        saved = tmp_path / "b.tmcl"
        saved.write_text("SAP MaxPositioningSpeed, 0, 1000\n")
        rc, out, err = run("--port", same.path, "--port", other.path, "-m", "TMCM-1311",
                           "--json", "-c", f".diff {saved} --exit-code")
        assert rc == 1, out + err
        summaries = {o["unit"]: o for o in _objects(out) if o.get("summary")}
        assert summaries[1]["result"] == "passed" and summaries[1]["error"] is None
        assert summaries[2]["result"] == "failed"
        assert "1 parameter differs from" in (summaries[2]["error"] or ""), summaries[2]
    finally:
        same.close()
        other.close()
