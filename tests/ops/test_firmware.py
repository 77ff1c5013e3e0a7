"""Firmware updates through real bytes (tmclsh.ops.firmware): against the simulator over a
pty, TCP and a python-can virtual bus, and against a bootloader written in the test from the
issue's table (tests/bootmodel.py); refusals before anything is erased; a checksum that does
not agree; a link lost and a module gone silent in the middle, then the same update again."""

from __future__ import annotations

import os
import threading
import uuid

import pytest

from bootmodel import START, BootModule, CanBootModule, hex_image
from responder import Module, SharedLine
from tmclsh.base.errors import TransportError
from tmclsh.ops.firmware import APPLICATION, WRITING, FirmwareError, ImageRefused, Step, FirmwareUpdate
from tmclsh.sim import Simulator
from tmclsh.sim.boot import Bootloader
from tmclsh.sim.serve import serve_can, serve_tcp
from tmclsh.tmcl.bootloader import Image, image_from_hex

SIM_START = Bootloader.START


def sim_image(version: str = "1311V112", size: int = 20000, start: int = SIM_START) -> Image:
    return image_from_hex(hex_image(version, size, start), f"{version}.hex")


def model_image(version: str = "1311V112", size: int = 5000) -> Image:
    return image_from_hex(hex_image(version, size, START), f"{version}.hex")


def run(settings: dict, image: Image, **kw):
    steps: list[Step] = []
    update = FirmwareUpdate({"timeout": 0.3, **settings}, image, progress=steps.append, **kw)
    try:
        return update, update.run(), steps
    finally:
        update.close()


def version_of(sim: Simulator) -> str:
    assert not sim.in_bootloader
    return sim.version_string


# -- against the simulator ------------------------------------------------------------------

def test_update_over_a_pty(make_pty_sim):
    sim, path = make_pty_sim()
    image = sim_image()
    update, result, steps = run({"port": path, "baud": 115200}, image)
    assert (result.old_version, result.new_version, result.written) == (
        "1311V111", "1311V112", image.length)
    assert version_of(sim) == "1311V112" and sim.firmware_version == 112
    assert [s.step for s in steps if s.step != "write"] == [
        "found", "enter", "enter", "info", "erase", "verify", "finish", "start", "done"]
    writes = [s for s in steps if s.step == "write"]
    assert writes[-1].done == writes[-1].total == image.length
    # the memory holds the image, byte for byte, where the bootloader's memory starts
    assert bytes(sim.boot.memory[:image.length]) == image.data


def test_update_over_tcp():
    sim = Simulator("TMCM-1640", 3)
    server = serve_tcp(sim, "127.0.0.1", 0)
    try:
        host, port = server.address
        _, result, _ = run({"port": f"socket://{host}:{port}", "address": 3},
                           sim_image("1640V211"))
        assert (result.old_version, result.new_version) == ("1640V210", "1640V211")
        assert version_of(sim) == "1640V211"
        assert sim.address == 3  # its settings outlived the update
    finally:
        server.close()
        sim.close()


def test_update_over_a_python_can_virtual_bus():
    sim = Simulator("TMCM-1311")
    channel = f"fw-{uuid.uuid4().hex[:8]}"
    server = serve_can(sim, "virtual", channel)
    try:
        _, result, _ = run({"can": f"virtual:{channel}"}, sim_image("1311V113"))
        assert result.new_version == "1311V113" and version_of(sim) == "1311V113"
    finally:
        server.close()
        sim.close()


def test_a_module_found_in_its_bootloader_is_completed(make_pty_sim):
    sim, path = make_pty_sim(bootloader=True)
    update, result, steps = run({"port": path}, sim_image())
    assert result.resumed and result.old_version is None
    assert version_of(sim) == "1311V112"
    assert "in its bootloader" in steps[0].text


def test_random_faults_on_every_reply_do_not_stop_it(make_pty_sim):
    """Lost, damaged, late and doubled replies: the write's commands are sent again where
    the instruction set allows it, and the checksum decides."""
    import random

    sim, path = make_pty_sim()
    sim.faults.rng = random.Random(5)
    sim.faults.rates = {"drop": 0.01, "corrupt": 0.01, "dup": 0.01, "garbage": 0.01}
    _, result, _ = run({"port": path, "retries": 5}, sim_image(size=8000))
    assert version_of(sim) == "1311V112" == result.new_version


