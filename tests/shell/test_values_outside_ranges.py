"""The module has the last word on what it holds (issue 23, part 1), against a module written
from the manual's byte tables (tests/responder.py: it stores whatever SAP/SGP send, as a
freshly flashed or differently configured module may hold values its manual does not list).

* A reply is shown as it carries its value (signed), with a note when the value lies outside
  the manual's range, and every reader (the result line, ``${...}``, ``.expect``, JSON, .save)
  uses that same value.
* A backup .save writes is always comparable and restorable: values outside the manual's
  ranges are said once at save time and written back by .restore as the module held them; a
  hand-edited value outside the range is refused unless forced, every refused line in one
  message.
* ``!`` before a TMCL line sends its value as typed, whatever the data says: the module's
  answer decides.
"""

from __future__ import annotations

import json
import re

import pytest

from responder import PtyModule

from tmclsh.base.errors import TmclError
from tmclsh.client.text import LineClient
from tmclsh.link import open_serial
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session

SAP, GAP, SGP = 5, 6, 9

# values a TMCM-1311 holds that its manual does not allow (type, motor, global)
HELD = {(4, 0, False): -5,        # MaxPositioningSpeed, 0..327679999
        (136, 0, False): 0,       # StandstillErrorGain, 10..50
        (140, 0, False): 12,      # MicrostepResolution, 0..8
        (214, 0, False): 0}       # PowerDownDelay, 1..65535


@pytest.fixture
def module():
    m = PtyModule(version="1311V111")
    m.values.update(HELD)
    yield m
    m.close()


def session_on(m, *, json_mode: bool = False, yes: bool = True) -> Session:
    client = LineClient(open_serial(m.path), timeout=0.5, retries=0)
    client.identify()
    return Session(client, Output(json_mode=json_mode), yes=yes)


def test_a_negative_value_is_shown_as_the_module_holds_it(module, capsys):
    s = session_on(module)
    try:
        s.run_line("GAP 4, 0")
        s.run_line("GAP MicrostepResolution, 0")
        s.run_line(".echo speed ${GAP 4, 0}")
        s.run_line(".expect GAP 4, 0 < 0")
        out = capsys.readouterr().out.splitlines()
    finally:
        s.client.close()
    assert out[0] == ("MaxPositioningSpeed = -5 pps (outside the manual's range "
                      "0..327679999)")
    assert out[1].startswith("MicrostepResolution = 12") and "outside the manual's range 0..8" \
        in out[1]
    assert out[2] == "speed -5" and "passed" in out[3]


def test_json_says_the_value_and_the_range_it_lies_outside(module, capsys):
    s = session_on(module, json_mode=True)
    try:
        s.run_line("GAP 4, 0")
        s.run_line("GAP 6, 0")  # (0: inside the range, nothing more said)
    finally:
        s.client.close()
    first, second = (json.loads(line) for line in capsys.readouterr().out.splitlines())
    assert first["reply"] == -5 and first["outside_range"] == "0..327679999"
    assert "outside_range" not in second


def test_a_backup_with_values_outside_the_ranges_is_compared_and_restored(module, tmp_path,
                                                                          capsys):
    s = session_on(module)
    path = tmp_path / "b.tmcl"
    try:
        s.run_line(f".save {path}")
        said = capsys.readouterr()
        text = path.read_text(encoding="utf-8")
        assert "!SAP MaxPositioningSpeed, 0, -5" in text and "!SAP MicrostepResolution, 0, 12" \
            in text
        # said briefly, once; every one of them named in the file
        assert re.search(r"; \d+ outside the manual's ranges, marked !",
                         " ".join((said.out + said.err).split()))
        head = [line for line in text.splitlines() if "lines start with !" in line]
        assert len(head) == 1 and all(name in head[0] for name in (
            "MaxPositioningSpeed", "StandstillErrorGain", "MicrostepResolution",
            "PowerDownDelay"))
        s.run_line("SAP 4, 0, 1000")  # the change made after the save
        s.run_line(f".diff {path}")
        assert "MaxPositioningSpeed" in capsys.readouterr().out
        s.run_line(f".restore {path}")
        restored = capsys.readouterr()
        assert module.values[(4, 0, False)] == -5  # back to what the module held
        assert "outside the manual's ranges, as the module took them" in restored.err
    finally:
        s.client.close()


