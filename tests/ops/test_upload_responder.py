"""An upload and its verify against a module written from the manual (``tests/responder.py``),
not the simulator: the request path's fast lanes for thousands of frames (issue 34) keep every
safety property. Each frame is stored once and answered LOADED, a refused frame ends the upload
and download mode, the verify compares every word, and a copy of one read-back taken for the
next cell's answer never passes that cell.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from tmclsh.client.text import LineClient
from tmclsh.link import open_serial
from tmclsh.ops import program
from tmclsh.base.errors import TmclError
from tmclsh.ops.program import UploadError
from tmclsh.base.interrupts import Terminated, stopped_by
from conftest import ROOT, patience, tmclsh_env
from tmclsh.tmcl import asm
from tmclsh.tmcl.frames import Instruction

from responder import LOADED, INVALID_VALUE, Responder, fields, reply

START, QUIT, READ = 132, 133, 134


class ProgramModule(Responder):
    """A TMCM-1311 with program memory, as the manual's control commands describe it: 132
    starts download mode at the value's address, every frame then is stored (status 101, its
    value echoed) until 133; 134 answers the stored instruction in the legacy layout (reply
    address, then the seven stored bytes, then the checksum). ``refuse_at``: the address
    whose frame is answered status 4 and not stored. ``stored_instead``: address -> the
    seven bytes the cell holds whatever was sent (a cell that went bad). ``copy_first``:
    addresses whose 134 is answered by a copy of the read-back before, then its own (a line
    that repeats a reply, late)."""

    def __init__(self, **kw):
        self.memory: dict[int, bytes] = {}
        self.downloading = False
        self.at = 0
        self.stores: list[int] = []  # every address a frame was stored at, in order
        self.refuse_at: int | None = None
        self.stored_instead: dict[int, bytes] = {}
        self.copy_first: set[int] = set()
        self.lose_at: int | None = None  # the address whose frame is stored, its reply lost
        self.lose_once: set[int] = set()  # ... the first time only (a noisy line)
        self.lose_start_once = False  # the first 132's reply lost (download mode begun)
        self.starts = 0  # 132s heard
        self.last_read = b""
        super().__init__(**kw)

    def answer(self, raw: bytes) -> bytes | None:
        addr, cmd, _, _, value = fields(raw)
        if addr != 1:
            return None
        if cmd == START:
            self.downloading, self.at = True, value
            self.starts += 1
            if self.lose_start_once:
                self.lose_start_once = False
                return None
            return reply(cmd, value)
        if cmd == QUIT:
            self.downloading = False
            return reply(cmd, 0)
        if self.downloading and cmd < 128:
            if self.at == self.refuse_at:
                return reply(cmd, value, INVALID_VALUE)
            self.memory[self.at] = self.stored_instead.get(self.at, raw[1:8])
            self.stores.append(self.at)
            self.at += 1
            if self.at - 1 == self.lose_at:
                return None
            if self.at - 1 in self.lose_once:
                self.lose_once.discard(self.at - 1)
                return None
            return reply(cmd, value, LOADED)
        if cmd == READ:
            body = bytes([2]) + self.memory.get(value, bytes(7))
            own = body + bytes([sum(body) & 0xFF])
            out = (self.last_read + own) if value in self.copy_first else own
            self.last_read = own
            return out
        return super().answer(raw)


@pytest.fixture
def module():
    m = ProgramModule()
    yield m
    m.close()


@pytest.fixture
def client(module):
    c = LineClient(open_serial(module.path), module="TMCM-1311", timeout=1.0, retries=2)
    yield c
    c.close()


def _program(n: int) -> list[Instruction]:
    """``n`` instructions with values of every sign and width (SGP n, 2, value)."""
    return [Instruction(9, i % 56, 2, (-1) ** i * (i * 977_123 % 2**31)) for i in range(n)]


def test_every_frame_stored_once_and_every_word_verified(module, client):
    prog = _program(300)
    result = program.upload(client, prog, origin=5)
    assert result.verified is True and result.mismatch is None
    assert module.stores == list(range(5, 305))  # each once, in order, none repeated
    assert [module.memory[5 + i] for i in range(300)] == [i.to_bytes() for i in prog]
    assert not module.downloading
    assert client.stats["timeouts"] == 0


def test_a_refused_frame_ends_the_upload_and_download_mode(module, client):
    module.refuse_at = 40
    with pytest.raises(UploadError) as info:
        program.upload(client, _program(100))
    err = info.value
    assert (err.acked, err.sent, err.download_ended) == (40, 40, True)
    assert "instruction at address 40" in str(err)
    assert module.stores == list(range(40))  # nothing after the refused frame was sent
    assert not module.downloading


def test_one_lost_reply_is_not_called_a_lost_link_when_the_module_answers_133(module, client):
    """One stored frame's reply lost on a noisy line: the module answered the 133 after it,
    so the link is there; the upload says which reply did not come, not 'link lost'."""
    module.lose_at = 7
    with pytest.raises(UploadError) as info:
        program.upload(client, _program(20))
    err = info.value
    assert err.download_ended and not module.downloading
    assert (err.acked, err.sent) == (7, 8)
    assert "link lost" not in str(err)
    assert str(err).startswith("upload failed: no reply to SGP from address 1 within 1 s;")


def test_a_reply_lost_once_stores_the_whole_program_again_from_132(module, client):
    """A noisy line loses one frame's reply: that frame may be stored or not, and one sent
    again would be stored twice; so download mode is ended and the program stored again
    from its start, whole, each frame once per attempt, and verified."""
    notices: list[str] = []
    client.on_notice = notices.append
    module.lose_once = {12}
    prog = _program(30)
    result = program.upload(client, prog, origin=3)
    assert result.verified and not module.downloading
    assert module.starts == 2
    assert module.stores == list(range(3, 13)) + list(range(3, 33))  # up to the lost one, then all
    assert [module.memory[3 + i] for i in range(30)] == [i.to_bytes() for i in prog]
    assert len(notices) == 1 and "no reply to SGP from address 1" in notices[0]
    assert "again from address 3 (attempt 2 of 3)" in notices[0]


def test_a_lost_answer_to_132_is_started_again(module, client):
    module.lose_start_once = True
    result = program.upload(client, _program(10))
    assert result.verified and module.starts == 2 and not module.downloading
    assert module.stores == list(range(10))  # (the first 132's frames: none went)


def test_a_reply_lost_at_every_attempt_ends_in_an_upload_error_naming_what_may_be_stored(
        module, client):
    module.lose_at = 7
    notices: list[str] = []
    client.on_notice = notices.append
    with pytest.raises(UploadError) as info:
        program.upload(client, _program(20))
    assert module.starts == 3 and len(notices) == 2  # as often as a request is retried
    assert (info.value.acked, info.value.sent) == (7, 8)
    assert not module.downloading


def test_no_retries_no_second_attempt(module, client):
    client.retries = 0
    module.lose_once = {4}
    with pytest.raises(UploadError):
        program.upload(client, _program(10))
    assert module.starts == 1 and module.stores == list(range(5))


@pytest.mark.parametrize("where", [0, 3, 6])  # the opcode, the motor, the value's top byte
def test_verify_names_the_one_word_that_differs(module, client, where):
    prog = _program(60)
    bad = bytearray(prog[33].to_bytes())
    bad[where] ^= 0x80
    module.stored_instead[33] = bytes(bad)
    result = program.upload(client, prog)
    assert result.verified is False
    assert result.mismatch is not None
    assert (result.mismatch.address, result.mismatch.doubtful) == (33, False)
    assert result.mismatch.actual.to_bytes() == bytes(bad)


def test_a_copy_of_the_read_back_before_never_passes_a_cell(module, client):
    # cells 20 and 21 are to hold the same instruction; 21 went bad on the module, and the
    # line brings a copy of 20's read-back first when 21 is read: the copy matches what 21
    # should hold, and must not be taken for 21's answer
    prog = _program(40)
    prog[21] = prog[20]
    bad = bytearray(prog[21].to_bytes())
    bad[6] ^= 0x01
    module.stored_instead[21] = bytes(bad)
    module.copy_first.add(21)
    result = program.upload(client, prog)
    assert result.verified is False
    assert result.mismatch is not None and result.mismatch.address == 21


def test_another_thread_on_the_client_waits_for_the_end_of_download_mode(module, client):
    # a second thread reads a parameter while the upload is between two frames: sent then,
    # the module would store the read as an instruction and answer it LOADED, and the
    # reader would get the frame's echo for a value
    import threading

    prog = _program(40)
    read: list[int] = []
    reader = threading.Thread(target=lambda: read.append(client.value("GAP 4, 0")))

    def progress(stage: str, done: int, total: int) -> None:
        if stage == "upload" and done == 10:
            reader.start()
            reader.join(0.5)  # (a reader that got through goes now; one that waits, waits)

    result = program.upload(client, prog, progress=progress)
    reader.join(30)
    assert result.verified is True
    assert module.stores == list(range(40))  # the read was not stored among them
    assert read == [0]  # the module's answer to GAP (status 100), not a stored frame's echo
    heard = [fields(raw)[1] for raw in module.log]
    assert heard.index(6) > heard.index(QUIT)  # the read went after download mode ended


def test_verify_takes_the_program_upload_took(module, client, tmp_path):
    # what load_program returns is what upload takes; verify took only instructions and
    # failed with "'Program' object is not iterable"
    source = tmp_path / "prog.tmc"
    source.write_text("SAP 4, 0, 1000\nLoop: MVP ABS, 0, 200\nJA Loop\n")
    prog = asm.load_program(source, client.require_module(), origin=7)
    assert program.upload(client, prog).verified is True
    assert program.verify_image(client, prog) is None  # read from its origin, 7
    module.memory[8] = bytes(7)
    mismatch = program.verify_image(client, prog)
    assert mismatch is not None and mismatch.address == 8
    assert program.verify_image(client, prog.instructions, 7).address == 8  # as before


def test_ctrl_c_in_an_upload_is_a_keyboard_interrupt_and_download_mode_is_ended(module,
                                                                                 client):
    # a production line's loop that logs a TmclError and goes on to the next module must
    # not go on after Ctrl-C: it was an UploadError (a TmclError) in the upload, and a
    # KeyboardInterrupt in its verify
    def progress(stage: str, done: int, total: int) -> None:
        if stage == "upload" and done == 12:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt) as info:
        try:
            program.upload(client, _program(40), progress=progress)
        except TmclError:
            pytest.fail("Ctrl-C was caught as a TmclError")
    cause = info.value.__cause__
    assert isinstance(cause, UploadError) and cause.interrupted and cause.download_ended
    assert cause.written == range(12) and "interrupted (Ctrl-C)" in str(info.value)
    assert module.stores == list(range(12)) and not module.downloading


_UNIT_STOP = stopped_by("terminated (SIGTERM)")  # (what ops/units raises in a unit's thread)


@pytest.mark.parametrize("stop, words", [
    (_UNIT_STOP, "terminated (SIGTERM)"),
    (lambda: Terminated(signal.SIGTERM), "terminated (SIGTERM)"),
    (lambda: Terminated(signal.SIGHUP), "hung up (SIGHUP)")])
def test_a_signal_in_an_upload_is_named_and_raised_as_itself(module, client, stop, words):
    """A unit stopped by SIGTERM (the stop ``ops/units`` raises in its thread), or a run's
    own SIGTERM or SIGHUP, cuts an upload short: the error says which (it said "interrupted
    (Ctrl-C)", or nothing for a run's own SIGTERM), and what is raised is still the stop of
    that kind (its exit status, a unit's words), the error its cause."""
    kind = type(stop())

    def progress(stage: str, done: int, total: int) -> None:
        if stage == "upload" and done == 12:
            raise stop()

    with pytest.raises(BaseException) as info:  # (a test that fails, not a run cut short)
        program.upload(client, _program(40), progress=progress)
    assert isinstance(info.value, kind), repr(info.value)
    cause = info.value.__cause__
    assert isinstance(cause, UploadError) and cause.interrupted and cause.download_ended
    assert cause.reason == words and "Ctrl-C" not in str(cause)
    assert str(cause).startswith(f"upload failed: {words}; instructions 0..11 written")
    assert getattr(info.value, "why", words) == words
    assert module.stores == list(range(12)) and not module.downloading


def _uploading(ports: list[str], tmp_path, modules: list[ProgramModule]) -> tuple[int, str, str]:
    """``tmclsh --port A [--port B] -f`` a script that uploads 1000 instructions, SIGTERM once
    every module has stored 20 of them; (status, stdout, stderr)."""
    prog = tmp_path / "long.tmcl"
    prog.write_text("".join(f"SGP {i % 56}, 2, {i}\n" for i in range(1000)))
    script = tmp_path / "up.tmcl"
    script.write_text(f".upload --yes {prog}\n")
    args = [a for p in ports for a in ("--port", p)]
    proc = subprocess.Popen([sys.executable, "-m", "tmclsh", *args, "-f", str(script)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=tmclsh_env(), cwd=str(ROOT))
    try:
        deadline = time.monotonic() + patience(30)
        while not all(len(m.stores) >= 20 for m in modules):
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
            time.sleep(0.01)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=patience(30))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return proc.returncode, out, err


@pytest.mark.parametrize("units", [1, 2])
def test_an_upload_cut_short_by_sigterm_says_so_and_what_memory_holds(tmp_path, units):
    """Each unit's upload stopped by SIGTERM says "terminated (SIGTERM)" (it said
    "interrupted (Ctrl-C)") with what the memory holds; a run of one module says that too
    (it said nothing of the memory). Download mode is ended; exit status 143."""
    modules = [ProgramModule(delay=0.005) for _ in range(units)]
    try:
        status, out, err = _uploading([m.path for m in modules], tmp_path, modules)
    finally:
        for m in modules:
            m.close()
    assert status == 143, err
    assert "Ctrl-C" not in out + err, out + err
    said = [line for line in err.splitlines()
            if "error: upload failed: terminated (SIGTERM); instructions 0.." in line]
    assert len(said) == units, err
    assert "download mode ended" in said[0]
    assert out.count("up.tmcl: terminated (SIGTERM) at line 1") == units, out
    assert not any(m.downloading for m in modules)


def test_ctrl_c_between_two_attempts_is_said_as_any_ctrl_c_in_the_upload(module, client):
    """Ctrl-C just as the upload says it stores the program again: a KeyboardInterrupt whose
    cause says what the memory holds, as anywhere else in the upload (the shell forgets the
    program it had uploaded before on that cause)."""
    module.lose_once = {4}

    def ctrl_c(text: str) -> None:
        raise KeyboardInterrupt

    client.on_notice = ctrl_c
    with pytest.raises(KeyboardInterrupt) as info:
        program.upload(client, _program(10))
    cause = info.value.__cause__
    assert isinstance(cause, UploadError) and cause.interrupted
    assert (cause.acked, cause.sent) == (4, 5) and cause.download_ended
    assert module.starts == 1 and not module.downloading


def test_the_ctrl_c_a_signal_stood_for_stays_that_signals_when_raised_again():
    """An upload cut short by the Ctrl-C a SIGTERM stands for (``interrupted``, a run that
    ends on all three alike) is raised again saying what memory holds, and still names the
    SIGTERM (``terminated_by``): its words and exit status are not lost to a plain Ctrl-C."""
    import signal

    from tmclsh.base.interrupts import interrupted, terminated_by
    from tmclsh.ops.program import UploadError, _again_as

    error = UploadError("terminated (SIGTERM)", start=0, total=4, acked=1, sent=2,
                        download_ended=True, end_error=None, interrupted=True)
    again = _again_as(interrupted(signal.SIGTERM), error)
    assert isinstance(again, KeyboardInterrupt) and "terminated (SIGTERM)" in str(again)
    found = terminated_by(again)
    assert found is not None and found.signum == signal.SIGTERM
    assert terminated_by(_again_as(KeyboardInterrupt(), error)) is None  # (Ctrl-C stays one)
