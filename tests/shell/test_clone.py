""".save/.diff/.restore through real bytes: the simulator served on a pty (binary and ASCII
links, all three modules, three motors on the TMCM-351), an independent responder written
here from the manuals' frame tables, and the CLI in a subprocess.

The responder is the check that does not agree with the client by construction: it knows
only the 9-byte frames (address, command, type, motor, value big-endian, checksum; replies
host, module, status, command, value, checksum) and a dictionary of values.
"""

from __future__ import annotations

import json
import os
import re
import threading
from pathlib import Path

import pytest

from tmclsh.tmcl import modules
from tmclsh.client.ascii import AsciiLink
from tmclsh.client.text import LineClient
from tmclsh.base.errors import TmclError
from tmclsh.shell.features.clone import CloneError, readable_slots
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Abort, Session
from tmclsh.sim import Simulator
from tmclsh.link import open_serial

from responder import PtyModule

# a line restores a value; "!" starts one outside the manual's range, sent as written
LINE = re.compile(r"^!?(SAP|SGP) (\w+), (\d+), (-?\d+)", re.M)


def shell(client: LineClient, json_mode: bool = False, yes: bool = False) -> Session:
    return Session(client, Output(json_mode=json_mode), yes=yes)


def json_lines(text: str) -> list[dict]:
    return [json.loads(x) for x in text.splitlines() if x.startswith("{")]


def file_values(path: Path, module) -> dict[tuple[str, int, int], int]:
    """(kind, number, motor/bank) -> value of every SAP/SGP line, read with a regex and the
    module's data file (not the project's parser)."""
    out = {}
    for mn, target, index, value in LINE.findall(path.read_text(encoding="utf-8")):
        kind = "axis" if mn == "SAP" else "global"
        if target.isdigit():
            number = int(target)
        else:
            pool = module.axis_params if kind == "axis" else module.global_params
            number = next(p.number for p in pool if p.name == target)
        out[(kind, number, int(index))] = int(value)
    return out


def changes(module) -> list[tuple[str, str, int]]:
    """A few configuration parameters to change: (line, kind, ...) on the last motor, plus a
    user variable; values inside each parameter's range."""
    motor = module.motors - 1
    picked = [p for p in module.axis_params
              if p.writable and p.readable and not p.state and not p.link
              and p.min is not None and p.max is not None and p.max - p.min >= 3][:2]
    lines = [(f"SAP {p.name}, {motor}, {p.min + 3}", "axis", p.number, motor) for p in picked]
    lines.append(("SGP 7, 2, 1234", "global", 7, 2))
    return lines


@pytest.fixture
def pty_client(make_pty_sim):
    made: list[LineClient] = []

    def make(module: str, *, ascii: bool = False, target=None) -> tuple[Simulator, LineClient]:
        sim, path = make_pty_sim(module, target=target)
        client = LineClient(open_serial(path, 115200), module=module, timeout=0.5, retries=2)
        made.append(client)
        if ascii:
            AsciiLink.attach(client)
        return sim, client

    yield make
    for c in made:
        c.close()


# -- the round trip on every module, binary and ASCII -----------------------------------------

@pytest.mark.parametrize("module,ascii", [
    ("TMCM-1311", False), ("TMCM-351", False), ("TMCM-1640", False),
    ("TMCM-1311", True), ("TMCM-351", True)])
