"""Stored programs on the simulator: download, read-back, run/step/stop/reset, the VM's
semantics, interrupts, and the manuals' example programs with their documented effect."""

from __future__ import annotations

import time

import pytest

from tmclsh.tmcl.asm import assemble
from tmclsh.tmcl.frames import Reply, ReplyKind, Request, Status
from tmclsh.sim import Simulator
from conftest import patience
from manuals import listing
from steppedsim import SteppedSimulator


class Host:
    def __init__(self, sim: Simulator):
        self.sim = sim
        self._buf = b""

    def raw(self, op, type_=0, motor=0, value=0, kind=ReplyKind.NORMAL) -> Reply:
        self.sim.write(Request(1, op, type_, motor, value).to_bytes())
        deadline = time.monotonic() + 1
        while len(self._buf) < 9 and time.monotonic() < deadline:
            self._buf += self.sim.read(deadline - time.monotonic())
        data, self._buf = self._buf[:9], self._buf[9:]
        return Reply.from_bytes(data, kind, module=1, opcode=op)

    def ok(self, *args) -> int:
        reply = self.raw(*args)
        assert reply.status == Status.OK, reply
        return reply.value

    def var(self, n: int) -> int:
        return self.ok(10, n, 2)

    def upload(self, source: str, start: int = 0) -> int:
        program = assemble(source, self.sim.module, origin=start)
        assert self.raw(132, 0, 0, start).ok
        for ins in program.instructions:
            assert self.raw(ins.opcode, ins.type, ins.motor, ins.value).status == Status.LOADED
        assert self.raw(133).ok
        return len(program)

    def run(self, source: str) -> None:
        self.upload(source)
        self.ok(129, 1, 0, 0)

    def wait(self, pred, timeout=3.0) -> None:
        deadline = time.monotonic() + timeout
        while not pred():
            assert time.monotonic() < deadline, "condition not met in time"
            time.sleep(0.005)


@pytest.fixture
def host():
    sim = Simulator("TMCM-1311", speed=10)
    yield Host(sim)
    sim.close()


def stopped(h: Host):
    return lambda: h.ok(135) == 0


# -- download, read-back, control commands ----------------------------------------------------------

def test_download_and_read_back(host):
    src = "SAP 4, 0, 1000\nLoop: MVP ABS, 0, -5\nWAIT POS, 0, 0\nJA Loop\n"
    program = assemble(src, host.sim.module)
    assert host.raw(132, 0, 0, 0).ok
    assert host.sim.param("global", 129) == 1
    for ins in program.instructions:
        reply = host.raw(ins.opcode, ins.type, ins.motor, ins.value)
        assert (reply.status, reply.opcode) == (Status.LOADED, ins.opcode)
    assert host.raw(133).ok
    assert host.ok(10, 129) == 0
    for address, ins in enumerate(program.instructions):
        assert host.raw(134, 0, 0, address, kind=ReplyKind.MEMORY).stored == ins
    assert host.raw(134, 0, 0, len(program), kind=ReplyKind.MEMORY).stored.opcode == 0
    assert host.ok(6, 4) != 1000  # stored, not executed


def test_download_refuses_what_the_module_lacks(host):
    assert host.raw(132, 0, 0, 2047).ok
    assert host.raw(29, 0, 0, 0).status == Status.COMMAND_NOT_AVAILABLE  # SAC
    assert host.raw(3, 0, 0, 0).status == Status.LOADED  # fills the last cell
    assert host.raw(3, 0, 0, 0).status == Status.INVALID_VALUE  # memory full
    for op in (128, 129, 130, 131, 137, 138, 139):
        assert host.raw(op).status == Status.COMMAND_NOT_AVAILABLE
    assert host.raw(133).ok
    assert host.raw(132, 0, 0, 2048).status == Status.INVALID_VALUE