# -- refused before anything is erased ---------------------------------------------------------

def test_an_image_for_another_module_is_refused_before_anything_is_sent():
    module = BootModule()
    try:
        with pytest.raises(ImageRefused, match="for the TMCM-1640.*not for this TMCM-1311"):
            run({"port": module.path}, model_image("1640V211"))
        # asked what it is (136) and whether it is in download mode (GGP 129); no more
        assert set(module.commands()) == {136, 10}
        assert not module.in_bootloader and module.erases == 0
    finally:
        module.close()


def test_an_image_with_no_version_string_is_refused():
    module = BootModule()
    try:
        image = image_from_hex(hex_image("no string", 3000), "x.hex")
        with pytest.raises(ImageRefused, match="carries no firmware version string"):
            run({"port": module.path}, image)
        assert 242 not in module.commands() and module.erases == 0
    finally:
        module.close()


def test_an_image_too_large_is_refused_before_the_erase_and_the_module_sent_back():
    module = BootModule()
    try:
        from bootmodel import SIZE

        update = FirmwareUpdate({"port": module.path, "timeout": 0.3}, model_image(size=SIZE + 4))
        with pytest.raises(ImageRefused, match="does not fit; refused, nothing was erased"):
            update.run()
        update.close()
        assert 200 not in module.commands() and module.erases == 0
        # the bootloader was asked (206), then the module sent back to its firmware (205)
        cmds = module.commands()
        assert cmds[cmds.index(206):] == [206, 206, 206, 205, 136]
        assert not module.in_bootloader and module.app_version == "1311V111"
        assert update.state == APPLICATION and update.sent_back
        assert "nothing was erased" in update.situation()
    finally:
        module.close()


def test_an_image_that_starts_elsewhere_is_refused_before_the_erase():
    module = BootModule()
    try:
        image = image_from_hex(hex_image("1311V112", 3000, START + 0x100), "x.hex")
        with pytest.raises(ImageRefused, match="starts at 0x00004100"):
            run({"port": module.path}, image)
        assert module.erases == 0 and not module.in_bootloader
    finally:
        module.close()


# -- against the bootloader of the table ----------------------------------------------

