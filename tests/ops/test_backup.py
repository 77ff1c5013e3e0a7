"""A module's configuration from Python, without a shell (tmclsh/ops/backup.py): backup ->
file -> compare -> restore, on the simulator through ``tmclsh.connect`` and on a module
written from the manual (tests/responder.py). Nothing is printed; the results are data."""

from __future__ import annotations

from pathlib import Path

import pytest

from responder import PtyModule

import tmclsh
from tmclsh.client.text import LineClient
from tmclsh.link import open_serial
from tmclsh.ops import backup

SAP, SGP = 5, 9


def roundtrip(client, path: Path) -> backup.Backup:
    conf = backup.read_configuration(client)
    backup.write_backup(path, conf.text())
    return backup.read_backup(client, path)


def test_backup_file_compare_restore_from_python_on_the_simulator(tmp_path, capsys):
    c = tmclsh.connect(sim="TMCM-1311")
    try:
        path = tmp_path / "m.tmcl"
        conf = backup.read_configuration(c)
        speed = next(s for s in conf.restorable if s.name == "MaxPositioningSpeed")
        assert [s.name for s in conf.link] and all(s.param.link for s in conf.link)
        backup.write_backup(path, conf.text())
        assert path.read_text().startswith(backup.BACKUP_MARK + " TMCM-1311")
        saved = backup.read_backup(c, path)
        assert backup.compare(c, saved) == []
        # link identity is in the file, and left alone unless asked for
        assert {s.name for s in saved.left_alone} == {s.name for s in conf.link}
        c.execute(f"SAP MaxPositioningSpeed, 0, {speed.value + 1000}")
        diffs = backup.compare(c, saved)
        assert [(d.slot.name, d.live, d.slot.value) for d in diffs] == [
            ("MaxPositioningSpeed", speed.value + 1000, speed.value)]
        done, link_changed = backup.restore(c, diffs)
        assert [(w.diff.slot.name, w.error, w.read_back) for w in done] == [
            ("MaxPositioningSpeed", None, speed.value)] and link_changed == []
        assert backup.compare(c, saved) == []
    finally:
        c.close()
    assert capsys.readouterr().out == ""


@pytest.fixture
def module():
    m = PtyModule(version="1311V111")
    yield m
    m.close()


def test_restore_onto_a_module_from_the_manual_leaves_its_link_identity_alone(module,
                                                                              tmp_path):
    """Restored onto another module: the values differ, its address and baud rate are its
    own (the backup's are not written without with_link)."""
    c = LineClient(open_serial(module.path), timeout=0.5, retries=0)
    c.identify()
    try:
        path = tmp_path / "m.tmcl"
        module.values[(4, 0, False)] = 1234  # MaxPositioningSpeed
        module.values[(65, 0, True)] = 3  # RS485BaudRate (link identity)
        saved = roundtrip(c, path)
        assert saved.slots[("axis", 4, 0)].value == 1234
        assert ("RS485BaudRate", 3) in [(s.name, s.value) for s in saved.left_alone]
        module.values[(4, 0, False)] = 99
        module.values[(65, 0, True)] = 0
        module.got.clear()
        diffs = backup.compare(c, saved)
        assert [(d.slot.name, d.live) for d in diffs] == [("MaxPositioningSpeed", 99)]
        done, _ = backup.restore(c, diffs)
        assert [w.error for w in done] == [None]
        assert module.values[(4, 0, False)] == 1234 and module.values[(65, 0, True)] == 0
        assert [(g[0], g[1]) for g in module.got if g[0] in (SAP, SGP)] == [(SAP, 4)]
    finally:
        c.close()


def test_a_line_that_is_no_backup_line_is_refused_before_anything_is_sent(module, tmp_path):
    c = LineClient(open_serial(module.path), timeout=0.5, retries=0)
    c.identify()
    try:
        path = tmp_path / "bad.tmcl"
        path.write_text("SAP MaxPositioningSpeed, 0, 1000\nMVP ABS, 0, 5\n")
        module.got.clear()
        with pytest.raises(backup.BackupFileError, match=r"bad.tmcl:2: MVP is not SAP or SGP"):
            backup.read_backup(c, path)
        assert module.got == []
    finally:
        c.close()


def test_what_restore_returns_is_stored_as_it_is_and_only_what_was_restored(module, tmp_path):
    """``tmclsh.store_backup`` (exported; README's ``backup.store`` was private) takes the
    restore's result whole: a value the module refused is not stored (STAP would store
    whatever it holds instead)."""
    STAP = 7
    c = tmclsh.connect(port=module.path, timeout=0.5, retries=0)
    try:
        module.values[(4, 0, False)] = 1234  # MaxPositioningSpeed
        module.values[(5, 0, False)] = 4321  # MaxAcceleration
        saved = roundtrip(c, tmp_path / "m.tmcl")
        module.values[(4, 0, False)] = module.values[(5, 0, False)] = 99
        module.refuse.add((SAP, 5, 0))
        done, link_changed = tmclsh.restore_backup(c, tmclsh.compare_backup(c, saved))
        assert sorted((w.diff.slot.name, w.error is None) for w in done) == [
            ("MaxAcceleration", False), ("MaxPositioningSpeed", True)]
        module.got.clear()
        assert tmclsh.store_backup(c, done, link_changed) == 1
        assert [g[:3] for g in module.got if g[0] == STAP] == [(STAP, 4, 0)]
    finally:
        c.close()


def test_another_modules_backup_read_from_python_names_the_argument_not_a_shell_command(
        tmp_path):
    one, other = tmclsh.connect(sim="TMCM-1311"), tmclsh.connect(sim="TMCM-351")
    try:
        path = tmp_path / "m.tmcl"
        backup.write_backup(path, backup.read_configuration(one).text())
        with pytest.raises(backup.BackupFileError) as exc:
            backup.read_backup(other, path)
        assert "read_backup(..., force=True)" in str(exc.value)
        assert ".restore" not in str(exc.value)
        assert backup.read_backup(other, path, force=True).skipped  # by name, as it says
    finally:
        one.close()
        other.close()