def test_run_step_stop_reset_and_status_parameters():
    # module time moved by the test: "not yet" stays not yet however late the next request
    host = Host(SteppedSimulator("TMCM-1311"))
    host.upload("CALC LOAD, 1\nCALC ADD, 2\nAGP 0, 2\nWAIT TICKS, 0, 20\nJA 0\n")
    assert host.ok(135) == 0
    host.ok(130)  # step
    assert (host.ok(135), host.ok(10, 128), host.ok(10, 130)) == (2, 2, 1)
    host.ok(130)
    host.ok(130)
    assert host.var(0) == 3 and host.ok(10, 130) == 3
    host.ok(130)  # WAIT TICKS 20: completes 200 ms later (module time)
    host.sim.step(0.15)
    assert host.ok(10, 130) == 3
    host.sim.step(0.1)
    assert host.ok(10, 130) == 4
    assert host.ok(135) == 2
    host.ok(129, 0, 0, 0)  # run from the current address
    assert host.ok(135) == 1
    host.ok(128)
    assert host.ok(135) == 0
    host.ok(131)
    assert (host.ok(135), host.ok(10, 130)) == (3, 0)
    assert host.raw(129, 2).status == Status.WRONG_TYPE
    assert host.raw(129, 1, 0, 4096).status == Status.INVALID_VALUE
    host.sim.close()


def test_stop_instruction_and_end_of_program(host):
    host.run("SGP 0, 2, 1\nSTOP\nSGP 0, 2, 2\n")
    host.wait(stopped(host))
    assert host.var(0) == 1 and host.ok(10, 130) == 1
    host.run("SGP 1, 2, 5\n")  # runs into unwritten memory (opcode 0)
    host.wait(stopped(host))
    assert host.var(1) == 5


def test_direct_mode_never_touches_the_accumulator(host):
    host.run("CALC LOAD, 5\nLoop: AGP 0, 2\nCOMP 5\nJC NE, Bad\nJA Loop\nBad: SGP 1, 2, 1\nSTOP\n")
    for _ in range(200):
        host.ok(6, 1)
        host.ok(10, 3, 2)
        host.ok(15, 0, 1)
        host.ok(31, 1, 0)
    assert host.var(0) == 5 and host.var(1) == 0 and host.ok(135) == 1


def test_autostart(host):
    host.upload("SGP 0, 2, 7\nSTOP\n")
    host.ok(9, 77, 0, 1)
    host.sim.reset()
    host.wait(lambda: host.var(0) == 7)
    with Simulator("TMCM-1311", autostart=False) as quiet:
        assert quiet.program_state == 0


# -- VM semantics -------------------------------------------------------------------------------------

def test_calc_and_calcx(host):
    host.run("""
        CALC LOAD, 17
        CALC MUL, -3      // -51
        CALC DIV, 4       // -12 (truncated toward zero)
        AGP 0, 2
        CALC LOAD, -7
        CALC MOD, 3       // -1 (sign of the dividend)
        AGP 1, 2
        CALC LOAD, 12
        CALC AND, 10      // 8
        CALC OR, 3        // 11
        CALC XOR, 1       // 10
        AGP 2, 2
        CALC NOT, 0
        AGP 3, 2          // ~10 = -11
        CALC LOAD, 2147483647
        CALC ADD, 1       // wraps to -2^31
        AGP 4, 2
        CALC LOAD, 9
        CALC DIV, 0       // division by zero leaves the accumulator
        AGP 5, 2
        CALC LOAD, 6
        CALCX LOAD        // X = 6
        CALC LOAD, 7
        CALCX MUL         // 42
        AGP 6, 2
        CALCX SWAP        // accu 6, X 42
        AGP 7, 2
        CALCX SUB         // 6 - 42
        AGP 8, 2
        STOP
    """)
    host.wait(stopped(host))
    assert [host.var(n) for n in range(9)] == [-12, -1, 10, -11, -2**31, 9, 42, 6, -36]


def test_comp_and_every_jc_condition(host):
    conditions = ["ZE", "NZ", "EQ", "NE", "GT", "GE", "LT", "LE"]
    lines = []
    for i, cond in enumerate(conditions):
        lines += ["CALC LOAD, 5", "COMP 7", f"JC {cond}, T{i}", f"SGP {i}, 2, 0",
                  f"JA N{i}", f"T{i}: SGP {i}, 2, 1", f"N{i}:"]
        lines += ["CALC LOAD, 7", "COMP 7", f"JC {cond}, U{i}", f"SGP {i + 10}, 2, 0",
                  f"JA M{i}", f"U{i}: SGP {i + 10}, 2, 1", f"M{i}:"]
    lines += ["GIO 0, 2", "JC ZE, Z", "STOP", "Z: SGP 30, 2, 1", "STOP"]
    host.run("\n".join(lines))
    host.wait(stopped(host))
    less = [host.var(i) for i in range(8)]
    equal = [host.var(i + 10) for i in range(8)]
    #             ZE NZ EQ NE GT GE LT LE
    assert less == [0, 1, 0, 1, 0, 0, 1, 1]
    assert equal == [1, 0, 1, 0, 0, 1, 0, 1]
    assert host.var(30) == 1  # a read sets the flags from the value read


