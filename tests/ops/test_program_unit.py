"""tmclsh.ops.program without a module: the checks that run before anything is sent.

The client here sits on pyserial's ``loop://`` and must never send a byte (``stats["sent"]``).
"""

from __future__ import annotations

import pytest

from tmclsh.tmcl import asm, modules
from tmclsh.ops import program
from tmclsh.client.text import LineClient
from tmclsh.base.errors import ValidationError
from tmclsh.ops.program import AppStatus, UploadError
from tmclsh.tmcl.frames import Instruction
from tmclsh.link import open_serial
from tmclsh.client.ascii import AsciiLink
from tmclsh.tmcl.frames import Request

from responder import OK, AsciiModeModule

M1311 = modules.load("TMCM-1311")


@pytest.fixture
def idle_client():
    c = LineClient(open_serial("loop://"), module="TMCM-1311", timeout=0.05, retries=0)
    yield c
    assert c.stats["sent"] == 0, "nothing may be sent by these checks"
    c.close()


def _err(acked, sent, total=10, start=0, ended=True, **kw) -> UploadError:
    return UploadError("why", start=start, total=total, acked=acked, sent=sent,
                       download_ended=ended, **kw)


def test_memory_text_midway() -> None:
    e = _err(42, 43, total=58)
    assert e.memory_text() == ("instructions 0..41 written, 42 unknown (sent, not confirmed), "
                               "43..57 unchanged (old contents)")
    assert list(e.written) == list(range(42)) and list(e.unknown) == [42]
    assert "download mode ended" in str(e) and "upload failed: why" in str(e)


def test_memory_text_edges() -> None:
    assert _err(0, 0).memory_text() == "nothing was written; the program memory is unchanged"
    assert _err(0, 1).memory_text() == ("0 unknown (sent, not confirmed), "
                                        "1..9 unchanged (old contents)")
    assert _err(10, 10).memory_text() == "instructions 0..9 written"
    assert _err(1, 1, total=3, start=100).memory_text() == \
        "instructions 100 written, 101..102 unchanged (old contents)"


def test_download_not_ended_is_said() -> None:
    e = _err(3, 4, ended=False, end_error="no reply")
    assert "could not end download mode (no reply)" in str(e)
    assert "power-cycle" in str(e)


def test_check_fits() -> None:
    program.check_fits(M1311, 0, 2048)
    program.check_fits(M1311, 2047, 1)
    with pytest.raises(ValidationError, match="only 48 fit.*2048 instructions.*nothing was sent"):
        program.check_fits(M1311, 2000, 49)
    with pytest.raises(ValidationError, match="outside program memory 0..2047"):
        program.check_fits(M1311, 2048, 1)


def test_upload_refuses_oversize_before_sending(idle_client) -> None:
    image = [Instruction(28)] * 2049
    with pytest.raises(ValidationError, match="2049 instructions"):
        program.upload(idle_client, image)
    with pytest.raises(ValidationError, match="only 8 fit"):
        program.upload(idle_client, [Instruction(28)] * 9, origin=2040)
    with pytest.raises(ValidationError, match="no instructions"):
        program.upload(idle_client, [])


class _ProgramModule(AsciiModeModule):
    """A module in its ASCII mode, from the manual (TMCM-1311 §4.4.3): RUN and STOP start
    and stop the stored program, GGP 128 reads the application status, GGP 130 the program
    counter; nothing else of
    the program's control commands exists there."""

    def __init__(self, **kw):
        self.state = 0
        super().__init__(**kw)

    def line(self, text: str) -> str | None:
        word = text[1:].strip().upper().replace(" ", "")
        answer = f"{chr(0x40 + self.host)}{self.char} {OK}"
        if text.startswith(self.char) and word in ("RUN", "STOP"):
            self.state = 1 if word == "RUN" else 0
            return f"{answer} 0"
        if text.startswith(self.char) and word == "GGP128,0":
            return f"{answer} {self.state}"
        if text.startswith(self.char) and word == "GGP130,0":
            return f"{answer} 0"  # (the program counter)
        return super().line(text)


