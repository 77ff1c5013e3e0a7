"""Issue 23, section 5 ("smaller things seen on the way"), each tried as a user would: through
``tmclsh -c``/``-f`` against a module written from the manual's byte tables
(tests/responder.py, which imports nothing of tmclsh) or the simulator served on a pty.
"""

from __future__ import annotations

import json

import pytest

from responder import PtyModule

SAVE_REFUSED = "nothing saved"


# -- .save without parameter data -------------------------------------------------------------

def test_save_on_a_module_without_parameter_data_fails_and_says_what_to_do(tmp_path,
                                                                           run_tmclsh):
    """A module tmclsh has no data for (a TMCM-1161 here) was "saved" as a backup of 0
    parameters, exit 0: a file that restores nothing. Now refused, nothing read or written."""
    module = PtyModule(version="1161V130")
    try:
        backup = tmp_path / "b.tmcl"
        run_tmclsh("--port", module.path, "-c", ".echo connected")
        connecting = module.commands()  # what bring-up asks
        module.got.clear()
        p = run_tmclsh("--port", module.path, "-c", f".save {backup}")
        assert p.returncode != 0
        assert SAVE_REFUSED in p.stderr and "--module-file" in p.stderr
        assert not backup.exists()
        assert module.commands() == connecting  # nothing read for the backup
        p = run_tmclsh("--json", "--port", module.path, "-c", f".save {backup}")
        assert p.returncode != 0
        record = json.loads(p.stdout.splitlines()[-1])
        assert SAVE_REFUSED in record["error"]
    finally:
        module.close()


def test_save_in_generic_mode_names_the_modules_own_data(tmp_path, run_tmclsh):
    module = PtyModule(version="1311V111")
    try:
        backup = tmp_path / "b.tmcl"
        p = run_tmclsh("--port", module.path, "-m", "generic", "-c", f".save {backup}")
        assert p.returncode != 0 and not backup.exists()
        assert "'.module TMCM-1311'" in p.stderr and SAVE_REFUSED in p.stderr
        # what it says works
        p = run_tmclsh("--port", module.path, "-m", "generic", "-c",
                       f".module TMCM-1311; .save {backup}")
        assert p.returncode == 0, p.stderr
        assert "SAP " in backup.read_text()
    finally:
        module.close()


# -- .ascii-config on a module without GP 67 ----------------------------------------------------

def test_ascii_config_offers_nothing_the_module_lacks(run_tmclsh):
    """The TMCM-1640's data has no ASCII interface; a module that answers GGP 67 with 0 (as
    an unset parameter may read) was offered a GP 67 written to EEPROM. Now refused from the
    module's data, before anything is sent, with --yes too."""
    module = PtyModule(version="1640V210")
    try:
        for line in (".ascii-config startup=ascii", ".ascii-config"):
            module.got.clear()
            p = run_tmclsh("--port", module.path, "-y", "-c", line)
            assert p.returncode != 0
            assert "the TMCM-1640 has no ASCII interface" in p.stderr and "nothing sent" in \
                p.stderr
            assert not [g for g in module.got if g[1] == 67]  # neither GGP nor SGP 67
    finally:
        module.close()
    # the 1311 has it: shown, and offered in completion; the 1640 offers nothing
    from tmclsh.shell.completer import complete_arg
    from tmclsh.shell.render import Output
    from tmclsh.shell.session import Session
    import tmclsh

    for name, offered in (("TMCM-1311", True), ("TMCM-1640", False)):
        client = tmclsh.connect(sim=name, timeout=0.5)
        try:
            session = Session(client, Output())
            texts = [c.text for c in complete_arg(session, ".ascii-config", "")]
            assert ("startup=ascii" in texts) is offered
        finally:
            client.close()


# -- .diff --force across module types ------------------------------------------------------------

def test_diff_across_module_types_never_compares_different_units(tmp_path, run_tmclsh):
    """A TMCM-1311 backup (MaxPositioningSpeed 1234 pps) against a TMCM-1640 (3000 rpm): the
    parameter is skipped and the units named, never read, compared or written as a number."""
    backup = tmp_path / "s1311.tmcl"
    p = run_tmclsh("--sim", "TMCM-1311", "-y", "-c", f"SAP 4, 0, 1234; SAP 6, 0, 100; "
                   f".save {backup}")
    assert p.returncode == 0, p.stderr
    module = PtyModule(version="1640V210")
    module.values[(4, 0, False)] = 3000  # rpm
    try:
        p = run_tmclsh("--port", module.path, "-c", f".diff {backup} --force")
        assert p.returncode == 0, p.stderr
        said = p.stdout + p.stderr
        assert ("MaxPositioningSpeed (motor 0, line 17): units differ: pps there, rpm on the "
                "TMCM-1640") in said
        assert "MaxCurrent (motor 0, line 19): units differ: 1/255 of module max. current " \
               "there, mA on the TMCM-1640" in said
        rows = [ln for ln in p.stdout.splitlines() if "│" in ln]
        assert rows and not [r for r in rows if r.startswith(("MaxPositioningSpeed", "MaxCurr"))]
        assert not [g for g in module.got if g[:3] in ((6, 4, 0), (6, 6, 0))]  # never read
        p = run_tmclsh("--json", "--port", module.path, "-c", f".diff {backup} --force")
        records = [json.loads(line) for line in p.stdout.splitlines()]
        why = {r["skipped"].split()[0]: r["why"] for r in records if "skipped" in r}
        assert why["MaxPositioningSpeed"].startswith("units differ: pps there, rpm")
        assert not any(r.get("name") == "MaxPositioningSpeed" for r in records)
        module.got.clear()
        p = run_tmclsh("--port", module.path, "-y", "-c", f".restore {backup} --force")
        assert not [g for g in module.got if g[:3] in ((5, 4, 0), (5, 6, 0))]  # never written
        assert module.values[(4, 0, False)] == 3000
    finally:
        module.close()