def test_subroutines_nest_eight_levels(host):
    host.run("""
        CALC LOAD, 0
        CSUB Rec
        AGP 1, 2
        STOP
    Rec: CALC ADD, 1
        AGP 0, 2
        COMP 20
        JC GE, Done
        CSUB Rec          // ignored once the stack holds 8 return addresses
    Done: RSUB
    """)
    host.wait(stopped(host))
    # 8 return addresses fit: Rec was entered 8 times, the 9th CSUB was skipped (manual:
    # "ignored if there is no more stack space left"), and all 8 returns came back to main
    assert host.var(0) == 8 and host.var(1) == 8 and host.ok(135) == 0


def test_wait_timeout_sets_eto(host):
    host.run("""
        ROR 0, 1000
        WAIT POS, 0, 10     // never reached: times out after 100 ms
        JC ETO, Timeout
        SGP 0, 2, 1
        STOP
    Timeout: SGP 0, 2, 2
        CLE ETO
        JC ETO, Still
        SGP 1, 2, 3
        WAIT TICKS, 0, 5
        MST 0
        STOP
    Still: SGP 1, 2, 4
        STOP
    """)
    host.wait(stopped(host))
    assert (host.var(0), host.var(1)) == (2, 3)


def test_wait_conditions(host):
    sim = host.sim
    host.run("""
        WAIT REFSW, 0, 0
        SGP 0, 2, 1
        WAIT LIMSW, 0, 0
        SGP 0, 2, 2
        RFS START, 0
        WAIT RFS, 0, 0
        SGP 0, 2, 3
        MVP ABS, 0, 300
        WAIT POS, 0, 0
        GAP 1, 0
        AGP 1, 2
        STOP
    """)
    time.sleep(0.05)
    assert host.var(0) == 0
    sim.set_switch(0, "ref", True)
    host.wait(lambda: host.var(0) == 1)
    sim.set_switch(0, "ref", None)
    sim.set_switch(0, "right", True)
    host.wait(lambda: host.var(0) == 2)
    sim.set_switch(0, "right", None)
    sim.set_switch_position(0, "ref", -200)
    host.wait(stopped(host))
    assert host.var(0) == 3 and host.var(1) == 300


def test_sio_minus_one_copies_the_accumulator(host):
    host.run("CALC LOAD, 0x1A5\nSIO 255, 2, -1\nSTOP\n")
    host.wait(stopped(host))
    assert host.ok(15, 255, 2) == 0xA5  # the low 8 bits


def test_aap_and_aco(host):
    host.run("CALC LOAD, 4321\nAAP 4, 0\nACO 3, 0\nGCO 3, 0\nCALC ADD, 1\nAGP 0, 2\nSTOP\n")
    host.wait(stopped(host))
    assert host.ok(6, 4) == 4321 and host.ok(31, 3, 0) == 4321 and host.var(0) == 4322


# -- interrupts (TMCM-1311 §5.6) ---------------------------------------------------------------------

TIMER_EXAMPLE = listing("tmcm1311-timer-interrupt")


def edges(samples: list[tuple[float, int]]) -> list[float]:
    return [t for (t, v), (_, w) in zip(samples, samples[1:]) if v != w]


def test_manual_timer_interrupt_toggles_out0():
    # module time moved by the test: a sample every 20 ms of it, however busy the machine
    with SteppedSimulator("TMCM-1311") as sim:
        h = Host(sim)
        h.run(TIMER_EXAMPLE)
        # each request brings the module up to date
        samples = sim.run_for(7.0, 0.02, lambda t: (h.ok(15, 0, 2), h.ok(15, 3, 2)))
        out0 = [(t, v[0]) for t, v in samples]
        out3 = [(t, v[1]) for t, v in samples]
        e0, e3 = edges(out0), edges(out3)
        assert len(e0) >= 4
        period = (e0[-1] - e0[0]) / (len(e0) - 1)
        assert 0.8 <= period <= 1.2, e0  # the timer toggles OUT_0 once a second
        assert len(e3) >= 8  # the main loop keeps toggling OUT_3 every 0.5 s
        period3 = (e3[-1] - e3[0]) / (len(e3) - 1)
        assert 0.4 <= period3 <= 0.6, e3


