"""The program stored on a module: upload, verify, read back, run, stop, step, status.

Operations on a :class:`~tmclsh.client.core.Client`, usable from Python and from the shell alike
(the shell's debugger is a thin layer over this module). Nothing here prints: progress goes to
a callback, problems are raised as :class:`~tmclsh.base.errors.TmclError` subclasses.

The control commands (TMCM-351 manual, "TMCL control commands"; used by the TMCL-IDE on all
three modules):

* 128 stop, 129 run (type 0 from the current address, type 1 from the value's address),
  130 step one instruction, 131 reset (program counter to 0, application stopped);
* 132 start download at the value's address: every following frame is stored (and answered
  with status 101) until 133 quits download mode;
* 134 reads one instruction back (reply in the legacy layout, ``Reply.stored``);
* 135 the application status (0 stop, 1 run, 2 step, 3 reset); GP 130 is the program counter,
  GP 129 the download-mode flag, GP 128 the application status as a parameter.

These firmwares have no breakpoint command: :func:`continue_to` runs to a breakpoint by
stepping the module and reading the program counter after every step.

In ASCII mode the module knows only ``RUN`` and ``STOP`` for its program (TMCM-1311 manual
§4.4.3), and GP 128 for 135: the instruction set says so (``ascii_word``, ``ascii_line``) and
the link's framing sends those lines for 128, 129 type 0 and 135, so nothing here asks which
mode the link is in. What the link cannot carry raises a
:class:`~tmclsh.base.errors.ValidationError` before anything is sent (``require_binary``).

Example::

    import tmclsh

    with tmclsh.connect(sim="TMCM-1311") as c:
        prog = tmclsh.load_program("demo.tmc", c.require_module())
        result = tmclsh.upload_program(c, prog)   # 132, frames, 133, then 134 verify
        assert result.verified
        tmclsh.run_program(c)                     # 129 type 0
        print(tmclsh.program_status(c))           # AppStatus(state='run', pc=...)
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from ..tmcl import instructions as isa
from ..tmcl.asm import Program
from ..base.errors import (ChecksumError, StatusError, TmclError, TmclTimeoutError, TransportError,
                           ValidationError)
from ..base.interrupts import Terminated, stopped_words
from ..base.logs import Logger
from ..tmcl.frames import AppState, Control, Instruction, Request, Status
from ..client.shared import shared_text
from .certain import read_until_certain


log = Logger(__name__)  # (logging imported when it first logs)

# GGP <type>, 0: the program's global parameters (bank 0)
GGP = int(isa.parameter_command("global", "read").opcode)
GP_DOWNLOAD_MODE = 129
GP_PROGRAM_COUNTER = 130
USER_VARIABLE_BANK = 2
#: ``progress(phase, done, total)``; phase is "upload", "verify" or "read"
Progress = Callable[[str, int, int], None]


def state_name(code: int) -> str:
    try:
        return AppState(code).name.lower()
    except ValueError:
        return f"unknown({code})"


@dataclass(frozen=True)
class AppStatus:
    """The stored application's state and program counter."""

    state: str  # stop | run | step | reset
    pc: int
    code: int

    def to_json(self) -> dict[str, object]:
        return {"state": self.state, "pc": self.pc}

    def __str__(self) -> str:
        return f"{self.state} at {self.pc}"


@dataclass(frozen=True)
class Mismatch:
    """The first address whose stored instruction differs from the one uploaded."""

    address: int
    expected: Instruction
    actual: Instruction
    # the read-back stayed in doubt (answers that may have been another request's, three
    # rounds running): not shown to differ, not shown to be the same either
    doubtful: bool = False
    # two modules answer at the module's address (Client.shared): why the read-back was
    # in doubt, and the program went to both
    shared: bool = False


@dataclass
class UploadResult:
    start: int
    count: int
    verified: bool | None  # None: not verified
    mismatch: Mismatch | None = None
    upload_seconds: float = 0.0
    verify_seconds: float = 0.0

    def to_json(self) -> dict[str, object]:
        obj: dict[str, object] = {"uploaded": self.count, "verified": bool(self.verified)}
        if self.mismatch is not None:
            obj["mismatch"] = self.mismatch.address
        return obj


