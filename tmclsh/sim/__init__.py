"""The simulated TMCL module: what tmclsh and its tests talk to when no hardware is attached.

``Simulator`` is one module (TMCM-1311, TMCM-351, TMCM-1640 or any module with a data file)
built entirely from its database entry: parameters with ranges, access and EEPROM copies,
I/O ports, motors, program memory, ASCII interface and interrupts. It speaks the serial byte
stream (binary frames and ASCII mode) and CAN frames, moves its motors in real time (or
``speed`` times faster), runs stored programs, and misbehaves on demand (``Faults``).
``SimBus`` puts several of them on one RS485 line; ``serve`` exposes one on a pty, a TCP
port or a python-can bus.

The decisions taken where the manuals are silent are listed in ``README.md`` beside this
file; the short version of the status codes: unknown opcode 2, wrong type field (unknown
parameter, access not allowed, unknown port or coordinate) 3, motor/bank/value out of range
4, configuration EEPROM locked 5, a command this module lacks, a program-only command in
direct mode, or a command not possible in the current state (e.g. in download mode) 6.
"""

from __future__ import annotations

from .device import SimBus, Simulator
from .faults import Faults

__all__ = ["Faults", "SimBus", "Simulator"]
