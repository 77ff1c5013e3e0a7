"""TMCL frames: the bytes on the wire, with no I/O.

A request is seven bytes of instruction (opcode, type, motor/bank, 32-bit big-endian value).
On serial links (RS232/RS485/USB) it is wrapped in an address byte and an 8-bit sum checksum;
on CAN the address lives in the CAN id and the checksum in the CAN CRC, so both are dropped.
Replies mirror that with host address, module address, status, opcode and value.

Three replies break the pattern and are modelled here so no caller re-invents them:

* 136 type 0 (firmware version string): host address + eight ASCII characters, no checksum.
* 134 (read program memory, firmware of these manuals): the module-address, status and opcode
  bytes hold the stored instruction's opcode, type and motor; the value holds its value.
* 138 (target reached event): a second, unsolicited reply with status 128 arrives later.

137 (factory reset) sends no reply at all.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum

from ..base.errors import ChecksumError, FrameError, ValidationError
from .status import STATUS_TEXT, Status, status_ok, status_text  # noqa: F401  (re-exported)

SERIAL_FRAME_LEN = 9
INSTRUCTION_LEN = 7
VERSION_STRING_LEN = 8

INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1
UINT32_MAX = 2**32 - 1


class Control(IntEnum):
    """The control commands 128-139 (they have no TMCL-IDE mnemonic)."""

    STOP_APPLICATION = 128
    RUN_APPLICATION = 129
    STEP_APPLICATION = 130
    RESET_APPLICATION = 131
    START_DOWNLOAD = 132
    QUIT_DOWNLOAD = 133
    READ_MEMORY = 134
    GET_STATUS = 135
    GET_VERSION = 136
    FACTORY_DEFAULT = 137
    TARGET_REACHED_EVENT = 138
    ENTER_ASCII = 139


FACTORY_DEFAULT_KEY = 1234


class AppState(IntEnum):
    """The stored program's state, as 135 answers it (and GP 128 holds it)."""

    STOP = 0
    RUN = 1
    STEP = 2
    RESET = 3


class ReplyKind(IntEnum):
    """How a request's answer is laid out on the wire."""

    NORMAL = 0
    VERSION_STRING = 1  # 136 type 0
    MEMORY = 2  # 134 legacy layout
    NONE = 3  # 137: no reply


def reply_kind(opcode: int, type_: int) -> ReplyKind:
    if opcode == Control.GET_VERSION and type_ == 0:
        return ReplyKind.VERSION_STRING
    if opcode == Control.READ_MEMORY:
        return ReplyKind.MEMORY
    if opcode == Control.FACTORY_DEFAULT:
        return ReplyKind.NONE
    return ReplyKind.NORMAL


def checksum(data: bytes) -> int:
    """8-bit sum of the bytes, as both directions of the serial framing use."""
    return sum(data) & 0xFF


def _check_byte(name: str, value: int) -> None:
    if not isinstance(value, int) or not 0 <= value <= 255:
        raise ValidationError(f"{name} must be 0..255, got {value!r}")


def _check_value(value: int) -> None:
    if not isinstance(value, int) or not INT32_MIN <= value <= UINT32_MAX:
        raise ValidationError(f"value must fit 32 bits ({INT32_MIN}..{UINT32_MAX}), got {value!r}")


# the first eight bytes of a serial frame, either direction; frozen dataclasses are filled
# by the hot-path constructors below through their slots' descriptors (after the classes)
_SERIAL_HEAD = struct.Struct(">BBBBi")
# a CAN reply's seven bytes: module, status, command, value (the serial frame's fields after
# its host byte, read the same way)
CAN_REPLY = struct.Struct(">BBBi")
_new = object.__new__
_STATUS_OK = int(Status.OK)  # (a plain int: a read-back's status, once per 134 answer)


def to_signed32(value: int) -> int:
    value &= 0xFFFFFFFF
    return value - 2**32 if value & 0x80000000 else value


def reply_frame(host: int, module: int, status: int, opcode: int, value: int) -> bytes:
    """A normal reply's nine bytes, ``Reply(...).to_bytes()`` without the object: a
    simulated module answers every request through here (``struct.error`` out of range)."""
    body = _SERIAL_HEAD.pack(host, module, status, opcode, to_signed32(value))
    return body + bytes((sum(body) & 0xFF,))