class UploadError(TmclError):
    """An upload that did not complete, with what the program memory holds now.

    ``written``: addresses confirmed stored (status 101); ``unknown``: the address whose frame
    was sent but not confirmed (it may or may not be stored); ``unchanged``: addresses after
    it, which still hold what was there before. ``download_ended`` says whether 133 was
    answered; ``interrupted`` is True for Ctrl-C, SIGTERM or SIGHUP (``reason`` names which,
    as a script's summary does), which ``upload`` raises as the ``KeyboardInterrupt`` or
    ``Terminated`` it is, this error its ``__cause__``.
    """

    def __init__(self, reason: str, *, start: int, total: int, acked: int, sent: int,
                 download_ended: bool, end_error: str | None = None,
                 interrupted: bool = False):
        self.reason = reason
        self.start = start
        self.total = total
        self.acked = acked
        self.sent = sent
        self.download_ended = download_ended
        self.end_error = end_error
        self.interrupted = interrupted
        super().__init__(self.describe())

    @property
    def written(self) -> range:
        return range(self.start, self.start + self.acked)

    @property
    def unknown(self) -> range:
        return range(self.start + self.acked, self.start + self.sent)

    @property
    def unchanged(self) -> range:
        return range(self.start + self.sent, self.start + self.total)

    def memory_text(self) -> str:
        parts = []
        if self.written:
            parts.append(f"instructions {_span(self.written)} written")
        if self.unknown:
            parts.append(f"{_span(self.unknown)} unknown (sent, not confirmed)")
        if self.unchanged:
            parts.append(f"{_span(self.unchanged)} unchanged (old contents)")
        if not self.written and not self.unknown:
            return "nothing was written; the program memory is unchanged"
        return ", ".join(parts)

    def describe(self) -> str:
        if self.download_ended:
            ended = "download mode ended"
        else:
            ended = (f"could not end download mode ({self.end_error}): the module may still "
                     "store every command it receives; the next command asks and ends it "
                     "first (else power-cycle the module)")
        return (f"upload failed: {self.reason}; {self.memory_text()}; {ended}. "
                "Upload again to store the whole program")


def _span(r: range) -> str:
    return str(r.start) if len(r) == 1 else f"{r.start}..{r.stop - 1}"


# -- checks ------------------------------------------------------------------------------

def carried(client, opcode: int, type_: int = 0) -> bool:
    """Can the link carry this control command as it is now (``Client.refusal``)? The
    module's ASCII mode knows RUN and STOP of the program's control commands, and 135 as
    GP 128, as the instruction set says (``ascii_word``, ``ascii_line``)."""
    return client.refusal(Request(client.address, opcode, type_, 0, 0)) is None


def require_binary(client, what: str, opcode: int, *more: int, type_: int = 0) -> None:
    """Refuse, before the first of its requests is sent, what the link cannot carry as it
    is now (``carried``)."""
    for op in (opcode, *more):
        why = client.refusal(Request(client.address, op, type_, 0, 0))
        if why is not None:
            raise ValidationError(f"{what} needs binary mode: {why}")


def require_alone(client) -> None:
    """Refuse to store a program where two modules answer at the address (``Client.shared``):
    it would be written to both, and no read-back could say what either holds."""
    if client.address in getattr(client, "shared", ()):
        raise ValidationError(f"not uploading, nothing was sent: {shared_text(client.address)}")


def check_fits(module, start: int, count: int) -> None:
    """Refuse a program that does not fit the module's memory, before anything is sent."""
    size = module.program_memory
    if not 0 <= start < size:
        raise ValidationError(f"start address {start} is outside program memory 0..{size - 1}")
    if start + count > size:
        raise ValidationError(
            f"the program has {count} instructions; from address {start} only "
            f"{size - start} fit in the {module.name}'s memory ({size} instructions); "
            "nothing was sent")


def _image(program: Program | Sequence[Instruction], origin: int | None
           ) -> tuple[list[Instruction], int]:
    if isinstance(program, Program):
        if origin is not None and origin != program.origin and any(
                (spec := isa.by_opcode(i.opcode)) is not None and spec.jumps
                for i in program.instructions):
            raise ValidationError(f"the program was assembled for address {program.origin}; "
                                  f"its jumps would be wrong at {origin} (assemble it there)")
        return list(program.instructions), program.origin if origin is None else origin
    return list(program), 0 if origin is None else origin


