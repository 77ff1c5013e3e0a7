"""Replacing a module in the field (tmclsh.ops.replace, tmclsh replace), through real bytes
against modules written from the manuals (tests/fieldmodule.py: parameters kept as given,
outside the manual's ranges too, a stored program, the bootloader of issue 24's table):
the new module ends equal on every readable setting, runs the old firmware version and
holds the same program, as read by raw pyserial; the old module hears only reads; a run
interrupted during a step leaves both modules where the report says, and the command it
names completes the job."""

from __future__ import annotations

import _thread
import os
import re
import shlex
import signal
import struct
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import serial

from bootmodel import START, hex_image
from fieldmodule import FieldModule
from tmclsh.ops.backup import readable_slots
from tmclsh.ops.replace import DONE, FAILED, NOT_RUN, SKIPPED, STEPS, STOPPED, Replacement
from tmclsh.tmcl import modules as moddb
from tmclsh.sim.boot import Bootloader
from tmclsh.tmcl.bootloader import image_from_hex

START_SIM = Bootloader.START
TMCLSH = str(Path(sys.executable).with_name("tmclsh"))
# what reading a module sends: 136 (version), GAP, GGP, 134 (program memory), 135 (status)
READS = {136, 6, 10, 134, 135}
# SAP 4, 0, 51200; WAIT TICKS, 0, 100; MVP ABS, 0, 12800; WAIT TICKS, 0, 100; JA 1
PROGRAM = [(5, 4, 0, 51200), (27, 0, 0, 100), (4, 0, 0, 12800), (27, 0, 0, 100), (22, 0, 0, 1)]


def outside_values(module) -> dict[tuple[str, int, int], int]:
    """A value beyond the manual's range for some writable settings (link identity aside)."""
    out = {}
    for kind, p, number, index in readable_slots(module):
        if (p.writable and not p.state and not p.link and p.max is not None
                and p.max < 2**31 - 1 and len(out) < 6 and p.count == 1):
            out[(kind, number, index)] = p.max + 7
    assert len(out) >= 3
    return out


def old_module(version: str = "1311V110", program=PROGRAM) -> FieldModule:
    module = FieldModule(version)
    mod = moddb.load("TMCM-1311")
    module.values.update(outside_values(mod))
    for at, ins in enumerate(program):
        module.stored[at] = ins
    return module


def image(version: str = "1311V110"):
    return image_from_hex(hex_image(version, 5000, START), f"{version}.hex")


def replace(old: FieldModule, new: FieldModule, **kw):
    steps = []
    r = Replacement({"port": old.path, "timeout": 0.5}, {"port": new.path, "timeout": 0.5},
                    on_step=steps.append, **kw)
    return r, steps


def raw(path: str, cmd: int, typ: int, motor: int, value: int = 0) -> bytes:
    """One request by hand with pyserial (no tmclsh code): the nine reply bytes."""
    body = struct.pack(">BBBBi", 1, cmd, typ, motor, value)
    with serial.Serial(path, 9600, timeout=2) as port:
        port.write(body + bytes([sum(body) & 0xFF]))
        return port.read(9)


def settings_read_raw(path: str) -> dict:
    """Every readable setting of a TMCM-1311, link identity aside, read with pyserial."""
    out = {}
    for kind, p, number, index in readable_slots(moddb.load("TMCM-1311")):
        if p.link or p.state or not p.writable:
            continue
        got = raw(path, 6 if kind == "axis" else 10, number, index)
        out[(kind, number, index)] = struct.unpack(">i", got[4:8])[0]
    return out


def program_read_raw(path: str, count: int) -> list[tuple[int, int, int, int]]:
    out = []
    for at in range(count):
        got = raw(path, 134, 0, 0, at)
        out.append((got[1], got[2], got[3], struct.unpack(">i", got[4:8])[0]))
    return out


def version_read_raw(path: str) -> str:
    body = bytes([1, 136, 0, 0, 0, 0, 0, 0])
    with serial.Serial(path, 9600, timeout=2) as port:
        port.write(body + bytes([sum(body) & 0xFF]))
        return port.read(9)[1:].decode("ascii")


