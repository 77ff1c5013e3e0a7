"""Source maps of uploads (tmclsh/tmcl/sourcemap.py) and what the debugger does with them: .dump
shows the source an image was uploaded from while the module's memory matches it; .step on
empty memory refuses; .connect refreshes the program state at once."""

from __future__ import annotations

import json
import os

import pytest

from tmclsh.tmcl import asm, sourcemap
from tmclsh.client.text import LineClient
from tmclsh.base.errors import TmclError
from tmclsh.tmcl.modules import load
from tmclsh.tmcl.frames import Control, Instruction, Request
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session
from tmclsh.sim import Simulator
from tmclsh.link.sim import SimTransport

from responder import Responder, reply

M1311 = load("TMCM-1311")

SOURCE = """\
// blink the output, count in a user variable
Start:  SIO 0, 2, 1          // output 0 on
        WAIT TICKS, 0, 10
        SIO 0, 2, 0          // and off
        AGP 0, 2             // placeholder: accumulator to user variable 0
        JA Start
"""


def image(text: str = SOURCE, origin: int = 0) -> list[Instruction]:
    return asm.assemble(text, M1311, "<test>", origin).instructions


# -- the cache on its own ---------------------------------------------------------------------

def test_kept_and_found_by_the_images_bytes(tmp_path):
    src = tmp_path / "blink.tmcl"
    src.write_text(SOURCE)
    path = sourcemap.save(image(), "TMCM-1311", 0, src, SOURCE)
    assert path is not None and path.parent == tmp_path / "cache" / "tmclsh" / "programs"
    found = sourcemap.lookup(image(), "TMCM-1311", 0)
    assert found is not None and found.text == SOURCE and found.file == str(src.resolve())
    # the same bytes elsewhere, on another module type, or one byte different: not this one
    assert sourcemap.lookup(image(), "TMCM-351", 0) is None
    assert sourcemap.lookup(image(SOURCE, 10), "TMCM-1311", 10) is None
    other = image(SOURCE.replace("TICKS, 0, 10", "TICKS, 0, 11"))
    assert sourcemap.lookup(other, "TMCM-1311", 0) is None
    assert sourcemap.lookup([], "TMCM-1311", 0) is None


def test_a_damaged_or_unwritable_cache_is_no_error(tmp_path, monkeypatch):
    src = tmp_path / "blink.tmcl"
    path = sourcemap.save(image(), "TMCM-1311", 0, src, SOURCE)
    path.write_text("{not json")
    assert sourcemap.lookup(image(), "TMCM-1311", 0) is None
    path.write_text(json.dumps({"version": 99}))
    assert sourcemap.lookup(image(), "TMCM-1311", 0) is None
    blocker = tmp_path / "file-not-dir"
    blocker.write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    assert sourcemap.save(image(), "TMCM-1311", 0, src, SOURCE) is None


def test_the_oldest_go_when_the_cache_is_full(tmp_path, monkeypatch):
    monkeypatch.setattr(sourcemap, "KEEP", 3)
    keys = []
    for n in range(5):
        ins = image(f"SAP 4, 0, {n}\n")
        path = sourcemap.save(ins, "TMCM-1311", 0, tmp_path / "x.tmcl", "")
        os.utime(path, (1000 + n, 1000 + n))
        keys.append(ins)
    sourcemap.save(image("MST 0\n"), "TMCM-1311", 0, tmp_path / "y.tmcl", "")
    kept = [sourcemap.lookup(k, "TMCM-1311", 0) is not None for k in keys]
    assert kept == [False, False, False, True, True]


# -- .dump --------------------------------------------------------------------------------------

@pytest.fixture
def sim():
    s = Simulator("TMCM-1311")
    yield s
    s.close()


def session_on(sim, json_mode: bool = False) -> Session:
    client = LineClient(SimTransport(simulator=sim), module="TMCM-1311", timeout=0.3)
    return Session(client, Output(json_mode=json_mode), yes=True)


def dump(s: Session, capsys) -> str:
    capsys.readouterr()
    s.run_line(".dump")
    return capsys.readouterr().out


def test_dump_gives_back_the_uploaded_source_while_memory_matches(sim, tmp_path, capsys):
    src = tmp_path / "blink.tmcl"
    src.write_text(SOURCE)
    session_on(sim).run_line(f".upload {src}")
    src.unlink()  # the file is gone: the cache still has its text
    later = session_on(sim)  # tmclsh started again, same module
    out = dump(later, capsys)
    assert "Start:  SIO 0, 2, 1          // output 0 on" in out
    assert "// blink the output, count in a user variable" in out
    assert f"// source: {src.resolve()}" in out
    assert "L0000" not in out
    # the text assembles to what the module holds
    body = out[out.index("// program memory"):]
    assert asm.assemble(body, M1311, "<dump>").instructions == image()

    # one instruction changed in the module's memory: generated labels again
    later.run_line("SAP 4, 0, 5")  # (not a program change)
    assert "Start:" in dump(later, capsys)
    # download mode at address 2, one instruction stored there (SAP 4, 0, 1), quit download
    # (downloading: status 101 is expected; outside an upload it is a DownloadModeError)
    later.client._downloading = True
    later.client.request(Request(1, Control.START_DOWNLOAD, 0, 0, 2))
    later.client.request(Request(1, 5, 4, 0, 1))
    later.client.request(Request(1, Control.QUIT_DOWNLOAD, 0, 0, 0))
    later.client._downloading = False
    out = dump(later, capsys)
    assert "Start:" not in out and "// output 0 on" not in out
    assert "L0000:" in out  # the jump target, generated


