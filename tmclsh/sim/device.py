"""The simulated module as a byte device: framing, addressing, dispatch, faults and time.

``Simulator.write`` takes whatever a host sends (binary frames or ASCII text) and processes it
synchronously on the caller's thread: a request is answered before ``write`` returns, unless a
telegram pause (GP 75) or a fault delay holds the reply back. One background thread advances
the clock: motion, the stored program, interrupts, the 138 event and delayed replies. All
state sits behind one lock, held only for short, bounded steps.

Module time runs ``speed`` times faster than real time (motion, WAIT ticks, timers, tick
timer); communication timing (telegram pause, fault delay, frame gap, heartbeat) is real time.
"""

from __future__ import annotations

import logging
import math
import random
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from ..tmcl import instructions as isa
from ..tmcl.asm import Line, encode, parse_line
from ..base.errors import AsmError
from ..tmcl.bootloader import bootloader_string
from ..tmcl.bootloader import facts as boot_facts
from ..tmcl.modules import Module, by_firmware_id, load
from ..tmcl.decoder import NOISE, WHOLE, FrameDecoder, is_frame
from ..tmcl.frames import (FACTORY_DEFAULT_KEY, SERIAL_FRAME_LEN, Control, Instruction, Reply,
                           Request, Status, to_signed32)
from ..tmcl.version import encode_type1
from .ascii import Echo, LineDiscipline, address_char, echo_mode, reply_line
from .boot import Bootloader
from .commands import Commands
from .model import AXIS, EEPROM_MAGIC, GLOBAL, Coordinates, IoState, Live, ParamStore
from .motion import SWITCHES, Axis
from .vm import TICK as VM_TICK
from .vm import WAIT, Vm

log = logging.getLogger(__name__)

SERIAL = "serial"
CAN = "can"

IRQ = isa.interrupts()
RUN_FROM_CURRENT, RUN_FROM_ADDRESS = 0, 1  # command 129 types
VERSION_STRING, VERSION_BINARY = 0, 1  # command 136 types
# Control commands whose reply value is a result; the others echo the request's value field.
RANDOM_DELAY = (0.2, 2.0)  # s a reply hit by the random "delay" fault is held back
ENTER_BOOTLOADER = isa.boot_command("enter")  # 242
BOOT = boot_facts()
RESULT_CONTROLS = frozenset({Control.READ_MEMORY, Control.GET_STATUS, Control.GET_VERSION,
                             Control.TARGET_REACHED_EVENT})


@dataclass
class Faults:
    """Switches a test flips to make the link misbehave; counters count down per reply.

    ``drop_next``: the next N requests are executed but their replies are not sent.
    ``lose_next``: the next N requests addressed to the module are lost before it sees them
    (not executed, no reply). ``corrupt_next``: one bit flipped in a random byte (never the
    last one) of the next N replies. ``truncate_next``: only the first half of the next N
    replies is sent. ``garbage``: bytes sent once, just before the next reply. ``delay``:
    seconds added before every reply. ``dup_next``: the next N replies are sent twice, back
    to back; ``dup_late_next``: a copy of each of the next N replies is held back and sent
    when the next request has arrived, before its reply (a repeater or an RS485 echo that
    lags). The 138 event counts as a reply.

    ``rates`` makes the link misbehave at random: a probability per reply for each kind in
    ``RATE_KINDS`` (``tmclsh sim --faults``), drawn from ``rng``.
    """

    corrupt_next: int = 0
    drop_next: int = 0
    delay: float = 0.0
    garbage: bytes = b""
    truncate_next: int = 0
    lose_next: int = 0
    dup_next: int = 0
    dup_late_next: int = 0
    rates: dict[str, float] = field(default_factory=dict)
    rng: random.Random = field(default_factory=lambda: random.Random(0), repr=False)

    def roll(self, kind: str) -> bool:
        """Does the random fault ``kind`` hit this reply?"""
        p = self.rates.get(kind)
        return bool(p) and self.rng.random() < p  # type: ignore[operator]

    def take(self, counter: str, kind: str) -> bool:
        """The counted fault ``counter`` (counted down) or else the random ``kind``."""
        n = getattr(self, counter)
        if n > 0:
            setattr(self, counter, n - 1)
            return True
        return bool(self.rates) and self.roll(kind)