def test_save_change_diff_restore(pty_client, tmp_path, capsys, module, ascii):
    sim, client = pty_client(module, ascii=ascii)
    mod = modules.load(module)
    s = shell(client, json_mode=True)
    path = tmp_path / "backup.tmcl"
    s.run_line(f".save {path}")
    saved = json_lines(capsys.readouterr().out)
    values = file_values(path, mod)
    link = {p.number for p in mod.global_params if p.link}
    assert saved == [{"saved": len(values), "file": str(path),
                      "link": sum(1 for k in values if k[0] == "global" and k[1] in link
                                  and k[2] == 0)}]
    if mod.motors > 1:  # every motor's parameters are in the file
        assert {k[2] for k in values if k[0] == "axis"} == set(range(mod.motors))
    head = path.read_text(encoding="utf-8").splitlines()[:6]
    assert f"// module: {module}" in head and "// address: 1" in head

    edits = changes(mod)
    for line, *_ in edits:
        s.run_line(line)
    capsys.readouterr()
    s.run_line(f".diff {path}")
    diffs = json_lines(capsys.readouterr().out)
    where = {(d["number"], d.get("motor", d.get("bank"))): d for d in diffs}
    assert len(diffs) == len(edits)
    for line, kind, number, index in edits:
        d = where[(number, index)]
        assert d["saved"] == values[(kind, number, index)]
        assert d["live"] == int(line.rsplit(",", 1)[1])
        assert set(d) == {"name", "number", "motor" if kind == "axis" else "bank", "saved", "live"}

    s.run_line(f".restore {path} --yes")
    out = json_lines(capsys.readouterr().out)
    assert len(out) == 1 and len(out[0]["restored"]) == len(edits) and out[0]["failed"] == []
    s.run_line(f".diff {path} --exit-code")
    assert json_lines(capsys.readouterr().out) == []
    # and the module holds the file's values (read with plain GAP/GGP lines)
    for line, kind, number, index in edits:
        mn = "GAP" if kind == "axis" else "GGP"
        assert client.value(f"{mn} {number}, {index}") == values[(kind, number, index)]


def test_state_is_a_comment_and_never_restored(pty_client, tmp_path, capsys):
    sim, client = pty_client("TMCM-1311")
    s = shell(client)
    s.run_line("SAP ActualPosition, 0, 51200")
    path = tmp_path / "b.tmcl"
    s.run_line(f".save {path}")
    text = path.read_text(encoding="utf-8")
    assert "// ActualPosition = 51200 µsteps (state, not restored" in text
    assert not re.search(r"^SAP (ActualPosition|TargetPosition|ActualSpeed|TargetSpeed)\b", text, re.M)
    # a hand-written state line is neither compared nor written
    path.write_text(text + "SAP ActualPosition, 0, 7\n", encoding="utf-8")
    s.run_line("SAP ActualPosition, 0, 100")
    capsys.readouterr()
    s.run_line(f".restore {path} --yes")
    assert "nothing to restore" in capsys.readouterr().out
    assert client.value("GAP ActualPosition, 0") == 100


# -- an independent responder: partial restore when it refuses one value ---------------------

@pytest.fixture
def responder():
    """A module that stores SAP/SGP values and answers GAP/GGP (tests/responder.py), from the
    manual's frame layout only; ``refuse`` holds (command, type, motor) it answers with
    status 4 (invalid value)."""
    r = PtyModule()
    yield r
    r.close()


def test_restore_onto_independent_responder_with_one_refusal(pty_client, responder, tmp_path,
                                                            capsys):
    sim, client = pty_client("TMCM-1311")
    path = tmp_path / "b.tmcl"
    shell(client).run_line(f".save {path}")
    mod = modules.load("TMCM-1311")
    want = file_values(path, mod)
    # the responder starts with every value the file has, except three
    for (kind, number, index), value in want.items():
        responder.values[(number, index, kind == "global")] = value
    responder.values[(4, 0, False)] = 999  # MaxPositioningSpeed
    responder.values[(6, 0, False)] = 17  # MaxCurrent: refused below
    responder.values[(12, 2, True)] = -5  # UserVariable #12
    responder.refuse.add((5, 6, 0))
    other = LineClient(open_serial(responder.path), module="TMCM-1311", timeout=0.5, retries=0)
    try:
        s = shell(other, json_mode=True)
        with pytest.raises(CloneError, match="1 of 3 parameters was not restored"):
            s.run_line(f".restore {path} --yes")
        out = json_lines(capsys.readouterr().out)[0]
        assert [(w["name"], w["old"], w["new"]) for w in out["restored"]] == [
            ("MaxPositioningSpeed", 999, want[("axis", 4, 0)]),
            ("UserVariable#12", -5, want[("global", 12, 2)])]
        assert out["failed"][0]["name"] == "MaxCurrent" and "status 4" in out["failed"][0]["error"]
        for (kind, number, index), value in want.items():
            got = responder.values[(number, index, kind == "global")]
            assert got == (17 if (kind, number, index) == ("axis", 6, 0) else value)
        # the fewest writes: one SAP/SGP per difference, nothing for equal values
        writes = [f for f in responder.log if f[1] in (5, 9)]
        assert sorted((f[1], f[2], f[3]) for f in writes) == [(5, 4, 0), (5, 6, 0), (9, 12, 2)]
    finally:
        other.close()


