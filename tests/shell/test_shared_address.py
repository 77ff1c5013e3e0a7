"""Two modules at one address are a finding everywhere (issue 31, "Safe on a shared line"):
`-c`, `-f`, an end-of-line run of units and the prompt name the address once and fail the
run; `.upload` refuses with that cause. The two modules are ``tests/responder.py``'s
``TwoAtOneAddress`` (written from the manual, no tmclsh inside); a single module on a line
that copies replies (the simulator's ``dup``/``dup-late`` faults) is not called shared."""

from __future__ import annotations

import json
import random
import re

import pytest

from conftest import ROOT

from responder import TwoAtOneAddress

SAID = "two modules answer at address 1"


@pytest.fixture
def line():
    made: list[TwoAtOneAddress] = []

    def make(**kw) -> TwoAtOneAddress:
        made.append(TwoAtOneAddress(**kw))
        return made[-1]
    yield make
    for m in made:
        m.close()


def _objects(out: str) -> list[dict]:
    return [json.loads(text) for text in out.splitlines() if text.startswith("{")]


@pytest.mark.parametrize("offset", [0.0, 0.03], ids=["back-to-back", "slower-second"])
def test_c_names_the_address_once_and_fails(line, run_tmclsh, offset):
    m = line(offset=offset)
    p = run_tmclsh("--port", m.path, "-c", "GAP 1, 0; GAP 2, 0; GGP 66, 0")
    assert p.returncode == 1, p.stderr
    assert p.stderr.count(SAID) == 1, p.stderr
    assert "warning: " + SAID in p.stderr


def test_c_json_has_one_duplicate_record(line, run_tmclsh):
    m = line()
    p = run_tmclsh("--port", m.path, "--json", "-c", "GAP 1, 0; GAP 2, 0")
    assert p.returncode == 1, p.stderr
    dups = [o for o in _objects(p.stdout) if o.get("duplicate")]
    assert len(dups) == 1 and dups[0]["address"] == 1 and SAID in dups[0]["warning"]


@pytest.mark.parametrize("versions", [None, ("1311V111", "1311V111")],
                         ids=["two-types", "alike"])
def test_f_says_it_in_the_summary_and_in_json(line, run_tmclsh, tmp_path, versions):
    m = line(versions=versions)
    script = tmp_path / "eol.tmcl"
    script.write_text("GAP 1, 0\n.expect GAP 1, 0 == 0\nSAP 4, 0, 100\n")
    p = run_tmclsh("--port", m.path, "-f", str(script))
    assert p.returncode == 1, p.stdout + p.stderr
    assert "1 check passed" in p.stdout and f"; {SAID}" in p.stdout
    assert (p.stdout + p.stderr).count("warning: " + SAID) == 1
    p = run_tmclsh("--port", m.path, "--json", "-f", str(script))
    assert p.returncode == 1
    assert [o["address"] for o in _objects(p.stdout) if o.get("duplicate")] == [1]


def test_an_end_of_line_unit_on_a_shared_address_fails_with_that_reason(line, run_tmclsh,
                                                                       tmp_path):
    """Units at 1 (two modules) and 2 (one) on one line: 1 fails, saying why; 2 passes."""
    m = line(alone=(2,))
    script = tmp_path / "eol.tmcl"
    script.write_text("GAP 1, 0\n.expect GAP 1, 0 == 0\nSAP 4, 0, 100\n")
    p = run_tmclsh("--port", m.path, "--address", "1,2", "-f", str(script))
    assert p.returncode == 1, p.stdout + p.stderr
    table = p.stdout + p.stderr
    rows = {r.split()[0]: r for r in table.splitlines() if r.strip()[:1].isdigit()}
    assert " failed " in rows["1"] and SAID in rows["1"], table
    assert " passed " in rows["2"] and "two modules" not in rows["2"], table
    p = run_tmclsh("--port", m.path, "--address", "1,2", "--json", "-f", str(script))
    summaries = {o["unit"]: o for o in _objects(p.stdout) if o.get("summary")}
    assert summaries[1]["result"] == "failed" and summaries[1]["duplicate"] is True
    assert SAID in summaries[1]["error"]
    assert summaries[2]["result"] == "passed" and "duplicate" not in summaries[2]


def test_upload_refuses_with_the_real_cause(line, run_tmclsh, tmp_path):
    m = line()
    script = tmp_path / "up.tmcl"
    program = ROOT / "scripts" / "programs" / "tmcm1311-first-program.tmc"
    script.write_text(f"GAP 1, 0\nGAP 2, 0\n.upload {program} --yes\n")
    p = run_tmclsh("--port", m.path, "-f", str(script))
    assert p.returncode == 1, p.stdout + p.stderr
    assert f"not uploading, nothing was sent: {SAID}" in p.stderr
    assert "quieter line" not in p.stderr
    assert not [raw for raw in m.log if raw[1:2] == bytes([132])]  # no download mode


def test_a_single_module_on_a_line_that_copies_replies_is_not_called_shared(
        make_pty_sim, run_tmclsh, tmp_path):
    sim, path = make_pty_sim()
    sim.faults.rng = random.Random(31)
    sim.faults.rates = {"dup": 0.05, "dup-late": 0.05}
    copied = []
    take = sim.faults.take
    sim.faults.take = lambda counter, kind: copied.append(kind) or True if take(
        counter, kind) else False
    script = tmp_path / "many.tmcl"
    script.write_text("".join(f"SGP 2, 2, {v}\nGAP 1, 0\n" for v in range(40)))
    p = run_tmclsh("--port", path, "--json", "-f", str(script))
    assert "two modules" not in p.stdout + p.stderr
    assert not [o for o in _objects(p.stdout) if o.get("duplicate")]
    assert p.stdout.count('"line"') >= 80 and len(copied) >= 5  # (the line did copy)


def test_the_prompt_names_the_address(line, terminal):
    from tmux import needs_tmux

    if needs_tmux.args[0]:
        pytest.skip("tmux is not installed")
    m = line()
    term = terminal()
    term.start("--port", m.path)
    term.wait("TMCM-1311:1>")
    said = re.compile(r"two\s+modules\s+answer\s+at\s+address\s+1:")
    term.run("GAP 1, 0", "ActualPosition")
    term.run("GAP 2, 0", "TargetSpeed")
    term.wait_for(said)
    term.run("GGP 66, 0", "SerialAddress")
    assert len(said.findall(term.screen())) == 1


def test_an_upload_that_finds_the_address_shared_says_so_not_a_quieter_line(
        make_pty_sim, run_tmclsh, tmp_path):
    """Two alike modules (the simulator's bus, an address given twice): not found yet when
    the upload starts (the bring-up is too short to count on), found by the replies of
    download mode (status 101, twice each); the verify then names the real cause."""
    from tmclsh.sim import SimBus, Simulator

    _, path = make_pty_sim(target=SimBus([Simulator("TMCM-1311", 1),
                                          Simulator("TMCM-1311", 1)]))
    program = ROOT / "scripts" / "programs" / "tmcm1311-first-program.tmc"
    script = tmp_path / "up.tmcl"
    script.write_text(f".upload {program} --yes\n")
    p = run_tmclsh("--port", path, "-f", str(script))
    assert p.returncode == 1, p.stdout + p.stderr
    assert re.search(r"error: verify failed at address \d+ \(.*\): " + SAID, p.stderr), p.stderr
    assert "quieter line" not in p.stderr
