"""``tmclsh scan --save INVENTORY`` / ``--expect INVENTORY`` (issue 33): what should answer on
a line, and every way the line differs from it. The lines are tests/responder.py's modules
(written from the manuals, not the simulator) on one pty, and the simulator in its
bootloader; the engine (``tmclsh.ops.inventory``) is checked from Python too."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from responder import AsciiModeModule, Module, PtyModule, SharedLine, TwoAtOneAddress

from tmclsh.ops import inventory
from tmclsh.ops.scan import Found

SCAN = ["--timeout", "0.3"]  # (a busy machine: a long wait)
GAP, GGP, VERSION = 6, 10, 136


def entry(address: int, firmware: str = "1311V111", mode: str = "binary",
          extra: str = "") -> str:
    return (f'[[module]]\naddress = {address}\ntype = "TMCM-1311"\nfirmware = "{firmware}"\n'
            f'mode = "{mode}"\n{extra}\n')


@pytest.fixture
def troubled_line():
    """1: two modules; 2: one in its bootloader; 3: one in ASCII mode; 4: older firmware;
    5: as it should be; 6 (named by the inventory): nothing."""
    bus = SharedLine()
    TwoAtOneAddress(line=bus)
    boot = Module(version="1311B100", address=2, line=bus)
    AsciiModeModule(address=3, line=bus)
    old = Module(version="1311V100", address=4, line=bus)
    good = Module(version="1311V111", address=5, line=bus)
    yield bus, boot, old, good
    bus.close()


def test_expect_names_each_difference_and_fails(troubled_line, run_tmclsh, tmp_path):
    bus, boot, old, good = troubled_line
    inv = tmp_path / "line.toml"
    inv.write_text("".join(entry(a) for a in range(1, 7)))
    p = run_tmclsh("scan", "--port", bus.path, "--to", "6", *SCAN, "--expect", str(inv),
                   "--json")
    assert p.returncode == 1, p.stderr
    rows = [json.loads(line) for line in p.stdout.splitlines()]
    diffs = {(r["address"], r["difference"]) for r in rows if "difference" in r}
    assert diffs == {(1, "doubled"), (2, "bootloader"), (3, "mode"), (4, "firmware"),
                     (6, "missing")}, rows
    assert rows[-1] == {"inventory": str(inv), "match": False, "differences": 5}
    texts = {r["address"]: r["text"] for r in rows if "difference" in r}
    assert "two modules answer" in texts[1] and "in its bootloader" in texts[2]
    assert "in ASCII mode" in texts[3] and "1311V100" in texts[4]
    assert "nothing answered" in texts[6]
    # nothing but the scan's probe reached a module (no settings named: none read)
    assert set(old.commands()) == set(good.commands()) == set(boot.commands()) == {VERSION}
    # without --json: one line per difference, and the count
    p = run_tmclsh("scan", "--port", bus.path, "--to", "6", *SCAN, "--expect", str(inv))
    assert p.returncode == 1, p.stderr
    said = [ln for ln in p.stdout.splitlines() if ln.startswith("differs: ")]
    assert len(said) == 5 and p.stdout.splitlines()[-1] == f"5 differences from {inv}"


def test_an_inventory_saved_from_a_line_matches_it(run_tmclsh, tmp_path):
    bus = SharedLine()
    try:
        AsciiModeModule(address=3, line=bus)
        Module(version="1311V111", address=5, line=bus)
        Module(version="0351V103", address=7, line=bus)
        inv = tmp_path / "saved.toml"
        p = run_tmclsh("scan", "--port", bus.path, "--to", "8", *SCAN, "--ascii",
                       "--save", str(inv), "--json")
        assert p.returncode == 0, p.stderr
        rows = [json.loads(line) for line in p.stdout.splitlines()]
        assert [r["address"] for r in rows[:-1]] == [5, 7, 3]  # (the ASCII pass comes last)
        assert rows[-1] == {"saved": str(inv), "modules": 3}
        saved = inventory.read_inventory(inv)
        assert [(e.address, e.module, e.mode) for e in saved.modules] == [
            (3, "TMCM-1311", "ascii"), (5, "TMCM-1311", "binary"), (7, "TMCM-351", "binary")]
        # (no --ascii now: the inventory's silent addresses are asked in ASCII mode)
        p = run_tmclsh("scan", "--port", bus.path, "--to", "8", *SCAN, "--expect", str(inv))
        assert p.returncode == 0, p.stdout + p.stderr
        assert p.stdout.splitlines()[-1] == f"the line matches {inv} (3 modules)"
    finally:
        bus.close()


def test_settings_that_differ_from_the_backup_are_named(run_tmclsh, tmp_path):
    module = PtyModule(version="1311V111", address=1)
    try:
        module.values[(4, 0, False)] = 1000  # AP 4 as the backup says; AP 5 reads 0
        backup = tmp_path / "axis.tmcl"
        backup.write_text("// hand-written\nSAP 4, 0, 1000\nSAP 5, 0, 2000\n")
        inv = tmp_path / "one.toml"
        inv.write_text(entry(1, extra='backup = "axis.tmcl"'))  # (beside the inventory)
        p = run_tmclsh("scan", "--port", module.path, "--to", "2", *SCAN, "--expect",
                       str(inv), "--json")
        assert p.returncode == 1, p.stderr
        rows = [json.loads(line) for line in p.stdout.splitlines()]
        diff = next(r for r in rows if "difference" in r)
        assert diff["difference"] == "settings" and diff["address"] == 1
        assert [(s["number"], s["saved"], s["live"]) for s in diff["settings"]] == [
            (5, 2000, 0)]
        assert "address 1: 1 setting differs from " in diff["text"], diff["text"]
        # only the parameters the backup names were read (and nothing written)
        assert sorted({(c, t) for c, t, *_ in module.got if c != VERSION}) == [
            (GAP, 4), (GAP, 5)]
        module.values[(5, 0, False)] = 2000
        p = run_tmclsh("scan", "--port", module.path, "--to", "2", *SCAN, "--expect",
                       str(inv))
        assert p.returncode == 0, p.stdout + p.stderr
    finally:
        module.close()


def test_a_module_in_its_bootloader_on_the_simulator(make_pty_sim, run_tmclsh, tmp_path):
    _, path = make_pty_sim("TMCM-1311", bootloader=True)
    inv = tmp_path / "line.toml"
    inv.write_text(entry(1))
    p = run_tmclsh("scan", "--port", path, "--to", "1", *SCAN, "--expect", str(inv), "--json")
    assert p.returncode == 1, p.stderr
    rows = [json.loads(line) for line in p.stdout.splitlines()]
    assert [r["difference"] for r in rows if "difference" in r] == ["bootloader"]


def test_nothing_answering_is_exit_3(make_pty_sim, run_tmclsh, tmp_path):
    _, path = make_pty_sim("TMCM-1311", address=1)
    inv = tmp_path / "line.toml"
    inv.write_text(entry(3))
    p = run_tmclsh("scan", "--port", path, "--from", "2", "--to", "4", *SCAN,
                   "--expect", str(inv))
    assert p.returncode == 3 and "nothing answered" in p.stderr


BAD = {
    "not toml": ("[[module]\n", "not TOML"),
    "unknown key": ('[[module]]\naddress = 1\ntype = "TMCM-1311"\nfirmwre = "1"\n',
                    "unknown key(s) firmwre"),
    "no type": ("[[module]]\naddress = 1\n", "'type' is missing"),
    "unknown type": ('[[module]]\naddress = 1\ntype = "TMCM-9999"\n', "TMCM-9999"),
    "address twice": (entry(1) + entry(1), "named twice"),
    "address range": (entry(300), "address"),
    "both versions": (entry(1, extra='lowest = "1311V100"'), "not both"),
    "mode": (entry(1, mode="text"), 'mode is "binary" or "ascii"'),
    "empty": ("", "no [[module]] entries"),
    "outside the range": (entry(9), "outside the scanned range 1..5"),
    "backup in ascii mode": (entry(1, mode="ascii", extra='backup = "b.tmcl"'),
                             "binary mode only"),
    "CAN ids on a serial line": ('[[module]]\ncan_id = 1\ntype = "TMCM-1311"\n',
                                 "names CAN ids; this link is a serial line"),
}


@pytest.mark.parametrize("text,said", BAD.values(), ids=BAD.keys())
def test_a_bad_inventory_is_one_line_and_nothing_sent(run_tmclsh, tmp_path, text, said):
    module = PtyModule(version="1311V111", address=1)
    try:
        inv = tmp_path / "bad.toml"
        inv.write_text(text)
        p = run_tmclsh("scan", "--port", module.path, "--to", "5", "--expect", str(inv))
        assert p.returncode == 2, p.stderr
        assert said in p.stderr and len(p.stderr.splitlines()) == 1, p.stderr
        assert "Traceback" not in p.stderr and module.log == []
    finally:
        module.close()


def test_save_and_expect_together_is_a_usage_error(run_tmclsh, tmp_path):
    p = run_tmclsh("scan", "--sim", "--save", str(tmp_path / "a"), "--expect",
                   str(tmp_path / "b"))
    assert p.returncode == 2 and "give one of them" in p.stderr


def test_save_over_an_inventory_that_exists_is_refused_and_it_is_kept(run_tmclsh, tmp_path):
    inv = tmp_path / "line.toml"
    inv.write_text("# edited by hand\n")
    p = run_tmclsh("scan", "--sim", "--save", str(inv))
    assert p.returncode == 2 and f"{inv} exists: not replaced" in p.stderr, p.stderr
    assert len(p.stderr.splitlines()) == 1 and inv.read_text() == "# edited by hand\n"


def test_an_unbounded_inventory_is_refused(tmp_path):
    with pytest.raises(inventory.InventoryError, match="/dev/zero"):
        inventory.read_inventory("/dev/zero")


# -- the engine, from Python -----------------------------------------------------------

def test_compare_lowest_version_and_extra_modules():
    inv = inventory.parse_inventory(
        '[[module]]\naddress = 1\ntype = "TMCM-1311"\nlowest = "1.10"\n', Path("x.toml"))
    ok = Found(1, "TMCM-1311", "1311V111")
    assert inventory.compare(inv, [ok]).matches
    older = Found(1, "TMCM-1311", "1311V109")
    assert [d.kind for d in inventory.compare(inv, [older]).differences] == ["firmware"]
    extra = Found(2, None, "1161V130")
    check = inventory.compare(inv, [ok, extra])
    assert [(d.kind, d.address) for d in check.differences] == [("extra", 2)]
    other = Found(1, "TMCM-351", "0351V103")  # another type: its firmware is not compared
    assert [d.kind for d in inventory.compare(inv, [other]).differences] == ["type"]


def test_saved_text_reads_back_as_what_answered():
    found = [Found(1, "TMCM-1311", "1311V111"), Found(2, None, "1161V130", ascii=True),
             Found(3, "TMCM-1311", "1311B100", bootloader=True)]
    inv = inventory.parse_inventory(inventory.inventory_text(found, can=True), "s.toml")
    assert inv.ids == inventory.CAN_ID
    assert [(e.address, e.module, e.firmware, e.mode) for e in inv.modules] == [
        (1, "TMCM-1311", "1311V111", "binary"), (2, "1161", "1161V130", "ascii"),
        (3, "TMCM-1311", None, "binary")]
    # the module in its bootloader is still named by the check
    assert [d.kind for d in inventory.compare(inv, found).differences] == ["bootloader"]


def test_a_can_bus_inventory_names_can_ids(monkeypatch, capsys, tmp_path):
    """On CAN the inventory's numbers are CAN ids (``can_id``), saved and checked so."""
    import uuid

    from tmclsh.cli import main as cli
    from tmclsh.sim import Simulator
    from tmclsh.sim.serve import serve_can

    monkeypatch.setenv("TMCLSH_CONFIG", "/dev/null")
    channel = f"inv-{uuid.uuid4().hex[:8]}"
    sim = Simulator("TMCM-1311", 1)
    server = serve_can(sim, "virtual", channel)
    inv = tmp_path / "bus.toml"
    try:
        assert cli.main(["scan", "--can", f"virtual:{channel}", "--to", "3",
                         "--save", str(inv)]) == 0
        assert "can_id = 1" in inv.read_text()
        assert cli.main(["scan", "--can", f"virtual:{channel}", "--to", "3",
                         "--expect", str(inv)]) == 0
        inv.write_text(inv.read_text() + '[[module]]\ncan_id = 2\ntype = "TMCM-351"\n')
        capsys.readouterr()
        assert cli.main(["scan", "--can", f"virtual:{channel}", "--to", "3",
                         "--expect", str(inv), "--json"]) == 1
    finally:
        server.close()
        sim.close()
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(r["difference"], r["can_id"]) for r in rows if "difference" in r] == [
        ("missing", 2)]
