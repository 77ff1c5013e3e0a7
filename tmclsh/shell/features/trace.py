"""Frames for people: the protocol-analyser view behind ``--trace``, ``.trace`` and ``.decode``.

A trace line is ``time  direction  hex  decoding``::

    14:02:07.113 tx> 01 06 04 00 00 00 00 00 0b  GAP 4, 0  // MaxPositioningSpeed
    14:02:07.114 <rx 02 01 64 06 00 00 03 e8 58  100 ok, value 1000

and goes to stderr, so stdout (results, ``--json``) stays clean. The trace subscribes to the
client as a tracer (``client.add_tracer``); it never reads the transport.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ...tmcl import asm
from ...tmcl import instructions as isa
from ...base.errors import FrameError, ValidationError
from ...tmcl.modules import Module
from ...tmcl.decoder import FRAME_PIECE, can_reply, pieces
from ...tmcl.frames import (INSTRUCTION_LEN, SERIAL_FRAME_LEN, VERSION_STRING_LEN, Instruction,
                            Reply, Request, Status, checksum, parse_hex, to_signed32)
from ..lang.commands import command
from ..render import describe_instruction, describe_reply

if TYPE_CHECKING:
    from ..lang.session import Session

_ARROW = {"tx": "tx>", "rx": "<rx", "drop": "!! ", "note": "-- "}


# -- trace lines -------------------------------------------------------------------------

_clock: tuple[int, str] = (-1, "")  # the last whole second worded: a log has many a second


def timestamp(now: float | None = None) -> str:
    global _clock
    now = time.time() if now is None else now
    clock = _clock
    second = int(now) if 0 <= now < 1e12 else -1  # (the second localtime reads: rounded down)
    if second != clock[0] or second < 0:
        clock = _clock = (second, time.strftime("%H:%M:%S", time.localtime(now)))
    return f"{clock[1]}.{int(now * 1000) % 1000:03d}"


def format_frame(direction: str, raw: bytes, decoded: object, module: Module | None = None,
                 request: Request | None = None, now: float | None = None):
    """One trace line as a rich ``Text`` (``str()`` of it is the plain line)."""
    from rich.text import Text

    line = Text()
    line.append(timestamp(now), style="tmcl.trace.time")
    line.append(f" {_ARROW.get(direction, direction)} ", style=f"tmcl.trace.{direction}"
                if direction in _ARROW else "")
    if raw:
        line.append(bytes(raw).hex(" "), style="tmcl.trace.hex")
        line.append("  ")
    if isinstance(decoded, Request):
        line.append(describe_instruction(decoded.instruction, module))
        if direction == "tx" and decoded.address is not None:
            line.append(f"  @{decoded.address}", style="tmcl.note")
    elif isinstance(decoded, Reply):
        style = "" if decoded.ok else "tmcl.status.error"
        line.append(describe_reply(decoded, module, request), style=style)
    elif decoded is not None:
        line.append(str(decoded), style="tmcl.trace.note")
    return line


def connect_tracer(client) -> Tracer:
    """``--trace`` for the connect's own frames, before there is a session: plain lines on
    stderr, decoded for the module known so far (the 136 answer names it)."""
    import sys

    return Tracer(None, write=lambda line: print(line.plain, file=sys.stderr, flush=True),
                  module=lambda: client.module)


class Tracer:
    """A client tracer that prints each frame to stderr (through the session's Output)."""

    def __init__(self, session: Session | None, *, write=None, module=None):
        self.session = session
        self.last_request: Request | None = None
        self._write = write  # (connect_tracer's: no session yet)
        self._module = module

    def __call__(self, direction: str, raw: bytes, decoded: object) -> None:
        if direction == "tx" and isinstance(decoded, Request):
            self.last_request = decoded
        session = self.session
        module = session.client.module if session is not None else self._module()
        line = format_frame(direction, raw, decoded, module,
                            self.last_request if direction == "rx" else None)
        if session is None:
            self._write(line)
        else:
            session.out.err.print(line, highlight=False, markup=False, soft_wrap=True)


def enable_trace(session: Session) -> None:
    """Print every frame the client sends and receives on stderr (``--trace``, ``.trace on``)."""
    if trace_enabled(session):
        return
    session.state.trace = session.client.add_tracer(Tracer(session))


def disable_trace(session: Session) -> None:
    unsubscribe = session.state.take("trace")
    if callable(unsubscribe):
        unsubscribe()


def trace_enabled(session: Session) -> bool:
    return callable(session.state.trace)


# -- .decode: bytes pasted from elsewhere ------------------------------------------------

HINTS = {"request": "request", "req": "request", "tx": "request",
         "reply": "reply", "rx": "reply",
         "memory": "memory", "mem": "memory", "134": "memory",
         "version": "version", "136": "version"}


@dataclass
class Reading:
    """One interpretation of some bytes: what they would be, and how plausible it is."""

    kind: str  # request | reply | version | memory | instruction | can-request | can-reply
    text: str
    checksum: str = ""  # "ok", "wrong: 0x12, should be 0x34", or "" (no checksum in layout)
    plausible: bool = True

    def lines(self) -> list[str]:
        head = f"{self.kind}: {self.text}"
        return [head] + ([f"  checksum {self.checksum}"] if self.checksum else [])


def _checksum_text(frame: bytes) -> str:
    want = checksum(frame[:-1])
    if frame[-1] == want:
        return f"ok ({frame[-1]:#04x})"
    return f"WRONG: {frame[-1]:#04x}, should be {want:#04x}"


def _known_opcode(op: int) -> bool:
    return isa.by_opcode(op) is not None or isa.control(op) is not None


def _instruction_plausible(ins: Instruction, module: Module | None) -> bool:
    if not _known_opcode(ins.opcode):
        return False
    if isa.is_control(ins.opcode):
        return True
    text, comment = asm.disassemble_instruction(ins, module)
    return not text[:1].isdigit()  # the raw form means fields the command does not take


def _read_request(frame: bytes, module: Module | None) -> Reading:
    ins = Instruction.from_bytes(frame[1:8])
    return Reading("request", f"to address {frame[0]}: {describe_instruction(ins, module)}",
                   _checksum_text(frame), _instruction_plausible(ins, module))


def _read_reply(frame: bytes, module: Module | None) -> Reading:
    value = to_signed32(int.from_bytes(frame[4:8], "big"))
    reply = Reply(frame[0], frame[1], frame[2], frame[3], value)
    ok_status = frame[2] in {int(s) for s in Status}
    text = f"from address {frame[1]} to host {frame[0]}: {describe_reply(reply, module)}"
    return Reading("reply", text, _checksum_text(frame), ok_status and _known_opcode(frame[3]))


def _read_memory(frame: bytes, module: Module | None) -> Reading:
    ins = Instruction.from_bytes(frame[1:8])
    return Reading("134 reply (program memory)",
                   f"to host {frame[0]}: stored {describe_instruction(ins, module)}",
                   _checksum_text(frame), _instruction_plausible(ins, module))


def _read_version(frame: bytes) -> Reading | None:
    body = frame[1:1 + VERSION_STRING_LEN]
    if len(body) != VERSION_STRING_LEN or not all(32 <= b < 127 for b in body):
        return None
    return Reading("136 reply (version string)",
                   f"to host {frame[0]}: {body.decode('ascii')!r} (no checksum in this layout)")


def decode_frame(frame: bytes, module: Module | None, hint: str | None = None) -> list[Reading]:
    """The plausible readings of one 9-byte serial frame (or 7/8-byte CAN data)."""
    if len(frame) == INSTRUCTION_LEN:
        ins = Instruction.from_bytes(frame)
        if hint == "reply":
            value = to_signed32(int.from_bytes(frame[3:7], "big"))
            reply = Reply(0, frame[0], frame[1], frame[2], value)
            return [Reading("CAN reply data", f"from address {frame[0]}: {describe_reply(reply, module)}")]
        return [Reading("instruction (CAN request data or program memory)",
                        describe_instruction(ins, module), "", _instruction_plausible(ins, module))]
    if len(frame) == VERSION_STRING_LEN:
        data = can_reply(frame, version=hint in (None, "version", "reply"))
        if len(data) == VERSION_STRING_LEN:
            return [Reading("136 reply on CAN (version string)", repr(frame.decode("ascii")))]
        return [_can_reply_reading("CAN reply data", data, module)]
    if len(frame) != SERIAL_FRAME_LEN:
        raise FrameError(f"{len(frame)} bytes: a serial frame is {SERIAL_FRAME_LEN} bytes, "
                         f"CAN data {INSTRUCTION_LEN}")
    if hint == "request":
        return [_read_request(frame, module)]
    if hint == "reply":
        return [_read_reply(frame, module)]
    if hint == "memory":
        return [_read_memory(frame, module)]
    if hint == "version":
        v = _read_version(frame)
        if v is None:
            raise FrameError("bytes 2..9 are not printable ASCII: not a version string")
        return [v]
    readings = [_read_reply(frame, module), _read_request(frame, module)]
    version = _read_version(frame)
    if version is not None and checksum(frame[:-1]) != frame[-1]:
        readings.insert(0, version)
    good = [r for r in readings if r.plausible]
    if not good:
        return readings + [_read_memory(frame, module)]
    return good


def _parse_hex(text: str) -> bytes:
    """Pasted bytes in any usual spelling; runs of digits split into pairs (``0231 33``)."""
    cleaned = re.sub(r"0[xX]|\$|[,;:]", " ", text)
    parts: list[str] = []
    for tok in cleaned.split():
        if len(tok) > 2 and len(tok) % 2 == 0:
            parts += [tok[i:i + 2] for i in range(0, len(tok), 2)]
        else:
            parts.append(tok)
    if any(len(p) > 2 for p in parts):
        return parse_hex(text)  # the protocol's parser names the problem
    try:
        return bytes(int(p, 16) for p in parts)
    except ValueError:
        raise FrameError(f"not hex bytes: {text.strip()!r}") from None


def decode_can(frame, module: Module | None, hint: str | None = None) -> list[Reading]:
    """The readings of one CAN frame (a pasted log line): a request to its id, a reply on
    it, or a version string; the factory's reply id (GP 70 = 2) puts the reply first."""
    can_id, data = frame.arbitration_id, frame.data
    where = f"id {can_id:#x}" if frame.extended else f"id {can_id}"
    if frame.error or frame.remote:
        kind = "error frame" if frame.error else "remote frame"
        return [Reading(f"CAN {kind}", f"on {where}: no TMCL frame", plausible=False)]
    if len(data) == VERSION_STRING_LEN:  # (the one reading of CAN replies: tmcl/decoder.py)
        got = can_reply(data, version=hint in (None, "version", "reply"))
        if len(got) == VERSION_STRING_LEN:
            return [Reading(f"CAN reply on {where} (136 version string)", repr(data.decode()))]
        return [_can_reply_reading(f"CAN reply on {where}", got, module)]
    if len(data) != INSTRUCTION_LEN:
        return [Reading(f"CAN frame on {where}", f"{len(data)} data bytes: no TMCL frame (7, "
                        "or 8 for a reply)", plausible=False)]
    ins = Instruction.from_bytes(data)
    request = Reading(f"CAN request to {where}", describe_instruction(ins, module), "",
                      _instruction_plausible(ins, module))
    value = to_signed32(int.from_bytes(data[3:7], "big"))
    reply = Reply(0, data[0], data[1], data[2], value)
    answer = Reading(f"CAN reply on {where}",
                     f"from address {data[0]}: {describe_reply(reply, module)}", "",
                     data[1] in {int(s) for s in Status} and _known_opcode(data[2]))
    if hint == "request":
        return [request]
    if hint == "reply":
        return [answer]
    readings = [answer, request] if can_id == _FACTORY_REPLY_ID else [request, answer]
    return [r for r in readings if r.plausible] or readings


_FACTORY_REPLY_ID = 2  # GP 70 as modules leave the factory


def _can_reply_reading(kind: str, seven: bytes, module: Module | None) -> Reading:
    """Eight data bytes that are no version string: a reply whose eighth byte (its sum or
    padding, as some modules send) is left out, as the client reads it."""
    value = to_signed32(int.from_bytes(seven[3:7], "big"))
    reply = Reply(0, seven[0], seven[1], seven[2], value)
    return Reading(kind, f"from address {seven[0]}: {describe_reply(reply, module)} (8 data "
                   "bytes: the eighth, a sum or padding, left out)", "",
                   seven[1] in {int(s) for s in Status} and _known_opcode(seven[2]))


def decode_hex(text: str, module: Module | None) -> list[tuple[bytes, list[Reading]]]:
    """``.decode [request|reply|memory|version] HEX``: every frame in the pasted bytes; or
    one CAN frame pasted as a log line (candump's output, a candump ``-L`` or ``.asc``
    line, read by python-can where it has a reader)."""
    words = text.split()
    hint = HINTS.get(words[0].lower()) if words else None
    if hint is not None:
        text = text.split(None, 1)[1] if len(words) > 1 else ""
    from ...link.canlog import parse_line

    can = parse_line(text)
    if can is not None:
        return [(can.data, decode_can(can, module, hint))]
    data = _parse_hex(text)
    if not data:
        raise FrameError("no bytes given: .decode 01 06 04 00 00 00 00 00 0b")
    if len(data) in (INSTRUCTION_LEN, VERSION_STRING_LEN):
        return [(data, decode_frame(data, module, hint))]  # CAN data
    # serial frames, found as every reader finds them (tmcl/decoder.py); a run of bytes that
    # are no frame is read nine bytes at a time when it has that length (a frame whose sum
    # is wrong, or a version string), else shown as what it is
    out: list[tuple[bytes, list[Reading]]] = []
    for kind, raw in pieces(data):
        if kind == FRAME_PIECE or len(raw) % SERIAL_FRAME_LEN == 0:
            out += [(raw[i:i + SERIAL_FRAME_LEN],
                     decode_frame(raw[i:i + SERIAL_FRAME_LEN], module, hint))
                    for i in range(0, len(raw), SERIAL_FRAME_LEN)]
        else:
            out.append((raw, [Reading("no frame", f"{len(raw)} bytes that are no frame "
                                                  "(no nine of them end in their sum)")]))
    if not any(len(f) == SERIAL_FRAME_LEN for f, _ in out):
        raise FrameError(f"{len(data)} bytes: expected 9-byte serial frames (or 7/8 bytes of "
                         "CAN data)")
    return out


__all__ = ["enable_trace", "disable_trace", "trace_enabled", "format_frame", "decode_hex",
           "decode_frame", "describe_instruction", "describe_reply"]


# -- .trace and .decode --------------------------------------------------------------------

@command(".trace")
def cmd_trace(session: Session, arg: str) -> None:
    word = arg.strip().lower()
    if word not in ("", "on", "off"):
        raise ValidationError(f".trace takes on or off, not {arg.strip()!r}")
    on = (not trace_enabled(session)) if not word else word == "on"
    if on:
        enable_trace(session)
        session.out.info("trace on: frames are shown on stderr")
    else:
        disable_trace(session)
        session.out.info("trace off")


@command(".decode")
def cmd_decode(session: Session, arg: str) -> None:
    from rich.text import Text

    frames = decode_hex(arg, session.client.module)
    out = session.out
    for frame, readings in frames:
        if out.json:
            out.emit({"bytes": frame.hex(" "), "readings": [
                {"kind": r.kind, "text": r.text, "checksum": r.checksum} for r in readings]})
            continue
        out.print(Text(frame.hex(" "), style="tmcl.value"))
        for r in readings:
            line = Text("  ")
            line.append(r.kind, style="tmcl.name")
            line.append(f": {r.text}")
            out.print(line)
            if r.checksum:
                out.print(Text(f"    checksum {r.checksum}",
                               style="tmcl.ok" if r.checksum.startswith("ok") else "tmcl.error"))