def assert_replaced(old: FieldModule, new: FieldModule) -> None:
    """The independent read: raw pyserial, against the old module's own answers."""
    assert version_read_raw(new.path) == "1311V110"
    want = settings_read_raw(old.path)
    assert settings_read_raw(new.path) == want
    outside = outside_values(moddb.load("TMCM-1311"))
    assert all(want[key] == value for key, value in outside.items())  # (as the old held them)
    assert program_read_raw(new.path, len(PROGRAM) + 1) == list(PROGRAM) + [(0, 0, 0, 0)]


def only_read(old: FieldModule) -> None:
    assert set(old.commands()) <= READS, sorted(set(old.commands()) - READS)


@pytest.fixture
def modules():
    made = []

    def make(*args, **kw):
        m = old_module(*args, **kw) if not made else FieldModule(*args, **kw)
        made.append(m)
        return m

    yield make
    for m in made:
        m.close()


def test_replace_onto_a_new_module_with_outside_values_older_firmware_and_a_program(modules):
    old, new = modules(), modules("1311V111")
    held = dict(old.values)
    r, steps = replace(old, new, image=image())
    report = r.run()
    assert report.ok, report.to_json()
    assert [o.step for o in report.steps] == list(STEPS)
    assert [o.state for o in report.steps] == [DONE] * 5
    assert "outside the manual's ranges" in report.steps[2].text
    assert_replaced(old, new)
    # the values outside the ranges, as the old module held them
    for key, value in outside_values(moddb.load("TMCM-1311")).items():
        assert new.values[key] == value
    only_read(old)
    assert old.values == held and not old.in_bootloader
    # link identity stays the new module's: no SGP 66 (address) reached it
    assert not any(c == 9 and t == 66 for c, t, *_ in new.heard)


def test_without_the_image_the_firmware_step_names_it_and_nothing_is_written(modules):
    old, new = modules(), modules("1311V111")
    r, steps = replace(old, new)
    report = r.run()
    assert [o.state for o in report.steps] == [DONE, FAILED, NOT_RUN, NOT_RUN, NOT_RUN]
    assert "1311V110" in report.steps[1].text and "--firmware" in report.steps[1].text
    assert report.steps[1].data["needed"] == "1311V110"
    assert set(new.commands()) <= READS  # the new module was only read too
    only_read(old)


def test_an_image_of_another_version_is_refused_before_anything_is_written(modules):
    old, new = modules(), modules("1311V111")
    report = replace(old, new, image=image("1311V112"))[0].run()
    assert report.steps[1].state == FAILED and "1311V112" in report.steps[1].text
    assert set(new.commands()) <= READS and new.erases == 0


def test_another_module_type_is_refused_unless_forced(modules):
    old, new = modules(), modules("1640V210")
    report = replace(old, new, image=image())[0].run()
    assert report.steps[0].state == FAILED and "TMCM-1640" in report.steps[0].text
    assert set(new.commands()) <= READS
    only_read(old)


def _interrupt_at(module: FieldModule, command: int, count: int) -> None:
    """Ctrl-C in tmclsh's thread when ``module`` hears ``command`` the ``count``th time."""
    seen = []

    def hook(m):
        seen.append(1)
        if len(seen) == count:
            _thread.interrupt_main()

    module.hooks[command] = hook


@pytest.mark.parametrize("step,command,count", [
    ("firmware", 201, 40),  # writing the image
    ("configuration", 5, 3),  # writing the settings
    ("program", 132, 1),  # starting the upload (the frames follow)
])
def test_interrupted_during_a_step_the_same_run_again_completes_it(modules, step, command,
                                                                   count):
    old, new = modules(), modules("1311V111")
    _interrupt_at(new, command, count)
    r, steps = replace(old, new, image=image())
    with pytest.raises(KeyboardInterrupt):
        r.run()
    states = {o.step: o.state for o in r.report.steps}
    assert states[step] == STOPPED, r.report.to_json()
    texts = {o.step: o.text for o in r.report.steps}
    assert texts[step] == "interrupted (Ctrl-C) during this step"
    assert r.report.situation.startswith("the old module was only read")
    new.hooks.clear()
    report = replace(old, new, image=image())[0].run()
    assert report.ok, report.to_json()
    done = {o.step: o.state for o in report.steps}
    if step != "firmware":
        assert done["firmware"] == SKIPPED  # it runs the old version already
    assert_replaced(old, new)
    only_read(old)


