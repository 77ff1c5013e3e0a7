"""The simulated module as a byte device: its parts put together, addressing, power and the
calls a host or a test makes.

``Simulator.write`` takes whatever a host sends (binary frames or ASCII text) and processes it
synchronously on the caller's thread: a request is answered before ``write`` returns, unless a
telegram pause (GP 75) or a fault delay holds the reply back. One background thread advances
the clock: motion, the stored program, interrupts, the 138 event and delayed replies. All
state sits behind one lock, held only for short, bounded steps.

The parts, each in its own file: the serial byte stream and ASCII mode (``front.py``), what a
request does (``requests.py``, on ``commands.py``, ``vm.py`` and ``boot.py``), module time and
what runs in it (``runtime.py``), interrupt sources (``interrupts.py``), what goes out and the
faults it meets (``output.py``, ``faults.py``); the state they share is the module's
parameters, I/O and motors (``model.py``, ``motion.py``).

Module time runs ``speed`` times faster than real time (motion, WAIT ticks, timers, tick
timer); communication timing (telegram pause, fault delay, frame gap, heartbeat) is real time.
"""

from __future__ import annotations

import logging
import random
import threading
import time
from collections.abc import Callable, Iterable

from ..tmcl import instructions as isa
from ..tmcl.modules import Module, by_firmware_id, load
from ..tmcl.frames import Instruction, Reply, Request, Status, reply_frame, to_signed32
from ..tmcl.version import encode_type1
from .boot import Bootloader
from .commands import Commands
from .faults import RATE_KINDS, Faults, parse_rates
from .front import SerialFront
from .interrupts import InterruptSources
from .model import AXIS, EEPROM_MAGIC, GLOBAL, Coordinates, IoState, Live, ParamStore
from .motion import SWITCHES, Axis
from .output import CAN, SERIAL, Output
from .requests import BOOT, Answer, Requests
from .runtime import Runtime
from .vm import Vm

log = logging.getLogger(__name__)

# (Faults, RATE_KINDS and parse_rates live in faults.py; named here for the imports of
# earlier releases)
__all__ = ["CAN", "RATE_KINDS", "SERIAL", "Answer", "Faults", "SimBus", "Simulator",
           "parse_rates"]


