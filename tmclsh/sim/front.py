"""The simulated module's serial byte stream as its firmware reads it: binary frames (found as
every reader of tmclsh finds them, ``tmcl/decoder.py``) and, in ASCII mode, lines echoed and read
as its ASCII interface reads them (``ascii.py``), each a command for the same dispatch as a
frame's."""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

from ..base.errors import AsmError
from ..tmcl import instructions as isa
from ..tmcl.asm import Line, encode, parse_line
from ..tmcl.decoder import NOISE, WHOLE, FrameDecoder, is_frame
from ..tmcl.frames import SERIAL_FRAME_LEN, Request, Status, to_signed32
from .ascii import Echo, LineDiscipline, address_char, echo_mode, reply_line
from .model import GLOBAL
from .output import SERIAL
from .requests import Answer

if TYPE_CHECKING:
    from .device import Simulator

log = logging.getLogger(__name__)


class SerialFront:
    """Bytes from the serial line to requests, in the mode the module is in."""

    FRAME_GAP = 0.05  # s of silence after which a partial binary frame is discarded

    def __init__(self, host: Simulator) -> None:
        self._host = host  # its address, its dispatch, its replies
        self._rx = FrameDecoder()  # requests: any frame that adds up
        self._rx_time = 0.0
        self._line = LineDiscipline()
        self.ascii = False

    def reset(self, ascii: bool) -> None:
        """A power cycle or a restart: no partial frame or line kept, in the mode given."""
        self._rx.clear()
        self._line.clear()
        self.ascii = ascii

    def enter_ascii(self) -> None:
        self.ascii = True
        self._line.clear()

    def leave_ascii(self) -> None:
        self.ascii = False
        self._line.clear()
        self._rx.clear()

    def receive(self, data: bytes) -> None:
        """Bytes from the host, read in the mode the module is in: a frame or line that
        switches the mode hands the bytes after it to the other reader."""
        while data:
            data = self._receive_ascii(data) if self.ascii else self._receive_binary(data)

    def _receive_binary(self, data: bytes) -> bytes:
        """Frames out of the bytes, as every reader finds them (tmcl/decoder.py)."""
        host = self._host
        now = time.monotonic()
        rx = self._rx
        if rx.buf and now - self._rx_time > self.FRAME_GAP:
            log.debug("discarding %d bytes of a partial frame after a gap", len(rx.buf))
            rx.clear()
        self._rx_time = now
        rx.feed(data)
        me = host.address
        while (piece := rx.next(whole=self._damaged)) is not None:
            kind, frame = piece
            if kind == NOISE:
                continue  # garbage or a misaligned frame: the decoder slid past it
            if kind == WHOLE:  # a frame for this module whose sum is wrong
                if not host.faults.lose():
                    host.runtime.heard(rearm=False)
                    host._send_reply(SERIAL, me, frame[1], Answer(Status.WRONG_CHECKSUM))
                continue
            if frame[0] != me:
                continue  # another module's frame on a shared line
            if not host.faults.lose():
                host._handle(Request.from_bytes(frame), SERIAL)
            if self.ascii:
                return rx.rest()
        return b""

    def _damaged(self, window: bytearray) -> bool:
        """Nine bytes addressed to this module that are no frame, with no frame for it
        starting inside them: a request damaged on the line, which a module answers with
        status 1. (A valid frame further on does not overlap the head, which is then a frame
        of its own; looking only this far keeps a flood of address bytes linear.)"""
        me = self._host.address
        return window[0] == me and not any(
            window[k] == me and is_frame(window[k:k + SERIAL_FRAME_LEN])
            for k in range(1, min(SERIAL_FRAME_LEN, len(window) - SERIAL_FRAME_LEN + 1)))

    def _receive_ascii(self, data: bytes) -> bytes:
        host = self._host
        me = address_char(host.address)
        mode = self._echo_mode()
        for i, byte in enumerate(data):
            echo, line = self._line.feed(byte, me, mode)
            if echo:
                host.out.queue(SERIAL, echo, reply=False)
            if line is None:
                continue
            self._ascii_line(line)
            if not self.ascii:
                return data[i + 1:]
            me, mode = address_char(host.address), self._echo_mode()
        return b""

    def _echo_mode(self) -> Echo:
        return echo_mode(self._host.store.get(GLOBAL, "ASCIIMode"))

    # -- ASCII commands -----------------------------------------------------------------------
    def _ascii_line(self, text: str) -> None:
        host = self._host
        host._send_late_copies()
        host.runtime.heard()
        if host.faults.lose():
            return
        address = host.address
        word = text.strip().upper()
        after = None
        if word == "BIN":
            ans = Answer()
            after = self.leave_ascii
        elif word == "RUN":
            ans = Answer(Status.COMMAND_NOT_AVAILABLE) if host.vm.download else Answer()
            if not host.vm.download:
                host.vm.reset()
                host.vm.run(0)
        elif word == "STOP":
            host.vm.stop()
            ans = Answer()
        else:
            ans = self._ascii_command(text.strip())
        if not host._suppressed():
            host.out.queue(SERIAL, reply_line(host.host_address, address, ans.status,
                                              to_signed32(ans.value)), reply=True)
        for fn in (ans.after, after):
            if fn is not None:
                fn()

    def _ascii_command(self, text: str) -> Answer:
        host = self._host
        try:
            line = parse_line(text)
        except AsmError:
            return Answer(Status.INVALID_COMMAND)
        if line.mnemonic is None or line.label or line.constant or line.mnemonic[0].isdigit():
            return Answer(Status.INVALID_COMMAND)
        spec = isa.by_mnemonic(line.mnemonic)
        if spec is None:
            return Answer(Status.INVALID_COMMAND)
        if not spec.on(host.module) or not spec.ascii or not spec.direct:
            return Answer(Status.COMMAND_NOT_AVAILABLE, _ascii_value_field(line, spec))
        try:
            enc = encode(line, host.module, direct=True, ascii=True)
        except ValueError as exc:  # AsmError (and ValidationError) are ValueErrors
            return Answer(_ascii_error_status(line, spec, getattr(exc, "col", None)),
                          _ascii_value_field(line, spec))
        ans = host._dispatch(enc.instruction, SERIAL)
        return Answer(ans.status, ans.value, after=ans.after)