def _ok(reply, what: str, expect: Iterable[int] = (Status.OK,)):
    if reply is None:
        raise TmclError(f"no reply to {what}")
    if reply.status not in tuple(expect):
        raise StatusError(reply.status, reply,
                          f"{what}: module answered status {reply.status} ({reply.status_text})")
    return reply


# plain ints: Request.make takes its fast path only for plain ints (Control is an IntEnum),
# and a verify sends this once per instruction; an upload's every frame is answered LOADED
_READ_MEMORY = int(Control.READ_MEMORY)
_LOADED = int(Status.LOADED)


def _made(reqs: list[Request]) -> list[Request]:
    """A run's requests with their frames made, before the first goes: what is made
    between a reply and the next request, or while the module answers, costs the line
    that time (Client.requests)."""
    for req in reqs:
        req.to_bytes()  # (kept by the request)
    return reqs


def _send(client, opcode: int, type_: int = 0, motor: int = 0, value: int = 0, *,
          timeout: float | None = None, retries: int | None = None):
    # an upload is thousands of these: Request.make checks plain in-range numbers without
    # the constructor's per-field calls (anything else still goes through the constructor);
    # the value is taken as 32 bits either way, signed as Request holds it
    value = ((value & 0xFFFFFFFF) ^ 0x80000000) - 0x80000000
    return client.request(Request.make(client.address, opcode, type_, motor, value),
                          timeout=timeout, retries=retries)


# -- upload and read-back ----------------------------------------------------------------

def upload(client, program: Program | Sequence[Instruction], origin: int | None = None, *,
           verify: bool = True, progress: Progress | None = None,
           timeout: float | None = None) -> UploadResult:
    """Store ``program`` on the module from ``origin`` (default: the program's origin).

    132 (start download), one frame per instruction (each answered with status 101), 133;
    then, with ``verify``, every instruction is read back with 134 and compared. A reply lost
    or damaged on a line that works (the module answers the 133 after it) cannot be asked
    again (the frame may be stored, and would be stored twice): the whole program is stored
    again from 132, as often as the client retries a request. Download mode
    is always ended (133 in a ``finally``, best effort, also after Ctrl-C); an upload that did
    not complete raises :class:`UploadError` saying what the memory holds now, and one cut
    short by Ctrl-C a ``KeyboardInterrupt`` whose ``__cause__`` is that error (a script that
    goes on after a ``TmclError`` must not go on after Ctrl-C). Other threads
    using the client wait from 132 until 133 is answered: a module in download mode stores
    whatever it hears.
    """
    instructions, start = _image(program, origin)
    module = client.require_module()
    require_binary(client, "uploading a program (132/133)", Control.START_DOWNLOAD,
                   Control.QUIT_DOWNLOAD)
    require_alone(client)
    if not instructions:
        raise ValidationError("the program has no instructions; nothing to upload")
    check_fits(module, start, len(instructions))
    total = len(instructions)
    began = time.monotonic()
    # the frames made before the first goes (every one goes to the module that got 132; an
    # Instruction holds plain ints in range, its value signed: make's fast path)
    make, address = Request.make, client.address
    reqs = _made([make(address, ins.opcode, ins.type, ins.motor, ins.value)
                  for ins in instructions])
    # the line is this upload's from 132 to 133: the module stores every frame it hears in
    # download mode, so another thread's request on the same client in between would be
    # stored as an instruction and answered as LOADED (its caller given a wrong value)
    tries = 1 + client.retries
    furthest = 0  # frames sent, in the attempt that sent the most (what may be stored)
    with client.lock:
        for attempt in range(1, tries + 1):
            acked, sent, failure, ended, end_error = _store(client, reqs, start, timeout,
                                                            progress)
            if isinstance(failure, StatusError) and acked < sent:
                sent = acked  # the module refused that frame: nothing was stored there
            furthest = max(furthest, sent)
            if failure is None or attempt == tries or not _again(failure, ended):
                break
            # a reply lost or damaged on a line that works (133 was answered): whether that
            # frame was stored cannot be known, and one sent again would be stored twice;
            # the whole program from 132 can, over what the attempt before stored
            try:
                client._taps.notice(f"upload: {_reason(failure, ended)}; storing the program "
                                    f"again from address {start} (attempt {attempt + 1} of "
                                    f"{tries})")
            except (KeyboardInterrupt, Terminated) as exc:  # (said as any in the upload is)
                failure = exc
                break
    sent = furthest
    upload_seconds = time.monotonic() - began
    if failure is not None:
        interrupted = isinstance(failure, (KeyboardInterrupt, Terminated))
        # (what stopped it by name: Ctrl-C, or the SIGTERM that stopped a unit or a run)
        reason = stopped_words(failure) if interrupted else _reason(failure, ended)
        error = UploadError(reason, start=start, total=total, acked=acked, sent=sent,
                            download_ended=ended, end_error=end_error, interrupted=interrupted)
        if interrupted:
            raise _again_as(failure, error) from error
        raise error from failure
    if not ended:
        raise UploadError("quit download (133) failed", start=start, total=total,
                          acked=acked, sent=sent, download_ended=False, end_error=end_error)
    result = UploadResult(start, total, None, upload_seconds=upload_seconds)
    if verify:
        began = time.monotonic()
        result.mismatch = verify_image(client, instructions, start, progress=progress,
                                       timeout=timeout)
        result.verified = result.mismatch is None
        result.verify_seconds = time.monotonic() - began
    return result