def test_the_note_on_values_outside_the_ranges_is_said_once_per_run(module, tmp_path,
                                                                    capsys, monkeypatch):
    """Issue 35: every unit's .save printed a four-line note; on fresh modules these are
    unset defaults. One short note per run, a count on each save, the details in the file."""
    from tmclsh.shell.features import clone

    monkeypatch.setattr(clone, "_SAID", set())
    s = session_on(module)
    try:
        s.run_line(f".save {tmp_path / 'one.tmcl'}")
        first = capsys.readouterr()
        s.run_line(f".save {tmp_path / 'two.tmcl'}")
        second = capsys.readouterr()
    finally:
        s.client.close()
    said = " ".join((first.out + first.err).split())  # (as one line: rich wraps at 80)
    assert said.count("unset default") == 1 and said.count("outside the manual") == 2, said
    again = " ".join((second.out + second.err).split())
    assert again.startswith("saved ") and again.count("saved ") == 1, again
    assert re.search(r"; \d+ outside the manual's ranges, marked !$", again), again


def test_hand_edited_values_outside_the_ranges_are_all_named_then_forced(module, tmp_path):
    s = session_on(module)
    path = tmp_path / "edited.tmcl"
    path.write_text("SAP MaxCurrent, 0, 999\nSAP 4, 0, 1000\nSAP MicrostepResolution, 0, 9\n",
                    encoding="utf-8")
    try:
        module.got.clear()
        with pytest.raises(TmclError) as exc:
            s.run_line(f".restore {path}")
        message = str(exc.value)
        assert f"{path}:1:" in message and f"{path}:3:" in message  # both, in one message
        assert "2 lines refused, nothing sent" in message
        assert not [g for g in module.got if g[0] == SAP]
        s.run_line(f".restore {path} --force")  # on purpose: the module decides
        assert module.values[(6, 0, False)] == 999 and module.values[(140, 0, False)] == 9
    finally:
        s.client.close()


def test_the_override_sends_what_the_data_refuses_and_the_module_decides(module, capsys):
    s = session_on(module)
    try:
        module.got.clear()
        with pytest.raises(TmclError, match="out of range"):
            s.run_line("SAP MicrostepResolution, 0, 12")
        assert module.got == []  # nothing sent
        s.run_line("!SAP MicrostepResolution, 0, 12")
        assert module.values[(140, 0, False)] == 12
        assert "MicrostepResolution set to 12" in capsys.readouterr().out
        module.refuse.add((SAP, 140, 0))  # a firmware that does not take it after all
        with pytest.raises(TmclError):
            s.run_line("! SAP 140, 0, 13")
        assert "error 4: invalid value" in capsys.readouterr().out  # the module's refusal
    finally:
        s.client.close()


def test_the_override_in_a_script_and_in_c(module, tmp_path, run_tmclsh):
    script = tmp_path / "s.tmcl"
    script.write_text("!SAP 140, 0, 11\nGAP 140, 0\n", encoding="utf-8")
    p = run_tmclsh("--port", module.path, "-f", str(script))
    assert p.returncode == 0, p.stderr
    assert "MicrostepResolution = 11" in p.stdout
    p = run_tmclsh("--port", module.path, "-c", "!SAP 136, 0, 3; GAP 136, 0")
    assert p.returncode == 0, p.stderr
    assert "StandstillErrorGain = 3 (outside the manual's range 10..50)" in p.stdout


def test_replaying_a_backup_that_stops_points_to_keep_going_and_restore(module, tmp_path,
                                                                        run_tmclsh):
    """Issue 35: a backup holding values outside the manual's ranges, replayed with -f on a
    stricter module (the simulator refuses them), stopped at the first refused !SAP without
    a word on --keep-going or .restore; another module's backup stopped at an unknown
    parameter without saying whose backup it is."""
    s = session_on(module)
    path = tmp_path / "fresh.tmcl"
    try:
        s.run_line(f".save {path}")
    finally:
        s.client.close()
    p = run_tmclsh("--sim", "TMCM-1311", "-f", str(path), "--yes")
    assert p.returncode == 1 and "status 4" in p.stderr
    said = " ".join((p.stdout + p.stderr).split())
    assert "--keep-going replays the rest" in said and f".restore {path}" in said
    p = run_tmclsh("--sim", "TMCM-1311", "-f", str(path), "--yes", "--keep-going")
    assert "--keep-going replays" not in p.stdout + p.stderr
    p = run_tmclsh("--sim", "TMCM-1640", "-f", str(path), "--yes")
    assert p.returncode == 2 and "unknown axis parameter" in p.stderr
    said = " ".join((p.stdout + p.stderr).split())
    assert f"is a backup of a TMCM-1311, not of this TMCM-1640: .restore {path} --force" in said