def test_update_against_the_tables_bootloader():
    module = BootModule()
    try:
        image = model_image()
        update, result, _ = run({"port": module.path}, image)
        assert (result.old_version, result.new_version) == ("1311V111", "1311V112")
        assert module.app_version == "1311V112" and not module.in_bootloader
        assert bytes(module.memory[:image.length]) == image.data
        cmds = module.commands()
        # every word once, each page written after its words, as the table says
        assert cmds.count(201) == -(-image.length // 4)
        assert cmds.count(202) == -(-image.length // 256)
        assert cmds.index(200) < cmds.index(201) and cmds.count(200) == 1
        assert [c for c in cmds if c in (203, 208, 205)] == [203, 208, 208, 205]
        lengths = [h for h in module.heard if h[0] == 208]
        assert lengths == [(208, 0, 0, image.length), (208, 1, 0, image.checksum)]
    finally:
        module.close()


@pytest.mark.parametrize("first", ["bootloader", "bystander"])
def test_another_module_at_the_bootloaders_address_refuses_the_update(first):
    """On a shared line the module at address 2 restarts into a bootloader answering at
    address 1: a module already at 1 (here hearing every rate) would get the erase and the
    writes and answer them too (or be taken for a module that did not restart). Asked
    before 242, nothing sent to change either. ``first``: whose answers come first."""
    bus = SharedLine()
    if first == "bystander":
        other = Module(version="1311V111", address=1, nines=True, line=bus)
        module = BootModule(address=2, line=bus)
    else:
        module = BootModule(address=2, line=bus)
        other = Module(version="1311V111", address=1, nines=True, line=bus)
    try:
        with pytest.raises(FirmwareError, match="another module answers at address 1"):
            run({"port": bus.path, "address": 2, "baud": 115200}, model_image())
        assert 242 not in module.commands() and module.app_version == "1311V111"
        assert [g[0] for g in other.got] == [136] and other.held == b""
    finally:
        bus.close()


def test_a_line_at_another_rate_than_the_bootloaders_is_not_asked_at_its_rate(monkeypatch):
    """At 9600 no module on the line can follow the bootloader's 115200 traffic, and a
    question at 115200 would be noise to every one of them: address 1 is not asked."""
    from tmclsh.ops import firmware as fw

    asked: list[int | None] = []
    monkeypatch.setattr(fw.FirmwareUpdate, "_ask_version",
                        lambda self, timeout: asked.append(fw.line_baud(self.client.transport)))
    bus = SharedLine()
    module = BootModule(address=2, line=bus)
    try:
        update = fw.FirmwareUpdate({"timeout": 0.3, "port": bus.path, "address": 2,
                                    "baud": 9600}, model_image(), progress=lambda s: None)
        try:
            update.find()
            update._boot_address_free()
        finally:
            update.close()
        assert asked == []
    finally:
        bus.close()


def test_a_free_bootloader_address_on_a_shared_line_updates():
    bus = SharedLine()
    module = BootModule(address=2, line=bus)
    other = Module(version="1311V111", address=5, nines=True, line=bus)
    try:
        _, result, _ = run({"port": bus.path, "address": 2}, model_image())
        assert result.new_version == "1311V112" and other.got == []
    finally:
        bus.close()


def test_the_tables_bootloader_found_at_its_own_baud_rate():
    """A module left in its bootloader answers at 115200 baud only; asked at 9600 (the
    application's factory rate), the update finds it there and completes."""
    module = BootModule(in_bootloader=True)
    try:
        update, result, steps = run({"port": module.path, "timeout": 0.1}, model_image())
        assert result.resumed and module.app_version == "1311V112"
        assert "found where a bootloader answers" in steps[0].text
    finally:
        module.close()


def test_a_resumed_update_whose_image_is_written_only_finishes():
    """Written and verified before it broke off: the checksum agrees, so nothing is erased
    or written again."""
    module = BootModule()
    image = model_image()
    try:
        module.hooks[208] = lambda m: setattr(m, "silent", True)  # stops before 208
        with pytest.raises(Exception):
            run({"port": module.path, "retries": 0, "timeout": 0.1}, image)
        assert module.in_bootloader
        module.hooks.clear()
        module.silent = False
        before = len(module.heard)
        _, result, _ = run({"port": module.path}, image)
        again = [h[0] for h in module.heard[before:]]
        assert 200 not in again and 201 not in again and again.count(208) == 2
        assert result.resumed and result.written == 0 and module.app_version == "1311V112"
    finally:
        module.close()


def test_a_checksum_that_does_not_agree_starts_nothing():
    module = BootModule()

    def damage(m):  # flash that keeps one wrong bit in the first page
        m.buffer[7] ^= 0x10

    module.hooks[202] = lambda m: damage(m) if m.commands().count(202) == 1 else None
    try:
        update = FirmwareUpdate({"port": module.path, "timeout": 0.3}, model_image())
        with pytest.raises(FirmwareError, match="checksum.*is not the image's.*not started"):
            update.run()
        update.close()
        cmds = module.commands()
        assert 208 not in cmds and 205 not in cmds
        assert module.in_bootloader and update.state == WRITING and update.resumable
        assert "firmware is erased" in update.situation()
        # the same update again: the checksum disagrees, so it is written again, and starts
        module.hooks.clear()
        _, result, _ = run({"port": module.path}, model_image())
        assert module.app_version == "1311V112" and module.erases == 2
    finally:
        module.close()


def test_a_module_gone_silent_mid_write_then_the_same_update_again():
    module = BootModule()
    module.hooks[201] = lambda m: setattr(m, "silent", m.commands().count(201) == 300)
    try:
        update = FirmwareUpdate({"port": module.path, "timeout": 0.1, "retries": 1}, model_image())
        with pytest.raises(TimeoutError):
            update.run()
        update.close()
        assert update.state == WRITING and 0 < update.written < 5000
        # the 300th word went unanswered: four pages of 64 words were written
        assert update.written == 1024
        assert "(1024 of 5000 bytes written)" in update.situation()
        module.hooks.clear()
        module.silent = False
        _, result, _ = run({"port": module.path}, model_image())
        assert module.app_version == "1311V112" and result.resumed
    finally:
        module.close()


def test_a_lost_tcp_link_mid_write_then_the_same_update_again():
    sim = Simulator("TMCM-1311")
    server = serve_tcp(sim, "127.0.0.1", 0)
    url = "socket://{}:{}".format(*server.address)
    steps_seen = []

    def progress(step: Step) -> None:
        steps_seen.append(step)
        if step.step == "write" and step.done and step.done >= 4096:
            server.drop_client()  # the cable is pulled

    try:
        update = FirmwareUpdate({"port": url, "timeout": 0.3}, sim_image(), progress=progress)
        with pytest.raises((TransportError, TimeoutError)):
            update.run()
        update.close()
        assert update.state == WRITING and sim.in_bootloader
        _, result, _ = run({"port": url}, sim_image())
        assert result.resumed and version_of(sim) == "1311V112"
    finally:
        server.close()
        sim.close()


def test_can_bootloader_answering_on_0x7ff():
    import can

    channel = f"fw-{uuid.uuid4().hex[:8]}"
    module = CanBootModule(can.Bus(interface="virtual", channel=channel))
    try:
        _, result, _ = run({"can": f"virtual:{channel}"}, model_image())
        assert result.new_version == "1311V112" and module.app_version == "1311V112"
        assert 205 in module.commands()
    finally:
        module.close()


def test_check_writes_nothing_and_says_whether_it_fits(make_pty_sim):
    sim, path = make_pty_sim(bootloader=True)
    update = FirmwareUpdate({"port": path, "timeout": 0.3}, sim_image())
    try:
        plan = update.check()
    finally:
        update.close()
    assert plan.in_bootloader and plan.fits is True and plan.problem is None
    assert plan.memory.page_size == Bootloader.PAGE_SIZE
    assert sim.in_bootloader and sim.boot.length == 0
    assert plan.to_json()["image_version"] == "1311V112"


def test_declining_changes_nothing(make_pty_sim):
    sim, path = make_pty_sim()
    update = FirmwareUpdate({"port": path, "timeout": 0.3}, sim_image(), confirm=lambda q: False)
    try:
        with pytest.raises(FirmwareError, match="not updated: nothing was changed"):
            update.run()
    finally:
        update.close()
    assert not sim.in_bootloader and sim.version_string == "1311V111"


def test_the_same_version_is_nothing_to_do(make_pty_sim):
    sim, path = make_pty_sim()
    _, result, _ = run({"port": path}, sim_image("1311V111"))
    assert result.nothing_to_do and not sim.in_bootloader
    assert sim.boot.checksum != 0  # its memory as it was


def test_a_turning_motor_is_stopped_before_the_restart(make_pty_sim):
    sim, path = make_pty_sim()
    sim.write(__import__("tmclsh.tmcl.frames", fromlist=["Request"]).Request(
        1, 1, 0, 0, 20000).to_bytes())  # ROR 0, 20000
    sim.read(0.2)
    questions = []
    steps: list[Step] = []
    update = FirmwareUpdate({"port": path, "timeout": 0.3}, sim_image(), progress=steps.append,
                    confirm=lambda q: questions.append(q) or True)
    try:
        update.run()
    finally:
        update.close()
    assert "motor 0 turns (speed" in questions[0] and "stopped first" in questions[0]
    stop = next(s for s in steps if s.step == "stop")
    assert steps.index(stop) < [s.step for s in steps].index("enter")
    assert version_of(sim) == "1311V112"


def test_a_usb_module_is_found_again_under_its_port_name(make_pty_sim, monkeypatch):
    """After 242 and 205 a module on its own USB port leaves the bus: the port is closed and
    opened again under the same name (here a pty stands in for the USB port)."""
    sim, path = make_pty_sim()
    monkeypatch.setattr(FirmwareUpdate, "_usb", lambda self: True)
    reopened = []
    real = FirmwareUpdate._reopen

    def counting(self):
        reopened.append(self.state)
        real(self)

    monkeypatch.setattr(FirmwareUpdate, "_reopen", counting)
    _, result, _ = run({"port": path}, sim_image())
    assert reopened == ["bootloader", "starting"]
    assert result.new_version == "1311V112" == version_of(sim)


class UsbModule(BootModule):
    """A module on its own USB port, written from what the bus does: its port (``port``, a
    link to the pty, as udev names one) is gone from the moment it restarts (242, 205)
    until it is back on the bus a moment later, under the same name."""

    def __init__(self, port, **kw):
        super().__init__(**kw)
        self.port = str(port)
        os.symlink(self.path, self.port)
        self.back: list[threading.Timer] = []

    def reset_to(self, bootloader: bool) -> None:
        super().reset_to(bootloader)
        os.unlink(self.port)  # (it leaves the bus)
        back = threading.Timer(0.2, os.symlink, (self.path, self.port))
        back.start()
        self.back.append(back)

    def close(self) -> None:
        for back in self.back:
            back.join()
        super().close()


def test_a_usb_module_is_opened_again_once_it_has_left_not_after_a_fixed_wait(
        tmp_path, monkeypatch):
    """After 242 and 205 the updater watches the port go and opens it again when it is
    back: none of its own waits is a fixed one (it slept 1 s after each restart before)."""
    import termios
    import time
    from types import SimpleNamespace

    import tmclsh.ops.firmware as fw

    slept: list[float] = []

    def sleep(seconds: float) -> None:
        slept.append(seconds)
        time.sleep(seconds)

    monkeypatch.setattr(fw, "time", SimpleNamespace(sleep=sleep, monotonic=time.monotonic))
    monkeypatch.setattr(FirmwareUpdate, "_usb", lambda self: True)
    reopened = []
    real = FirmwareUpdate._reopen

    def counting(self):
        reopened.append(self.state)
        real(self)

    monkeypatch.setattr(FirmwareUpdate, "_reopen", counting)
    module = UsbModule(tmp_path / "ttyACM0", app_speed=termios.B115200)
    try:
        image = model_image()
        _, result, _ = run({"port": module.port, "baud": 115200}, image)
        assert (result.old_version, result.new_version) == ("1311V111", "1311V112")
        assert reopened == ["bootloader", "starting"]
        assert max(slept, default=0) < 0.1, slept  # (only looks at the port, never a wait)
    finally:
        module.close()


# -- the image measured before the restart (issue 31) --------------------------------------

@pytest.fixture
def memory_in_module_data(tmp_path):
    """A user's TMCM-1311 file that gives the application memory (the table bootloader's):
    tmclsh knows it before the module is restarted."""
    from importlib import resources

    from bootmodel import SIZE
    from tmclsh.tmcl import modules

    text = resources.files("tmclsh.tmcl.modules").joinpath("tmcm1311.toml").read_text()
    text = text.replace("program_memory = 2048\n", "program_memory = 2048\nfirmware_start = "
                        f"0x{START:X}\nfirmware_size = 0x{SIZE:X}\n", 1)
    path = tmp_path / "tmcm1311.toml"
    path.write_text(text)
    modules.add_file(path)
    yield SIZE
    modules.forget_user_files()


def test_too_large_for_the_module_data_is_refused_before_the_restart(memory_in_module_data):
    module = BootModule()
    try:
        image = model_image(size=memory_in_module_data + 256)
        update = FirmwareUpdate({"port": module.path, "timeout": 0.3}, image)
        try:
            plan = update.check()
        finally:
            update.close()
        assert plan.fits is False and plan.memory.told_by == "module data"
        assert "lies beyond the TMCM-1311's application memory" in plan.problem
        update = FirmwareUpdate({"port": module.path, "timeout": 0.3}, image)
        with pytest.raises(ImageRefused, match=r"^1311V112.hex:\d+: this record lies beyond "
                           r"the TMCM-1311's application memory \(131072 bytes at 0x00004000.."
                           r"0x00023FFF, from its module data\).*does not fit; refused before "
                           "anything was sent to change it"):
            update.run()
        update.close()
        assert 242 not in module.commands() and not module.in_bootloader
        assert update.state == APPLICATION and not update.sent_back
        assert update.situation() == "nothing was changed: the module runs its firmware 1311V111"
    finally:
        module.close()


def test_the_bootloaders_memory_decides_over_the_module_data(memory_in_module_data):
    """The module data says the memory is larger than the bootloader answers: the bootloader
    has the last word, and the firmware is started again."""
    module = BootModule()
    try:
        import bootmodel

        bootmodel_size = bootmodel.SIZE
        bootmodel.SIZE = bootmodel_size // 2  # (this module's memory: half the data's)
        try:
            update = FirmwareUpdate({"port": module.path, "timeout": 0.3},
                            model_image(size=bootmodel_size // 2 + 256))
            with pytest.raises(ImageRefused, match="does not fit; refused, nothing was erased"):
                update.run()
            update.close()
        finally:
            bootmodel.SIZE = bootmodel_size
        assert 242 in module.commands() and module.erases == 0
        assert not module.in_bootloader and update.sent_back
    finally:
        module.close()


def test_a_downgrade_is_named_in_the_question_and_the_result():
    module = BootModule()
    questions: list[str] = []
    try:
        update, result, _ = run({"port": module.path}, model_image("1311V110"),
                                confirm=lambda q: questions.append(q) or True)
        assert questions[0].startswith("Downgrade the TMCM-1311 at address 1 on ")
        assert "from 1311V111 to 1311V110, an OLDER version than it runs (" in questions[0]
        assert result.change == "downgrade" and result.to_json()["change"] == "downgrade"
        assert module.app_version == "1311V110"
        _, result, _ = run({"port": module.path}, model_image("1311V112"),
                           confirm=lambda q: questions.append(q) or True)
        assert questions[1].startswith("Update the TMCM-1311") and "OLDER" not in questions[1]
        assert result.change == "upgrade"
    finally:
        module.close()


def test_an_image_starting_in_the_bootloaders_area_is_refused_for_that():
    """Found in its bootloader, the memory is known first: an image that starts below it is
    refused for where it starts, not for the version string it lacks."""
    module = BootModule(in_bootloader=True)
    try:
        image = image_from_hex(hex_image("no string", 3000, 0x1000), "boot.hex")
        update = FirmwareUpdate({"port": module.path, "timeout": 0.1}, image)
        try:
            plan = update.check()
        finally:
            update.close()
        assert plan.problem.startswith("boot.hex:2: the image starts at 0x00001000, below the "
                                       "TMCM-1311's application memory")
        assert "bootloader's own area" in plan.problem and "version string" not in plan.problem
        with pytest.raises(ImageRefused, match="bootloader's own area"):
            run({"port": module.path, "timeout": 0.1}, image)
        assert module.erases == 0
    finally:
        module.close()


def test_a_refused_image_whose_restart_goes_unanswered_says_so():
    """The bootloader refuses the image, 205 is sent to start the firmware again, and the
    module does not answer: what is said is that, not that it waits in its bootloader."""
    from bootmodel import SIZE

    module = BootModule()
    module.hooks[205] = lambda m: setattr(m, "silent", True)  # (205 is not acted on)
    try:
        update = FirmwareUpdate({"port": module.path, "timeout": 0.2}, model_image(size=SIZE + 4))
        with pytest.raises(ImageRefused, match="does not fit; refused, nothing was erased"):
            update.run()
        update.close()
        assert module.commands()[-1] == 205 and module.erases == 0
        assert update.state == "bootloader" and not update.sent_back
        assert update.situation() == (
            "nothing was erased: 205 was sent to start its firmware 1311V111 again, but it has "
            "not answered at address 1 yet; its firmware 1311V111 is intact, and starts again "
            "when the module is switched off and on")
    finally:
        module.close()


# -- the restarts waited for by asking, not by the clock (issue 34) ---------------------------

class RestartingModule(BootModule):
    """The table's bootloader, deaf to the first request after each restart (242, 205): what
    reaches a restarting module is lost."""

    def reset_to(self, bootloader: bool) -> None:
        super().reset_to(bootloader)
        self.deaf = 1

    def answer(self, raw: bytes) -> bytes | None:
        if getattr(self, "deaf", 0):
            self.deaf -= 1
            return None
        return super().answer(raw)


def test_a_restart_is_waited_for_by_asking_not_by_a_fixed_sleep(monkeypatch):
    import termios

    import tmclsh.ops.firmware as fw

    import time
    from types import SimpleNamespace

    slept: list[float] = []  # what the update slept (its own clock only, not the model's)

    def sleep(seconds: float) -> None:
        slept.append(seconds)
        time.sleep(seconds)

    monkeypatch.setattr(fw, "time", SimpleNamespace(sleep=sleep, monotonic=time.monotonic))
    # (its application at the bootloader's baud rate: the line's rate never changes)
    module = RestartingModule(app_speed=termios.B115200)
    try:
        image = model_image()
        update, result, steps = run({"port": module.path, "baud": 115200}, image)
        assert (result.old_version, result.new_version) == ("1311V111", "1311V112")
        assert module.app_version == "1311V112" and not module.in_bootloader
        # the first 136 after each restart was lost, and asked again
        versions = [i for i, c in enumerate(module.commands()) if c == 136]
        assert len(versions) >= 4
        # nothing waited by the clock: each restart was waited for by asking
        assert slept == []
    finally:
        module.close()