def test_input_interrupt_with_edge_and_context_restore(host):
    sim = host.sim
    host.run("""
        VECT 39, Pin0
        SGP 39, 3, 1        // low -> high only
        EI 39
        EI 255
        SGP 20, 2, 1        // ready
        CALC LOAD, 7
    Loop: COMP 7
        JC NE, Bad
        JA Loop
    Bad: SGP 9, 2, 1
        STOP
    Pin0: GGP 0, 2
        CALC ADD, 1
        AGP 0, 2
        RETI
    """)
    host.wait(lambda: host.var(20) == 1)
    sim.set_input(0, 0, 1)
    host.wait(lambda: host.var(0) == 1)
    sim.set_input(0, 0, 0)  # high -> low: not configured
    time.sleep(0.03)
    sim.set_input(0, 0, 1)
    host.wait(lambda: host.var(0) == 2)
    sim.set_input(1, 0, 0)  # analog view of the same pin goes low, then high
    sim.set_input(1, 0, 4095)
    host.wait(lambda: host.var(0) == 3)
    time.sleep(0.03)
    assert host.var(9) == 0 and host.ok(135) == 1  # accumulator and flags restored


def test_no_interrupt_nesting(host):
    sim = host.sim
    host.run("""
        VECT 39, Pin0
        VECT 40, Pin1
        SGP 39, 3, 3
        SGP 40, 3, 3
        EI 39
        EI 40
        EI 255
        SGP 20, 2, 1      // ready
    Loop: JA Loop
    Pin0: SGP 0, 2, 1
        WAIT TICKS, 0, 50
        GGP 1, 2
        AGP 2, 2          // copy of var 1 while Pin0 runs
        SGP 3, 2, 1
        RETI
    Pin1: SGP 1, 2, 1
        RETI
    """)
    host.wait(lambda: host.var(20) == 1)
    sim.set_input(0, 0, 1)
    host.wait(lambda: host.var(0) == 1)  # Pin0 is running (waiting 0.5 s module time)
    sim.set_input(0, 1, 1)
    host.wait(lambda: host.var(1) == 1)
    assert host.var(3) == 1 and host.var(2) == 0  # Pin1 waited for Pin0's RETI


def test_target_reached_and_stop_switch_interrupts(host):
    sim = host.sim
    host.run("""
        VECT 3, Reached
        VECT 27, Left
        SGP 27, 3, 1
        EI 3
        EI 27
        EI 255
        MVP ABS, 0, 2000
    Loop: JA Loop
    Reached: SGP 0, 2, 1
        RETI
    Left: SGP 1, 2, 1
        RETI
    """)
    host.wait(lambda: host.var(0) == 1)
    sim.set_switch(0, "left", True)
    host.wait(lambda: host.var(1) == 1)


def test_disabled_interrupt_does_not_fire(host):
    sim = host.sim
    host.run("VECT 39, Pin0\nSGP 39, 3, 3\nEI 39\nEI 255\nDI 39\nSGP 20, 2, 1\nLoop: JA Loop\n"
             "Pin0: SGP 0, 2, 1\nRETI\n")
    host.wait(lambda: host.var(20) == 1)
    sim.set_input(0, 0, 1)
    time.sleep(0.05)
    assert host.var(0) == 0


# -- the manuals' example programs ----------------------------------------------------------------------

SIMPLE_PROGRAM = """
        ROL 0, 50000                //Rotate motor 0 with speed 50000
        WAIT TICKS, 0, 500
        MST 0
        ROR 0, 50000                 //Rotate motor 0 with 50000
        WAIT TICKS, 0, 500
        MST 0
        SAP 4, 0, 50000               //Set max. Velocity
        SAP 5, 0, 50000                //Set max. Acceleration
Loop:   MVP ABS, 0, 100000           //Move to Position 10000
        WAIT POS, 0, 0              //Wait until position reached
        MVP ABS, 0, -100000          //Move to Position -10000
        WAIT POS, 0, 0              //Wait until position reached
        JA Loop                     //Infinite Loop
"""


def sweep(h: Host, seconds: float) -> tuple[list[int], list[int], list[int]]:
    """Target positions, positions and speeds sampled for ``seconds`` of real time."""
    targets, positions, speeds = [], [], []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        targets.append(h.ok(6, 0))
        positions.append(h.ok(6, 1))
        speeds.append(h.ok(6, 3))
        time.sleep(0.001)
    return targets, positions, speeds


def changes(values: list[int]) -> list[int]:
    """The distinct successive values: [5, 5, 0, 0, 5] -> [5, 0, 5]."""
    return [v for i, v in enumerate(values) if i == 0 or values[i - 1] != v]