def _again_as(stop: BaseException, error: UploadError) -> BaseException:
    """The Ctrl-C or signal that cut an upload short, to raise again with ``error`` (what
    the memory holds) as its cause: SIGTERM's own exception (its exit status), a Ctrl-C of
    the same kind (a unit's names what stopped it) saying the error."""
    if isinstance(stop, Terminated):
        return stop
    try:
        again = type(stop)(str(error))
    except TypeError:  # (a kind that takes other arguments)
        again = KeyboardInterrupt(str(error))
    signum = getattr(stop, "signum", None)
    if signum is not None:  # (the Ctrl-C a SIGTERM stood for stays that SIGTERM's)
        again.signum = signum  # type: ignore[attr-defined]
    return again


def _store(client, reqs: list[Request], start: int, timeout: float | None,
           progress: Progress | None
           ) -> tuple[int, int, BaseException | None, bool, str | None]:
    """One attempt of ``upload``'s: 132, the frames, 133 (always, in a ``finally``). Returns
    the frames acknowledged, the frames sent (the last may be stored or not), what stopped
    it (None: every frame stored), whether 133 was answered and why not."""
    total = len(reqs)
    acked = sent = 0
    failure: BaseException | None = None
    frames = client.requests(reqs, timeout=timeout)  # (one run of requests)
    client._downloading = True  # no retries: a repeated frame would be stored twice
    try:
        _ok(_send(client, Control.START_DOWNLOAD, 0, 0, start, timeout=timeout),
            f"start download (132) at address {start}")
        while acked < total:
            sent = acked + 1  # (the next frame goes out, or may have, whatever happens)
            reply = next(frames)
            if reply is None or reply.status != _LOADED:
                _ok(reply, f"instruction at address {start + acked}", (Status.LOADED,))
            acked += 1
            if progress is not None:
                progress("upload", acked, total)
    except (TmclError, KeyboardInterrupt, Terminated) as exc:
        failure = exc
    finally:
        frames.close()
        ended, end_error = _quit_download(client, timeout)
        client._downloading = False
        if not ended:
            client._lifecycle.check_download_next()  # the next command ends it first
    return acked, sent, failure, ended, end_error


def _again(failure: BaseException, ended: bool) -> bool:
    """Is an upload that ``failure`` stopped worth storing again from 132? When a reply was
    lost or damaged and the module answered the 133 after it (the line works, download mode
    is over); not for a frame the module refused (it would refuse it again), a link gone,
    or Ctrl-C."""
    return ended and isinstance(failure, (TmclTimeoutError, ChecksumError)) and not \
        isinstance(failure, TransportError)


def _reason(exc: BaseException, answered_133: bool) -> str:
    """Why an upload stopped, in words true of the link: a reply that did not come, when
    the module answered the 133 after it, was lost on a line that works (a noisy one)."""
    if isinstance(exc, TransportError) or (isinstance(exc, TmclTimeoutError)
                                           and not answered_133):
        return f"link lost ({exc})"
    return str(exc)