# -- refused before anything is sent --------------------------------------------------------

class Recording(Simulator):
    """The simulator, remembering every byte it received."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.received = bytearray()

    def write(self, data: bytes) -> None:
        self.received += data
        super().write(data)


def test_out_of_range_line_refused_at_its_line_before_sending(pty_client, tmp_path):
    sim, client = pty_client("TMCM-351", target=Recording("TMCM-351"))
    s = shell(client)
    path = tmp_path / "b.tmcl"
    s.run_line(f".save {path}")
    lines = path.read_text(encoding="utf-8").splitlines()
    n = next(i for i, t in enumerate(lines, 1) if t.startswith("SAP MaxCurrent, 1,"))
    lines[n - 1] = "SAP MaxCurrent, 1, 300  // hand-edited"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    s.run_line("SAP MaxCurrent, 0, 5")  # a real difference on an earlier line
    sim.received.clear()
    with pytest.raises(CloneError) as exc:
        s.run_line(f".restore {path} --yes")
    assert f"{path}:{n}:" in str(exc.value) and "out of range" in str(exc.value)
    assert bytes(sim.received) == b""
    # .diff compares whatever the file holds: the edit is a difference like any other
    s.run_line(f".diff {path}")
    assert bytes(sim.received)  # it read the module's values to compare


# -- across modules -------------------------------------------------------------------------

def test_other_module_refused_unless_force(pty_client, tmp_path, capsys):
    sim, c1311 = pty_client("TMCM-1311")
    path = tmp_path / "b1311.tmcl"
    s = shell(c1311)
    s.run_line("SAP MaxCurrent, 0, 77")
    s.run_line(f".save {path}")
    rec, c351 = pty_client("TMCM-351", target=Recording("TMCM-351"))
    t = shell(c351, json_mode=True)
    with pytest.raises(CloneError, match="backup of a TMCM-1311.*--force") as exc:
        t.run_line(f".restore {path} --yes")
    assert f"restore by parameter name with .restore {path} --force" in str(exc.value)
    # the hint names the command that was typed: a .diff is not told to restore
    with pytest.raises(CloneError) as exc:
        t.run_line(f".diff {path}")
    assert f"compare by parameter name with .diff {path} --force" in str(exc.value)
    assert "restore" not in str(exc.value)
    assert bytes(rec.received) == b""
    capsys.readouterr()
    t.run_line(f".restore {path} --yes --force")
    cap = capsys.readouterr()
    out = json_lines(cap.out)[0]
    assert [w["name"] for w in out["restored"]] == ["MaxCurrent"]
    assert any(x.startswith("ChopperMode ") for x in out["skipped"])
    assert any(x.startswith("MaxPositioningSpeed ") for x in out["skipped"])  # out of range
    assert "ChopperMode" in cap.err and "has no such parameter" in cap.err
    assert c351.value("GAP MaxCurrent, 0") == 77
    assert c351.value("GAP MaxCurrent, 1") == 0  # the 1311 has no motor 1


# -- plain scripts, the CLI, replay -----------------------------------------------------------

def test_any_script_of_sap_sgp_lines(pty_client, tmp_path, capsys):
    sim, client = pty_client("TMCM-1311")
    path = tmp_path / "hand.tmcl"
    path.write_text("// set up the axis\n# a shell comment\n\n   \nSAP 4, 0, 2000\n"
                    "SAP MaxCurrent, 0, 40  // run current\n5 140, 0, 5 # raw SAP\n"
                    "SGP 3, 2, 1; SGP 3, 2, 9\n", encoding="utf-8")
    s = shell(client)
    s.run_line(f".diff {path}")
    out = capsys.readouterr().out
    assert "4 of 4 parameters differ" in out and "MaxCurrent" in out
    s.run_line(f".restore {path} -y")
    capsys.readouterr()
    s.run_line(f".diff {path}")
    assert "no differences" in capsys.readouterr().out
    assert client.value("GAP 4, 0") == 2000 and client.value("GGP 3, 2") == 9


def test_counts_in_the_singular(pty_client, tmp_path, capsys):
    sim, client = pty_client("TMCM-1311")
    s = shell(client)
    path = tmp_path / "one.tmcl"
    path.write_text("SAP MaxCurrent, 0, 0\nSAP TargetPosition, 0, 5\n", encoding="utf-8")
    s.run_line(f".diff {path}")
    cap = capsys.readouterr()
    assert "(1 parameter compared)" in cap.out and "1 state line in" in cap.out + cap.err
    s.run_line("SAP MaxCurrent, 0, 4")
    capsys.readouterr()
    with pytest.raises(TmclError, match=r"^1 parameter differs from "):
        s.run_line(f".diff {path} --exit-code")
    assert "1 of 1 parameter differs" in capsys.readouterr().out


NOT_A_BACKUP_LINE = [
    ("SPA MaxPositioningSpeed, 0, 1234", "unknown command 'SPA'; did you mean"),
    ("GARBAGE LINE", "unknown command 'GARBAGE'"),
    ("MVP ABS, 0, 1000", "MVP is not SAP or SGP: a backup holds only SAP/SGP lines"),
    ("6 140, 0, 0", "command 6 (GAP) is not SAP (5) or SGP (9)"),
    (".let speed = 1", "shell command '.let'"),
    ("SAP MaxCurrent, 0, ${speed}", "variable"),
    ("loop: SAP MaxCurrent, 0, 1", "a label (loop:)"),
    ("speed = 5", "a constant (speed = ...)"),
    ("SAP MaxPossibleCurrent, 0, 5", "AP 15 MaxPossibleCurrent is read-only"),
    ("5 15, 0, 5", "AP 15 MaxPossibleCurrent is read-only"),
    ("SAP MaxCurrent, 1, 5", "TMCM-1311 has no motor 1: only motor 0"),
    ("SAP 4, 0, 1000 ; SPA 4, 0, 1", "unknown command 'SPA'"),
]


@pytest.mark.parametrize("bad,message", NOT_A_BACKUP_LINE)
def test_a_line_that_is_not_a_sap_sgp_line_the_module_accepts_is_refused(
        pty_client, tmp_path, bad, message):
    """A typo in a backup must not read as "matches": the whole file is checked before
    anything is compared or sent, and the bad line is named as -f names it."""
    sim, client = pty_client("TMCM-1311", target=Recording("TMCM-1311"))
    s = shell(client, yes=True)
    path = tmp_path / "b.tmcl"
    path.write_text(f"// hand-written\nSAP MaxCurrent, 0, 40\n{bad}\nSAP 4, 0, 2000\n",
                    encoding="utf-8")
    sim.received.clear()
    for cmd in (".diff", ".diff --exit-code", ".restore --yes"):
        with pytest.raises(CloneError) as exc:
            s.run_line(f"{cmd.split()[0]} {path} {' '.join(cmd.split()[1:])}")
        assert str(exc.value).startswith(f"{path}:3: "), str(exc.value)
        assert message in str(exc.value)
    assert bytes(sim.received) == b""


def test_cli_refuses_a_bad_backup_with_exit_status_2(tmp_path, run_tmclsh):
    path = tmp_path / "t.tmcl"
    path.write_text("SAP MaxCurrent, 0, 0\nSPA MaxPositioningSpeed, 0, 1234\n", encoding="utf-8")
    for cmd in (f".diff --exit-code {path}", f".diff {path}", f".restore {path} --yes"):
        r = run_tmclsh("--sim", "-c", cmd)
        assert r.returncode == 2, (cmd, r.stdout, r.stderr)
        assert f"{path}:2: unknown command 'SPA'" in r.stderr
        assert "no differences" not in r.stdout and "restored" not in r.stdout
    # -f says the same of the same file
    r = run_tmclsh("--sim", "-f", str(path))
    assert r.returncode == 2 and f"{path}:2: unknown command 'SPA'" in r.stderr
    # after a line that was sent, the run failed (1), as -c says of any error
    r = run_tmclsh("--sim", "-c", f"GAP 4, 0\n.diff {path}")
    assert r.returncode == 1 and f"{path}:2: unknown command 'SPA'" in r.stderr


@pytest.mark.parametrize("make,message", [
    (lambda p: None, "no such file"),
    (lambda p: p.write_bytes(bytes(range(256)) * 8), "not a text file"),
    (lambda p: p.mkdir(), "it is a directory"),
    (lambda p: p.write_text("", encoding="utf-8"), "has no SAP/SGP lines"),
    (lambda p: p.write_text("// only a comment\n\n", encoding="utf-8"), "has no SAP/SGP lines"),
    (lambda p: p.write_text("SAP 4, 0, 1000\n" * 100_001, encoding="utf-8"),
     "backup longer than 100,000 lines; not read"),
])
def test_cli_unusable_backup_file_is_one_line(tmp_path, run_tmclsh, make, message):
    path = tmp_path / "b.tmcl"
    make(path)
    for cmd in (f".diff {path}", f".restore {path} --yes"):
        r = run_tmclsh("--sim", "-c", cmd)
        assert r.returncode == 2, (r.stdout, r.stderr)
        assert message in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert "Traceback" not in r.stderr


def test_cli_exit_code_json_and_replay(make_pty_sim, run_tmclsh, tmp_path):
    sim, pty = make_pty_sim("TMCM-351")
    path = tmp_path / "b.tmcl"
    r = run_tmclsh("--port", pty, "-m", "TMCM-351", "--json", "-c", f".save {path}")
    assert r.returncode == 0, r.stderr
    text = path.read_text("utf-8")
    link_part = text.split("// -- link identity:")[1]  # the last section: its own place
    assert json.loads(r.stdout) == {"saved": len(LINE.findall(text)),
                                    "link": len(LINE.findall(link_part)), "file": str(path)}
    change = "SAP MaxCurrent, 2, 9\n"
    r = run_tmclsh("--port", pty, "-m", "TMCM-351", "-c", change + f".diff {path}")
    assert r.returncode == 0 and "MaxCurrent" in r.stdout, r.stderr
    r = run_tmclsh("--port", pty, "-m", "TMCM-351", "--json", "-c", f".diff {path} --exit-code")
    assert r.returncode == 1
    assert [json.loads(x) for x in r.stdout.splitlines()] == [
        {"name": "MaxCurrent", "number": 6, "motor": 2, "saved": 0, "live": 9}]
    # replaying the backup as a script puts it back too
    r = run_tmclsh("--port", pty, "-m", "TMCM-351", "--yes", "-f", str(path))
    assert r.returncode == 0, r.stderr
    r = run_tmclsh("--port", pty, "-m", "TMCM-351", "-c", f".diff {path} --exit-code")
    assert r.returncode == 0 and "no differences" in r.stdout, r.stdout + r.stderr
    # and the file replays on a fresh simulated module
    r = run_tmclsh("--sim", "TMCM-351", "--yes", "-f", str(path))
    assert r.returncode == 0, r.stderr


def test_restore_asks_first(pty_client, tmp_path, capsys):
    sim, client = pty_client("TMCM-1311", target=Recording("TMCM-1311"))
    s = shell(client)
    path = tmp_path / "b.tmcl"
    s.run_line(f".save {path}")
    s.run_line("SAP MaxCurrent, 0, 33")
    with pytest.raises(Abort, match="pass --yes"):
        s.run_line(f".restore {path}")
    assert client.value("GAP MaxCurrent, 0") == 33
    writes = [f for f in _frames(sim.received) if f[1] in (5, 9)]
    assert [tuple(f[1:4]) for f in writes] == [(5, 6, 0)]  # only the change typed above


def _frames(data: bytes) -> list[bytes]:
    return [bytes(data[i:i + 9]) for i in range(0, len(data) - len(data) % 9, 9)]


def test_save_over_an_existing_file_asks_at_the_prompt(pty_client, tmp_path, capsys):
    """The golden backup of the old module must not go with one wrong Enter."""
    sim, client = pty_client("TMCM-1311", target=Recording("TMCM-1311"))
    path = tmp_path / "golden.tmcl"
    path.write_text("// module: TMCM-1311\n// date: 2026-11-30 08:00:00 UTC\nSAP 4, 0, 7\n",
                    encoding="utf-8")
    golden = path.read_text(encoding="utf-8")
    asked: list[str] = []
    s = Session(client, Output(), interactive=True)
    s.ask = lambda q: asked.append(q) or False
    sim.received.clear()
    with pytest.raises(Abort, match="cancelled"):
        s.run_line(f".save {path}")
    assert asked == [f"{path} (a backup of a TMCM-1311, 2026-11-30 08:00:00 UTC) exists; "
                     "overwrite it?"]
    assert path.read_text(encoding="utf-8") == golden
    assert bytes(sim.received) == b""  # asked before anything was read
    s.ask = lambda q: asked.append(q) or True
    s.run_line(f".save {path}")
    assert len(asked) == 2 and path.read_text(encoding="utf-8") != golden
    asked.clear()
    s.run_line(f".save {tmp_path / 'new.tmcl'}")  # a new file: nothing to ask
    s.run_line(f".save {path} --yes")
    assert asked == []


def test_cli_save_over_an_existing_file_needs_yes(tmp_path, run_tmclsh):
    path = tmp_path / "golden.tmcl"
    path.write_text("// the old module\n", encoding="utf-8")
    for args in (("-c", f".save {path}"), ("-c", f".save {path} --program")):
        r = run_tmclsh("--sim", *args)
        assert r.returncode == 1, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and "add --yes" in r.stderr, r.stderr
        assert "another name" in r.stderr and path.read_text("utf-8") == "// the old module\n"
    assert not (tmp_path / "golden.program.tmcl").exists()
    r = run_tmclsh("--sim", "-c", f".save {path} -y")
    assert r.returncode == 0 and "SAP MaxCurrent" in path.read_text("utf-8"), r.stderr
    path.write_text("// the old module\n", encoding="utf-8")
    r = run_tmclsh("--sim", "--yes", "-c", f".save {path}")
    assert r.returncode == 0 and "SAP MaxCurrent" in path.read_text("utf-8"), r.stderr
    # the program file beside it counts as well
    r = run_tmclsh("--sim", "-c", f".save {tmp_path / 'other.tmcl'} --program")
    assert r.returncode == 0, r.stderr
    (tmp_path / "other.tmcl").unlink()
    r = run_tmclsh("--sim", "-c", f".save {tmp_path / 'other.tmcl'} --program")
    assert r.returncode == 1 and "other.program.tmcl exists" in r.stderr, r.stderr
    assert not (tmp_path / "other.tmcl").exists()


def test_store_after_restore(pty_client, tmp_path, capsys):
    sim, client = pty_client("TMCM-1311", target=Recording("TMCM-1311"))
    s = shell(client, json_mode=True, yes=True)
    path = tmp_path / "b.tmcl"
    s.run_line(f".save {path}")
    s.run_line("SAP MaxCurrent, 0, 33")
    s.run_line("SAP ChopperMode, 0, 1")  # RW: not storable
    sim.received.clear()
    capsys.readouterr()
    s.run_line(f".restore {path} --store")
    out = json_lines(capsys.readouterr().out)[0]
    assert out["stored"] == 1
    stores = [tuple(f[1:4]) for f in _frames(sim.received) if f[1] in (7, 11)]
    assert stores == [(7, 6, 0)]


def test_save_write_failure_is_one_line(pty_client, tmp_path):
    sim, client = pty_client("TMCM-1640")
    s = shell(client)
    missing = tmp_path / "no" / "such" / "b.tmcl"
    with pytest.raises(TmclError, match=rf"cannot write {re.escape(str(missing))}: no such "
                                        rf"folder {re.escape(str(missing.parent))}$"):
        s.run_line(f".save {missing}")
    # an existing backup is not half-overwritten when the save fails part-way
    good = tmp_path / "b.tmcl"
    good.write_text("old\n", encoding="utf-8")
    sim.faults.lose_next = 1000
    client.retries = 0
    client.timeout = 0.05
    with pytest.raises(TmclError):
        s.run_line(f".save {good}")
    assert good.read_text(encoding="utf-8") == "old\n"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_save_to_a_pipe_writes_into_it_and_leaves_it_a_pipe(pty_client, tmp_path):
    """A device or FIFO is written as it is: renaming a temporary file over it replaced the
    device node itself (``.save /dev/full`` as root left a regular file at /dev/full)."""
    _, client = pty_client("TMCM-1640")
    fifo = tmp_path / "backup.fifo"
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    shell(client).run_line(f".save {fifo}")
    reader.join(5)
    assert fifo.is_fifo()
    assert got and got[0].startswith(b"// tmclsh configuration backup of a TMCM-1640")
    assert [p.name for p in tmp_path.iterdir()] == ["backup.fifo"]  # no temporary left


def test_diff_of_a_file_without_end_is_refused_unread(pty_client, tmp_path):
    _, client = pty_client("TMCM-1640")
    huge = tmp_path / "huge.tmcl"
    with open(huge, "wb") as fh:
        fh.truncate(17 * 1024 * 1024)  # sparse: no disk used
    for line in (f".diff {huge}", f".restore {huge} --yes"):
        with pytest.raises(CloneError, match=r"huge.tmcl: backup larger than 16 MiB; not read"):
            shell(client, yes=True).run_line(line)


def test_save_program(pty_client, tmp_path, capsys):
    sim, client = pty_client("TMCM-1311")
    src = tmp_path / "p.tmcl"
    src.write_text("loop: MVP ABS, 0, 1000\n WAIT POS, 0, 0\n JA loop\n", encoding="utf-8")
    s = shell(client, json_mode=True, yes=True)
    s.run_line(f".upload {src}")
    capsys.readouterr()
    path = tmp_path / "b.tmcl"
    s.run_line(f".save {path} --program")
    out = json_lines(capsys.readouterr().out)[0]
    prog = tmp_path / "b.program.tmcl"
    assert out == {"saved": out["saved"], "link": 11, "file": str(path), "program": str(prog),
                   "instructions": 3}
    assert "// program: b.program.tmcl" in path.read_text(encoding="utf-8")
    text = prog.read_text(encoding="utf-8")
    assert "MVP ABS, 0, 1000" in text and "JA" in text


def test_one_request_per_parameter(pty_client, tmp_path):
    sim, client = pty_client("TMCM-1311", target=Recording("TMCM-1311"))
    client.version = "1311V111"  # known already: no 136 in the count
    shell(client).run_line(f".save {tmp_path / 'b.tmcl'}")
    frames = _frames(sim.received)
    slots = list(readable_slots(modules.load("TMCM-1311")))
    # one request per parameter, and one more where an answer was byte for byte the one
    # before it (it may have been a copy: Client._judge), the same frame again
    assert len(frames) == len(slots) + client.stats["judged"]
    assert client.stats["judged"] <= len(slots) // 10  # (GAPs and GGPs read in turn)
    assert {tuple(f[:4]) for f in frames} == {(1, 6 if k == "axis" else 10, n, i)
                                             for k, _, n, i in slots}


def test_numbers_only_module_compares_a_named_backup_by_number(pty_client, tmp_path, capsys):
    """A module without parameter data (generic mode) still diffs and restores a backup whose
    header names a known module: the names give the numbers, compared by number."""
    from tmclsh.tmcl.modules import Module

    sim, client = pty_client("TMCM-1311")
    path = tmp_path / "b.tmcl"
    shell(client).run_line(f".save {path}")
    bare = Module({"module": {"name": "generic", "motors": 1, "program_memory": 2048,
                              "firmware_id": 0, "version_string": ""}})
    client.module = bare
    s = shell(client, json_mode=True, yes=True)
    s.run_line("5 6, 0, 99")  # SAP 6 (MaxCurrent) as a raw command
    capsys.readouterr()
    s.run_line(f".diff {path}")
    assert json_lines(capsys.readouterr().out) == [
        {"name": None, "number": 6, "motor": 0, "saved": 0, "live": 99}]
    s.run_line(f".restore {path}")
    capsys.readouterr()
    s.run_line(f".diff {path} --exit-code")
    assert json_lines(capsys.readouterr().out) == []


def test_bench_save_runs(tmp_path):
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    p = subprocess.run([sys.executable, str(root / "scripts" / "bench.py"), "save", "--rounds",
                        "1", "--json"], capture_output=True, text=True, timeout=120, cwd=root)
    assert p.returncode == 0, p.stderr
    result = json.loads(p.stdout)
    assert result["transactions"] == len(list(readable_slots(modules.load("TMCM-1311"))))
    assert result["save_s"] > 0 and result["raw_s"] > 0 and "ratio" in result


def test_link_settings_are_left_alone_or_written_last_and_followed(pty_client, tmp_path,
                                                                    capsys):
    sim, client = pty_client("TMCM-1311", target=Recording("TMCM-1311"))
    s = shell(client, yes=True)
    path = tmp_path / "b.tmcl"
    s.run_line(f".save {path}")
    text = path.read_text(encoding="utf-8")
    assert re.search(r"^SGP SerialAddress, 0, 1\b", text, re.M)
    # a replacement module that answers at address 1, restored from a backup of address 5
    text = re.sub(r"^SGP SerialAddress, 0, 1\b", "SGP SerialAddress, 0, 5", text, flags=re.M)
    path.write_text(text, encoding="utf-8")
    s.run_line("SAP MaxCurrent, 0, 44")
    sim.received.clear()
    capsys.readouterr()
    s.run_line(f".restore {path}")  # the address is the module's own: left alone
    cap = capsys.readouterr()
    writes = [tuple(f[:4]) for f in _frames(sim.received) if f[1] in (5, 9)]
    assert writes == [(1, 5, 6, 0)]
    assert "left alone" in cap.out and "SerialAddress = 5" in cap.out
    s.run_line("SAP MaxCurrent, 0, 44")
    sim.received.clear()
    capsys.readouterr()
    s.run_line(f".restore {path} --with-link")
    cap = capsys.readouterr()
    sent = [tuple(f[:4]) for f in _frames(sim.received)]
    writes = [f for f in sent if f[1] in (5, 9)]
    assert writes == [(1, 5, 6, 0), (1, 9, 66, 0)]  # the address last
    assert sent[-1] == (5, 10, 66, 0)  # ... and read back where the module answers now
    said = cap.out + cap.err
    assert "answers at address 5 now" in said and "reconnect" not in said
    assert client.address == 5 and client.value("GAP MaxCurrent, 0") == 0


def test_save_from_independent_responder(responder, tmp_path):
    """The file holds what the module answered: values set in the responder, read by GAP/GGP
    frames only, come back in the file's SAP/SGP lines (unsigned ones as unsigned)."""
    mod = modules.load("TMCM-1640")
    for kind, p, number, index in readable_slots(mod):
        if p.writable and not p.state:
            v = (p.min or 0) + (number * 7 + index) % max(1, min((p.max or 255) - (p.min or 0), 200))
            responder.values[(number, index, kind == "global")] = v
    responder.values[(26, 0, False)] = -1  # I2tLimit, 0..4294967295: 0xFFFFFFFF on the wire
    client = LineClient(open_serial(responder.path), module="TMCM-1640", timeout=0.5, retries=0)
    client.version = "1640V100"
    try:
        shell(client).run_line(f".save {tmp_path / 'b.tmcl'}")
    finally:
        client.close()
    got = file_values(tmp_path / "b.tmcl", mod)
    want = {(("global" if g else "axis"), n, i): v for (n, i, g), v in responder.values.items()}
    want[("axis", 26, 0)] = 4294967295
    assert got == want
    assert {f[1] for f in responder.log} == {6, 10}
    # (one more read where an answer was the one before it, byte for byte: Client._judge)
    assert len(responder.log) == len(list(readable_slots(mod))) + client.stats["judged"]