class Simulator:
    """One simulated TMCL module (see the package docstring and README for its decisions)."""

    FRAME_GAP = SerialFront.FRAME_GAP  # s of silence after which a partial frame is discarded

    def __init__(self, module: str | Module = "TMCM-1311", address: int = 1, *,
                 host_address: int = 2, ascii_startup: bool | None = None,
                 autostart: bool = True, speed: float = 1.0, bootloader: bool = False):
        self.module = load(module) if isinstance(module, str) else module
        if self.module.generic:  # a simulated module is its data: there is nothing to simulate
            from ..base.errors import ValidationError

            raise ValidationError("the simulator needs a module's data; generic mode is for "
                                  "real modules tmclsh has no data for (simulate one of "
                                  "TMCM-1311, TMCM-351, TMCM-1640 or a module file's)")
        for name, value in (("address", address), ("host_address", host_address)):
            if not 0 <= value <= 255:
                raise ValueError(f"{name} must be 0..255, got {value}")
        if ascii_startup and not self.module.ascii_mode:
            raise ValueError(f"{self.module.name} has no ASCII interface")
        if speed <= 0:
            raise ValueError("speed must be positive")
        overrides = {"SerialAddress": address, "SerialHostAddress": host_address}
        if ascii_startup is not None:
            overrides["ASCIIMode"] = int(ascii_startup)
        self._default_address, self._default_host = address, host_address
        self._overrides = overrides
        self.out = Output(self)
        self.front = SerialFront(self)
        self.requests = Requests(self)
        self.runtime = Runtime(self)
        self.interrupts = InterruptSources(self)
        self._build(self.module)
        # the firmware it runs: the module data's, until an update writes another
        self.version_string = self.module.version_string
        self.firmware_version = self.module.firmware_version
        self.boot = Bootloader(self.module.firmware_start, self.module.firmware_size)
        if not bootloader:  # (in it: as after an update that broke off, nothing to start)
            self.boot.install(self.version_string)
        self.faults = Faults()
        self.on_output: Callable[[bytes], None] | None = None
        self.on_can_output: Callable[[int, bytes], None] | None = None

        self._lock = threading.RLock()
        self._speed = float(speed)
        self._mono0 = time.monotonic()
        self._sim0 = 0.0
        with self._lock:
            self._power_up(autostart and not bootloader)
            if bootloader:
                self._enter_bootloader()

        self._closed = threading.Event()
        self._wake = threading.Event()
        self._idle = True
        self._thread = threading.Thread(target=self.runtime.run, name=f"sim-{self.module.name}",
                                        daemon=True)
        self._thread.start()

    def _build(self, module: Module) -> None:
        """The module's state from its data: parameters, I/O, coordinates, motors, program
        memory (at construction, and when an update starts another module type)."""
        self.module = module
        self.store = ParamStore(module, self._overrides)
        self.io = IoState(module)
        self.coords = Coordinates(module.motors, module.coordinates)
        self.axes = [Axis() for _ in range(module.motors)]
        self.commands = Commands(module, self.store, self.io, self.coords, self.axes,
                                 self.clock)
        self.vm = Vm(module.program_memory, self.runtime, module.interrupts)
        self._register_global_live()

    def __repr__(self) -> str:
        return f"Simulator({self.module.name!r}, address={self.address})"

    def __enter__(self) -> Simulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- public state ---------------------------------------------------------------------------
    @property
    def address(self) -> int:
        if self.boot.active:
            return BOOT.address
        return self.store.get(GLOBAL, "SerialAddress", default=self._default_address)

    @property
    def host_address(self) -> int:
        if self.boot.active:
            return BOOT.host_address
        return self.store.get(GLOBAL, "SerialHostAddress", default=self._default_host)

    @property
    def in_bootloader(self) -> bool:
        """It runs its bootloader (after 242, or an update that did not complete)."""
        return self.boot.active

    @property
    def ascii_active(self) -> bool:
        return self.front.ascii

    @property
    def program_state(self) -> int:
        with self._lock:
            self.runtime.advance()
            return int(self.vm.state)

    @property
    def pc(self) -> int:
        with self._lock:
            self.runtime.advance()
            return self.vm.pc

    @property
    def speed(self) -> float:
        return self._speed

    @speed.setter
    def speed(self, value: float) -> None:
        if value <= 0:
            raise ValueError("speed must be positive")
        with self._lock:
            self._sim0 = self.now()
            self._mono0 = time.monotonic()
            self._speed = float(value)

    def now(self) -> float:
        """Module time in seconds (runs ``speed`` times faster than real time)."""
        return self._sim0 + (time.monotonic() - self._mono0) * self._speed

    # -- the serial byte stream -----------------------------------------------------------------
    def write(self, data: bytes) -> None:
        """Bytes from the host; never blocks on the reply."""
        if not data:
            return
        with self._lock:
            self.runtime.advance()
            self.front.receive(bytes(data))
            self.runtime.check_events()
            busy = self.runtime.busy()
        self.out.drain()
        if (busy and self._idle) or self.out.pending():
            self._wake.set()

    def read(self, timeout: float | None = 0.0) -> bytes:
        """Bytes the module sent: waits up to ``timeout`` for the first, returns all there are."""
        return self.out.read(timeout)

    # -- CAN --------------------------------------------------------------------------------------
    @property
    def can_id(self) -> int:
        if self.boot.active:
            return BOOT.can_id
        return self.store.get(GLOBAL, "CANID", default=self.address)

    @property
    def can_reply_id(self) -> int:
        if self.boot.active:
            return BOOT.can_reply_id
        return self.store.get(GLOBAL, "CANReplyID", default=self.host_address)

    def can_write(self, arbitration_id: int, data: bytes) -> None:
        """A CAN frame from the bus; frames for other ids (or shorter than 7 bytes) are ignored."""
        with self._lock:
            self.runtime.advance()
            second = None if self.boot.active else self.store.get(GLOBAL, "CANSecondaryAddress")
            if arbitration_id != self.can_id and not (second and arbitration_id == second):
                return
            if len(data) < 7:
                log.debug("CAN frame with %d data bytes ignored", len(data))
                return
            if not self.faults.lose():
                self._handle(Request.from_can(self.address, bytes(data[:7])), CAN)
            self.runtime.check_events()
            busy = self.runtime.busy()
        self.out.drain()
        if (busy and self._idle) or self.out.pending():
            self._wake.set()

    def can_read(self, timeout: float | None = 0.0) -> tuple[int, bytes] | None:
        return self.out.can_read(timeout)

    # -- test hooks -------------------------------------------------------------------------------
    def set_input(self, bank: int, port: int, value: int) -> None:
        """Drive an input pin (digital bank 0 or analog bank 1, as the data file lists them)."""
        with self._lock:
            self.runtime.advance()
            before = self.interrupts.pin_levels()
            self.io.set_input(bank, port, value)
            self.interrupts.pin_edges(before, self.interrupts.pin_levels())
        self._wake.set()

    def set_switch(self, motor: int, which: str, active: bool | None) -> None:
        """Force a switch level ("left" | "right" | "ref"); None hands it back to its position."""
        sw = self._switch(motor, which)
        with self._lock:
            self.runtime.advance()
            sw.forced = active
            self.axes[motor].settle()
        self._wake.set()

    def set_switch_position(self, motor: int, which: str, position: float | None) -> None:
        """Place a switch: left/ref are active at and below ``position``, right at and above."""
        sw = self._switch(motor, which)
        with self._lock:
            self.runtime.advance()
            sw.forced = None
            sw.position = None if position is None else float(position)
            self.axes[motor].settle()
        self._wake.set()

    BENCH_REFERENCE_POSITION = -20000

    def bench_layout(self) -> Simulator:
        """Place a reference switch below position 0 on every motor, as on a bench rig.

        The shell's built-in simulator and ``tmclsh sim`` use this layout so that a homing
        script (RFS) finds a switch the way it would on real hardware; a bare ``Simulator``
        has no switch placed, which is what most tests want.
        """
        if self.module.has_instruction(isa.Opcode.RFS):
            for motor in range(self.module.motors):
                self.set_switch_position(motor, "ref", self.BENCH_REFERENCE_POSITION)
        return self

    def _switch(self, motor: int, which: str):
        if not 0 <= motor < self.module.motors:
            raise ValueError(f"{self.module.name} has no motor {motor}")
        if which not in SWITCHES:
            raise ValueError(f"switch must be one of {', '.join(SWITCHES)}, got {which!r}")
        return self.axes[motor].switches[which]

    def param(self, kind: str, number: int, motor_or_bank: int = 0) -> int:
        """A parameter's current value, read past its access flags (tests)."""
        kind = _kind(kind)
        with self._lock:
            self.runtime.advance()
            status, value = self.store.read(kind, number, motor_or_bank, check_access=False)
        if status != Status.OK:
            raise KeyError(f"{self.module.name} has no {kind} parameter {number} "
                           f"({'bank' if kind == GLOBAL else 'motor'} {motor_or_bank})")
        return value

    def stored_param(self, kind: str, number: int, motor_or_bank: int = 0) -> int | None:
        """The EEPROM copy of a parameter (None when it has none)."""
        with self._lock:
            return self.store.eeprom.get((_kind(kind), motor_or_bank, number))

    def load_program(self, instructions: Iterable[Instruction], start: int = 0) -> int:
        """Write instructions straight into program memory (tests); returns the count."""
        instructions = list(instructions)
        if not 0 <= start or start + len(instructions) > self.vm.size:
            raise ValueError(f"{len(instructions)} instructions at {start} do not fit in "
                             f"{self.vm.size} words of program memory")
        with self._lock:
            n = 0
            for n, ins in enumerate(instructions, 1):
                self.vm.memory[start + n - 1] = ins
            return n

    def reset(self) -> None:
        """Power cycle: RAM from EEPROM, program stopped (GP 77 auto start honoured), mode
        from GP 67 bit 0, pending replies and events gone. In the bootloader: the
        application starts if the memory holds a valid one (else it stays there)."""
        with self._lock:
            if self.boot.active:
                self._start_application()
            else:
                self._power_up(True)
        self._wake.set()

    def close(self) -> None:
        self._closed.set()
        self._wake.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=2)

    # -- power ----------------------------------------------------------------------------------
    def _power_up(self, autostart: bool) -> None:
        magic = self.store.by_name(GLOBAL, "EEPROMMagic")
        if magic is not None and self.store.eeprom.get((GLOBAL, magic.bank, magic.number)) \
                != EEPROM_MAGIC:
            log.info("EEPROM magic is not $E4: restoring factory defaults")
            self.store.factory_reset()
        self.store.power_up()
        for port in self.module.io:
            if port.kind == "digital_out":
                self.io.values[(port.bank, port.port)] = port.default or 0
        for axis in self.axes:
            axis.power_cycle()
        keep = self.store.get(GLOBAL, "CoordinateStorage") == 1
        for m in range(self.module.motors):
            for n in range(self.coords.count):
                self.coords.ram[m][n] = self.coords.eeprom[m][n] if keep and n else 0
        self.vm.power_up()
        self.runtime.restart()
        self.front.reset(self.module.ascii_mode
                         and bool(self.store.get(GLOBAL, "ASCIIMode") & 1))
        self.out.clear()
        self.interrupts.timer_due.clear()
        self.interrupts.snapshot()
        if autostart and self.store.get(GLOBAL, "AutoStartMode") == 1:
            self.vm.run(0)

    def _factory_reset(self) -> None:
        self.store.factory_reset()
        for row in self.coords.eeprom:
            row[:] = [0] * len(row)
        self._power_up(True)

    def _register_global_live(self) -> None:
        vm, rt = self.vm, self.runtime

        def set_tick(bank: int, value: int) -> int:
            rt.tick_base = rt.t - value / 1000.0
            return Status.OK

        self.store.add_live(GLOBAL, "ApplicationStatus", Live(lambda b: int(vm.state)))
        self.store.add_live(GLOBAL, "DownloadMode", Live(lambda b: int(vm.download)))
        self.store.add_live(GLOBAL, "ProgramCounter", Live(lambda b: vm.pc))
        self.store.add_live(GLOBAL, "TickTimer", Live(
            lambda b: int((rt.t - rt.tick_base) * 1000 + 1e-6) & 0xFFFFFFFF, set_tick))
        self.store.add_live(GLOBAL, "RandomNumber", Live(lambda b: random.randrange(2**31)))
        self.interrupts.register()
        protection = self.store.by_name(GLOBAL, "TMCLCodeProtection")
        if protection is not None:
            key = (GLOBAL, protection.bank, protection.number)

            def set_protection(bank: int, value: int) -> int:
                # "Changing this value from 1 or 3 to 0 or 2, the TMCL program will be wiped off"
                if self.store.ram.get(key, 0) & 1 and not value & 1:
                    vm.erase()
                self.store.ram[key] = value
                return Status.OK

            self.store.add_live(GLOBAL, "TMCLCodeProtection",
                                Live(lambda b: self.store.ram.get(key, 0), set_protection))
        _register_clear_on_null(self.store)

    # -- requests ---------------------------------------------------------------------------------
    def _handle(self, req: Request, channel: str) -> None:
        if self.out.has_late_copies():
            self._send_late_copies()
        self.runtime.heard()
        ans = self._dispatch(req.instruction, channel)
        if not ans.silent:
            self._send_reply(channel, req.address, req.opcode, ans)
        if ans.after is not None:
            ans.after()

    def _suppressed(self) -> bool:
        return not self.boot.active and self.store.get(GLOBAL, "SuppressReply") == 1

    def _send_reply(self, channel: str, module: int, opcode: int, ans: Answer) -> None:
        if self._suppressed():
            return
        if channel != CAN and ans.version is None and ans.stored is None:
            self.out.queue(SERIAL, reply_frame(self.host_address, module, ans.status, opcode,
                                               ans.value), reply=True)
            return
        reply = Reply(self.host_address, module, ans.status, opcode, to_signed32(ans.value),
                      version=ans.version, stored=ans.stored)
        if channel == CAN:
            self.out.queue(CAN, (self.can_reply_id, reply.to_can()), reply=True)
        else:
            self.out.queue(SERIAL, reply.to_bytes(), reply=True)

    def _dispatch(self, ins: Instruction, channel: str) -> Answer:
        return self.requests.dispatch(ins, channel)

    def _send_late_copies(self) -> None:
        """A request arrived: the copies held back by the "dup-late" fault go out first."""
        self.out.send_late_copies()

    def _version_binary(self) -> int:
        """136 type 1, in the byte order the module's data file gives (``version_layout``)."""
        mod = self.module
        return encode_type1(mod.firmware_id, self.firmware_version, mod.version_layout)

    # -- the bootloader (boot.py) -----------------------------------------------------------
    def _enter_bootloader(self) -> None:
        """242: the module restarts into its bootloader: motors and program stop, the
        application's settings no longer apply (it answers at the bootloader's address)."""
        self.boot.active = True
        for axis in self.axes:
            axis.power_cycle()
        self.vm.power_up()
        self.runtime.events.clear()
        self.front.leave_ascii()

    def _start_application(self) -> None:
        """205 (or a power cycle in the bootloader): run the application the memory holds,
        as the module type and version its version string names; with no valid one, or one
        for a type the simulator has no data for, stay in the bootloader."""
        found = self.boot.application()
        module = by_firmware_id(found.type_number) if found is not None else None
        if found is None or module is None:
            log.info("no valid application to start: staying in the bootloader")
            return
        with self._lock:
            self.boot.active = False
            if module.name != self.module.name:
                self._build(module)
            self.version_string = f"{found.text:<8.8}"
            self.firmware_version = found.number or 0
            self._power_up(True)

    # -- module time (runtime.py) ---------------------------------------------------------------
    def clock(self) -> float:
        """Module time of the step being executed: WAIT ticks count on the same clock as
        motion, timers and the tick timer, however long one update is."""
        return self.runtime.t


