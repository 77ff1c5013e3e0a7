"""Uploading, reading back, stepping and running programs against the simulator.

Through real bytes: a ``LineClient`` on the in-process simulator (``SimTransport``), on a
pty-served one (``tmclsh.sim.serve``) and on a python-can virtual bus. Faults come from the
simulator's ``Faults``; a test "presses Ctrl-C" or "pulls the cable" from a client tracer, at
the moment a given frame has been sent.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from tmclsh.tmcl import asm
from tmclsh.ops import program
from tmclsh.client.text import LineClient
from tmclsh.base.errors import TmclError, ValidationError
from tmclsh.ops.program import UploadError
from tmclsh.tmcl.frames import Instruction
from tmclsh.shell.features import debugger
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session
from tmclsh.sim import Simulator
from tmclsh.link.sim import SimTransport
from manuals import listing

# TMCM-1311 TMCL firmware manual (V1.11, rev. 1.17), §5.6.5 "Using Interrupts in TMCL":
# the timer-interrupt example, as printed.
TIMER_EXAMPLE = listing("tmcm1311-timer-interrupt")
# source line of each address (the file starts with the listing above)
TIMER_LINES = {0: 1, 1: 2, 2: 3, 3: 4, 4: 8, 5: 9, 6: 10, 7: 11, 8: 12, 9: 16, 10: 17,
               11: 18, 12: 19, 13: 21, 14: 22}
DEMO = Path(__file__).resolve().parents[2] / "scripts" / "programs" / "demo" / "demo-counter.tmc"
SPEED = 50.0  # module time runs this much faster: WAIT TICKS, 0, 50 takes 10 ms


@pytest.fixture
def sim():
    s = Simulator("TMCM-1311", speed=SPEED)
    yield s
    s.close()


@pytest.fixture
def client(sim):
    c = LineClient(SimTransport(simulator=sim), module="TMCM-1311", timeout=0.3)
    yield c
    c.close()


@pytest.fixture
def timer_file(tmp_path) -> Path:
    p = tmp_path / "timer.tmc"
    p.write_text(TIMER_EXAMPLE, encoding="utf-8")
    return p


def json_session(client) -> Session:
    return Session(client, Output(json_mode=True), yes=True)


def run_json(session: Session, capsys, line: str) -> list[dict]:
    capsys.readouterr()
    session.run_line(line)
    objs = [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.strip()]
    assert all(o.pop("simulated") is True for o in objs), objs  # the simulator says so
    return objs


def fail_at_frame(client, frame: int, action) -> None:
    """Call ``action()`` right after the ``frame``-th instruction frame (1-based) of a
    download went out (132 itself not counted). The in-process simulator answers a frame as
    it is written, so a reply fault set here hits the reply to the *next* frame."""
    seen = [0]

    def tracer(direction, raw, decoded):
        if direction != "tx" or not client._downloading:
            return
        op = getattr(decoded, "opcode", None)
        if op is not None and op < 128:
            seen[0] += 1
            if seen[0] == frame:
                action()

    client.add_tracer(tracer)


# -- the acceptance walk-through, through the Python API ----------------------------------

def test_manual_example_upload_verify_readback_step_break_stop_reset(client, sim, timer_file):
    prog = asm.assemble_file(timer_file, client.require_module())
    assert len(prog) == 15
    result = program.upload(client, prog)
    assert (result.count, result.verified, result.start) == (15, True, 0)
    assert result.to_json() == {"uploaded": 15, "verified": True}
    assert not program.download_mode(client)

    image = program.read_program(client)  # up to the end marker
    assert program.same_image(image, prog.instructions)
    text = asm.disassemble(image, client.module)
    assert program.same_image(asm.assemble(text, client.module).instructions, image)

    st = program.status(client)
    assert (st.state, st.pc) == ("stop", 0)
    seen = []
    for _ in range(5):
        program.step(client)
        st = program.status(client)
        seen.append((st.state, st.pc, prog.loc(st.pc).line))
    assert seen == [("step", 1, 2), ("step", 2, 3), ("step", 3, 4), ("step", 4, 8),
                    ("step", 5, 9)]

    # run to the JA at the end of the main loop: through both WAITs, by stepping
    info = program.continue_to(client, {prog.labels["Loop"] + 4})
    assert (info.reason, info.pc) == ("breakpoint", 8)
    assert program.status(client).state == "step"
    # and once more round the loop to the same breakpoint
    info = program.continue_to(client, {8})
    assert (info.reason, info.pc) == ("breakpoint", 8) and info.steps >= 5

    program.run(client)
    assert program.status(client).state == "run"
    program.stop(client)
    assert program.status(client).state == "stop"
    program.reset(client)
    st = program.status(client)
    assert (st.state, st.pc) == ("reset", 0)


def test_continue_stops_when_the_program_ends(client):
    prog = asm.assemble("    SIO 0, 2, 1\n    SIO 0, 2, 0\n    STOP\n", client.require_module())
    program.upload(client, prog)
    info = program.continue_to(client, {40})
    assert info.reason == "ended" and info.pc == 2
    info = program.continue_to(client, {40}, max_steps=1)
    assert info.reason in ("ended", "limit")


def test_run_from_address_and_program_counter(client, sim):
    prog = asm.assemble("    SIO 0, 2, 1\nHere:\n    JA Here\n", client.require_module())
    program.upload(client, prog)
    program.run(client, 1)
    client.wait_until(lambda: program.program_counter(client) == 1, timeout=2)
    assert program.status(client).state == "run"
    assert sim.io is not None and program.status(client).pc == 1
    program.stop(client)
    with pytest.raises(ValidationError, match="outside program memory"):
        program.run(client, 5000)


def test_upload_at_an_address_and_read_back(client):
    prog = asm.assemble_file(DEMO, client.require_module(), origin=100)
    result = program.upload(client, prog)
    assert result.start == 100 and result.verified
    assert program.same_image(program.read_program(client, 100), prog.instructions)
    assert program.read_program(client, 0) == []  # nothing at 0: the end marker


# -- interrupted uploads ------------------------------------------------------------------

def _old_then_new(client, sim):
    """Store the demo program, then prepare the manual example to overwrite it."""
    module = client.require_module()
    old = asm.assemble_file(DEMO, module)
    program.upload(client, old)
    new = asm.assemble(TIMER_EXAMPLE, module)
    return old, new


def test_a_corrupted_reply_during_upload_stores_the_program_again_from_132(client, sim):
    """A damaged reply on a line that works (the 133 after it is answered): that frame may
    be stored, so it cannot be sent again alone; the whole program is, from 132, and the
    verify says it is all there."""
    old, new = _old_then_new(client, sim)
    notices: list[str] = []
    client.on_notice = notices.append

    def corrupt():
        sim.faults.corrupt_next = 1

    fail_at_frame(client, 5, corrupt)  # the reply to frame 6 (address 5) is corrupted
    result = program.upload(client, new)
    assert result.verified
    assert len(notices) == 1 and "corrupted reply" in notices[0]
    assert "storing the program again from address 0 (attempt 2 of 3)" in notices[0]
    assert program.same_image(program.read_program(client, 0, 15), new.instructions)
    assert sim.param("global", 129) == 0


def test_corrupted_reply_during_upload(client, sim):
    """With no retries (--retries 0) the upload stops at the damaged reply and says what
    the memory holds."""
    old, new = _old_then_new(client, sim)
    client.retries = 0

    def corrupt():
        sim.faults.corrupt_next = 1

    fail_at_frame(client, 5, corrupt)  # the reply to frame 6 (address 5) is corrupted
    with pytest.raises(UploadError) as err:
        program.upload(client, new)
    e = err.value
    msg = str(e)
    assert "corrupted reply" in msg
    assert "instructions 0..4 written, 5 unknown (sent, not confirmed), 6..14 unchanged " \
           "(old contents)" in msg
    assert "download mode ended" in msg and e.download_ended
    assert sim.param("global", 129) == 0  # GP 129: download mode is over
    assert not program.download_mode(client)  # and the link is usable again
    stored = program.read_program(client, 0, 16)
    assert program.same_image(stored[:5], new.instructions[:5])
    assert program.same_image(stored[6:16], old.instructions[6:16])


def test_lost_link_during_upload_all_replies_dropped(client, sim):
    _old, new = _old_then_new(client, sim)

    def pull():
        sim.faults.drop_next = 10**6  # the module still hears us; nothing comes back

    fail_at_frame(client, 3, pull)  # replies from frame 4 (address 3) on are lost
    began = time.monotonic()
    with pytest.raises(UploadError) as err:
        program.upload(client, new)
    assert time.monotonic() - began < 3
    e = err.value
    assert "link lost (no reply" in str(e)
    assert e.memory_text() == ("instructions 0..2 written, 3 unknown (sent, not confirmed), "
                               "4..14 unchanged (old contents)")
    # 133 went out (more than once) but its answer was lost too: said so, plainly
    assert not e.download_ended
    assert "could not end download mode" in str(e) and "power-cycle" in str(e)
    assert sim.param("global", 129) == 0  # the module did end download mode
    sim.faults.drop_next = 0
    assert not program.download_mode(client)


def test_lost_link_during_upload_pty_closed(sim):
    from tmclsh.sim.serve import serve_pty
    from tmclsh.link import open_serial

    server = serve_pty(sim)
    c = LineClient(open_serial(server.path), module="TMCM-1311", timeout=0.3)
    try:
        module = c.require_module()
        fail_at_frame(c, 5, server.close)
        with pytest.raises(UploadError) as err:
            program.upload(c, asm.assemble(TIMER_EXAMPLE, module))
        e = err.value
        assert "link lost" in str(e)
        assert e.acked in (4, 5) and not e.download_ended  # frame 5's reply may be out
        assert f"instructions 0..{e.acked - 1} written" in str(e)
        assert "could not end download mode" in str(e)
        # the module never heard 133; on a new link, 133 alone ends download mode
        assert sim.param("global", 129) == 1
    finally:
        c.close()
        server.close()
    server = serve_pty(sim)
    c = LineClient(open_serial(server.path), module="TMCM-1311", timeout=0.3)
    try:
        program.end_download(c)
        assert sim.param("global", 129) == 0
    finally:
        c.close()
        server.close()


def test_ctrl_c_during_upload_ends_download_mode(client, sim):
    _old, new = _old_then_new(client, sim)

    def ctrl_c():
        raise KeyboardInterrupt

    fail_at_frame(client, 7, ctrl_c)
    with pytest.raises(KeyboardInterrupt) as err:  # Ctrl-C stays Ctrl-C for the caller
        program.upload(client, new)
    e = err.value.__cause__  # what the memory holds now
    assert isinstance(e, UploadError) and e.interrupted and e.download_ended
    assert "upload failed: interrupted (Ctrl-C); instructions 0..5 written, 6 unknown" in str(e)
    assert sim.param("global", 129) == 0
    assert program.status(client).state == "stop"


def test_verify_reports_first_mismatch(client, sim):
    prog = asm.assemble(TIMER_EXAMPLE, client.require_module())

    def tamper(phase, done, total):
        if phase == "upload" and done == total:
            sim.vm.memory[3] = Instruction(25, 1, 0, 0)  # EI 1 instead of EI 255

    result = program.upload(client, prog, progress=tamper)
    assert result.verified is False
    assert result.mismatch is not None and result.mismatch.address == 3
    assert result.to_json() == {"uploaded": 15, "verified": False, "mismatch": 3}


# -- the shell commands -------------------------------------------------------------------

def test_shell_walkthrough_json(client, sim, timer_file, tmp_path, capsys):
    s = json_session(client)
    assert run_json(s, capsys, f".upload {timer_file}") == [{"uploaded": 15, "verified": True}]
    assert s.state.program_state == "stop"

    out = run_json(s, capsys, ".status")
    assert out == [{"state": "stop", "pc": 0, "file": str(timer_file), "line": 1,
                    "text": "VECT 0, Timer0Irq  //define the interrupt vector"}]

    (step,) = run_json(s, capsys, ".step")
    assert (step["state"], step["pc"], step["line"]) == ("step", 1, 2)
    assert step["text"].startswith("SGP 0, 3, 1000")
    assert s.state.repeat_on_empty == ".step"
    assert s.state.program_state == "step @1"
    steps = run_json(s, capsys, ".step 3")
    assert [(o["pc"], o["line"], o["step"]) for o in steps] == [(2, 3, 1), (3, 4, 2), (4, 8, 3)]
    assert s.state.repeat_on_empty == ".step 3"

    run_json(s, capsys, ".display GGP 0, 2")
    (bp,) = run_json(s, capsys, ".break 12")  # the line of "JA Loop"
    assert (bp["breakpoint"], bp["address"], bp["line"]) == (1, 8, 12)
    (hit,) = run_json(s, capsys, ".continue")
    assert (hit["reason"], hit["pc"], hit["line"], hit["breakpoint"]) == \
        ("breakpoint", 8, 12, 1)
    assert hit["display"] == {"GGP 0, 2": "0"}
    assert s.state.repeat_on_empty is None

    (stopped,) = run_json(s, capsys, ".stop")
    assert (stopped["state"], stopped["pc"]) == ("stop", 8)
    (reset,) = run_json(s, capsys, ".reset")
    assert (reset["state"], reset["pc"], reset["line"]) == ("reset", 0, 1)
    assert s.state.program_state == "reset"

    (ran,) = run_json(s, capsys, ".run Loop")
    assert ran["state"] == "run"
    run_json(s, capsys, ".stop")

    dumped = tmp_path / "dumped.tmc"
    (d,) = run_json(s, capsys, f".dump {dumped}")
    assert d == {"dumped": 15, "file": str(dumped), "identical": True,
                 "uploaded_from": str(timer_file.resolve())}  # the source map of the upload
    again = asm.assemble_file(dumped, client.module)
    assert program.same_image(again.instructions, asm.assemble_file(timer_file, client.module)
                              .instructions)


def test_shell_people_output(client, sim, timer_file, capsys):
    s = Session(client, Output(), yes=True)
    s.run_line(f".upload {timer_file}")
    out = capsys.readouterr().out
    assert "uploaded 15 instructions from timer.tmc to 0..14" in out
    assert "verified: read back identical" in out
    s.run_line(".step 2")
    out = capsys.readouterr().out
    assert "step @1" in out and "timer.tmc:2" in out and "SGP 0, 3, 1000" in out
    assert "step @2" in out and "timer.tmc:3" in out
    s.run_line(".list")
    out = capsys.readouterr().out
    assert "->" in out and "@2" in out and "EI 0" in out and "//define the interrupt" in out
    s.run_line(".where")
    assert "timer.tmc:3" in capsys.readouterr().out
    s.run_line(".break Timer0Irq")
    assert "breakpoint 1 at @9" in capsys.readouterr().out


def test_shell_without_source_shows_disassembly(client, sim, capsys):
    prog = asm.assemble(TIMER_EXAMPLE, client.require_module())
    sim.load_program(prog.instructions)  # stored by someone else: no source known here
    s = Session(client, Output(), yes=True)
    s.run_line(".step")
    out = capsys.readouterr().out
    assert "step @1" in out and "SGP 0, 3, 1000" in out and "timer" not in out
    s.run_line(".break 5")  # no source: a number is an address
    s.run_line(".break L0009")
    s.run_line(".list")
    out = capsys.readouterr().out
    assert "@5" in out and "WAIT TICKS, 0, 50" in out and "B" in out


def test_shell_source_map(client, sim, timer_file, tmp_path, capsys):
    sim.load_program(asm.assemble(TIMER_EXAMPLE, client.require_module()).instructions)
    s = Session(client, Output(), yes=True)
    s.run_line(f".source-map {timer_file}")
    assert "matches the stored program" in capsys.readouterr().out
    s.run_line(".step")
    assert "timer.tmc:2" in capsys.readouterr().out
    other = tmp_path / "other.tmc"
    other.write_text(TIMER_EXAMPLE.replace("EI 255", "EI 1"))
    s.run_line(f".source-map {other}")
    assert "differs from other.tmc at address 3" in capsys.readouterr().err


def test_shell_upload_interrupted_message(client, sim, timer_file, capsys):
    s = Session(client, Output(), yes=True)
    s.run_line(f".upload {DEMO}")
    client.retries = 0  # (else the program is stored again, and the upload succeeds)

    def corrupt():
        sim.faults.corrupt_next = 1

    fail_at_frame(client, 2, corrupt)
    with pytest.raises(UploadError, match="instructions 0..1 written, 2 unknown .*"
                                          "download mode ended"):
        s.run_line(f".upload {timer_file}")
    assert debugger.state(s).program is None  # half old, half new: no source map
    assert sim.param("global", 129) == 0


def test_shell_verify_failure_is_an_error(client, sim, timer_file, capsys):
    s = json_session(client)
    tampered = [False]

    def tracer(direction, raw, decoded):
        if direction == "tx" and getattr(decoded, "opcode", None) == 134 and not tampered[0]:
            tampered[0] = True
            sim.vm.memory[5] = Instruction(27, 0, 0, 51)

    client.add_tracer(tracer)
    with pytest.raises(TmclError, match=r"verify failed at address 5 \(.*timer.tmc:9\): "
                                        "uploaded 'WAIT TICKS, 0, 50', the module holds "
                                        "'WAIT TICKS, 0, 51'"):
        s.run_line(f".upload {timer_file}")
    (obj,) = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert obj["uploaded"] == 15 and obj["verified"] is False and obj["mismatch"] == 5


def test_shell_vars_and_display_with_demo(client, sim, capsys):
    s = Session(client, Output(), yes=True)
    s.run_line(f".upload {DEMO}")
    s.run_line(".display GGP 0, 2")
    s.run_line(".break Twice")
    capsys.readouterr()
    s.run_line(".continue")
    out = capsys.readouterr().out
    assert "breakpoint 1" in out and "demo-counter.tmc:31" in out and "GGP 0, 2 = 1" in out
    s.run_line(".delete")
    s.run_line(".run")
    client.wait_until(lambda: program.status(client).state == "stop", timeout=5)
    capsys.readouterr()
    s.run_line(".vars")
    out = capsys.readouterr().out
    assert "#0" in out and "10" in out and "#1" in out and "20" in out
    assert "254 more are 0" in out
    s.run_line(".vars 0..2")
    out = capsys.readouterr().out
    assert "#2" in out


def test_too_large_program_refused_before_sending(client, tmp_path):
    s = Session(client, Output(), yes=True)
    sent = client.stats["sent"]
    with pytest.raises(ValidationError, match="only 8 fit"):
        program.upload(client, [Instruction(28)] * 9, origin=2040)
    assert client.stats["sent"] == sent
    big = tmp_path / "big.tmc"
    big.write_text("    STOP\n" * 2049)
    with pytest.raises(TmclError, match="holds 2048"):
        s.run_line(f".upload {big}")
    assert client.stats["sent"] == sent


# -- other links --------------------------------------------------------------------------

def test_upload_and_step_over_can(sim):
    pytest.importorskip("can")
    from tmclsh.sim.serve import serve_can
    from tmclsh.link import open_can

    channel = f"tmclsh-program-{id(sim)}"
    server = serve_can(sim, "virtual", channel)
    c = LineClient(open_can(f"virtual:{channel}"), module="TMCM-1311", timeout=0.5)
    try:
        prog = asm.assemble(TIMER_EXAMPLE, c.require_module())
        assert program.upload(c, prog).verified
        assert program.same_image(program.read_program(c), prog.instructions)
        program.step(c)
        assert program.status(c).to_json() == {"state": "step", "pc": 1}
        program.reset(c)
    finally:
        c.close()
        server.close()


def test_ascii_mode_run_stop_status(sim):
    from tmclsh.client.ascii import AsciiLink

    c = LineClient(SimTransport(simulator=sim), module="TMCM-1311", timeout=0.5)
    try:
        prog = asm.assemble(TIMER_EXAMPLE, c.require_module())
        program.upload(c, prog)
        AsciiLink.attach(c)
        assert c.mode == "ascii"
        s = json_session(c)
        s.run_line(".run")
        assert program.status(c).state == "run"
        s.run_line(".stop")
        assert program.status(c).state == "stop"
        for line, what in ((".step", "stepping"), (".reset", "reset"),
                           (".dump", "reading program memory"), (".run Loop", "address")):
            with pytest.raises(ValidationError, match=f"{what}.*needs binary mode"):
                s.run_line(line)
    finally:
        c.close()


def test_shell_ctrl_c_during_upload(client, sim, timer_file, capsys):
    s = Session(client, Output(), yes=True)

    def ctrl_c():
        raise KeyboardInterrupt

    fail_at_frame(client, 4, ctrl_c)
    # the message says what is in memory; then Ctrl-C goes on to the shell (which stops motors)
    with pytest.raises(KeyboardInterrupt):
        s.run_line(f".upload {timer_file}")
    err = capsys.readouterr().err
    assert "interrupted (Ctrl-C); instructions 0..2 written, 3 unknown" in err
    assert "download mode ended" in err
    assert sim.param("global", 129) == 0


def test_shell_ctrl_c_during_continue(client, sim, timer_file, capsys):
    s = Session(client, Output(), yes=True)
    s.run_line(f".upload {timer_file}")
    s.run_line(".break Timer0Irq")  # never reached by stepping: no interrupts in step mode
    calls = [0]

    def tracer(direction, raw, decoded):
        if direction == "tx" and getattr(decoded, "opcode", None) == 130:
            calls[0] += 1
            if calls[0] == 12:
                raise KeyboardInterrupt

    client.add_tracer(tracer)
    capsys.readouterr()
    with pytest.raises(KeyboardInterrupt):
        s.run_line(".continue")
    out = capsys.readouterr()
    assert "interrupted after 11 steps" in out.out + out.err
    assert "step @" in out.out
    assert program.status(client).state == "step"


def test_stop_with_no_program_says_so_rather_than_showing_zeros(client, capsys):
    """Memory never written reads 0 0, 0, 0: no command, so no disassembly of one."""
    Session(client, Output(), yes=True).run_line(".stop")
    out = capsys.readouterr().out
    assert out.startswith("stop @0") and "the end of the stored program" in out
    assert "0, 0, 0" not in out
    (obj,) = run_json(json_session(client), capsys, ".status")
    assert obj["state"] == "stop" and obj["pc"] == 0 and obj["end"] is True and "text" not in obj


# -- issue 35: the rough edges a first try found -----------------------------------------

# 7 instructions on 8 lines: the last line (`JA Loop` at @6) is the one a window cut off
EIGHT_LINES = ("// blink\n"
               "Loop:   SIO 0, 2, 1\n"
               "        WAIT TICKS, 0, 5\n"
               "        SIO 0, 2, 0\n"
               "        WAIT TICKS, 0, 5\n"
               "        SAP 4, 0, 1000\n"
               "        SAP 4, 0, 0\n"
               "        JA Loop\n")


def test_list_shows_a_short_program_whole(client, tmp_path, capsys):
    src = tmp_path / "blink.tmc"
    src.write_text(EIGHT_LINES, encoding="utf-8")
    s = Session(client, Output(), yes=True)
    s.run_line(f".upload {src}")
    capsys.readouterr()
    s.run_line(".list")
    out = capsys.readouterr().out
    assert "8     @6  " in out and "JA Loop" in out and "..." not in out


def test_list_marks_a_cut_window_and_takes_a_range(client, timer_file, capsys):
    s = Session(client, Output(), yes=True)
    s.run_line(f".upload {timer_file}")  # 22 lines: longer than a whole listing
    capsys.readouterr()
    s.run_line(".list")
    out = capsys.readouterr().out.splitlines()
    assert out[-1].strip() == "..." and "..." not in out[0]
    s.run_line(".list 1 8")
    out = capsys.readouterr().out
    rows = [x for x in out.splitlines() if x.strip() != "..."]
    assert [int(r[4:8]) for r in rows] == list(range(1, 9))
    assert "unknown label" not in out and out.rstrip().endswith("...")
    for arg in ("1,8", "1-8", "1..8", "@0 @4"):
        s.run_line(f".list {arg}")
        assert capsys.readouterr().out == out
    js = json_session(client)
    js.run_line(f".upload {timer_file}")
    objs = run_json(js, capsys, ".list 2 3")
    assert [r["line"] for r in objs[0]["lines"]] == [2, 3]
    assert objs[0]["more"] == {"before": True, "after": True}


def test_continue_stops_at_the_end_of_the_stored_program(client, capsys):
    """Past the last instruction memory is empty: .continue stops there and says why,
    instead of stepping on through empty memory until Ctrl-C."""
    prog = asm.assemble("    SIO 0, 2, 1\n    SIO 0, 2, 0\n", client.require_module())
    program.upload(client, prog)
    info = program.continue_to(client, {40}, max_steps=50)
    assert (info.reason, info.pc, info.steps) == ("end", 2, 2)
    again = program.continue_to(client, {40}, max_steps=50)  # nothing more is stepped
    assert (again.reason, again.steps) == ("end", 0)
    s = Session(client, Output(), yes=True)
    s.run_line(".break @40")
    capsys.readouterr()
    s.run_line(".continue 50")
    out = capsys.readouterr().out
    assert "end of the stored program, no breakpoint reached" in out and "0 steps" in out


def test_step_after_a_binary_upload_cites_the_disassembly(client, tmp_path, capsys):
    image = tmp_path / "pp.bin"
    image.write_bytes(asm.assemble(EIGHT_LINES, client.require_module()).to_binary())
    s = Session(client, Output(), yes=True)
    s.run_line(f".upload {image}")
    capsys.readouterr()
    s.run_line(".step")
    out = capsys.readouterr().out
    assert "step @1" in out and "WAIT TICKS, 0, 5" in out and "pp.bin:" not in out


def test_upload_question_says_the_program_is_running(client, tmp_path):
    src = tmp_path / "blink.tmc"
    src.write_text(EIGHT_LINES, encoding="utf-8")
    program.upload(client, asm.assemble(EIGHT_LINES, client.require_module()))
    program.run(client)
    asked: list[str] = []
    s = Session(client, Output(), interactive=True)
    s.ask = lambda q: asked.append(q) or False
    with pytest.raises(Exception, match="cancelled"):
        s.run_line(f".upload {src}")
    assert asked and asked[0].startswith("the stored program is running (at @")
    assert "the upload stops it" in asked[0]
    program.stop(client)
    s.run_line(".reset")
    asked.clear()
    with pytest.raises(Exception, match="cancelled"):
        s.run_line(f".upload {src}")
    assert asked[0].startswith("overwrite")