#: random faults per reply (``Faults.rates``), with what each does, for --help and the docs
RATE_KINDS = {
    "drop": "the reply is not sent (the command was executed)",
    "corrupt": "one bit of the reply flipped",
    "truncate": "only the first half of the reply is sent",
    "delay": f"the reply is held back {RANDOM_DELAY[0]:g}..{RANDOM_DELAY[1]:g} s "
             "(and the replies behind it)",
    "garbage": "1..8 bytes of noise before the reply",
    "dup": "the reply is sent twice, back to back",
    "dup-late": "a copy of the reply follows once the next request has arrived",
}


def parse_rates(text: str) -> dict[str, float]:
    """``"drop=0.1,dup=0.05"`` -> rates; ValueError (one line, for users) on bad input."""
    rates: dict[str, float] = {}
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        kind, sep, prob = part.partition("=")
        kind = kind.strip().lower()
        if not sep or kind not in RATE_KINDS:
            raise ValueError(f"{part!r} is not KIND=PROBABILITY (kinds: "
                             f"{', '.join(RATE_KINDS)})")
        try:
            p = float(prob)
        except ValueError:
            p = -1.0
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"{kind}={prob.strip()}: the probability must be a number "
                             "from 0 to 1")
        rates[kind] = p
    if not rates:
        raise ValueError("no faults given (e.g. drop=0.1,dup=0.05; kinds: "
                         f"{', '.join(RATE_KINDS)})")
    return rates


@dataclass
class Answer:
    status: int = Status.OK
    value: int = 0
    version: str | None = None
    stored: Instruction | None = None
    silent: bool = False  # 137: no reply at all
    after: Callable[[], None] | None = None  # runs once the reply is queued


