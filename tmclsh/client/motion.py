"""What tmclsh itself set the motors doing: the record every leave-check reads.

A motor's actual speed is no answer to "did we leave it turning": a real motor reads 0 for
a moment after ROR, and a stalled one reads 0 for as long as it stalls, while the module
still holds the target speed it was given and drives it again as soon as it can. So the
client notes each motion command the module accepted (the instruction set's
``starts_motion``, ``turns`` and ``stops``, and a write to a parameter whose data says it
starts the motor, SAP TargetSpeed), motor by motor, and forgets a motor when it is stopped
(MST, the safety stop's MST, a target speed of 0) or its position move is reported reached
(a 138 event). Whether a position move has ended otherwise is the module's to say
(``ops/stop.activity`` reads it back). Nothing here sends or prints.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import cache

from ..tmcl import instructions as isa
from ..tmcl.frames import Request, Status
from ..tmcl.modules import Module

_OK = int(Status.OK)  # (101, "loaded": stored in program memory, not executed)


@dataclass(frozen=True)
class Commanded:
    """One motor's last accepted motion command: ``kind`` "speed" (``target`` the signed
    target speed) or "position" (``target`` the position value as sent); ``line`` as it
    went out (``ROR 0, 1000``)."""

    kind: str
    target: int
    line: str


@cache
def watched_opcodes() -> frozenset[int]:
    """The commands the record looks at: the ones that start or stop a motor, and the
    parameter writes (one of which may be a target speed). A set lookup per request."""
    return frozenset(s.opcode for s in isa.all_instructions()
                     if (s.starts_motion or s.stops
                          or (s.access == "write" and s.type_kind == "axis_param")))


class MotionRecord:
    """Motor -> :class:`Commanded`, for the module one client talks to. Thread-safe (a
    watch's thread and the unit's may both send)."""

    def __init__(self) -> None:
        self._motors: dict[int, Commanded] = {}
        self._lock = threading.Lock()

    def take(self, module: Module | None, req: Request, status: int) -> None:
        """A request the module answered with ``status``: note what it set a motor doing."""
        if status != _OK:
            return
        spec = isa.by_opcode(req.opcode)
        if spec is None or spec.motor_kind != "motor":
            return
        motion = _motion(spec, module, req)
        with self._lock:
            if motion is None:
                return
            if motion is _STOP:
                self._motors.pop(req.motor, None)
            else:
                self._motors[req.motor] = motion

    def reached(self, mask: int) -> None:
        """A 138 event: the position moves of the motors in ``mask`` have ended."""
        with self._lock:
            for m in [m for m, c in self._motors.items() if c.kind == "position"
                      and mask >> m & 1]:
                del self._motors[m]

    def forget(self, motor: int | None = None) -> None:
        """``motor`` (every one when None) is known to be still, or another module is there."""
        with self._lock:
            if motor is None:
                self._motors.clear()
            else:
                self._motors.pop(motor, None)

    def motors(self) -> dict[int, Commanded]:
        with self._lock:
            return dict(self._motors)

    def __bool__(self) -> bool:
        return bool(self._motors)


_STOP = Commanded("stop", 0, "")


def _motion(spec: isa.InstructionSpec, module: Module | None, req: Request) -> Commanded | None:
    """What ``req`` sets its motor doing: a Commanded, _STOP, or None (nothing)."""
    line = f"{spec.mnemonic} {req.motor}, {req.value}"
    if spec.stops:
        return _STOP
    if spec.turns is not None:  # ROR/ROL: a target speed, its sign by the way it turns
        speed = req.value if spec.turns == "right" else -req.value
        return Commanded("speed", speed, line) if speed else _STOP
    if spec.starts_motion and spec.value_kind == "position":
        name = spec.type_name(req.type, module)
        return Commanded("position", req.value,
                         f"{spec.mnemonic} {name or req.type}, {req.motor}, {req.value}")
    if spec.access == "write" and spec.type_kind == "axis_param" and module is not None:
        param = module.axis(req.type)
        if param is None or not param.starts_motion:
            return None
        written = f"{spec.mnemonic} {param.name}, {req.motor}, {req.value}"
        return Commanded("speed", req.value, written) if req.value else _STOP
    return None


__all__ = ["Commanded", "MotionRecord", "watched_opcodes"]