def _quit_download(client, timeout: float | None) -> tuple[bool, str | None]:
    """133, best effort: sent again while it gets no reply (a repeated 133 is harmless), as
    often as the client retries a request, and at least twice."""
    error = None
    for _ in range(max(2, 1 + client.retries)):
        try:
            reply = _send(client, Control.QUIT_DOWNLOAD, timeout=timeout)
            if reply is not None and reply.ok:
                return True, None
            error = f"status {reply.status}" if reply is not None else "no reply"
        except KeyboardInterrupt:
            return False, "interrupted"
        except TmclError as exc:
            error = str(exc)
            if isinstance(exc, TransportError) and not client.connected:
                break
        log.warning("quit download (133) failed: %s", error)
    return False, error


def end_download(client, *, timeout: float | None = None) -> None:
    """133 on its own: end a download mode left behind (e.g. by a link lost mid-upload)."""
    require_binary(client, "quit download (133)", Control.QUIT_DOWNLOAD)
    client._downloading = True  # until it is answered, the module may store what it gets
    ended = False
    try:
        _ok(_send(client, Control.QUIT_DOWNLOAD, timeout=timeout), "quit download (133)")
        ended = True
    finally:
        client._downloading = False
        if not ended:
            client._lifecycle.check_download_next()


def read_instruction(client, address: int, *, timeout: float | None = None) -> Instruction:
    """The instruction stored at ``address`` (134)."""
    require_binary(client, "reading program memory (134)", _READ_MEMORY)
    reply = _send(client, _READ_MEMORY, 0, 0, address, timeout=timeout)
    if reply is None or reply.stored is None:
        raise TmclError(f"no program-memory reply for address {address}")
    return reply.stored


def is_end_marker(ins: Instruction) -> bool:
    """Memory never written, or cleared (``isa.END_MARKER``), or an erased cell (all bytes
    0xFF)."""
    return ins.opcode == isa.END_MARKER or ins.to_bytes() == b"\xff" * 7


def read_program(client, start: int = 0, count: int | None = None, *,
                 progress: Progress | None = None, timeout: float | None = None
                 ) -> list[Instruction]:
    """Read the stored program back with 134.

    With ``count``, exactly that many instructions; else up to the end marker (see
    :func:`is_end_marker`, not included) or the end of memory.
    """
    module = client.require_module()
    require_binary(client, "reading program memory (134)", _READ_MEMORY)
    size = module.program_memory
    if not 0 <= start < size:
        raise ValidationError(f"address {start} is outside program memory 0..{size - 1}")
    end = size if count is None else start + count
    if end > size:
        raise ValidationError(f"{start}+{count} runs past the end of program memory ({size})")
    out: list[Instruction] = []
    for addr in range(start, end):
        ins = read_instruction(client, addr, timeout=timeout)
        if count is None and is_end_marker(ins):
            break
        out.append(ins)
        if progress is not None:
            progress("read", len(out), end - start)
    return out


def verify_image(client, instructions: Program | Sequence[Instruction],
                 start: int | None = None, *, progress: Progress | None = None,
                 timeout: float | None = None) -> Mismatch | None:
    """Read every instruction back and compare bytes; the first difference, or None.
    ``instructions`` is what ``upload`` takes: a ``Program`` (from its origin unless
    ``start`` says) or instructions (from ``start``, default 0).

    A 134 answer is any well-formed frame, so a copy of an earlier answer that a bad line
    brings late reads as the cell's content: it may match where the cell differs, or differ
    where it matches. The client finds such a read out when the cell's own answer comes
    while nothing waits (a suspect); those cells are read again, ``CONFIRM_ROUNDS`` times
    at most. A cell still in doubt then is no pass (``Mismatch.doubtful``): verified means
    certain (``read_until_certain``, on ``Client.in_doubt``)."""
    instructions, start = _image(instructions, start)
    total = len(instructions)
    got: dict[int, Instruction] = {}

    def read(todo: set[int] | None) -> dict[int, int]:
        # (thousands of reads at the line's pace: what read_instruction checks and builds
        # for one read is done once a round, the loop only sends and keeps the answers)
        require_binary(client, "reading program memory (134)", _READ_MEMORY)
        read_at: dict[int, int] = {}  # Client._replies after the read -> the cell's index
        make, module = Request.make, client.address
        cells = range(total) if todo is None else sorted(todo)
        reads = client.requests(_made([make(module, _READ_MEMORY, 0, 0, start + idx)
                                       for idx in cells]), timeout=timeout)
        ledger = client._ledger  # (its count of replies: ``Client._replies``)
        for n, (idx, reply) in enumerate(zip(cells, reads)):
            if reply is None or reply.stored is None:
                raise TmclError(f"no program-memory reply for address {start + idx}")
            got[idx] = reply.stored
            read_at[ledger.replies] = idx
            if progress is not None and todo is None:
                progress("verify", n + 1, total)
        return read_at

    doubtful = read_until_certain(client, read).doubt
    shared = client.address in getattr(client, "shared", ())
    for idx, want in enumerate(instructions):
        if idx in doubtful:
            return Mismatch(start + idx, want, got[idx], doubtful=True, shared=shared)
        # (equal Instructions are equal bytes, their values held signed; only what is not
        # equal is compared as bytes, so an unnormalised value is no false difference)
        if got[idx] != want and got[idx].to_bytes() != want.to_bytes():
            # a difference is said only when a second read says the same (a copy of another
            # frame that no suspect gave away would otherwise be named the cell's content)
            again = read_instruction(client, start + idx, timeout=timeout)
            unsure = bool(client.in_doubt({client._replies: idx}))
            if again.to_bytes() == want.to_bytes() and not unsure:
                continue
            certain = again.to_bytes() == got[idx].to_bytes() and not unsure
            return Mismatch(start + idx, want, again, doubtful=not certain, shared=shared)
    return None