def test_a_link_lost_mid_upload_stops_the_step_and_the_same_run_completes_it(modules):
    old, new = modules(), modules("1311V111")
    frames = []

    def pull_the_cable(m):
        frames.append(1)
        if len(frames) == 2:
            m.silent = True

    new.hooks[27] = pull_the_cable  # (the program's WAIT frames, while they are stored)
    report = replace(old, new, image=image())[0].run()
    assert report.steps[3].state == STOPPED, report.to_json()
    assert "written" in report.situation or "unchanged" in report.situation
    new.hooks.clear()
    new.silent = False
    new.downloading = False  # (a power cycle: the technician plugs it in again)
    report = replace(old, new, image=image())[0].run()
    assert report.ok, report.to_json()
    assert_replaced(old, new)


# -- the command line -------------------------------------------------------------------------

def _run(args: list[str], **kw) -> subprocess.CompletedProcess:
    return subprocess.run([TMCLSH, *args], capture_output=True, text=True, timeout=300,
                          stdin=subprocess.DEVNULL, **kw)


# where a fresh run is in each step, by what the new module hears: identify reads GGP once,
# the firmware step writes the image (201), the configuration step writes settings (SAP), the
# program step starts the upload (132), verify reads every setting again (its first GGP is
# the 82nd the new module hears: 1 identify, 2 firmware, 78 configuration)
KILL_AT = [("identify", 10, 1), ("firmware", 201, 40), ("configuration", 5, 3),
           ("program", 132, 1), ("verify", 10, 82)]


# what each step stopped there says of the new module
SITUATION = {"identify": "new module: nothing was written to the new module",
             "firmware": "new module: ",
             # (two written, the third sent as the signal came: it said "no setting")
             "configuration": "new module: 3 settings written to the new module, the last "
                              "as it was stopped (it may not have been taken); the rest as "
                              "they were",
             # (132 answered once the signal landed: download mode begun, nothing stored)
             "program": "new module: program memory: nothing was written; the program memory "
                        "is unchanged",
             "verify": "new module: written as the steps above say"}


