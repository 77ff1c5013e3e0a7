"""``tmclsh firmware`` as a user runs it: a process on a pty-served module, interrupted at
every phase (Ctrl-C as the module is reached there) and resumed with the very command it
printed; killed mid-write; --check, --json, refusals; connect and scan meeting a module in
its bootloader."""

from __future__ import annotations

import json
import shlex
import signal
import subprocess
import sys
import time

import pytest

from bootmodel import START, BootModule, hex_image
from conftest import ROOT, delivered, patience, tmclsh_env
from tmclsh.sim import Simulator
from tmclsh.sim.boot import Bootloader
from tmclsh.sim.serve import serve_pty


@pytest.fixture
def model_hex(tmp_path):
    def make(version: str = "1311V112", size: int = 5000, start: int = START) -> str:
        path = tmp_path / f"{version}-{size}-{start:x}.hex"
        path.write_text(hex_image(version, size, start))
        return str(path)
    return make


@pytest.fixture
def sim_hex(model_hex):
    return lambda version="1311V112", size=20000: model_hex(version, size, Bootloader.START)


def tmclsh(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "tmclsh", *args], cwd=str(ROOT),
                            env=tmclsh_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, text=True, **kw)


def finish(p: subprocess.Popen, timeout: float = 60) -> tuple[int, str, str]:
    out, err = p.communicate(timeout=patience(timeout))
    return p.returncode, out, err


def resume_line(err: str) -> list[str]:
    """The command the interrupted run printed, as argv for this checkout."""
    line = next(ln for ln in err.splitlines() if "to complete the update, run:" in ln)
    words = shlex.split(line.split("run:", 1)[1])
    assert words[:2] == ["tmclsh", "firmware"]
    return words[1:]


# -- interrupted at every phase, then the command it printed -------------------------------

def interrupt_on(module: BootModule, command: int, nth: int = 1):
    """Ctrl-C to the update when the module gets its ``nth`` request ``command``, before it
    answers it."""
    holder: dict = {}

    def hook(m):
        if m.commands().count(command) == nth and "p" in holder:
            holder["p"].send_signal(signal.SIGINT)
            # the signal lands while the update waits for this answer: handed to the process
            # (however long a busy machine takes to run it), then a moment for its handler
            delivered(holder["p"].pid)
            time.sleep(0.2)
    module.hooks[command] = hook
    return holder


@pytest.mark.parametrize("phase, command, nth", [
    ("before erase", 206, 1), ("after erase", 200, 1), ("mid-write", 201, 700),
    ("before 208", 203, 1), ("after 205", 205, 1)])
def test_interrupted_then_resumed(model_hex, phase, command, nth):
    module = BootModule()
    image = model_hex(size=5000)
    try:
        holder = interrupt_on(module, command, nth)
        p = holder["p"] = tmclsh("firmware", image, "--port", module.path, "--yes",
                                 "--timeout", "0.2")
        rc, out, err = finish(p)
        assert rc == 130, err
        assert "interrupted" in err and "Traceback" not in err
        module.hooks.clear()
        same = ["firmware", image, "--port", module.path, "--timeout", "0.2", "--yes"]
        if phase == "before erase":
            # nothing erased: the module was sent back to its firmware, nothing to resume
            assert "nothing was erased: the module runs its firmware 1311V111 again" in err
            assert "to complete the update" not in err
            assert not module.in_bootloader and module.erases == 0
            argv = same  # the user runs it again
        elif phase == "after 205":
            assert "the new firmware was started (205) and has not answered yet" in err
            argv = resume_line(err)
            assert argv == same
        else:
            assert module.in_bootloader
            assert "the module is in its bootloader and its firmware is erased" in err
            argv = resume_line(err)
            assert argv == same
        before = len(module.heard)
        rc, out, err = finish(tmclsh(*argv))
        assert rc == 0, err
        again = [h[0] for h in module.heard[before:]]
        assert module.app_version == "1311V112" and not module.in_bootloader
        if phase == "after 205":
            assert "runs 1311V112, the image's version, already: nothing to do" in out
            assert (out + err).count("nothing to do") == 1  # said once
            assert 200 not in again
        elif phase == "before 208":
            assert 200 not in again and 201 not in again  # written already: only finished
            assert again.count(208) == 2 and 205 in again
            assert "updated the TMCM-1311 from its bootloader" in out
        else:
            assert again.count(200) == 1 and 205 in again
            assert out.startswith("updated the TMCM-1311 from ")
    finally:
        module.close()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_second_signal_while_the_module_is_sent_back_says_where_it_stands(model_hex, sig):
    """Interrupted before the erase, and again as the module is sent back to its firmware
    (205 out, its answer awaited): it said "the module is in its bootloader ... starts again
    when switched off and on" of a module that ran its firmware again. 205 is said to have
    gone out."""
    module = BootModule()
    image = model_hex(size=5000)
    holder: dict = {}

    def signal_again(m):  # the signal lands while the update waits for this answer
        if "p" in holder:
            holder["p"].send_signal(sig)
            delivered(holder["p"].pid, sig)

    try:
        # before the erase (206: the memory asked), and as 205 arrives to send it back
        module.hooks[206] = module.hooks[205] = signal_again
        p = holder["p"] = tmclsh("firmware", image, "--port", module.path, "--yes",
                                 "--timeout", "0.2")
        rc, out, err = finish(p)
        assert rc == 128 + sig, err
        assert "Traceback" not in err, err
        deadline = time.monotonic() + patience(10)
        while module.in_bootloader and time.monotonic() < deadline:
            time.sleep(0.02)
        assert not module.in_bootloader and module.erases == 0
        assert "the module is in its bootloader; nothing was erased" not in err, err
        assert "205 was sent to start its firmware 1311V111 again" in err, err
    finally:
        module.close()


