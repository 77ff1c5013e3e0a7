"""What scripts say when something is off (a backup that cannot be made, a module of another
type, a wait that times out, an extra operand), each tried as a user would: through
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
    from tmclsh.shell.repl.completer import complete_arg
    from tmclsh.shell.render import Output
    from tmclsh.shell.lang.session import Session
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
    module.values[(77, 0, True)] = 1  # AutoStartMode: a difference both modules can show
    try:
        p = run_tmclsh("--port", module.path, "-c", f".diff {backup} --force")
        assert p.returncode == 0, p.stderr
        said = p.stdout + p.stderr
        assert ("MaxPositioningSpeed (motor 0, line 19): units differ: pps there, rpm on the "
                "TMCM-1640") in said
        assert "MaxCurrent (motor 0, line 21): units differ: 1/255 of module max. current " \
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


# -- JSON of checks: the same record passed or failed; exit 3 a record too ----------------------

def test_check_records_are_uniform(run_tmclsh):
    """.expect passed and failed, .wait met and timed out: one record each, with "check",
    "passed" and the values read (a failed .expect had no "passed": false, a .wait none)."""
    module = PtyModule(version="1311V111")
    module.values[(4, 0, False)] = 1234
    try:
        p = run_tmclsh("--json", "--port", module.path, "--keep-going", "-c",
                       ".expect GAP 4, 0 == 1234\n.expect GAP 4, 0 > 2000\n"
                       ".wait GAP 4, 0 == 1234 --timeout 2\n"
                       ".wait GAP 4, 0 == 5 --timeout 0.3 --interval 0.05")
    finally:
        module.close()
    assert p.returncode == 1
    passed, failed, met, timed_out = (json.loads(line) for line in p.stdout.splitlines())
    for record, ok in ((passed, True), (failed, False), (met, True), (timed_out, False)):
        assert record["passed"] is ok and record["values"] == {"GAP 4, 0": 1234}
    assert passed["check"] == "GAP 4, 0 == 1234" and "error" not in passed
    assert failed["check"] == "GAP 4, 0 > 2000" and "expectation failed" in failed["error"]
    assert met["check"] == "GAP 4, 0 == 1234" and 0 <= met["elapsed"] < 2
    assert timed_out["timed_out"] is True and 0.3 <= timed_out["elapsed"] < 1.5
    assert 0 <= timed_out["read_at"] <= timed_out["elapsed"]
    assert "timed out after 0.3 s waiting for GAP 4, 0 == 5 (GAP 4, 0 is 1234)" \
        in timed_out["error"]


def test_the_exit_3_message_is_a_record_under_json(tmp_path, run_tmclsh):
    missing = str(tmp_path / "no-such-port")
    for args, line in ((("--json", "-c", "GAP 4, 0"), True),
                       (("--json", "--port", missing, "-c", "GAP 4, 0"), True),
                       (("--json", "--port", missing, "-f", "-"), True),
                       (("--json", "scan", "--port", missing), True)):  # (one envelope)
        p = run_tmclsh(*args, input="GAP 4, 0\n")
        assert p.returncode == 3
        (record,) = [json.loads(x) for x in p.stdout.splitlines()]
        assert record["exit"] == 3 and record["error"]
        assert ("line" in record) is line
        assert p.stderr.startswith("tmclsh: ") or p.stderr.startswith("nothing answered")
    p = run_tmclsh("--port", missing, "-c", "GAP 4, 0")  # without --json: a line on stderr
    assert p.returncode == 3 and p.stdout == "" and p.stderr.startswith("tmclsh: ")


# -- .wait timing out: what was waited for, the last value read or why none, and when -----------

class StopsAnswering(PtyModule):
    """A TMCM-1311 (tests/responder.py) that answers GAP 4 ``answers`` times, then never."""

    def __init__(self, answers: int, **kw):
        self.answers = answers
        super().__init__(version="1311V111", **kw)

    def answer(self, raw: bytes) -> bytes | None:
        if raw[1] == 6 and raw[2] == 4:
            if self.answers <= 0:
                self.got.append((6, 4, raw[3], 0))
                return None
            self.answers -= 1
        return super().answer(raw)


@pytest.mark.parametrize("answers", [0, 1])
def test_wait_timing_out_says_what_it_read_or_why_not(answers, run_tmclsh):
    """A read that got no answer ended the wait at once with "timed out after 3 s ... ()";
    now the wait polls on to its timeout and says the last value read and when, or that
    none could be read, and why."""
    module = StopsAnswering(answers)
    module.values[(4, 0, False)] = 777
    try:
        p = run_tmclsh("--json", "--port", module.path, "--timeout", "0.1", "--retries", "0",
                       "-c", ".wait GAP 4, 0 == 5 --timeout 1 --interval 0.05")
    finally:
        module.close()
    assert p.returncode == 1
    (record,) = [json.loads(x) for x in p.stdout.splitlines()]
    message = record["error"]
    assert not message.endswith("()") and "waiting for GAP 4, 0 == 5" in message
    assert record["elapsed"] >= 1.0  # it waited its time, polling
    assert len([g for g in module.got if g[:2] == (6, 4)]) >= 4
    assert "no reply to GAP" in record["read_error"]
    if answers:
        assert "(GAP 4, 0 is 777, read at 0.0" in message and "reads after it failed" in message
        assert record["values"] == {"GAP 4, 0": 777} and record["read_at"] < 0.2
    else:
        assert "(no value could be read: no reply to GAP" in message
        assert record["values"] is None


def test_wait_under_the_simulators_faults_never_ends_in_empty_brackets(make_pty_sim, capsys):
    """The simulator on a pty dropping and garbling replies at random (seeded): each timed-out
    wait names the condition and either a value read or why none could be."""
    import random

    from tmclsh.base.errors import TmclError
    from tmclsh.client.text import LineClient
    from tmclsh.link import open_serial
    from tmclsh.shell.render import Output
    from tmclsh.shell.lang.session import Session

    sim, path = make_pty_sim()
    client = LineClient(open_serial(path), module="TMCM-1311", timeout=0.1, retries=0)
    try:
        session = Session(client, Output(), yes=True)
        session.run_line("GAP 4, 0")
        sim.faults.rng = random.Random(23)
        sim.faults.rates = {"drop": 0.5, "garbage": 0.2, "corrupt": 0.1}
        messages = []
        for _ in range(6):
            with pytest.raises(TmclError) as exc:
                session.run_line(".wait GAP 4, 0 == 5 --timeout 0.4 --interval 0.02")
            messages.append(str(exc.value))
    finally:
        sim.faults.rates = {}
        client.close()
    for message in messages:
        assert message.startswith("timed out after 0.4 s waiting for GAP 4, 0 == 5 (")
        assert not message.endswith("()")
        assert "GAP 4, 0 is 51200" in message or "no value could be read: " in message


# -- an operand in a field the command does not use ---------------------------------------------

def test_an_extra_operand_is_refused_and_nothing_is_sent(tmp_path, run_tmclsh):
    """`GAP 4, 0, 5` sent GAP 4, 0 (the 5 dropped, or put in the unused value field) without a
    word; now one line naming the field, exit 2, and the module hears nothing of it."""
    module = PtyModule(version="1311V111")
    script = tmp_path / "s.tmcl"
    script.write_text("GAP 4, 0\nGAP 4, 0, 5\n")
    try:
        run_tmclsh("--port", module.path, "-c", ".echo connected")
        connecting = module.commands()
        for args in (("-c", "GAP 4, 0, 5"), ("-c", "GAP 4, 0; MST 0, 0, 5"),
                     ("-f", str(script))):
            module.got.clear()
            p = run_tmclsh("--port", module.path, *args)
            assert p.returncode == 2, p.stderr
            (line,) = [x for x in p.stderr.splitlines() if "too many operands" in x]
            assert "does not use its value field" in line
            assert module.commands() == connecting  # checked before anything was sent
        module.got.clear()
        p = run_tmclsh("--port", module.path, "-c", "GAP 4, 0, 0; 6 4, 0, 5")
        assert p.returncode == 0, p.stderr  # the manuals' form; the raw form as written
        # (a reply byte for byte the one before is asked again: it may be a late copy)
        assert {g for g in module.got if g[0] == 6} == {(6, 4, 0, 0), (6, 4, 0, 5)}
    finally:
        module.close()