@pytest.fixture
def ascii_module():
    module = _ProgramModule()
    c = LineClient(open_serial(module.path), module="TMCM-1311", timeout=1.0, retries=0)
    AsciiLink.attach(c)
    yield module, c
    c.close()
    module.close()


def _lines(module) -> list[str]:
    return [raw.decode("latin-1")[1:].strip() for raw in module.log if isinstance(raw, bytes)]


def test_ascii_mode_allows_only_run_and_stop(ascii_module) -> None:
    """What the module's ASCII mode does not know is refused before anything is sent (the
    framing says so, from the instruction set), not by asking which mode the link is in."""
    module, c = ascii_module
    before = list(module.log)
    for call in (lambda: program.step(c), lambda: program.reset(c),
                 lambda: program.upload(c, [Instruction(28)]),
                 lambda: program.read_program(c),
                 lambda: program.continue_to(c, {3})):
        with pytest.raises(ValidationError, match="needs binary mode.*RUN.*STOP"):
            call()
    assert module.log == before  # nothing was sent


def test_ascii_run_stop_status_are_the_instruction_sets_lines(ascii_module) -> None:
    """129 type 0 goes as RUN, 128 as STOP, 135 as GGP 128, 0 (``ascii_word``,
    ``ascii_line``); 129 type 1 has no ASCII line and is refused, nothing sent."""
    module, c = ascii_module
    program.run(c)
    assert program.status(c).state == "run"
    program.stop(c)
    assert program.status(c).state == "stop"
    asked = _lines(module)
    assert [x for x in asked if x in ("RUN", "STOP", "GGP 128, 0")] == \
        ["RUN", "GGP 128, 0", "STOP", "GGP 128, 0"]
    before = list(module.log)
    with pytest.raises(ValidationError, match="from an address.*needs binary mode"):
        program.run(c, 5)
    assert module.log == before
    # the client's request path does it for any caller, not only these operations
    assert c.request(Request(1, 129, 0, 0, 0)).status == 100 and module.state == 1


def test_end_marker_and_image_compare() -> None:
    assert program.is_end_marker(Instruction(0))
    assert program.is_end_marker(Instruction.from_bytes(b"\xff" * 7))
    assert not program.is_end_marker(Instruction(28))
    # a negative value read back (signed) equals the same bytes uploaded (unsigned)
    assert program.same_image([Instruction(4, 1, 0, 0xFFFFFFFF)], [Instruction(4, 1, 0, -1)])
    assert not program.same_image([Instruction(28)], [])


def test_status_json_and_names() -> None:
    assert AppStatus("step", 12, 2).to_json() == {"state": "step", "pc": 12}
    assert [program.state_name(i) for i in range(4)] == ["stop", "run", "step", "reset"]
    assert program.state_name(9) == "unknown(9)"


def test_user_variable_range() -> None:
    assert program.user_variable_range(M1311) == range(0, 256)


def test_upload_result_json() -> None:
    r = program.UploadResult(0, 16, True)
    assert r.to_json() == {"uploaded": 16, "verified": True}
    r = program.UploadResult(0, 16, False, program.Mismatch(3, Instruction(28), Instruction(1)))
    assert r.to_json() == {"uploaded": 16, "verified": False, "mismatch": 3}


def test_demo_program_assembles_for_every_module() -> None:
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "scripts" / "programs" / "demo" / \
        "demo-counter.tmc"
    for name in modules.available():
        prog = asm.assemble_file(path, modules.load(name))
        assert prog.labels == {"Loop": 2, "Twice": 12}
        text = asm.disassemble(prog.instructions, prog.module)
        assert program.same_image(asm.assemble(text, prog.module).instructions,
                                  prog.instructions)


def test_program_with_jumps_must_be_assembled_where_it_goes(idle_client) -> None:
    prog = asm.assemble("Here:\n    JA Here\n", M1311)
    with pytest.raises(ValidationError, match="assembled for address 0.*wrong at 10"):
        program.upload(idle_client, prog, 10)
