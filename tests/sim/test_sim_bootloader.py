"""The simulator's bootloader (sim/boot.py), through its bytes: 242 and its key, the memory
it reports and takes, the checks of 205, faults; and PyTrinamic's own updater
(``tmclfwupload``) updating ``tmclsh sim --pty`` in another process."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest

from bootmodel import hex_image
from conftest import ROOT, tmclsh_env
from tmclsh.sim import Simulator
from tmclsh.sim.boot import Bootloader
from tmclsh.tmcl.frames import Reply, Request, Status

KEY = (0x81, 0x92, 0xA3B4C5D6)
P, S, N = Bootloader.PAGE_SIZE, Bootloader.START, Bootloader.SIZE


def ask(sim: Simulator, address: int, op: int, type_: int = 0, motor: int = 0,
        value: int = 0, wait: float = 0.2) -> bytes:
    sim.write(Request(address, op, type_, motor, value).to_bytes())
    return sim.read(wait)


def value(raw: bytes) -> tuple[int, int]:
    r = Reply.from_bytes(raw)
    return r.status, r.value & 0xFFFFFFFF


def write_image(sim: Simulator, data: bytes) -> None:
    """The protocol as the issue's table gives it, by hand: words into the buffer, pages."""
    for page in range(0, len(data), P):
        chunk = data[page:page + P]
        for off in range(0, len(chunk), 4):
            word = int.from_bytes(chunk[off:off + 4].ljust(4, b"\0"), "little")
            idx = off // 4
            assert value(ask(sim, 1, 201, idx & 0xFF, idx >> 8, word))[0] == Status.OK
        assert value(ask(sim, 1, 202, 0, 0, S + page))[0] == Status.OK


@pytest.fixture
def booted():
    sim = Simulator("TMCM-1311", 3)
    ask(sim, 3, 242, *KEY)
    yield sim
    sim.close()


def test_242_needs_its_key_and_is_not_answered():
    with Simulator("TMCM-1311", 3) as sim:
        assert ask(sim, 3, 242, 0x81, 0x92, 0) == b""  # the wrong key: ignored
        assert not sim.in_bootloader
        assert ask(sim, 3, 136) == b"\x021311V111"
        assert ask(sim, 3, 242, *KEY) == b""  # no reply: the module restarts
        assert sim.in_bootloader
        # the bootloader answers at its own address, whatever the application's was
        assert ask(sim, 3, 136, wait=0.1) == b""
        assert ask(sim, 1, 136) == b"\x021311B100"