class Simulator:
    """One simulated TMCL module (see the package docstring and README for its decisions)."""

    FRAME_GAP = 0.05  # s of silence after which a partial binary frame is discarded
    TICK = 0.005  # s between background steps while something moves or runs
    IDLE_TICK = 0.05
    MAX_STEP = 0.01  # s of module time per physics/program step
    MAX_STEPS = 50  # steps per advance; beyond that the steps get longer
    INSTRUCTIONS_PER_SECOND = 10_000  # stored-program execution rate (module time)
    MAX_CREDIT = 200
    MIN_BURST = 16  # instructions a step may run on credit

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
        self._out_lock = threading.Lock()
        self._rx_cond = threading.Condition()
        self._can_cond = threading.Condition()
        self._outbuf = bytearray()
        self._canbuf: deque[tuple[int, bytes]] = deque()
        self._outq: deque[tuple[float, str, object]] = deque()
        self._late_copies: deque[tuple[str, object]] = deque()  # the "dup-late" fault
        self._last_due = 0.0
        self._rx = FrameDecoder()  # requests: any frame that adds up
        self._rx_time = 0.0
        self._line = LineDiscipline()
        self._ascii = False
        self._events: list[tuple[int, str, int]] = []
        self._speed = float(speed)
        self._mono0 = time.monotonic()
        self._sim0 = 0.0
        self._t = 0.0
        self._tick_base = 0.0
        self._credit = 0.0
        self._timer_due: dict[int, tuple[float, float]] = {}  # irq -> (period, due)
        self._prev: dict[str, object] = {}
        self._last_command = time.monotonic()
        self._heartbeat_fired = False
        with self._lock:
            self._power_up(autostart and not bootloader)
            if bootloader:
                self._enter_bootloader()

        self._closed = threading.Event()
        self._wake = threading.Event()
        self._idle = True
        self._thread = threading.Thread(target=self._run, name=f"sim-{self.module.name}",
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
        self.vm = Vm(module.program_memory, self, module.interrupts)
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
        return self._ascii

    @property
    def program_state(self) -> int:
        with self._lock:
            self._advance()
            return int(self.vm.state)

    @property
    def pc(self) -> int:
        with self._lock:
            self._advance()
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
            self._advance()
            self._receive(bytes(data))
            self._check_events()
            busy = self._busy()
        self._drain()
        if (busy and self._idle) or self._outq:
            self._wake.set()

    def read(self, timeout: float | None = 0.0) -> bytes:
        """Bytes the module sent: waits up to ``timeout`` for the first, returns all there are."""
        self._drain()
        with self._rx_cond:
            if not self._outbuf and timeout != 0:
                self._rx_cond.wait_for(lambda: bool(self._outbuf), timeout)
            data = bytes(self._outbuf)
            self._outbuf.clear()
        return data

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
            self._advance()
            second = None if self.boot.active else self.store.get(GLOBAL, "CANSecondaryAddress")
            if arbitration_id != self.can_id and not (second and arbitration_id == second):
                return
            if len(data) < 7:
                log.debug("CAN frame with %d data bytes ignored", len(data))
                return
            if not self._lose():
                self._handle(Request.from_can(self.address, bytes(data[:7])), CAN)
            self._check_events()
            busy = self._busy()
        self._drain()
        if (busy and self._idle) or self._outq:
            self._wake.set()

    def can_read(self, timeout: float | None = 0.0) -> tuple[int, bytes] | None:
        self._drain()
        with self._can_cond:
            if not self._canbuf and timeout != 0:
                self._can_cond.wait_for(lambda: bool(self._canbuf), timeout)
            return self._canbuf.popleft() if self._canbuf else None

    # -- test hooks -------------------------------------------------------------------------------
    def set_input(self, bank: int, port: int, value: int) -> None:
        """Drive an input pin (digital bank 0 or analog bank 1, as the data file lists them)."""
        with self._lock:
            self._advance()
            before = self._pin_levels()
            self.io.set_input(bank, port, value)
            self._pin_edges(before, self._pin_levels())
        self._wake.set()

    def set_switch(self, motor: int, which: str, active: bool | None) -> None:
        """Force a switch level ("left" | "right" | "ref"); None hands it back to its position."""
        sw = self._switch(motor, which)
        with self._lock:
            self._advance()
            sw.forced = active
            self.axes[motor].settle()
        self._wake.set()

    def set_switch_position(self, motor: int, which: str, position: float | None) -> None:
        """Place a switch: left/ref are active at and below ``position``, right at and above."""
        sw = self._switch(motor, which)
        with self._lock:
            self._advance()
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
            self._advance()
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
        self._events.clear()
        self._rx.clear()
        self._line.clear()
        with self._out_lock:
            self._outq.clear()
        self._ascii = self.module.ascii_mode and bool(self.store.get(GLOBAL, "ASCIIMode") & 1)
        self._t = self.now()
        self._tick_base = self._t
        self._timer_due.clear()
        self._snapshot()
        if autostart and self.store.get(GLOBAL, "AutoStartMode") == 1:
            self.vm.run(0)

    def _factory_reset(self) -> None:
        self.store.factory_reset()
        for row in self.coords.eeprom:
            row[:] = [0] * len(row)
        self._power_up(True)

    def _register_global_live(self) -> None:
        vm = self.vm

        def set_tick(bank: int, value: int) -> int:
            self._tick_base = self._t - value / 1000.0
            return Status.OK

        self.store.add_live(GLOBAL, "ApplicationStatus", Live(lambda b: int(vm.state)))
        self.store.add_live(GLOBAL, "DownloadMode", Live(lambda b: int(vm.download)))
        self.store.add_live(GLOBAL, "ProgramCounter", Live(lambda b: vm.pc))
        self.store.add_live(GLOBAL, "TickTimer", Live(
            lambda b: int((self._t - self._tick_base) * 1000 + 1e-6) & 0xFFFFFFFF, set_tick))
        self.store.add_live(GLOBAL, "RandomNumber", Live(lambda b: random.randrange(2**31)))
        for irq in (IRQ["TI_TIMER0"], IRQ["TI_TIMER1"], IRQ["TI_TIMER2"]):
            timer = self.store.param(GLOBAL, irq, 3)
            if timer is not None:
                self.store.add_live(GLOBAL, timer.name, self._timer_period(irq))
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
        self._register_clear_on_null()

    def _register_clear_on_null(self) -> None:
        """TMCM-1311 AP 198 "can be used to set bit 2 of axis parameter 201": 1 sets it, 0
        deletes it; the other bits of AP 201 (bit 3, the polarity bit 4) stay as they are.
        Read back, AP 198 is that bit."""
        store = self.store
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

    def _timer_period(self, irq: int) -> Live:
        """Timer interrupt periods (GP bank 3 #0-2): a period counts from when it is set."""
        key = (GLOBAL, 3, irq)

        def set_period(bank: int, value: int) -> int:
            self.store.ram[key] = value
            if value > 0:
                self._timer_due[irq] = (value / 1000.0, self._t + value / 1000.0)
            else:
                self._timer_due.pop(irq, None)
            return Status.OK

        return Live(lambda b: self.store.ram.get(key, 0), set_period)

    # -- receiving --------------------------------------------------------------------------------
    def _receive(self, data: bytes) -> None:
        while data:
            data = self._receive_ascii(data) if self._ascii else self._receive_binary(data)

    def _lose(self) -> bool:
        if self.faults.lose_next > 0:
            self.faults.lose_next -= 1
            return True
        return False

    def _receive_binary(self, data: bytes) -> bytes:
        """Frames out of the bytes, as every reader finds them (tmcl/decoder.py)."""
        now = time.monotonic()
        rx = self._rx
        if rx.buf and now - self._rx_time > self.FRAME_GAP:
            log.debug("discarding %d bytes of a partial frame after a gap", len(rx.buf))
            rx.clear()
        self._rx_time = now
        rx.feed(data)
        me = self.address
        while (piece := rx.next(whole=self._damaged)) is not None:
            kind, frame = piece
            if kind == NOISE:
                continue  # garbage or a misaligned frame: the decoder slid past it
            if kind == WHOLE:  # a frame for this module whose sum is wrong
                if not self._lose():
                    self._last_command = time.monotonic()
                    self._send_reply(SERIAL, me, frame[1], Answer(Status.WRONG_CHECKSUM))
                continue
            if frame[0] != me:
                continue  # another module's frame on a shared line
            if not self._lose():
                self._handle(Request.from_bytes(frame), SERIAL)
            if self._ascii:
                return rx.rest()
        return b""

    def _damaged(self, window: bytearray) -> bool:
        """Nine bytes addressed to this module that are no frame, with no frame for it
        starting inside them: a request damaged on the line, which a module answers with
        status 1. (A valid frame further on does not overlap the head, which is then a frame
        of its own; looking only this far keeps a flood of address bytes linear.)"""
        me = self.address
        return window[0] == me and not any(
            window[k] == me and is_frame(window[k:k + SERIAL_FRAME_LEN])
            for k in range(1, min(SERIAL_FRAME_LEN, len(window) - SERIAL_FRAME_LEN + 1)))

    def _receive_ascii(self, data: bytes) -> bytes:
        me = address_char(self.address)
        mode = self._echo_mode()
        for i, byte in enumerate(data):
            echo, line = self._line.feed(byte, me, mode)
            if echo:
                self._queue(SERIAL, echo, reply=False)
            if line is None:
                continue
            self._ascii_line(line)
            if not self._ascii:
                return data[i + 1:]
            me, mode = address_char(self.address), self._echo_mode()
        return b""

    def _echo_mode(self) -> Echo:
        return echo_mode(self.store.get(GLOBAL, "ASCIIMode"))

    # -- ASCII commands ---------------------------------------------------------------------------
    def _ascii_line(self, text: str) -> None:
        self._send_late_copies()
        self._last_command = time.monotonic()
        self._heartbeat_fired = False
        if self._lose():
            return
        address = self.address
        word = text.strip().upper()
        after = None
        if word == "BIN":
            ans = Answer()
            after = self._leave_ascii
        elif word == "RUN":
            ans = Answer(Status.COMMAND_NOT_AVAILABLE) if self.vm.download else Answer()
            if not self.vm.download:
                self.vm.reset()
                self.vm.run(0)
        elif word == "STOP":
            self.vm.stop()
            ans = Answer()
        else:
            ans = self._ascii_command(text.strip())
        if not self._suppressed():
            self._queue(SERIAL, reply_line(self.host_address, address, ans.status,
                                           to_signed32(ans.value)), reply=True)
        for fn in (ans.after, after):
            if fn is not None:
                fn()

    def _leave_ascii(self) -> None:
        self._ascii = False
        self._line.clear()
        self._rx.clear()

    def _ascii_command(self, text: str) -> Answer:
        try:
            line = parse_line(text)
        except AsmError:
            return Answer(Status.INVALID_COMMAND)
        if line.mnemonic is None or line.label or line.constant or line.mnemonic[0].isdigit():
            return Answer(Status.INVALID_COMMAND)
        spec = isa.by_mnemonic(line.mnemonic)
        if spec is None:
            return Answer(Status.INVALID_COMMAND)
        if not spec.on(self.module) or not spec.ascii or not spec.direct:
            return Answer(Status.COMMAND_NOT_AVAILABLE, _ascii_value_field(line, spec))
        try:
            enc = encode(line, self.module, direct=True, ascii=True)
        except ValueError as exc:  # AsmError (and ValidationError) are ValueErrors
            return Answer(_ascii_error_status(line, spec, getattr(exc, "col", None)),
                          _ascii_value_field(line, spec))
        ans = self._dispatch(enc.instruction, SERIAL)
        return Answer(ans.status, ans.value, after=ans.after)

    # -- requests ---------------------------------------------------------------------------------
    def _handle(self, req: Request, channel: str) -> None:
        if self._late_copies:
            self._send_late_copies()
        self._last_command = time.monotonic()
        self._heartbeat_fired = False
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
        reply = Reply(self.host_address, module, ans.status, opcode, to_signed32(ans.value),
                      version=ans.version, stored=ans.stored)
        if channel == CAN:
            self._queue(CAN, (self.can_reply_id, reply.to_can()), reply=True)
        else:
            self._queue(SERIAL, reply.to_bytes(), reply=True)

    def _dispatch(self, ins: Instruction, channel: str) -> Answer:
        """Execute one request; the reply value is the request's value field unless the
        command answers with a result (the firmware fills the reply with the request first:
        TMCM-1311 §5.7.16 shows ``CALC MUL, -5000`` answered with -5000)."""
        if self.boot.active:
            return self._boot_dispatch(ins)
        ans = self._execute(ins, channel)
        if not (ans.status == Status.OK and self._answers_value(ins)):
            ans.value = ins.signed_value
        return ans

    @staticmethod
    def _answers_value(ins: Instruction) -> bool:
        op = ins.opcode
        if op >= Control.STOP_APPLICATION:
            return op in RESULT_CONTROLS
        spec = isa.by_opcode(op)
        if spec is None:
            return False
        if spec.mnemonic == "RFS":
            return ins.type == spec.type_names().get("STATUS")
        return spec.reads

    def _execute(self, ins: Instruction, channel: str) -> Answer:
        op = ins.opcode
        if op >= Control.STOP_APPLICATION:
            return self._control(ins, channel)
        spec = isa.by_opcode(op)
        if spec is None:
            return Answer(Status.INVALID_COMMAND)
        if not spec.on(self.module):
            return Answer(Status.COMMAND_NOT_AVAILABLE)
        if self.vm.download:
            if self.vm.download_addr >= self.vm.size:
                return Answer(Status.INVALID_VALUE)
            self.vm.memory[self.vm.download_addr] = ins
            self.vm.download_addr += 1
            return Answer(Status.LOADED)
        if not spec.direct:
            return Answer(Status.COMMAND_NOT_AVAILABLE)
        status, value = self.commands.execute(ins)
        return Answer(status, value)

    def _control(self, ins: Instruction, channel: str) -> Answer:
        op, vm = ins.opcode, self.vm
        if not self.module.has_control(op):
            return Answer(Status.INVALID_COMMAND)
        if vm.download and op not in (Control.START_DOWNLOAD, Control.QUIT_DOWNLOAD,
                                      Control.READ_MEMORY, Control.GET_STATUS,
                                      Control.GET_VERSION):
            return Answer(Status.COMMAND_NOT_AVAILABLE)
        value = ins.signed_value
        if op == Control.STOP_APPLICATION:
            vm.stop()
        elif op == Control.RUN_APPLICATION:
            if ins.type == RUN_FROM_CURRENT:
                vm.run()
            elif ins.type == RUN_FROM_ADDRESS:
                if not 0 <= value < vm.size:
                    return Answer(Status.INVALID_VALUE)
                vm.run(value)
            else:
                return Answer(Status.WRONG_TYPE)
        elif op == Control.STEP_APPLICATION:
            vm.step()
        elif op == Control.RESET_APPLICATION:
            vm.reset()
        elif op == Control.START_DOWNLOAD:
            if not 0 <= value < vm.size:
                return Answer(Status.INVALID_VALUE)
            vm.stop()
            vm.download, vm.download_addr = True, value
        elif op == Control.QUIT_DOWNLOAD:
            vm.download = False
        elif op == Control.READ_MEMORY:
            if not 0 <= value < vm.size:
                return Answer(Status.INVALID_VALUE)
            return Answer(stored=vm.read(value))
        elif op == Control.GET_STATUS:
            return Answer(value=int(vm.state))
        elif op == Control.GET_VERSION:
            if ins.type == VERSION_STRING:
                return Answer(version=self.version_string)
            if ins.type == VERSION_BINARY:
                return Answer(value=self._version_binary())
            return Answer(Status.WRONG_TYPE)
        elif op == ENTER_BOOTLOADER:
            # the key or nothing: anything else is ignored; no reply, the module restarts
            if (ins.type, ins.motor, ins.value & 0xFFFFFFFF) != BOOT.key:
                return Answer(silent=True)
            return Answer(silent=True, after=self._enter_bootloader)
        elif op == Control.FACTORY_DEFAULT:
            if value != FACTORY_DEFAULT_KEY:
                return Answer(Status.INVALID_VALUE)
            return Answer(silent=True, after=self._factory_reset)
        elif op == Control.TARGET_REACHED_EVENT:
            if not 0 <= value < self.module.motors:
                return Answer(Status.INVALID_VALUE)
            self._events.append((value, channel, self.address))
            return Answer(value=1 << value)
        elif op == Control.ENTER_ASCII:
            if channel != SERIAL or not self.module.ascii_mode:
                return Answer(Status.COMMAND_NOT_AVAILABLE)
            return Answer(after=self._enter_ascii)
        return Answer()

    def _enter_ascii(self) -> None:
        self._ascii = True
        self._line.clear()

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
        self._events.clear()
        self._ascii = False
        self._line.clear()
        self._rx.clear()

    def _boot_dispatch(self, ins: Instruction) -> Answer:
        if ins.opcode == Control.GET_VERSION:
            if ins.type == VERSION_STRING:
                return Answer(version=bootloader_string(self.module.firmware_id,
                                                        self.boot.VERSION))
            if ins.type == VERSION_BINARY:
                mod = self.module
                return Answer(value=encode_type1(mod.firmware_id, self.boot.VERSION,
                                                 mod.version_layout))
            return Answer(Status.WRONG_TYPE, ins.signed_value)
        got = self.boot.execute(ins)
        return Answer(got.status, got.value, silent=got.silent,
                      after=self._start_application if got.start else None)

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

    # -- VM host --------------------------------------------------------------------------------
    def clock(self) -> float:
        """Module time of the step being executed: WAIT ticks count on the same clock as
        motion, timers and the tick timer, however long one update is."""
        return self._t

    def command(self, ins: Instruction, accu: int | None) -> tuple[int, int]:
        return self.commands.execute(ins, accu)

    def condition(self, kind: int, motor: int) -> bool | None:
        if not 0 <= motor < self.module.motors:
            return True
        axis = self.axes[motor]
        if kind == WAIT["POS"]:
            return axis.reached
        if kind == WAIT["REFSW"]:
            return axis.switch("ref")
        if kind == WAIT["LIMSW"]:
            return axis.switch("left") or axis.switch("right")
        if kind == WAIT["RFS"]:
            return not axis.rfs
        return True

    # -- time ---------------------------------------------------------------------------------------
    def _busy(self) -> bool:
        return (self.vm.active or bool(self._events)
                or any(a.moving for a in self.axes))

    def _advance(self) -> None:
        now = self.now()
        dt = now - self._t
        if dt <= 0:
            return
        if not self._busy():
            self._t = now
            self._snapshot()
            return
        n = min(self.MAX_STEPS, max(1, math.ceil(dt / self.MAX_STEP)))
        h = dt / n
        limits = self._limits()
        # Steps end early at a WAIT deadline or a timer period, so that WAIT TICKS and
        # timer interrupts keep module time exactly however long the update is.
        for _ in range(n + self.MAX_DEADLINE_CUTS):
            left = now - self._t
            if left <= 1e-12:
                break
            step = min(h, left)
            due = self._next_deadline()
            if due is not None and self._t + 1e-9 < due < self._t + step:
                step = due - self._t
            limits = self._step(step, limits)
        else:
            if now > self._t:
                self._step(now - self._t, limits)

    MAX_DEADLINE_CUTS = 1000  # extra (shorter) steps per update for WAIT and timer deadlines

    def _step(self, h: float, limits: list) -> list:
        for axis, lim in zip(self.axes, limits):
            if axis.moving:
                axis.advance(h, lim, now=self._t + h)
        self._t += h
        self._interrupt_sources()
        if self.vm.active:
            self._credit = min(self._credit + h * self.INSTRUCTIONS_PER_SECOND,
                               self.MAX_CREDIT)
            # A short step (cut at a deadline) still runs what follows at once: a few
            # instructions on credit, paid back from the next steps.
            ran = self.vm.tick(max(int(self._credit), self.MIN_BURST))
            self._credit = max(self._credit - ran, -self.MAX_CREDIT)
            if ran:
                limits = self._limits()  # the program may have changed speeds
        self._check_events()
        return limits

    def _next_deadline(self) -> float | None:
        """The next module time at which a WAIT times out or a timer interrupt falls due."""
        times = []
        w = self.vm.wait
        if w is not None and w.ticks:
            times.append(w.start + w.ticks * VM_TICK)
        if self.vm.active:
            times += [due for _, due in self._timer_due.values()]
        return min(times) if times else None

    def _limits(self):
        return [self.commands.limits(m) for m in range(self.module.motors)]

    def _check_events(self) -> None:
        if not self._events:
            return
        waiting = []
        for motor, channel, module in self._events:
            if self.axes[motor].reached:
                self._send_reply(channel, module, Control.TARGET_REACHED_EVENT,
                                 Answer(Status.EVENT, 1 << motor))
            else:
                waiting.append((motor, channel, module))
        self._events = waiting

    # -- interrupt sources (TMCM-1311 §5.6) ---------------------------------------------------
    def _pin_levels(self) -> dict[int, int]:
        return {p.port: self.io.get(0, p.port) for p in self.io.ports(0, ("digital_in",))}

    @staticmethod
    def _edge(config: int, old: bool, new: bool) -> bool:
        return old != new and (config == 3 or (config == 1 and new) or (config == 2 and not new))

    def _config(self, irq: int) -> int:
        return self.store.read(GLOBAL, irq, 3, check_access=False)[1]

    def _pin_edges(self, before: dict[int, int], after: dict[int, int]) -> None:
        if not self.module.interrupts:
            return
        for port, new in after.items():
            irq = IRQ["TI_PIN0"] + port
            if port < 8 and self._edge(self._config(irq), bool(before.get(port)), bool(new)):
                self.vm.raise_interrupt(irq)

    def _snapshot(self) -> None:
        axis = self.axes[0]
        self._prev = {"reached": axis.reached, "left": axis.switch("left"),
                      "right": axis.switch("right")}

    def _interrupt_sources(self) -> None:
        if not self.module.interrupts:
            return
        vm, t = self.vm, self._t
        for name in ("TI_TIMER0", "TI_TIMER1", "TI_TIMER2"):
            irq = IRQ[name]
            period = self._config(irq) / 1000.0
            last = self._timer_due.get(irq)
            if period <= 0:
                self._timer_due.pop(irq, None)
            elif last is None or last[0] != period:
                self._timer_due[irq] = (period, t + period)  # counted from when it is set
            elif t >= last[1] - 1e-9:
                vm.raise_interrupt(irq)
                due = last[1] + period
                self._timer_due[irq] = (period, due if due > t else t + period)
        axis, prev = self.axes[0], self._prev
        if axis.reached and not prev.get("reached"):
            vm.raise_interrupt(IRQ["TI_TARGET"])
        for side, name in (("left", "TI_STOPL"), ("right", "TI_STOPR")):
            level = axis.switch(side)
            if self._edge(self._config(IRQ[name]), bool(prev.get(side)), level):
                vm.raise_interrupt(IRQ[name])
        self._snapshot()

    # -- output ---------------------------------------------------------------------------------
    def _queue(self, channel: str, payload: object, *, reply: bool) -> None:
        delay = 0.0
        copies = 1
        if reply:
            f = self.faults
            # (the faults are looked at only when one is set: this runs for every reply)
            faulty = f.rates or f.drop_next or f.dup_next or f.dup_late_next
            if faulty and f.take("drop_next", "drop"):
                return
            payload = self._apply_faults(channel, payload)
            delay = f.delay
            if channel == SERIAL and not self.boot.active:
                delay += self.store.get(GLOBAL, "TelegramPauseTime") / 1000.0
            if faulty:
                if f.rates and f.roll("delay"):
                    delay += f.rng.uniform(*RANDOM_DELAY)
                if f.take("dup_next", "dup"):
                    copies = 2
                if f.take("dup_late_next", "dup-late"):
                    self._late_copies.append((channel, payload))
        due = max(time.monotonic() + delay, self._last_due)
        self._last_due = due
        for _ in range(copies):
            self._outq.append((due, channel, payload))

    def _send_late_copies(self) -> None:
        """A request arrived: the copies held back by the "dup-late" fault go out first."""
        while self._late_copies:
            channel, payload = self._late_copies.popleft()
            due = max(time.monotonic(), self._last_due)
            self._last_due = due
            self._outq.append((due, channel, payload))

    def _apply_faults(self, channel: str, payload: object) -> object:
        f = self.faults
        if f.rates and f.roll("garbage"):
            f.garbage += bytes(f.rng.randrange(256) for _ in range(f.rng.randint(1, 8)))
        if channel == CAN:
            can_id, data = payload  # type: ignore[misc]
            data = self._mangle(data)
            if f.garbage:
                self._outq.append((self._last_due, CAN, (can_id, f.garbage[:8])))
                f.garbage = b""
            return can_id, data
        data = self._mangle(payload)  # type: ignore[arg-type]
        if f.garbage:
            data, f.garbage = f.garbage + data, b""
        return data

    def _mangle(self, data: bytes) -> bytes:
        f = self.faults
        if not (f.rates or f.corrupt_next or f.truncate_next):
            return data
        if data and f.take("corrupt_next", "corrupt"):
            buf = bytearray(data)
            i = f.rng.randrange(max(1, len(buf) - 1))
            buf[i] ^= 1 << f.rng.randrange(8)
            data = bytes(buf)
        if f.take("truncate_next", "truncate"):
            data = data[:len(data) // 2]
        return data

    def _drain(self) -> None:
        with self._out_lock:
            now = time.monotonic()
            serial = bytearray()  # what is due goes out in one piece, as a UART sends it
            while self._outq and self._outq[0][0] <= now:
                _, channel, payload = self._outq.popleft()
                if channel == SERIAL:
                    serial += payload  # type: ignore[operator]
                    continue
                if serial:
                    self._deliver(SERIAL, bytes(serial))
                    serial.clear()
                self._deliver(channel, payload)
            if serial:
                self._deliver(SERIAL, bytes(serial))

    def _deliver(self, channel: str, payload: object) -> None:
        try:
            if channel == CAN:
                can_id, data = payload  # type: ignore[misc]
                cb = self.on_can_output
                if cb is not None:
                    cb(can_id, data)
                    return
                with self._can_cond:
                    self._canbuf.append((can_id, data))
                    self._can_cond.notify_all()
                return
            cb_serial = self.on_output
            if cb_serial is not None:
                cb_serial(payload)  # type: ignore[arg-type]
                return
            with self._rx_cond:
                self._outbuf += payload  # type: ignore[operator]
                self._rx_cond.notify_all()
        except Exception:  # a broken consumer must not kill the module
            log.exception("delivering output failed")

    # -- background thread --------------------------------------------------------------------
    def _heartbeat(self) -> None:
        limit = self.store.get(GLOBAL, "SerialHeartbeat")
        if limit > 0 and not self._heartbeat_fired and \
                time.monotonic() - self._last_command > limit / 1000.0:
            log.info("serial heartbeat timeout: motors stopped")
            self._heartbeat_fired = True
            for axis in self.axes:
                axis.stop()

    def _run(self) -> None:
        while not self._closed.is_set():
            try:
                with self._lock:
                    self._advance()
                    self._check_events()
                    self._heartbeat()
                    busy = self._busy()
                self._drain()
            except Exception:
                log.exception("simulator step failed")
                busy = False
            timeout = self.TICK if busy else self.IDLE_TICK
            try:
                timeout = min(timeout, max(0.0, self._outq[0][0] - time.monotonic()))
            except IndexError:
                pass
            self._idle = not busy
            self._wake.wait(timeout)
            self._wake.clear()


def _kind(kind: str) -> str:
    k = kind.lower()
    if k in ("axis", "ap", "a"):
        return AXIS
    if k in ("global", "gp", "g"):
        return GLOBAL
    raise ValueError(f"parameter kind must be 'axis' or 'global', got {kind!r}")


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