def same_image(a: Sequence[Instruction], b: Sequence[Instruction]) -> bool:
    return len(a) == len(b) and all(x.to_bytes() == y.to_bytes() for x, y in zip(a, b))


# -- running -----------------------------------------------------------------------------

def run(client, address: int | None = None) -> None:
    """129: type 0 runs from the current address, type 1 from ``address`` (on the module's
    ASCII line: RUN, which runs from the current address only)."""
    module = client.require_module()
    if address is not None and not 0 <= address < module.program_memory:
        raise ValidationError(f"address {address} is outside program memory "
                              f"0..{module.program_memory - 1}")
    if address is None:
        _ok(_send(client, Control.RUN_APPLICATION, 0), "run (129)")
    else:
        require_binary(client, "running from an address (129 type 1)",
                       Control.RUN_APPLICATION, type_=1)
        _ok(_send(client, Control.RUN_APPLICATION, 1, 0, address), f"run from {address} (129)")


def stop(client) -> None:
    """128: stop the running (or stepped) application."""
    _ok(_send(client, Control.STOP_APPLICATION), "stop (128)")


def reset(client) -> None:
    """131: program counter to 0, application stopped."""
    require_binary(client, "reset (131)", Control.RESET_APPLICATION)
    _ok(_send(client, Control.RESET_APPLICATION), "reset (131)")


def step(client) -> None:
    """130: execute the next instruction."""
    require_binary(client, "stepping (130)", Control.STEP_APPLICATION)
    _ok(_send(client, Control.STEP_APPLICATION), "step (130)")


def program_counter(client) -> int:
    """GP 130."""
    reply = _ok(_send(client, GGP, GP_PROGRAM_COUNTER, 0), "program counter (GGP 130)")
    return reply.value


def status(client) -> AppStatus:
    """135 (GP 128 on the module's ASCII line: the instruction set's ``ascii_line``) and the
    program counter (GP 130)."""
    code = _ok(_send(client, Control.GET_STATUS), "application status (135)").value
    return AppStatus(state_name(code), program_counter(client), code)


def download_mode(client) -> bool:
    """GP 129: True while the module is in download mode."""
    return bool(_ok(_send(client, GGP, GP_DOWNLOAD_MODE, 0), "download mode (GGP 129)").value)


@dataclass
class StopInfo:
    """Why :func:`continue_to` returned: "breakpoint", "ended" (it stopped by itself),
    "end" (the program counter is past the stored program) or "limit"."""

    reason: str
    pc: int
    steps: int
    status: AppStatus | None = None