def test_killed_mid_write_then_the_same_command_completes(sim_hex):
    """SIGKILL: nothing is said; the module stays in its bootloader, and the same command
    finds it there and completes."""
    class Watched(Simulator):
        writes = 0

        def _dispatch(self, ins, channel):
            if self.in_bootloader and ins.opcode == 201:
                Watched.writes += 1
            return super()._dispatch(ins, channel)

    sim = Watched("TMCM-1311")
    server = serve_pty(sim)
    image = sim_hex(size=20000)  # (killed a fifth of the way through its writes)
    try:
        argv = ("firmware", image, "--port", server.path, "--yes")
        p = tmclsh(*argv)
        deadline = time.monotonic() + patience(30)
        while Watched.writes < 1000 and time.monotonic() < deadline:
            time.sleep(0.005)
        p.kill()
        p.wait(10)
        assert sim.in_bootloader and sim.boot.length == 0
        rc, out, err = finish(tmclsh(*argv))
        assert rc == 0, err
        assert "in its bootloader (1311B100)" in err
        assert "updated the TMCM-1311 from its bootloader" in out
        assert not sim.in_bootloader and sim.version_string == "1311V112"
    finally:
        server.close()
        sim.close()


def test_sigterm_mid_write_says_where_the_module_stands(sim_hex):
    sim = Simulator("TMCM-1311")
    sim.faults.delay = 0.002  # every reply late: the write takes a few seconds
    server = serve_pty(sim)
    try:
        p = tmclsh("firmware", sim_hex(size=40000), "--port", server.path, "--yes", "--json")
        deadline = time.monotonic() + 20
        while not (sim.in_bootloader and sim.boot.length == 0) and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.5)
        p.send_signal(signal.SIGTERM)
        rc, out, err = finish(p)
        assert rc == 128 + signal.SIGTERM
        last = json.loads(out.splitlines()[-1])
        assert last["state"] == "writing" and last["error"] == "terminated (SIGTERM); exit status 143"
        assert last["resume"].startswith("tmclsh firmware ") and "--yes" in last["resume"]
    finally:
        server.close()
        sim.close()


# -- what a user sees -----------------------------------------------------------------------

def test_json_steps_then_the_result(make_pty_sim, sim_hex):
    sim, path = make_pty_sim()
    rc, out, err = finish(tmclsh("firmware", sim_hex(), "--port", path, "--yes", "--json"))
    assert rc == 0, err
    objs = [json.loads(line) for line in out.splitlines()]
    steps = [o["step"] for o in objs if "step" in o]
    assert steps[0] == "found" and steps[-1] == "done"
    assert {"enter", "info", "erase", "write", "verify", "finish", "start"} <= set(steps)
    writes = [o for o in objs if o.get("step") == "write"]
    assert writes[-1]["done"] == writes[-1]["total"] == 20000
    assert objs[-1] == {"updated": True, "module": "TMCM-1311", "old_version": "1311V111",
                        "new_version": "1311V112", "written": 20000,
                        "seconds": objs[-1]["seconds"], "resumed": False, "change": "upgrade"}


def test_check_says_what_would_happen_and_writes_nothing(model_hex):
    module = BootModule()
    try:
        rc, out, err = finish(tmclsh("firmware", model_hex(), "--port", module.path, "--check"))
        assert rc == 0, err
        assert "module  TMCM-1311, running its firmware: 1311V111" in out
        assert "image   " in out and "1311V112, 5000 bytes at 0x00004000" in out
        assert "would   restart it into its bootloader, erase, write 5000 bytes" in out
        assert 242 not in module.commands()
    finally:
        module.close()