def test_manual_simple_program_moves_between_two_positions():
    """§3.3.2: rotate left, rotate right, then run between ±100000 forever.

    A new target is only set after WAIT POS saw the old one reached, so the alternating
    target positions prove each move arrived."""
    with SteppedSimulator("TMCM-1311") as sim:  # module time moved by the test
        h = Host(sim)
        h.run(SIMPLE_PROGRAM)
        h.wait(lambda: sim.step(0.05) or h.ok(6, 3) < -40000, patience(30))  # ROL 0, 50000
        h.wait(lambda: sim.step(0.05) or h.ok(6, 3) > 40000, patience(30))  # ROR 0, 50000
        # the first move of the loop arrived
        h.wait(lambda: sim.step(0.05) or h.ok(6, 0) == -100000, patience(30))
        rows = sim.run_for(40.0, 0.05, lambda t: (h.ok(6, 0), h.ok(6, 1), h.ok(6, 3)))
        targets, positions, speeds = ([r[i] for _, r in rows] for i in range(3))
        seq = changes(targets)
        assert len(seq) >= 3 and set(seq) == {100000, -100000}
        assert max(positions) <= 100000 and min(positions) >= -100000
        assert max(abs(v) for v in speeds) <= 50000


MAIN_LOOP = """
//Initialization
SAP 4, 0, 500  //define max. positioning speed
SAP 5, 0, 100  //define max. acceleration
MainLoop:
 //do something, in this example just running between two positions
 MVP ABS, 0, 5000
 WAIT POS, 0, 0
 MVP ABS, 0, 0
 WAIT POS, 0, 0
 JA MainLoop  //end of the main loop => run infinitely
"""


def test_manual_main_loop_example():
    """§11.2: positioning speed 500, acceleration 100, between 0 and 5000."""
    with Simulator("TMCM-1311", speed=100) as sim:
        h = Host(sim)
        h.run(MAIN_LOOP)
        targets, positions, speeds = sweep(h, 0.7)  # 70 s of module time, a move takes 15 s
        seq = changes(targets)
        assert seq[:4] == [5000, 0, 5000, 0]
        assert max(positions) <= 5000 and min(positions) >= 0
        assert max(speeds) == 500 and min(speeds) == -500


def test_manual_inputs_to_outputs_loop(host):
    """§5.7.14: GIO 255, 0 / SIO 255, 2, -1 mirrors the inputs on the outputs."""
    host.run("Loop: GIO 255, 0\nSIO 255, 2,-1\n JA Loop\n")
    host.sim.set_input(0, 2, 1)
    host.sim.set_input(0, 5, 1)
    host.wait(lambda: host.ok(15, 255, 2) == 0b100100)
    host.sim.set_input(0, 2, 0)
    host.wait(lambda: host.ok(15, 255, 2) == 0b100000)


def test_manual_run_with_address_calls_routines():
    """§11.6: a host starts routine 1 with 'run command with address 1'."""
    src = """
Func1: JA Func1Start
Func2: JA Func2Start
Func3: JA Func3Start
Func1Start: MVP ABS, 0, 1000
  WAIT POS, 0, 0
  MVP ABS, 0, 0
  WAIT POS, 0, 0
  STOP
Func2Start: ROL 0, 500
  WAIT TICKS, 0, 100
  MST 0
  STOP
Func3Start:
ROR 0, 1000
  WAIT TICKS, 0, 700
  MST 0
  STOP
"""
    with Simulator("TMCM-1311", speed=20) as sim:
        h = Host(sim)
        h.upload(src)
        h.ok(129, 1, 0, 1)
        h.wait(lambda: h.ok(6, 3) < 0)
        h.wait(lambda: h.ok(135) == 0 and h.ok(6, 3) == 0)
        assert h.ok(6, 1) < 0


def test_351_and_1640_run_programs_without_interrupts():
    for name in ("TMCM-351", "TMCM-1640"):
        with Simulator(name, speed=10) as sim:
            h = Host(sim)
            h.run("CALC LOAD, 3\nCALC MUL, 4\nAGP 0, 2\nMVP ABS, 0, 50\nWAIT POS, 0, 0\nSTOP\n")
            h.wait(stopped(h))
            assert h.var(0) == 12 and h.ok(6, 1) == 50
            assert h.raw(25, 3).status == Status.COMMAND_NOT_AVAILABLE