def test_dump_without_a_kept_source_generates_labels(sim, tmp_path, capsys, monkeypatch):
    src = tmp_path / "blink.tmcl"
    src.write_text(SOURCE)
    session_on(sim).run_line(f".upload {src}")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "another-user"))
    out = dump(session_on(sim), capsys)
    assert "L0000:" in out and "Start:" not in out


def test_dump_json_names_the_upload(sim, tmp_path, capsys):
    src = tmp_path / "blink.tmcl"
    src.write_text(SOURCE)
    s = session_on(sim, json_mode=True)
    s.run_line(f".upload {src}")
    capsys.readouterr()
    s.run_line(".dump")
    obj = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert obj["dumped"] == 5 and obj["uploaded_from"] == str(src.resolve())
    assert "Start:" in obj["source"]


def test_an_image_upload_lists_its_disassembly_and_dump_names_it(sim, tmp_path, capsys):
    """Issue 23: .list after `.upload loop.bin` printed the image's bytes (escape characters
    into the terminal), and .dump named an older upload of the same bytes from source."""
    src = tmp_path / "blink.tmcl"
    src.write_text(SOURCE)
    binary = tmp_path / "blink.bin"
    binary.write_bytes(asm.image_bytes(image()))
    s = session_on(sim)
    s.run_line(f".upload {src}")
    s.run_line(f".upload {binary}")  # the same bytes, from the image this time
    capsys.readouterr()
    s.run_line(".list")
    listing = capsys.readouterr().out
    assert "SIO 0, 2, 1" in listing and "JA 0" in listing
    assert all(ch.isprintable() for line in listing.splitlines() for ch in line)
    assert "@5  (no instruction stored)" in listing  # past the image: the end marker
    out = dump(s, capsys)
    assert f"// uploaded from the image {binary.resolve()}" in out
    assert "Start:" not in out and "// output 0 on" not in out  # not the older source
    body = out[out.index("// program memory"):]
    assert asm.assemble(body, M1311, "<dump>").instructions == image()
    js = session_on(sim, json_mode=True)
    capsys.readouterr()
    js.run_line(".dump")
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["uploaded_from"] == str(
        binary.resolve())
    # and the source again: .dump names it again
    s.run_line(f".upload {src}")
    assert "Start:  SIO 0, 2, 1" in dump(s, capsys)


# -- .step on empty memory, against a module written from the manual's byte tables -------------

class EmptyModule(Responder):
    """A TMCM-1311 that has never stored a program (tests/responder.py: the manual's frame
    layout only): 134 answers an all-zero stored instruction, GGP 130 (the program counter) 0,
    135 (status) 0 = stopped, every other command status 100, value 0."""

    def answer(self, raw: bytes) -> bytes | None:
        if raw[1] == 134:  # the stored instruction in place of module, status, command
            body = bytes([2, 0, 0, 0]) + (0).to_bytes(4, "big")
            return body + bytes([sum(body) & 0xFF])
        return reply(raw[1], 0)  # every value the debugger asks for (pc, state) is 0 here


def test_step_on_empty_memory_says_so_and_sends_no_step():
    from tmclsh.link import open_serial

    module = EmptyModule()
    client = LineClient(open_serial(module.path), module="TMCM-1311", timeout=0.5, retries=0)
    try:
        s = Session(client, Output(), yes=True)
        with pytest.raises(TmclError, match=r"program memory of the TMCM-1311 is empty"):
            s.run_line(".step")
        assert 130 not in module.commands()  # nothing stepped
        assert 134 in module.commands()  # it looked at the memory
        assert s.state.repeat_on_empty is None  # an empty line will not try again
    finally:
        client.close()
        module.close()


def test_step_past_the_end_of_a_program(sim, tmp_path):
    src = tmp_path / "one.tmcl"
    src.write_text("SAP 4, 0, 1\n")
    s = session_on(sim)
    s.run_line(f".upload {src}")
    s.run_line(".step")
    assert s.state.program_state == "step @1"
    with pytest.raises(TmclError, match=r"no instruction at @1 \(the end of the stored"):
        s.run_line(".step")
    assert s.state.program_state == "step @1"  # nothing was stepped


# -- .connect --------------------------------------------------------------------------------

def test_connect_refreshes_the_program_state(sim, tmp_path):
    src = tmp_path / "loop.tmcl"
    src.write_text("Loop: WAIT TICKS, 0, 100\nJA Loop\n")
    s = session_on(sim)
    s.run_line(f".upload {src}")
    s.run_line(".run")
    assert s.state.program_state == "run"
    s.run_line(".connect sim TMCM-1311")  # another (simulated) module: nothing runs there
    assert s.state.program_state == "stop"
    s.state.program_state = "run"  # what the prompt showed before a cable was pulled
    s.run_line(".connect")  # the same link again: read at once, not remembered
    assert s.state.program_state == "stop"
    s.client.close()
