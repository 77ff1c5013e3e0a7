"""What one request does to the simulated module, and what it answers: the instruction set's
commands (``commands.py``), the program and module controls (128-139, 242, 254, 255) and,
while it runs, the bootloader's commands (``boot.py``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..tmcl import instructions as isa
from ..tmcl.bootloader import bootloader_string
from ..tmcl.bootloader import facts as boot_facts
from ..tmcl.frames import FACTORY_DEFAULT_KEY, Control, Instruction, Status
from ..tmcl.version import encode_type1
from .output import SERIAL

if TYPE_CHECKING:
    from .device import Simulator

RUN_FROM_CURRENT, RUN_FROM_ADDRESS = 0, 1  # command 129 types
VERSION_STRING, VERSION_BINARY = 0, 1  # command 136 types
ENTER_BOOTLOADER = isa.boot_command("enter")  # 242
BOOT = boot_facts()
# Control commands whose reply value is a result; the others echo the request's value field.
RESULT_CONTROLS = frozenset({Control.READ_MEMORY, Control.GET_STATUS, Control.GET_VERSION,
                             Control.TARGET_REACHED_EVENT})


@dataclass
class Answer:
    status: int = Status.OK
    value: int = 0
    version: str | None = None
    stored: Instruction | None = None
    silent: bool = False  # 137: no reply at all
    after: Callable[[], None] | None = None  # runs once the reply is queued


class Requests:
    """The request side of one simulated module, on its host's state (which an update can
    replace whole: the host's parameters, program and motors are looked up every time)."""

    def __init__(self, host: Simulator) -> None:
        self._host = host

    def dispatch(self, ins: Instruction, channel: str) -> Answer:
        """Execute one request; the reply value is the request's value field unless the
        command answers with a result (the firmware fills the reply with the request first:
        TMCM-1311 §5.7.16 shows ``CALC MUL, -5000`` answered with -5000)."""
        if self._host.boot.active:
            return self._boot(ins)
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
        host = self._host
        op = ins.opcode
        if op >= Control.STOP_APPLICATION:
            return self._control(ins, channel)
        spec = isa.by_opcode(op)
        if spec is None:
            return Answer(Status.INVALID_COMMAND)
        if not spec.on(host.module):
            return Answer(Status.COMMAND_NOT_AVAILABLE)
        vm = host.vm
        if vm.download:
            if vm.download_addr >= vm.size:
                return Answer(Status.INVALID_VALUE)
            vm.memory[vm.download_addr] = ins
            vm.download_addr += 1
            return Answer(Status.LOADED)
        if not spec.direct:
            return Answer(Status.COMMAND_NOT_AVAILABLE)
        status, value = host.commands.execute(ins)
        return Answer(status, value)

    def _control(self, ins: Instruction, channel: str) -> Answer:
        host = self._host
        op, vm = ins.opcode, host.vm
        if not host.module.has_control(op):
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
                return Answer(version=host.version_string)
            if ins.type == VERSION_BINARY:
                return Answer(value=host._version_binary())
            return Answer(Status.WRONG_TYPE)
        elif op == ENTER_BOOTLOADER:
            # the key or nothing: anything else is ignored; no reply, the module restarts
            if (ins.type, ins.motor, ins.value & 0xFFFFFFFF) != BOOT.key:
                return Answer(silent=True)
            return Answer(silent=True, after=host._enter_bootloader)
        elif op == Control.FACTORY_DEFAULT:
            if value != FACTORY_DEFAULT_KEY:
                return Answer(Status.INVALID_VALUE)
            return Answer(silent=True, after=host._factory_reset)
        elif op == Control.TARGET_REACHED_EVENT:
            if not 0 <= value < host.module.motors:
                return Answer(Status.INVALID_VALUE)
            host.runtime.events.append((value, channel, host.address))
            return Answer(value=1 << value)
        elif op == Control.ENTER_ASCII:
            if channel != SERIAL or not host.module.ascii_mode:
                return Answer(Status.COMMAND_NOT_AVAILABLE)
            return Answer(after=host.front.enter_ascii)
        return Answer()

    def _boot(self, ins: Instruction) -> Answer:
        host = self._host
        if ins.opcode == Control.GET_VERSION:
            if ins.type == VERSION_STRING:
                return Answer(version=bootloader_string(host.module.firmware_id,
                                                        host.boot.VERSION))
            if ins.type == VERSION_BINARY:
                mod = host.module
                return Answer(value=encode_type1(mod.firmware_id, host.boot.VERSION,
                                                 mod.version_layout))
            return Answer(Status.WRONG_TYPE, ins.signed_value)
        got = host.boot.execute(ins)
        return Answer(got.status, got.value, silent=got.silent,
                      after=host._start_application if got.start else None)