def test_the_memory_it_reports_and_its_checks(booted):
    sim = booted
    assert [value(ask(sim, 1, 206, t))[1] for t in (0, 1, 2)] == [P, S, N]
    assert value(ask(sim, 1, 206, 3))[0] == Status.WRONG_TYPE
    assert value(ask(sim, 1, 201, P // 4 & 0xFF, P // 4 >> 8, 1))[0] == Status.INVALID_VALUE
    assert value(ask(sim, 1, 202, 0, 0, S + 4))[0] == Status.INVALID_VALUE  # not a page
    assert value(ask(sim, 1, 202, 0, 0, S + N))[0] == Status.INVALID_VALUE  # past the end
    assert value(ask(sim, 1, 203, 0, 0, S - 1))[0] == Status.INVALID_VALUE
    assert value(ask(sim, 1, 208, 0, 0, N + 1))[0] == Status.INVALID_VALUE
    assert value(ask(sim, 1, 6, 1, 0))[0] == Status.INVALID_COMMAND  # no GAP here
    assert ask(sim, 1, 136, 1) != b""  # 136 type 1 answers too (scan's probe)


def test_write_verify_and_start_an_image_of_another_version(booted):
    sim = booted
    data = bytearray(range(256)) * 20
    data[0x300:0x308] = b"1311V120"
    assert value(ask(sim, 1, 200))[0] == Status.OK
    assert value(ask(sim, 1, 203, 0, 0, S + len(data) - 1))[1] == (0xFF * len(data))
    write_image(sim, bytes(data))
    assert value(ask(sim, 1, 203, 0, 0, S + len(data) - 1))[1] == sum(data)
    assert value(ask(sim, 1, 204, 0, 0, S + 0x300))[1] == int.from_bytes(b"1311", "little")
    # 205 before length and checksum are written: it stays in its bootloader
    assert ask(sim, 1, 205) == b"" and sim.in_bootloader
    ask(sim, 1, 208, 0, 0, len(data))
    ask(sim, 1, 208, 1, 0, sum(data) + 1)  # a wrong checksum
    assert ask(sim, 1, 205) == b"" and sim.in_bootloader
    ask(sim, 1, 208, 1, 0, sum(data))
    assert ask(sim, 1, 205) == b""
    assert not sim.in_bootloader and ask(sim, 3, 136) == b"\x021311V120"
    assert sim.firmware_version == 120


def test_an_image_of_another_type_makes_it_that_module(booted):
    sim = booted
    data = bytearray(b"\x11") * 3000
    data[100:108] = b"1640V212"
    ask(sim, 1, 200)
    write_image(sim, bytes(data))
    ask(sim, 1, 208, 0, 0, len(data))
    ask(sim, 1, 208, 1, 0, sum(data))
    ask(sim, 1, 205)
    assert sim.module.name == "TMCM-1640" and ask(sim, 3, 136) == b"\x021640V212"


def test_a_page_written_twice_without_an_erase_holds_both_as_flash_does(booted):
    sim = booted
    ask(sim, 1, 200)
    ask(sim, 1, 201, 0, 0, 0x0F0F0F0F)
    ask(sim, 1, 202, 0, 0, S)
    ask(sim, 1, 201, 0, 0, 0x3C3C3C3C)
    ask(sim, 1, 202, 0, 0, S)
    assert value(ask(sim, 1, 204, 0, 0, S))[1] == 0x0C0C0C0C
    # and the buffer reads erased once written: a 202 sent again changes nothing
    ask(sim, 1, 202, 0, 0, S)
    assert value(ask(sim, 1, 204, 0, 0, S))[1] == 0x0C0C0C0C


def test_started_in_its_bootloader_and_a_power_cycle():
    with Simulator("TMCM-351", bootloader=True) as sim:
        assert ask(sim, 1, 136) == b"\x02351B1.00"
        sim.reset()  # nothing valid to start
        assert sim.in_bootloader
    with Simulator("TMCM-1311", 2) as sim:
        ask(sim, 2, 242, *KEY)
        sim.reset()  # its firmware was never erased: it starts again
        assert not sim.in_bootloader and ask(sim, 2, 136) == b"\x021311V111"


def test_faults_apply_to_the_bootloader(booted):
    sim = booted
    sim.faults.drop_next = 1
    assert ask(sim, 1, 206, 0, wait=0.1) == b""
    sim.faults.corrupt_next = 1
    raw = ask(sim, 1, 206, 0)
    assert len(raw) == 9 and sum(raw[:8]) & 0xFF != raw[8]
    sim.faults.lose_next = 1
    assert ask(sim, 1, 200, wait=0.1) == b""
    assert value(ask(sim, 1, 206, 0))[1] == P


def test_pytrinamic_tmclfwupload_updates_tmclsh_sim_pty(tmp_path):
    """A client the project did not write: PyTrinamic's updater, as a user runs it."""
    pytest.importorskip("pytrinamic")
    tool = shutil.which("tmclfwupload", path=str(__import__("pathlib").Path(
        sys.executable).parent))
    if tool is None:
        pytest.skip("PyTrinamic's tmclfwupload is not installed")
    image = tmp_path / "fw.hex"
    image.write_text(hex_image("1311V123", 12000, S))
    sim = subprocess.Popen([sys.executable, "-m", "tmclsh", "sim", "--pty"], cwd=str(ROOT),
                           env=tmclsh_env(), stdout=subprocess.PIPE, text=True)
    try:
        path = sim.stdout.readline().strip()
        p = subprocess.run([tool, str(image), "--interface", "serial_tmcl", "--port", path,
                            "--data-rate", "115200"], capture_output=True, text=True,
                           timeout=120)
        assert p.returncode in (0, None), p.stdout + p.stderr
        assert "Checksum of the uploaded firmware matches" in p.stdout
        assert "Starting the firmware" in p.stdout
        import serial

        with serial.Serial(path, 115200, timeout=1) as port:
            port.write(Request(1, 136, 0).to_bytes())
            assert port.read(9) == b"\x021311V123"
    finally:
        sim.terminate()
        sim.wait(10)


def test_the_memory_a_module_file_gives_is_the_one_the_bootloader_answers(tmp_path):
    """firmware_start/firmware_size in a module file: the simulated bootloader answers them
    (206), so what tmclsh checks before a restart and what the bootloader says agree."""
    from importlib import resources

    from tmclsh.base.errors import ValidationError
    from tmclsh.tmcl import modules

    text = resources.files("tmclsh.tmcl.modules").joinpath("tmcm1311.toml").read_text()
    path = tmp_path / "tmcm1311.toml"
    path.write_text(text.replace("program_memory = 2048\n", "program_memory = 2048\n"
                                 "firmware_start = 0x10000\nfirmware_size = 0x4000\n", 1))
    modules.add_file(path)
    try:
        sim = Simulator("TMCM-1311")
        try:
            assert ask(sim, 1, 242, *KEY) == b""
            answers = [value(ask(sim, 1, 206, t))[1] for t in (0, 1, 2)]
            assert answers == [P, 0x10000, 0x4000]
        finally:
            sim.close()
        path.write_text(text.replace("program_memory = 2048\n", "program_memory = 2048\n"
                                     "firmware_size = 0x4000\n", 1))
        with pytest.raises(ValidationError, match="firmware_size needs firmware_start"):
            modules.read_file(path)
    finally:
        modules.forget_user_files()