def _register_clear_on_null(store: ParamStore) -> None:
    """TMCM-1311 AP 198 "can be used to set bit 2 of axis parameter 201": 1 sets it, 0
    deletes it; the other bits of AP 201 (bit 3, the polarity bit 4) stay as they are.
    Read back, AP 198 is that bit."""
    mode = store.by_name(AXIS, "EncoderMode")
    if mode is None or not store.has(AXIS, "ClearOnNull"):
        return
    bit = 1 << 2

    def get(motor: int) -> int:
        return store.ram.get((AXIS, motor, mode.number), 0) >> 2 & 1

    def set_(motor: int, value: int) -> int:
        key = (AXIS, motor, mode.number)
        now = store.ram.get(key, 0)
        store.ram[key] = now | bit if value else now & ~bit
        return Status.OK

    store.add_live(AXIS, "ClearOnNull", Live(get, set_))


def _kind(kind: str) -> str:
    k = kind.lower()
    if k in ("axis", "ap", "a"):
        return AXIS
    if k in ("global", "gp", "g"):
        return GLOBAL
    raise ValueError(f"parameter kind must be 'axis' or 'global', got {kind!r}")


class SimBus:
    """Several simulators on one RS485 line: each answers only its own address."""

    def __init__(self, simulators: list[Simulator]):
        self.simulators = list(simulators)
        self.on_output: Callable[[bytes], None] | None = None
        self._cond = threading.Condition()
        self._buf = bytearray()
        self._deliver_lock = threading.Lock()
        for sim in self.simulators:
            sim.on_output = self._deliver

    def _deliver(self, data: bytes) -> None:
        with self._deliver_lock:
            cb = self.on_output
            if cb is not None:
                cb(data)
                return
            with self._cond:
                self._buf += data
                self._cond.notify_all()

    def write(self, data: bytes) -> None:
        for sim in self.simulators:
            sim.write(data)

    def read(self, timeout: float | None = 0.0) -> bytes:
        with self._cond:
            if not self._buf and timeout != 0:
                self._cond.wait_for(lambda: bool(self._buf), timeout)
            data = bytes(self._buf)
            self._buf.clear()
        return data

    def close(self) -> None:
        for sim in self.simulators:
            sim.close()

    def __enter__(self) -> SimBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