def step_one(client, *, pc: int | None = None,
             instruction_at: Callable[[int], Instruction] | None = None,
             on_wait: Callable[[int], None] | None = None) -> int:
    """130 once and return the new program counter; a WAIT is stepped over in its time.

    A step that starts a WAIT leaves the program counter on it until the module finishes
    the WAIT by itself; sending 130 again meanwhile could run the next instruction as soon as
    the WAIT ends, unseen. So while a WAIT holds the program counter this polls GP 130 (read
    only) until it moves, calling ``on_wait(pc)`` once first (Ctrl-C interrupts the wait;
    the module stays in step mode). ``pc``: the program counter before the step, if known.
    """
    require_binary(client, "stepping (130)", Control.STEP_APPLICATION)
    if pc is None:
        pc = program_counter(client)
    step(client)
    new = program_counter(client)
    if new != pc:
        return new
    ins = instruction_at(pc) if instruction_at is not None else read_instruction(client, pc)
    if not is_wait(ins):
        return new  # a jump to itself, or a STOP
    if on_wait is not None:
        on_wait(pc)
    polls = 0
    while new == pc:
        polls += 1
        time.sleep(min(0.02, 0.001 * polls))
        new = program_counter(client)
        if new == pc and polls % 16 == 0 and status(client).state != "step":
            break  # stopped or reset meanwhile
    return new


def continue_to(client, breakpoints: Iterable[int], *, max_steps: int | None = None,
                on_step: Callable[[int, int], None] | None = None,
                instruction_at: Callable[[int], Instruction] | None = None) -> StopInfo:
    """Step until the program counter arrives at a breakpoint (at least one step).

    These firmwares have no breakpoint command, so this costs two round trips per
    instruction, and a WAIT takes its full time (see :func:`step_one`). A breakpoint counts
    when the program counter arrives there: moving off the breakpoint it starts at takes a
    step. Returns when a breakpoint is reached, the program stopped by itself (STOP, or the
    end of the program), the program counter is where no instruction is stored (nothing is
    stepped there), or after ``max_steps`` steps. KeyboardInterrupt propagates (the
    module stays in step mode, at an instruction boundary). ``instruction_at(address)`` gives
    the stored instruction (default: read with 134, once per address).
    """
    require_binary(client, "running to a breakpoint (130 steps)",
                   Control.STEP_APPLICATION)
    targets = set(breakpoints)
    cache: dict[int, Instruction] = {}

    def stored(address: int) -> Instruction:
        if instruction_at is not None:
            return instruction_at(address)
        if address not in cache:
            cache[address] = read_instruction(client, address)
        return cache[address]

    steps = 0
    pc = program_counter(client)
    while max_steps is None or steps < max_steps:
        if is_end_marker(stored(pc)):
            # past the stored program: stepping on would run through empty memory for ever
            return StopInfo("end", pc, steps)
        before = pc
        pc = step_one(client, pc=pc, instruction_at=stored)
        steps += 1
        if on_step is not None:
            on_step(steps, pc)
        if pc in targets:
            return StopInfo("breakpoint", pc, steps)
        if pc == before:
            st = status(client)
            if st.state != "step":  # STOP ran, or the end of the program
                return StopInfo("ended", st.pc, steps, st)
    return StopInfo("limit", pc, steps)


def is_wait(ins: Instruction) -> bool:
    """Does it hold the program counter until its condition is met (WAIT)?"""
    spec = isa.by_opcode(ins.opcode)
    return spec is not None and spec.waits


# -- user variables ----------------------------------------------------------------------

def user_variable_range(module) -> range:
    """All user variables (global parameters of bank 2) the module's database lists."""
    params = [p for p in module.global_params if p.bank == USER_VARIABLE_BANK]
    if not params:
        raise ValidationError(f"the {module.name} has no user variables (bank 2)")
    lo = min(p.number for p in params)
    hi = max(p.number + p.count for p in params)
    return range(lo, hi)


def read_user_variables(client, numbers: Iterable[int]) -> dict[int, int]:
    """GGP n, 2 for each number."""
    module = client.require_module()
    valid = user_variable_range(module)
    out = {}
    for n in numbers:
        if n not in valid:
            raise ValidationError(f"user variable {n} does not exist on the {module.name}: "
                                  f"{valid.start}..{valid.stop - 1}")
        out[n] = _ok(_send(client, GGP, n, USER_VARIABLE_BANK), f"GGP {n}, 2").value
    return out


__all__ = ["AppState", "AppStatus", "Mismatch", "UploadResult", "UploadError", "StopInfo",
           "upload", "end_download", "verify_image", "read_program", "read_instruction", "is_end_marker",
           "same_image", "run", "stop", "reset", "step", "status", "program_counter",
           "download_mode", "continue_to", "step_one", "is_wait", "check_fits", "require_binary",
           "carried",
           "user_variable_range", "read_user_variables", "state_name"]