def test_cli_backup_replayed_without_yes_is_refused_before_anything_is_written(
        responder, run_tmclsh, tmp_path):
    """A backup holds bank 0 global parameters, each asked before it writes the EEPROM; with
    -f and no --yes nobody can answer. Asked only at that line, the replay stopped halfway
    (the SAP lines before it written) and pointed at --keep-going, which fails every one of
    them the same way; refused whole, the module is as it was."""
    responder.version = "1311V111"
    path = tmp_path / "b.tmcl"
    r = run_tmclsh("--port", responder.path, "-m", "TMCM-1311", "-c", f".save {path}")
    assert r.returncode == 0, r.stderr
    lines = path.read_text("utf-8").splitlines()
    first_sgp = next(n for n, line in enumerate(lines, 1) if line.startswith("SGP "))
    responder.got.clear()
    r = run_tmclsh("--port", responder.path, "-m", "TMCM-1311", "-f", str(path))
    assert r.returncode == 2, r.stdout + r.stderr
    assert (f"{path}:{first_sgp}: SGP " in r.stderr and "writes the module's EEPROM, and "
            "nobody can answer here: replay the configuration backup with --yes" in r.stderr)
    assert "nothing was sent" in r.stderr and "--keep-going" not in r.stdout + r.stderr
    assert not [g for g in responder.got if g[0] in (5, 9)]  # not one SAP or SGP
    r = run_tmclsh("--port", responder.path, "-m", "TMCM-1311", "--yes", "-f", str(path))
    assert r.returncode == 0, r.stdout + r.stderr
    assert [g for g in responder.got if g[0] == 9]  # with --yes: written, the EEPROM's too