def _value_bytes(value: int) -> bytes:
    return struct.pack(">I", value & 0xFFFFFFFF)


@dataclass(frozen=True, slots=True)
class Instruction:
    """The seven bytes every TMCL command shares: what the program memory stores."""

    opcode: int
    type: int = 0
    motor: int = 0
    value: int = 0

    def __post_init__(self) -> None:
        _check_byte("opcode", self.opcode)
        _check_byte("type", self.type)
        _check_byte("motor/bank", self.motor)
        _check_value(self.value)
        # one value, one representation: 0xFFFFD8F0 and -10000 are the same four bytes
        object.__setattr__(self, "value", to_signed32(self.value))

    def to_bytes(self) -> bytes:
        return bytes((self.opcode, self.type, self.motor)) + _value_bytes(self.value)

    @classmethod
    def from_bytes(cls, data: bytes) -> Instruction:
        if len(data) != INSTRUCTION_LEN:
            raise FrameError(f"an instruction is {INSTRUCTION_LEN} bytes, got {len(data)}")
        return cls(data[0], data[1], data[2], struct.unpack(">i", data[3:7])[0])

    @property
    def signed_value(self) -> int:
        return to_signed32(self.value)

    def __str__(self) -> str:
        return f"op {self.opcode} type {self.type} motor {self.motor} value {self.signed_value}"


@dataclass(frozen=True, slots=True)
class Request:
    """A command addressed to one module."""

    address: int
    opcode: int
    type: int = 0
    motor: int = 0
    value: int = 0
    # the nine bytes, made when first sent: a script or watch sends the same request again
    _frame: bytes | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        _check_byte("address", self.address)
        _check_byte("opcode", self.opcode)
        _check_byte("type", self.type)
        _check_byte("motor/bank", self.motor)
        _check_value(self.value)
        # one value, one representation: 0xFFFFD8F0 and -10000 are the same four bytes
        object.__setattr__(self, "value", to_signed32(self.value))

    @property
    def instruction(self) -> Instruction:
        # (its fields passed the same checks when the request was made: the simulator asks
        # this of every request it hears)
        ins = _new(_FillInstruction)
        ins.opcode = self.opcode
        ins.type = self.type
        ins.motor = self.motor
        ins.value = self.value
        ins.__class__ = Instruction
        return ins

    @property
    def reply_kind(self) -> ReplyKind:
        return reply_kind(self.opcode, self.type)

    @classmethod
    def make(cls, address: int, opcode: int, type: int = 0, motor: int = 0,
             value: int = 0) -> Request:
        """``Request(...)`` for the client's hot path: plain in-range ints skip the checks they
        would pass anyway (a dozen calls, a measurable share of a 30 us round trip); anything
        else goes through ``__init__``, which normalises it or raises naming the field."""
        if (address.__class__ is int and opcode.__class__ is int and type.__class__ is int
                and motor.__class__ is int and value.__class__ is int
                and 0 <= address <= 255 and 0 <= opcode <= 255 and 0 <= type <= 255
                and 0 <= motor <= 255 and INT32_MIN <= value <= INT32_MAX):
            req = _new(_FillRequest)
            req.address = address
            req.opcode = opcode
            req.type = type
            req.motor = motor
            req.value = value
            req._frame = None
            req.__class__ = Request
            return req
        return cls(address, opcode, type, motor, value)

    def to_bytes(self) -> bytes:
        """Serial framing: address, instruction, checksum."""
        frame = self._frame
        if frame is None:
            body = _SERIAL_HEAD.pack(self.address, self.opcode, self.type, self.motor,
                                     self.value)
            frame = body + bytes((sum(body) & 0xFF,))
            _req_frame(self, frame)
        return frame

    def to_can(self) -> bytes:
        """CAN data field: the instruction alone (the id addresses the module)."""
        return self.instruction.to_bytes()

    @classmethod
    def from_bytes(cls, data: bytes) -> Request:
        """Parse a serial request; raises ChecksumError on a bad sum (the module's status 1)."""
        if len(data) != SERIAL_FRAME_LEN:
            raise FrameError(f"a serial request is {SERIAL_FRAME_LEN} bytes, got {len(data)}")
        if checksum(data[:8]) != data[8]:
            raise ChecksumError(
                f"request checksum {data[8]:#04x} should be {checksum(data[:8]):#04x}")
        # four bytes and a signed 32-bit value: nothing left to check (the simulator reads
        # every request it hears through here)
        return cls.make(*_SERIAL_HEAD.unpack_from(data))

    @classmethod
    def from_can(cls, address: int, data: bytes) -> Request:
        ins = Instruction.from_bytes(bytes(data))
        return cls(address, ins.opcode, ins.type, ins.motor, ins.value)

    def __str__(self) -> str:
        return (f"-> addr {self.address} op {self.opcode} type {self.type} "
                f"motor {self.motor} value {to_signed32(self.value)}")