def test_check_in_the_bootloader_says_whether_it_fits(model_hex):
    module = BootModule(in_bootloader=True)
    try:
        from bootmodel import SIZE

        rc, out, err = finish(tmclsh("firmware", model_hex(size=SIZE + 8), "--port",
                                     module.path, "--check", "--json", "--timeout", "0.1"))
        assert rc == 1, err
        plan = json.loads(out.splitlines()[-1])
        assert plan["bootloader"] is True and plan["fits"] is False
        assert "does not fit" in plan["problem"]
        assert plan["memory"] == {"page_size": 256, "start": START, "size": SIZE,
                                  "from": "bootloader"}
        assert set(module.commands()) <= {136, 206} and module.erases == 0
    finally:
        module.close()


def test_an_image_for_another_module_is_one_clear_line(model_hex):
    module = BootModule()
    try:
        rc, out, err = finish(tmclsh("firmware", model_hex("1640V211"), "--port",
                                     module.path, "--yes"))
        assert rc == 1 and out == ""
        assert ("is firmware for the TMCM-1640 (its version string 1640V211), not for this "
                "TMCM-1311: refused, nothing was written") in err
        assert "Traceback" not in err and 242 not in module.commands()
    finally:
        module.close()


def test_an_image_refused_by_a_module_in_its_bootloader_is_not_offered_again(model_hex):
    """The module waits in its bootloader (an earlier update broke off): the way out names an
    image for this module, not the refused one again (it said to run the same command)."""
    module = BootModule(in_bootloader=True)
    try:
        image = model_hex("1640V211")
        rc, out, err = finish(tmclsh("firmware", image, "--port", module.path, "--yes"))
        assert rc == 1 and "not for this TMCM-1311" in err
        (resume,) = [line for line in err.splitlines() if "to complete the update" in line]
        assert image not in resume
        assert "tmclsh firmware IMAGE.hex" in resume and "for the TMCM-1311" in resume
    finally:
        module.close()


def test_no_answer_possible_needs_yes_and_nothing_is_sent(model_hex):
    module = BootModule()
    try:
        rc, out, err = finish(tmclsh("firmware", model_hex(), "--port", module.path))
        assert rc == 2 and "give --yes" in err and "nothing was sent" in err
        assert module.heard == []
    finally:
        module.close()


def test_a_hex_file_with_a_bad_record_checksum_is_refused_before_anything_is_sent(tmp_path):
    module = BootModule()
    bad = tmp_path / "bad.hex"
    text = hex_image("1311V112", 64).splitlines()
    text[1] = text[1][:-2] + ("00" if text[1][-2:] != "00" else "01")
    bad.write_text("\n".join(text) + "\n")
    binary = tmp_path / "fw.bin"
    binary.write_bytes(bytes(range(256)))
    try:
        rc, out, err = finish(tmclsh("firmware", str(bad), "--port", module.path, "--yes"))
        assert rc == 2 and "not a valid Intel HEX file" in err and "checksum" in err
        rc, out, err = finish(tmclsh("firmware", str(binary), "--port", module.path, "--yes"))
        assert rc == 2 and "not an Intel HEX file" in err
        assert module.heard == []
    finally:
        module.close()


# -- meeting a module in its bootloader ---------------------------------------------------

def test_connect_to_a_module_in_its_bootloader_points_at_tmclsh_firmware(run_tmclsh):
    sim = Simulator("TMCM-1311", bootloader=True)
    server = serve_pty(sim)
    try:
        p = run_tmclsh("--port", server.path, "-c", "GAP 1, 0")
        assert p.returncode == 3
        assert ("is in its bootloader (it answers '1311B100'): a firmware update did not "
                "complete") in p.stderr
        assert "runs no firmware while it is there" in p.stderr  # (not "until one does")
        assert f"'tmclsh firmware FILE.hex --port {server.path}'" in p.stderr
        assert "unknown module type" not in p.stderr
    finally:
        server.close()
        sim.close()


def test_scan_marks_a_module_in_its_bootloader(run_tmclsh):
    sim = Simulator("TMCM-351", bootloader=True)
    server = serve_pty(sim)
    try:
        p = run_tmclsh("scan", "--port", server.path, "--to", "3")
        assert p.returncode == 0, p.stderr
        assert "address   1  TMCM-351    bootloader 351B1.00  IN ITS BOOTLOADER" in p.stdout
        assert f"'tmclsh firmware FILE.hex --port {server.path}'" in p.stdout
        p = run_tmclsh("scan", "--port", server.path, "--to", "3", "--json")
        assert json.loads(p.stdout) == {"address": 1, "module": "TMCM-351",
                                        "version": "351B1.00", "bootloader": True}
    finally:
        server.close()
        sim.close()


