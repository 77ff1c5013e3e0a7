"""Program memory and the TMCL interpreter of a simulated module.

The VM owns only what a stored program owns: program memory, program counter, accumulator,
X register, flags, the subroutine stack and the interrupt machinery. Every instruction that
touches the module (motion, parameters, I/O, coordinates) goes back to the host, the same
code path a direct-mode command takes, so a program and a host see one module.

Flags: COMP sets them from ``accu <=> value``; every instruction that loads the accumulator
(GAP/GGP/GIO/GCO, CALC, CALCX) sets them from ``accu <=> 0``. So ``JC ZE/NZ`` after a
``GIO`` tests the value read, as the TMCM-1311 timer-interrupt example (§5.6.5) relies on,
and after a ``COMP`` ZE/EQ and NZ/NE agree.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Protocol

from ..tmcl import instructions as isa
from ..tmcl.frames import AppState, Instruction, Status, to_signed32

log = logging.getLogger(__name__)

STACK_DEPTH = 8  # CSUB nesting (TMCM-1311 §5.7.20, §11.5)
TICK = 0.010  # seconds per WAIT tick


def _op(mnemonic: str) -> int:
    spec = isa.by_mnemonic(mnemonic)
    assert spec is not None, mnemonic
    return spec.opcode


def _types(mnemonic: str) -> dict[str, int]:
    spec = isa.by_mnemonic(mnemonic)
    assert spec is not None, mnemonic
    return spec.type_names()


OP = {name: _op(name) for name in (
    "GAP", "GGP", "GIO", "GCO", "RFS", "SAP", "SGP", "SCO", "SIO", "CALC", "COMP", "JC", "JA",
    "CSUB", "RSUB", "EI", "DI", "WAIT", "STOP", "CALCX", "AAP", "AGP", "CLE", "VECT", "RETI",
    "ACO")}
CALC = _types("CALC")
CALCX = _types("CALCX")
JC = _types("JC")
WAIT = _types("WAIT")
CLE = _types("CLE")
RFS = _types("RFS")
GLOBAL_IRQ = isa.interrupts()["TI_GLOBAL"]


class Host(Protocol):
    def command(self, ins: Instruction, accu: int | None) -> tuple[int, int]: ...
    def clock(self) -> float: ...  # module time of the step being executed
    def condition(self, kind: int, motor: int) -> bool | None: ...


@dataclass
class Wait:
    kind: int
    motor: int
    start: float
    ticks: int


@dataclass
class Context:
    """What an interrupt saves and RETI restores (accumulator, X register, flags)."""

    pc: int
    accu: int
    x: int
    cmp: int
    eto: bool
    wait: Wait | None


def _int32(value: int) -> int:
    return to_signed32(value)


def _div(a: int, b: int) -> int:
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b >= 0) else -q


def _arith(op: int, a: int, b: int, table: dict[str, int]) -> int | None:
    """One CALC/CALCX operation; None for division by zero (accumulator left unchanged)."""
    if op == table["ADD"]:
        return _int32(a + b)
    if op == table["SUB"]:
        return _int32(a - b)
    if op == table["MUL"]:
        return _int32(a * b)
    if op in (table["DIV"], table["MOD"]):
        if b == 0:
            return None
        q = _div(a, b)
        return _int32(q if op == table["DIV"] else a - q * b)
    if op == table["AND"]:
        return _int32(a & b)
    if op == table["OR"]:
        return _int32(a | b)
    if op == table["XOR"]:
        return _int32(a ^ b)
    return None


@dataclass
class Vm:
    size: int
    host: Host
    interrupts_supported: bool = False
    memory: list[Instruction | None] = field(init=False)
    state: AppState = AppState.STOP
    pc: int = 0
    accu: int = 0
    x: int = 0
    cmp: int = 0  # sign of the last comparison
    eto: bool = False
    edv: bool = False
    stack: list[int] = field(default_factory=list)
    wait: Wait | None = None
    download: bool = False
    download_addr: int = 0
    vectors: dict[int, int] = field(default_factory=dict)
    enabled: set[int] = field(default_factory=set)
    global_enabled: bool = False
    pending: set[int] = field(default_factory=set)
    isr: Context | None = None

    def __post_init__(self) -> None:
        self.memory = [None] * self.size

    # -- host-facing controls (128-135) ----------------------------------------------------
    @property
    def active(self) -> bool:
        return self.state == AppState.RUN or self.wait is not None

    def reset(self) -> None:
        self.state = AppState.RESET
        self.pc = 0
        self._clear()

    def power_up(self) -> None:
        self.reset()
        self.state = AppState.STOP
        self.download = False

    def _clear(self) -> None:
        self.accu = self.x = self.cmp = 0
        self.eto = self.edv = False
        self.stack.clear()
        self.wait = None
        self.vectors.clear()
        self.enabled.clear()
        self.global_enabled = False
        self.pending.clear()
        self.isr = None

    def erase(self) -> None:
        """Wipe program memory (GP 81 code protection switched off); the program stops."""
        self.memory = [None] * self.size
        self.reset()
        self.state = AppState.STOP

    def stop(self) -> None:
        self.state = AppState.STOP
        self.wait = None

    def run(self, address: int | None = None) -> None:
        if address is not None:
            self.pc = address
            self.stack.clear()
            self.isr = None
            self.pending.clear()
            self.wait = None
        self.state = AppState.RUN

    def step(self) -> None:
        """Execute one instruction; a WAIT that is not yet met completes in later ticks."""
        if self.wait is not None:
            return
        self.state = AppState.STEP
        self._execute_one()

    def read(self, address: int) -> Instruction:
        return self.memory[address] or Instruction(0)

    # -- interrupts ---------------------------------------------------------------------------
    def raise_interrupt(self, number: int) -> None:
        if self.interrupts_supported and self.state == AppState.RUN and number in self.enabled:
            self.pending.add(number)

    def _service_interrupt(self) -> bool:
        if not (self.global_enabled and self.isr is None and self.pending):
            return False
        for number in sorted(self.pending):  # lower number = higher priority (§10.4)
            self.pending.discard(number)
            vector = self.vectors.get(number)
            if vector is None or number not in self.enabled:
                continue
            self.isr = Context(self.pc, self.accu, self.x, self.cmp, self.eto, self.wait)
            self.wait = None
            self.pc = vector
            return True
        return False

    # -- running ------------------------------------------------------------------------------
    def tick(self, budget: int) -> int:
        """Run up to ``budget`` instructions (RUN state) and complete a pending WAIT."""
        done = 0
        if self.state == AppState.RUN:
            self._service_interrupt()
        if self.wait is not None and not self._poll_wait():
            return 0
        while self.state == AppState.RUN and done < budget:
            self._service_interrupt()
            self._execute_one()
            done += 1
            if self.wait is not None:
                break
        return done

    def _poll_wait(self) -> bool:
        w = self.wait
        assert w is not None
        now = self.host.clock()
        if w.kind == WAIT["TICKS"]:
            met = now >= w.start + w.ticks * TICK - 1e-9
        elif w.kind not in WAIT.values():
            met = True  # unknown condition: nothing to wait for
        else:
            met = bool(self.host.condition(w.kind, w.motor))
            if not met and w.ticks and now >= w.start + w.ticks * TICK - 1e-9:
                self.eto = True
                met = True
        if met:
            self.wait = None
            self.pc += 1
        return met

    def _execute_one(self) -> None:
        if not 0 <= self.pc < self.size:
            log.info("program counter %d left program memory: program stopped", self.pc)
            self.state = AppState.STOP
            return
        ins = self.memory[self.pc]
        if ins is None or ins.opcode == 0:
            self.state = AppState.STOP  # unwritten memory reads as opcode 0: end of program
            return
        self._exec(ins)

    def _jump(self, address: int) -> None:
        if 0 <= address < self.size:
            self.pc = address
        else:
            log.info("jump to %d outside program memory: program stopped", address)
            self.state = AppState.STOP

    def _load(self, value: int) -> None:
        self.accu = _int32(value)
        self.cmp = (self.accu > 0) - (self.accu < 0)

    def _exec(self, ins: Instruction) -> None:
        op, value = ins.opcode, ins.signed_value
        nxt = self.pc + 1
        if op == OP["JA"]:
            return self._jump(value)
        if op == OP["JC"]:
            if self._condition(ins.type):
                return self._jump(value)
            self.pc = nxt
            return None
        if op == OP["CSUB"]:
            if len(self.stack) >= STACK_DEPTH:
                log.info("CSUB at %d ignored: subroutine stack full", self.pc)
                self.pc = nxt
                return None
            self.stack.append(nxt)
            return self._jump(value)
        if op == OP["RSUB"]:
            self.pc = self.stack.pop() if self.stack else nxt
            return None
        if op == OP["STOP"]:
            self.state = AppState.STOP
            return None
        if op == OP["WAIT"]:
            self.wait = Wait(ins.type, ins.motor, self.host.clock(), max(value, 0))
            self._poll_wait()
            return None
        if op == OP["RETI"]:
            if self.isr is not None:
                ctx, self.isr = self.isr, None
                self.pc, self.accu, self.x, self.cmp, self.eto = (ctx.pc, ctx.accu, ctx.x, ctx.cmp,
                                                                  ctx.eto)
                self.wait = ctx.wait  # an interrupted WAIT resumes with its own deadline
                if self.wait is not None:
                    self._poll_wait()  # (it may have run out while the routine ran)
            else:
                self.pc = nxt
            return None
        self.pc = nxt
        if op == OP["CALC"]:
            if ins.type == CALC["LOAD"]:
                self._load(value)
            elif ins.type == CALC["NOT"]:
                self._load(~self.accu)
            else:
                result = _arith(ins.type, self.accu, value, CALC)
                if result is not None:
                    self._load(result)
        elif op == OP["CALCX"]:
            if ins.type == CALCX["LOAD"]:
                self.x = self.accu
            elif ins.type == CALCX["SWAP"]:
                self.accu, self.x = self.x, self.accu
                self._load(self.accu)
            elif ins.type == CALCX["NOT"]:
                self.x = _int32(~self.x)  # the manual's table: "logical invert X-register"
            else:
                result = _arith(ins.type, self.accu, self.x, CALCX)
                if result is not None:
                    self._load(result)
        elif op == OP["COMP"]:
            self.cmp = (self.accu > value) - (self.accu < value)
        elif op == OP["CLE"]:
            if ins.type in (CLE["ALL"], CLE["ETO"]):
                self.eto = False
            if ins.type in (CLE["ALL"], CLE["EDV"]):
                self.edv = False
        elif op == OP["VECT"]:
            self.vectors[ins.type] = value
        elif op in (OP["EI"], OP["DI"]):
            on = op == OP["EI"]
            if ins.type == GLOBAL_IRQ:
                self.global_enabled = on
            elif on:
                self.enabled.add(ins.type)
            else:
                self.enabled.discard(ins.type)
                self.pending.discard(ins.type)
        elif op == OP["AAP"]:
            self.host.command(Instruction(OP["SAP"], ins.type, ins.motor, self.accu & 0xFFFFFFFF),
                              self.accu)
        elif op == OP["AGP"]:
            self.host.command(Instruction(OP["SGP"], ins.type, ins.motor, self.accu & 0xFFFFFFFF),
                              self.accu)
        elif op == OP["ACO"]:
            self.host.command(Instruction(OP["SCO"], ins.type, ins.motor, self.accu & 0xFFFFFFFF),
                              self.accu)
        elif op >= 128:
            log.info("control command %d at %d ignored inside a program", op, self.pc - 1)
        else:
            status, result = self.host.command(ins, self.accu)
            reads = op in (OP["GAP"], OP["GGP"], OP["GIO"], OP["GCO"]) or (
                op == OP["RFS"] and ins.type == RFS["STATUS"])
            if reads and status == Status.OK:
                self._load(to_signed32(result))
        return None

    def _condition(self, cond: int) -> bool:
        c = self.cmp
        table = {JC["ZE"]: c == 0, JC["NZ"]: c != 0, JC["EQ"]: c == 0, JC["NE"]: c != 0,
                 JC["GT"]: c > 0, JC["GE"]: c >= 0, JC["LT"]: c < 0, JC["LE"]: c <= 0,
                 JC["ETO"]: self.eto}
        return table.get(cond, False)  # EAL (external alarm, TMCM-1640) never set here