@dataclass(frozen=True, slots=True)
class Reply:
    """A module's answer.

    ``version`` is set for 136 type 0 string replies and ``stored`` for 134 read-back replies;
    for those the other fields are filled as well as the layout allows (see module docstring).
    """

    host: int
    module: int
    status: int
    opcode: int
    value: int = 0
    version: str | None = None
    stored: Instruction | None = None

    def __post_init__(self) -> None:
        _check_byte("host address", self.host)
        _check_byte("module address", self.module)
        _check_byte("status", self.status)
        _check_byte("opcode", self.opcode)
        _check_value(self.value)
        object.__setattr__(self, "value", to_signed32(self.value))
        if self.version is not None and len(self.version) != VERSION_STRING_LEN:
            raise ValueError(f"a version string is {VERSION_STRING_LEN} characters, "
                             f"got {self.version!r}")

    @classmethod
    def from_frame(cls, frame: bytes) -> Reply:
        """A normal reply from nine bytes whose checksum the caller has verified: every field
        is one byte or a signed 32-bit value, so there is nothing left to check (hot path)."""
        r = _new(_FillReply)
        r.host, r.module, r.status, r.opcode, r.value = _SERIAL_HEAD.unpack_from(frame)
        r.version = r.stored = None
        r.__class__ = Reply
        return r

    @classmethod
    def from_memory_frame(cls, frame: bytes, module: int, opcode: int) -> Reply:
        """A 134 read-back from nine bytes whose checksum the caller has verified (the same
        reply as ``from_bytes(frame, ReplyKind.MEMORY, module, opcode)``; upload verifies one
        per instruction)."""
        stored = _new(_FillInstruction)
        r = _new(_FillReply)
        # (unpacked straight into the slots: the frame's host, the stored instruction)
        r.host, stored.opcode, stored.type, stored.motor, stored.value = \
            _SERIAL_HEAD.unpack_from(frame)
        stored.__class__ = Instruction
        r.value = stored.value
        r.module = module
        r.status = _STATUS_OK
        r.opcode = opcode
        r.version = None
        r.stored = stored
        r.__class__ = Reply
        return r

    @property
    def ok(self) -> bool:
        return status_ok(self.status)

    @property
    def is_event(self) -> bool:
        return self.status == Status.EVENT

    @property
    def status_text(self) -> str:
        return status_text(self.status)

    def to_bytes(self) -> bytes:
        if self.version is not None:
            return bytes((self.host,)) + self.version.encode("ascii", "replace")
        if self.stored is not None:
            s = self.stored
            body = bytes((self.host, s.opcode, s.type, s.motor)) + _value_bytes(s.value)
        else:
            body = bytes((self.host, self.module, self.status, self.opcode)) + _value_bytes(self.value)
        return body + bytes((checksum(body),))

    def to_can(self) -> bytes:
        """CAN data: module address, status, opcode, value (host address is the CAN id)."""
        if self.version is not None:
            return self.version.encode("ascii")
        if self.stored is not None:
            s = self.stored
            return bytes((s.opcode, s.type, s.motor)) + _value_bytes(s.value)
        return bytes((self.module, self.status, self.opcode)) + _value_bytes(self.value)

    @classmethod
    def from_bytes(cls, data: bytes, kind: ReplyKind = ReplyKind.NORMAL,
                   module: int | None = None, opcode: int | None = None) -> Reply:
        """Parse one serial reply of the given layout.

        ``module`` and ``opcode`` fill the fields that the 134 and 136 layouts do not carry.
        """
        data = bytes(data)
        if kind == ReplyKind.VERSION_STRING:
            if len(data) != SERIAL_FRAME_LEN:
                raise FrameError(f"a version reply is {SERIAL_FRAME_LEN} bytes, got {len(data)}")
            text = data[1:].decode("ascii", errors="replace")
            if not all(32 <= b < 127 for b in data[1:]):
                raise FrameError(f"version reply holds non-printable bytes: {data[1:].hex(' ')}")
            return cls(data[0], module if module is not None else 0, Status.OK,
                       Control.GET_VERSION, 0, version=text)
        if len(data) != SERIAL_FRAME_LEN:
            raise FrameError(f"a serial reply is {SERIAL_FRAME_LEN} bytes, got {len(data)}")
        if checksum(data[:8]) != data[8]:
            raise ChecksumError(
                f"reply checksum {data[8]:#04x} should be {checksum(data[:8]):#04x} "
                f"({data.hex(' ')})")
        value = struct.unpack(">i", data[4:8])[0]
        if kind == ReplyKind.MEMORY:
            stored = Instruction(data[1], data[2], data[3], value)
            return cls(data[0], module if module is not None else 0, Status.OK,
                       opcode if opcode is not None else Control.READ_MEMORY, value, stored=stored)
        return cls(data[0], data[1], data[2], data[3], value)

    @classmethod
    def from_can(cls, host: int, data: bytes, kind: ReplyKind = ReplyKind.NORMAL,
                 module: int | None = None) -> Reply:
        data = bytes(data)
        if kind == ReplyKind.VERSION_STRING:
            if len(data) != VERSION_STRING_LEN:
                raise FrameError(f"a CAN version reply is 8 bytes, got {len(data)}")
            return cls(host, module if module is not None else 0, Status.OK,
                       Control.GET_VERSION, 0, version=data.decode("ascii", errors="replace"))
        if len(data) != INSTRUCTION_LEN:
            raise FrameError(f"a CAN reply is {INSTRUCTION_LEN} bytes, got {len(data)}")
        value = struct.unpack(">i", data[3:7])[0]
        if kind == ReplyKind.MEMORY:
            stored = Instruction(data[0], data[1], data[2], value)
            return cls(host, module if module is not None else 0, Status.OK,
                       Control.READ_MEMORY, value, stored=stored)
        return cls(host, data[0], data[1], data[2], value)

    def __str__(self) -> str:
        if self.version is not None:
            return f"<- host {self.host} version {self.version!r}"
        if self.stored is not None:
            return f"<- host {self.host} stored {self.stored}"
        return (f"<- host {self.host} module {self.module} status {self.status} "
                f"({self.status_text}) op {self.opcode} value {self.value}")