def test_242_has_help_and_is_not_sent_as_a_line(run_tmclsh):
    p = run_tmclsh("--sim", "-c", "help 242")
    assert "(command 242: enter the bootloader" in p.stdout + p.stderr
    p = run_tmclsh("--sim", "-c", "242 $81, $92, $A3B4C5D6")
    assert p.returncode == 1
    assert "242 (enter the bootloader" in p.stderr and "is not sent as a line" in p.stderr
    assert "'tmclsh firmware FILE.hex' updates the firmware" in p.stderr


# -- images checked whole before anything is restarted (issue 31) ---------------------------

def test_a_hex_file_without_its_end_record_is_refused_check_included(model_hex, tmp_path):
    module = BootModule()
    with open(model_hex(size=5000)) as f:
        lines = f.read().splitlines()
    cut = tmp_path / "cut.hex"
    cut.write_text("\n".join(lines[:-1]) + "\n")  # cut at a record boundary
    try:
        for extra in ((), ("--check",)):
            rc, out, err = finish(tmclsh("firmware", str(cut), "--port", module.path, "--yes",
                                         *extra))
            assert rc == 2 and out == "", err
            assert (f"tmclsh: {cut}:{len(lines) - 1}: the file ends without its end-of-file "
                    "record (:00000001FF)") in err
            assert "nothing was sent" in err and "Traceback" not in err
        assert module.heard == [] and not module.in_bootloader
    finally:
        module.close()


def test_too_large_is_refused_and_the_firmware_started_again(model_hex, run_tmclsh):
    """Only the bootloader knows the memory here: the refusal starts the firmware again, and
    the next connect finds it running."""
    from bootmodel import SIZE

    module = BootModule()
    try:
        rc, out, err = finish(tmclsh("firmware", model_hex(size=SIZE + 16), "--port",
                                     module.path, "--yes"))
        assert rc == 1 and out == "", err
        assert "does not fit; refused, nothing was erased" in err
        assert "nothing was erased: the module runs its firmware 1311V111 again" in err
        assert "to complete the update" not in err
        assert not module.in_bootloader and module.erases == 0
        p = run_tmclsh("--port", module.path, "-c", "GAP 1, 0")
        assert p.returncode == 0 and "runs no firmware" not in p.stderr, p.stderr
    finally:
        module.close()


def test_too_large_for_the_module_file_is_refused_before_the_restart(model_hex, tmp_path):
    from importlib import resources

    from bootmodel import SIZE

    text = resources.files("tmclsh.tmcl.modules").joinpath("tmcm1311.toml").read_text()
    data = tmp_path / "tmcm1311.toml"
    data.write_text(text.replace("program_memory = 2048\n", "program_memory = 2048\n"
                                 f"firmware_start = {START}\nfirmware_size = {SIZE}\n", 1))
    module = BootModule()
    image = model_hex(size=SIZE + 16)
    try:
        rc, out, err = finish(tmclsh("--module-file", str(data), "firmware", image, "--port",
                                     module.path, "--check"))
        assert rc == 1, err
        assert ("fits    NO: application memory 131072 bytes at 0x00004000..0x00023FFF, from "
                "its module data") in out
        assert "would   refuse: " in out and "does not fit" in out
        rc, out, err = finish(tmclsh("--module-file", str(data), "firmware", image, "--port",
                                     module.path, "--yes"))
        assert rc == 1 and "refused before anything was sent to change it" in err, err
        assert "nothing was changed: the module runs its firmware 1311V111" in err
        assert 242 not in module.commands() and not module.in_bootloader
    finally:
        module.close()


def test_a_downgrade_is_named_in_the_report(model_hex):
    module = BootModule()
    try:
        rc, out, err = finish(tmclsh("firmware", model_hex("1311V110"), "--port", module.path,
                                     "--check"))
        assert rc == 0 and "start 1311V110 (a DOWNGRADE: older than 1311V111)" in out, err
        rc, out, err = finish(tmclsh("firmware", model_hex("1311V110"), "--port", module.path,
                                     "--yes"))
        assert rc == 0, err
        assert out.startswith("downgraded the TMCM-1311 from 1311V111 to 1311V110, an older "
                              "version (5000 bytes written")
        rc, out, err = finish(tmclsh("firmware", model_hex("1311V111"), "--port", module.path,
                                     "--yes", "--json"))
        assert rc == 0, err
        last = json.loads(out.splitlines()[-1])
        assert last["change"] == "upgrade" and last["new_version"] == "1311V111"
    finally:
        module.close()


def test_check_of_an_image_for_another_module_says_one_thing(model_hex):
    module = BootModule()
    try:
        rc, out, err = finish(tmclsh("firmware", model_hex("1640V211"), "--port", module.path,
                                     "--check"))
        assert rc == 1, err
        assert "image   " in out and ": 1640V211, 5000 bytes at 0x00004000" in out
        assert "no version string" not in out
        assert "would   refuse: " in out and "is firmware for the TMCM-1640" in out
    finally:
        module.close()