@pytest.mark.parametrize("step,command,count", KILL_AT, ids=[k[0] for k in KILL_AT])
def test_command_line_killed_during_a_step_names_the_command_that_completes_it(modules,
                                                                            tmp_path, step,
                                                                            command, count):
    from conftest import delivered

    old, new = modules(), modules("1311V111")
    hexfile = tmp_path / "1311V110.hex"
    hexfile.write_text(hex_image("1311V110", 5000, START))
    args = ["replace", "--from", old.path, "--to", new.path, "--firmware", str(hexfile),
            "--yes", "--timeout", "0.5"]
    proc = subprocess.Popen([TMCLSH, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, text=True)
    sent = threading.Event()
    heard = []

    def kill(m):  # SIGTERM during the step; the module's reply waits until it has landed
        heard.append(1)
        if len(heard) == count and not sent.is_set():
            sent.set()
            os.kill(proc.pid, signal.SIGTERM)
            delivered(proc.pid, signal.SIGTERM)

    new.hooks[command] = kill
    out, err = proc.communicate(timeout=300)
    assert sent.is_set() and proc.returncode == 128 + signal.SIGTERM, err
    assert re.search(rf"^{step}\s+stopped", out, re.M), out
    assert "the old module was only read" in err
    # which signal stopped which step, in every command's words (it said "stopped by a
    # signal"), and what the step had done to the new module
    assert f"{step}: stopped: terminated (SIGTERM) during this step" in err, err
    assert SITUATION[step] in err, err
    command = re.search(r"to complete the replacement, run: (.*)$", err, re.M).group(1)
    words = shlex.split(command)
    assert words[0] == "tmclsh" and sorted(words[1:]) == sorted(args)  # the same command
    new.hooks.clear()
    done = _run(words[1:])
    assert done.returncode == 0, done.stderr
    assert "replaced:" in done.stdout and re.search(r"^verify\s+done", done.stdout, re.M)
    assert_replaced(old, new)
    only_read(old)


def test_command_line_json_report_and_exit_statuses(modules, tmp_path):
    old, new = modules(), modules("1311V111")
    got = _run(["replace", "--from", old.path, "--to", new.path, "--yes", "--json",
                "--timeout", "0.5"])
    assert got.returncode == 1
    import json

    obj = json.loads(got.stdout)
    assert obj["replace"] == "incomplete" and obj["exit"] == 1
    assert [s["outcome"] for s in obj["steps"]] == [DONE, FAILED, NOT_RUN, NOT_RUN, NOT_RUN]
    assert "--firmware IMAGE.hex" in obj["resume"]
    # no module at --to: exit 3, a one-line error
    gone = _run(["replace", "--from", old.path, "--to", str(tmp_path / "nothing"), "--yes",
                 "--timeout", "0.2"])
    assert gone.returncode == 3 and "Traceback" not in gone.stderr
    assert len(gone.stderr.strip().splitlines()) == 1
    # nobody to answer the question: refused before anything is sent
    ask = _run(["replace", "--from", old.path, "--to", new.path])
    assert ask.returncode == 2 and "--yes" in ask.stderr
    only_read(old)


# -- against the simulator: a new module left in its bootloader, an old one's backup ---------

def sim_old(make_pty_sim):
    """A simulated old module: an older firmware, settings changed, a stored program."""
    import tmclsh
    from tmclsh.ops import program
    from tmclsh.tmcl import asm
    from tmclsh.tmcl.frames import Request

    sim, path = make_pty_sim()
    sim.version_string, sim.firmware_version = "1311V110", 110
    with tmclsh.connect(port=path, timeout=0.5) as c:
        c.request(Request(1, 5, 4, 0, 1234))  # SAP 4, 0, 1234
        c.request(Request(1, 5, 6, 0, 100))  # SAP 6, 0, 100
        program.upload(c, asm.assemble("SAP 4, 0, 500\nWAIT TICKS, 0, 10\nJA 0\n",
                                       c.require_module()))
    return sim, path


def test_onto_a_simulated_module_left_in_its_bootloader(make_pty_sim):
    from tmclsh.sim.boot import Bootloader

    old, old_path = sim_old(make_pty_sim)
    new, new_path = make_pty_sim(bootloader=True)
    img = image_from_hex(hex_image("1311V110", 20000, Bootloader.START), "1311V110.hex")
    report = Replacement({"port": old_path, "timeout": 0.5},
                         {"port": new_path, "timeout": 0.5}, image=img).run()
    assert report.ok, report.to_json()
    assert "bootloader" in report.steps[0].text and report.steps[1].state == DONE
    assert not new.in_bootloader and new.version_string == "1311V110"
    # a second tmclsh process reads the new module: the same settings and program
    gap = [_run(["--port", p, "-c", "GAP 4, 0; GAP 6, 0"]).stdout for p in (old_path, new_path)]
    assert gap[0] == gap[1] and "1234" in gap[1]
    assert [i.to_bytes() for i in new.vm.memory[:3]] == [i.to_bytes() for i in old.vm.memory[:3]]


def test_from_a_backup_with_its_program(make_pty_sim, tmp_path):
    import tmclsh
    from tmclsh.ops import backup, program
    from tmclsh.tmcl import asm

    old, old_path = sim_old(make_pty_sim)
    new, new_path = make_pty_sim()
    with tmclsh.connect(port=old_path, timeout=0.5) as c:
        conf = backup.read_configuration(c)
        image_ = program.read_program(c)
        (tmp_path / "m.program.tmcl").write_text(asm.disassemble(image_, c.require_module()))
        backup.write_backup(tmp_path / "m.tmcl", conf.text("m.program.tmcl"))
    old.close()  # gone: the backup is all there is
    got = _run(["replace", "--from", str(tmp_path / "m.tmcl"), "--to", new_path, "--yes"])
    # the backup says 1311V110, the new module runs 1311V111: the image is asked for
    assert got.returncode == 1 and "1311V110" in got.stdout
    # no old module was read, only its backup: where things stand says so
    assert f"the old module's backup {tmp_path / 'm.tmcl'} was only read" in got.stderr
    assert "the old module was only read" not in got.stderr
    hexfile = tmp_path / "fw.hex"
    from tmclsh.sim.boot import Bootloader

    hexfile.write_text(hex_image("1311V110", 20000, Bootloader.START))
    got = _run(["replace", "--from", str(tmp_path / "m.tmcl"), "--to", new_path, "--yes",
                "--firmware", str(hexfile)])
    assert got.returncode == 0, got.stdout + got.stderr
    assert re.search(r"^program\s+done", got.stdout, re.M)
    after = _run(["--port", new_path, "-c", "GAP 4, 0"]).stdout
    assert "1234" in after


def test_forced_onto_another_type_carries_settings_by_name_and_nothing_else(modules):
    old, new = modules(), modules("1640V210")
    report = replace(old, new, image=image(), force=True)[0].run()
    assert report.ok, report.to_json()
    states = {o.step: o.state for o in report.steps}
    assert states["firmware"] == SKIPPED and states["program"] == SKIPPED
    assert "units differ" in report.steps[2].text  # pps is no rpm: skipped, said so
    assert new.app_version == "1640V210" and new.erases == 0 and not new.stored
    only_read(old)


def test_with_link_the_new_module_moves_and_the_same_run_again_finds_it(make_pty_sim):
    old, old_path = sim_old(make_pty_sim)
    new, new_path = make_pty_sim(address=2)
    img = image_from_hex(hex_image("1311V110", 20000, START_SIM), "1311V110.hex")

    def run():
        return Replacement({"port": old_path, "timeout": 0.5},
                           {"port": new_path, "timeout": 0.5, "address": 2}, image=img,
                           with_link=True).run()

    report = run()
    assert report.ok, report.to_json()
    assert new.address == 1 and "address 1" in report.steps[2].text
    again = run()  # (as after a stop: --to-address 2 no longer answers)
    assert again.ok, again.to_json()
    assert [o.state for o in again.steps] == [DONE, SKIPPED, SKIPPED, SKIPPED, DONE]


def test_from_a_file_that_is_not_a_backup_is_refused_as_such(modules, tmp_path):
    """A capture or a script given to --from was opened as a serial port ("Could not
    configure port: (25, 'Inappropriate ioctl for device')")."""
    new = modules("1311V111")
    other = tmp_path / "plc.txt"
    other.write_text("1796421018.647436 tx 01 06 04 00 00 00 00 00 0b\n")
    new.heard.clear()
    got = _run(["replace", "--from", str(other), "--to", new.path, "--yes"])
    assert got.returncode == 2, got.stdout + got.stderr
    assert (f"--from {other}: a file, but not a backup .save wrote" in got.stderr
            and "nothing was sent" in got.stderr and "ioctl" not in got.stderr)
    # it says what a backup begins with, not that this file begins so
    assert "(a backup's first line is '// tmclsh configuration backup')" in got.stderr
    assert new.heard == []


def test_from_an_old_module_in_its_ascii_mode(make_pty_sim):
    """The old module driven in its ASCII mode has no 134 to read its program with (the
    link refuses it): the settings are carried, the program is said to be unknown rather
    than copied as empty, and the old module is left in ASCII mode, as it was found."""
    import tmclsh
    from tmclsh.client.ascii import switch

    old, old_path = sim_old(make_pty_sim)
    old.version_string, old.firmware_version = "1311V111", 111  # (no firmware step)
    with tmclsh.connect(port=old_path, timeout=0.5) as c:
        switch(c, "ascii", keep=True)
    assert old.ascii_active
    new, new_path = make_pty_sim()
    report = Replacement({"port": old_path, "timeout": 0.5},
                         {"port": new_path, "timeout": 0.5}).run()
    steps = {s.step: s for s in report.steps}
    assert steps["configuration"].state == DONE, report.to_json()
    assert steps["program"].state == SKIPPED and "not read" in steps["program"].text
    assert new.vm.memory[:3] == [None, None, None]  # (nothing stored)
    assert old.ascii_active
    gap = [_run(["--port", p, "-c", "GAP 4, 0"]).stdout for p in (old_path, new_path)]
    assert "1234" in gap[1]
