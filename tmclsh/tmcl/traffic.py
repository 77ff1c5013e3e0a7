"""Frames read from outside: what the protocol says about traffic tmclsh did not send.

A tap on a bus, a bridge and a log file see requests and replies of a master tmclsh does not
know, in both directions at once. Which of them is a reply, which frames are plausible after
noise, which answer names a module, and which request switches the line to text: these are
facts of the protocol, kept here beside the frames, so the monitor (ops/monitor.py) asks them
instead of spelling out command numbers.
"""

from __future__ import annotations

from . import instructions as isa
from .decoder import FRAME, is_frame
from .frames import Control, Instruction, Reply, ReplyKind
from .status import Status

STATUSES = frozenset(int(s) for s in Status)
_EVENT = int(Status.EVENT)
_TARGET_REACHED = int(Control.TARGET_REACHED_EVENT)
_GET_VERSION = int(Control.GET_VERSION)
_ENTER_ASCII = int(Control.ENTER_ASCII)


def known_command(opcode: int) -> bool:
    """A command the instruction set describes (an instruction or a control command)."""
    return isa.spec_of(opcode) is not None


def is_event(status: int, opcode: int) -> bool:
    """An unsolicited 138 (target reached): status 128 and the event's own number."""
    return status == _EVENT and opcode == _TARGET_REACHED


def expects(ins: Instruction) -> ReplyKind:
    """How the answer to this request is laid out, or that none comes by design (137, and
    the bootloader's 242 and 205: the instruction set's ``reply = "none"``)."""
    return isa.reply_kind(ins.opcode, ins.type)


def plausible_request(frame: bytes | bytearray) -> bool:
    """Nine bytes that add up, read as a request after noise: a command the instruction set
    knows (a number it does not know is taken only where no noise came before it)."""
    return known_command(frame[1])


def plausible_reply(frame: bytes | bytearray, hosts: frozenset[int] | set[int] = frozenset()
                    ) -> bool:
    """Nine bytes that add up, read as a reply after noise: a TMCL status and a known
    command, to one of ``hosts`` (any host when none is known)."""
    return ((not hosts or frame[0] in hosts) and frame[2] in STATUSES
            and known_command(frame[3]))


def damaged_request(window: bytes | bytearray, addresses: frozenset[int] | set[int] = frozenset()
                    ) -> bool:
    """Nine bytes whose sum is wrong, read as a request damaged on its way (what a module
    answers with status 1, and what one listens in to find): a known command, to an address
    seen before (any while none is), and no frame starting inside them (``window`` is the
    nine bytes and what lies after them), so noise before a frame is not taken for one."""
    if len(window) < FRAME or is_frame(window[:FRAME]) or not known_command(window[1]):
        return False
    if addresses and window[0] not in addresses:
        return False
    return not any(is_frame(window[k:k + FRAME])
                   for k in range(1, min(FRAME, len(window) - FRAME + 1)))


def version_answer(ins: Instruction, reply: Reply) -> tuple[str | None, int | None]:
    """What a 136 exchange says the module is: ``(string, None)`` for type 0, ``(None,
    value)`` for type 1; ``(None, None)`` for any other exchange."""
    if reply.version is not None:
        return reply.version, None
    if ins.opcode == _GET_VERSION and ins.type == 1 and reply.ok and reply.opcode == _GET_VERSION:
        return None, reply.value
    return None, None


def teaches(ins: Instruction) -> bool:
    """An exchange that tells a listener more than itself: what the module is (136) or that
    the line turns to text (139); every other answered request only answers."""
    return ins.opcode == _GET_VERSION or ins.opcode == _ENTER_ASCII


def enters_ascii(ins: Instruction) -> bool:
    """After this request is accepted the module reads text lines, not frames (139)."""
    return ins.opcode == _ENTER_ASCII


def leaves_ascii(line: bytes) -> bool:
    """A command line (address character, then the word) that takes the module back to
    binary frames (``ABIN``)."""
    word = bytes(line)[1:].strip().upper()
    return word == isa.ASCII_BIN.encode()