def _ascii_error_status(line: Line, spec: isa.InstructionSpec, col: int | None) -> int:
    """The status a line the shared parser refused gets: the field the error points at."""
    slots = list(spec.fields) + [f for f in ("type", "motor", "value") if f not in spec.fields]
    ops = line.operands
    if col is not None and ops and col >= ops[0].col:
        idx = max(i for i, op in enumerate(ops) if op.col <= col)
        if idx >= len(slots):
            return Status.INVALID_VALUE
        return Status.WRONG_TYPE if slots[idx] == "type" else Status.INVALID_VALUE
    missing = spec.fields[len(ops):]
    if missing:
        return Status.WRONG_TYPE if "type" in missing else Status.INVALID_VALUE
    return Status.WRONG_TYPE  # access refused (read-only written, ...) like the binary path


def _ascii_value_field(line: Line, spec: isa.InstructionSpec) -> int:
    """The value field of a refused line as the module read it (a refused command still
    echoes its value, like a binary one); 0 when it is not a plain number."""
    if "value" not in spec.fields:
        return 0
    idx = spec.fields.index("value")
    if idx >= len(line.operands):
        return 0
    expr, sign = line.operands[idx], 1
    while expr.op == "neg" and expr.args:
        expr, sign = expr.args[0], -sign
    if expr.op != "num" or expr.value is None or not -2**31 <= sign * expr.value < 2**32:
        return 0
    return to_signed32((sign * expr.value) & 0xFFFFFFFF)