def _filling(cls: type) -> type:
    """A plain class with ``cls``'s slots. The hot-path constructors above fill one of these
    with plain stores and then make it a ``cls`` (``__class__`` assignment, which Python
    allows between classes of one layout): a frozen instance can only be filled through
    its slots' descriptors, one call per field, which took twice as long (a reply is made
    per answer, an upload's verify makes an instruction with each). Never seen outside."""
    return type(f"_Filling{cls.__name__}", (), {"__slots__": cls.__slots__})


_FillRequest, _FillReply, _FillInstruction = (_filling(c) for c in (Request, Reply, Instruction))
# (a request's frame is made once, when first asked for: set on the frozen request)
_req_frame = Request.__dict__["_frame"].__set__


def hexdump(data: bytes) -> str:
    return bytes(data).hex(" ")


def parse_hex(text: str) -> bytes:
    """Bytes pasted from elsewhere: ``01 06 01 00 ...``, ``$01 $06``, ``0x01,0x06``, ``010601``."""
    cleaned = text.replace(",", " ").replace("$", " ").replace("0x", " ").replace("0X", " ")
    parts = cleaned.split()
    if len(parts) == 1 and len(parts[0]) > 2:
        parts = [parts[0][i:i + 2] for i in range(0, len(parts[0]), 2)]
    try:
        return bytes(int(p, 16) for p in parts)
    except ValueError as exc:
        raise FrameError(f"not hex bytes: {text!r}") from exc
