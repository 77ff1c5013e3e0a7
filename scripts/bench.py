#!/usr/bin/env python3
"""tmclsh benchmarks: every path as a ratio to the wire's floor, measured in the same run.

    python scripts/bench.py                 # every row, then the table against the targets
    python scripts/bench.py request execute # some rows
    python scripts/bench.py --count 500 --rounds 2   # a quick run
    python scripts/bench.py script -v       # each pair's figures
    python scripts/bench.py --tree ../main  # measure another checkout (before/after)
    python scripts/bench.py --list

The floor is raw pyserial: write a 9-byte GAP, read the 9-byte reply, against the same
simulator served on a pty (``tmclsh sim --pty`` in its own process, always from this checkout,
so two trees are measured against the same module).

This machine's round trip drifts by half within a second, so a floor and a path measured
seconds apart do not compare. The client rows (request, execute, pytrinamic) and the script
rows (script, script-json) therefore run many short blocks, alternating: raw, path, raw, path,
..., raw. Each path block and the two raw blocks either side of it make a pair; the pair's
ratio is the path block's figure over the mean of those two raw blocks' floors, and the row's
figure is the median of the pair ratios (stderr shows their middle half and range; the JSON
has ``ratio_q1``/``ratio_q3``/``ratio_min``/``ratio_max``). A client block is ``--count``/10
GAP round trips, timed one by one (its figure: the median), 20 x ``--rounds`` pairs. A script
block is one run of a (2 x ``--count``)-line script and one of a 1-line script, in separate
``tmclsh -f`` processes, and the same two of a raw pyserial script process (``RAW_SCRIPT``:
the script's frames in order, each reply written out), in an order that turns round every
block: (long - short) / (lines - 1) is the time per line of each, start-up subtracted with a
run measured right beside it, and the table's figure is tmclsh's over the raw script's, block
by block; 4 x ``--rounds`` pairs, fewer once 35 s have passed (unless ``--pairs`` is given).
A process's time per round trip measured so is 1.1-1.4x the long-lived benchmark's own median
one on this VM, for the same pyserial calls: the raw blocks between measure the in-process
floors for comparison, the issue's GAP round trip (the row's note), its mean (a line's time is
a mean) and the script's own frames in its order (GAP 1 / GAP 4 / SAP 4 / GIO 0, each costing
the simulator differently). CPU per round trip (per script line) is
reported beside the wall clock the same way, pair by pair: a loaded machine adds waiting
to the wall clock far more than CPU time. The units row pairs the same way, whole runs: N
raw pyserial processes run together, then tmclsh with N units, ..., raw (8 and 32 by
default, ``--units N`` for others). The other rows alternate whole rounds and take the
best round's figure (other work on the machine only ever adds time); start-up rows are the
fastest of several runs.

Each benchmark is registered with ``@benchmark(name, help)``, gets the parsed arguments and
returns a dict; rows with a target carry ``row``, ``value``, ``unit``, ``target`` and ``ok``,
and ``main`` prints them as one table at the end (one JSON object per line with ``--json``).
These are measurements, not tests: nothing here fails on a slow machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BAUD = 115200


# Where the modules measured live: this tree's layout, or the one before the core
# restructuring (tmclsh/client.py, protocol.py, transport/, ...), so that --tree measures an
# older checkout against this one.
_OLD_LAYOUT = {"tmclsh.client.text": "tmclsh.client", "tmclsh.tmcl.frames": "tmclsh.protocol",
               "tmclsh.link": "tmclsh.transport", "tmclsh.tmcl.asm": "tmclsh.asm",
               "tmclsh.ops.program": "tmclsh.program", "tmclsh.tmcl.modules": "tmclsh.modules"}


def tm(name: str):
    """The measured tree's module ``name`` (as this tree calls it). An installed tmclsh may
    find a new name in another tree, so the measured tree's own folders decide the layout."""
    import importlib

    import tmclsh

    new_layout = (Path(tmclsh.__file__).parent / "tmcl").is_dir()
    return importlib.import_module(name if new_layout else _OLD_LAYOUT[name])


def shell_module(name: str):
    """The measured tree's shell module ``name`` (as this tree calls it,
    ``tmclsh.shell.lang.session``); before the shell's folders (``repl/``, ``lang/``,
    ``features/``) it was ``tmclsh.shell.session``."""
    import importlib

    import tmclsh

    parts = name.split(".")
    folders = (Path(tmclsh.__file__).parent / "shell" / "lang").is_dir()
    if not folders and len(parts) > 3 and parts[2] in ("repl", "lang", "features"):
        name = ".".join(parts[:2] + parts[3:])
    return importlib.import_module(name)


def client_class():
    """The client that takes TMCL lines (``LineClient``; ``Client`` before the split)."""
    text = tm("tmclsh.client.text")
    return getattr(text, "LineClient", None) or text.Client

Benchmark = Callable[[argparse.Namespace], dict]
BENCHMARKS: dict[str, tuple[Benchmark, str]] = {}


def benchmark(name: str, help: str = "") -> Callable[[Benchmark], Benchmark]:
    def register(fn: Benchmark) -> Benchmark:
        BENCHMARKS[name] = (fn, help or (fn.__doc__ or "").strip().splitlines()[0])
        return fn
    return register


def say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


# -- shared helpers ---------------------------------------------------------------------------

def tree_env(args: argparse.Namespace, **extra: str) -> dict[str, str]:
    """Environment for a tmclsh subprocess of the measured tree: no user config, its own
    history, nothing from the developer's TMCLSH_* settings. (They run in ``args.state_dir``:
    ``python -m`` puts the current folder first on sys.path, and this checkout's tmclsh must
    not win from there.)"""
    env = {k: v for k, v in os.environ.items() if not k.startswith("TMCLSH_")
           and k not in ("PYTHONUNBUFFERED", "PYTHONDONTWRITEBYTECODE")}  # as a user runs it
    env["PYTHONPATH"] = str(args.tree) + os.pathsep + os.environ.get("PYTHONPATH", "")
    env["TMCLSH_CONFIG"] = os.devnull
    env["XDG_STATE_HOME"] = args.state_dir
    env.update(extra)
    return env


def tmclsh_cmd(*argv: str) -> list[str]:
    return [sys.executable, "-m", "tmclsh", *argv]


class SimProcess:
    """``tmclsh sim --pty`` of this checkout in a subprocess (its own interpreter, so it does
    not share the benchmark's GIL); ``path`` is the pty to open."""

    def __init__(self, module: str = "TMCM-1311", address: int = 1, baud: int | None = None):
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tmclsh", "sim", "--pty", "-m", module,
             "--address", str(address), *(["--baud", str(baud)] if baud else [])],
            stdout=subprocess.PIPE, text=True, env=env, cwd=str(ROOT))
        assert self.proc.stdout is not None
        self.path = self.proc.stdout.readline().strip()
        if not self.path:
            self.close()
            raise RuntimeError("the simulator did not start")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def __enter__(self) -> SimProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _per_second(seconds: float, count: int) -> float:
    return count / seconds if seconds > 0 else float("inf")


def tmcl_frame(opcode: int, type_: int, motor: int, value: int, address: int = 1) -> bytes:
    """A 9-byte TMCL request, built here (not by the measured tree): address, opcode, type,
    motor/bank, value (big-endian, signed), checksum (the sum of the eight bytes)."""
    body = struct.pack(">BBBBi", address, opcode, type_, motor, value)
    return body + bytes((sum(body) & 0xFF,))


def gap_frame() -> bytes:
    """GAP 1, 0 to address 1: the floor's frame."""
    return tmcl_frame(6, 1, 0, 0)


def raw_latencies(path: str, frame: bytes, warm: int, count: int) -> list[float]:
    """Seconds per raw pyserial round trip (write ``frame``, read the 9-byte reply), after
    ``warm`` untimed ones: the floor every path is compared with."""
    with RawPort(path) as raw:
        raw.round_trips([frame], warm)
        return raw.round_trips([frame], count)


class RawPort:
    """Bare pyserial on the simulator's pty, open for a whole row. It takes no lock, so the
    measured path (a client, a tmclsh process) opens the same pty between raw blocks; nothing
    reads this descriptor then, so no reply goes astray."""

    def __init__(self, path: str):
        import serial

        self.ser = serial.serial_for_url(path, baudrate=BAUD, timeout=1.0)

    def round_trips(self, frames: list[bytes], count: int) -> list[float]:
        """``count`` passes over ``frames`` (write one, read its 9-byte reply, the next...):
        seconds per round trip of each pass."""
        clock = time.perf_counter
        write, read = self.ser.write, self.ser.read
        per = len(frames)
        out = []
        reply = b"x" * 9
        for _ in range(count):
            t0 = clock()
            for frame in frames:
                write(frame)
                reply = read(9)
            out.append((clock() - t0) / per)
        if len(reply) != 9:
            raise RuntimeError(f"raw read timed out (got {reply!r})")
        return out

    def close(self) -> None:
        self.ser.close()

    def __enter__(self) -> RawPort:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


Block = dict[str, float]


def bracket(pairs: int, raw_block: Callable[[int], Block], path_block: Callable[[int], Block],
            verbose: bool, budget: float = float("inf"),
            least: int = 1) -> tuple[list[Block], list[Block]]:
    """Short blocks, alternating: raw, path, raw, path, ..., raw, so every path block has a raw
    block measured right before and right after it (this machine's round trip drifts by half
    within seconds: a floor and a path measured seconds apart do not compare). Each block
    returns its figures by name; returns the raw blocks and the path blocks (one fewer) in
    order: ``pairs`` of them, or fewer (but ``least``) once ``budget`` seconds have passed."""
    start = time.perf_counter()
    raws = [raw_block(0)]
    paths: list[Block] = []
    for i in range(pairs):
        paths.append(path_block(i))
        raws.append(raw_block(i + 1))
        if verbose:
            say(f"  pair {i + 1:>2}: raw {_figures(raws[-2])} | path {_figures(paths[-1])} | "
                f"raw {_figures(raws[-1])}")
        if i + 1 >= least and time.perf_counter() - start > budget:
            say(f"  (stopped after {i + 1} of {pairs} pairs: the {budget:g} s budget is spent)")
            break
    return raws, paths


def load_note() -> str:
    """How busy the machine is (other work stretches every wall-clock figure here)."""
    return f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs"


def _figures(block: Block) -> str:
    return " ".join(f"{k} {v:.4g}" for k, v in block.items())


def pair_ratios(raws: list[Block], paths: list[Block], key: str, floor: str) -> list[float]:
    """Each path block's ``key`` over the mean ``floor`` of the raw blocks either side."""
    return [p[key] / ((a[floor] + b[floor]) / 2) for p, a, b in zip(paths, raws, raws[1:])]


def spread(ratios: list[float]) -> dict[str, float]:
    """The median of the pair ratios (the row's figure), their middle half and their range."""
    q1, _, q3 = (statistics.quantiles(ratios, n=4, method="inclusive") if len(ratios) > 1
                 else [ratios[0]] * 3)
    return {"ratio": statistics.median(ratios), "ratio_q1": q1, "ratio_q3": q3,
            "ratio_min": min(ratios), "ratio_max": max(ratios)}


def show_spread(s: dict[str, float], pairs: int) -> str:
    return (f"{s['ratio']:.2f}x (median of {pairs} pair ratios; middle half "
            f"{s['ratio_q1']:.2f}..{s['ratio_q3']:.2f}, all {s['ratio_min']:.2f}.."
            f"{s['ratio_max']:.2f})")


def rounded(s: dict[str, float], prefix: str = "") -> dict[str, float]:
    return {prefix + k: round(v, 3) for k, v in s.items()}


def median_of(blocks: list[Block], key: str) -> float:
    return statistics.median(b[key] for b in blocks)


def row(result: dict, name: str, value: float, unit: str, target: float, note: str = "") -> dict:
    """A table row: ``value`` against ``target`` (both in ``unit``; lower is better)."""
    result.update(row=name, value=round(value, 3), unit=unit, target=target,
                  ok=bool(value <= target), note=note)
    return result


def _cpu_seconds() -> float:
    """CPU of this process and of its children that have ended (a tmclsh run; the
    simulator's own process is still running, so it is not in here)."""
    import resource

    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def alternate(rounds: int, runs: dict[str, Callable[[], float]], verbose: bool,
              figures: dict[str, list[float]] | None = None) -> dict[str, float]:
    """Run each of ``runs`` once per round, in alternating order; each returns its figure for
    the round (lower is better). Returns the best round's figure for each (``-v`` shows each
    run's CPU time too); ``figures``, if given, gets every round's."""
    figures = {name: [] for name in runs} if figures is None else figures
    figures.update({name: [] for name in runs})
    cpu: dict[str, list[float]] = {name: [] for name in runs}
    for rnd in range(rounds):
        order = list(runs) if rnd % 2 == 0 else list(reversed(runs))
        for name in order:
            c0 = _cpu_seconds()
            figures[name].append(runs[name]())
            cpu[name].append(_cpu_seconds() - c0)
            if verbose:
                say(f"  round {rnd + 1} {name:<10}: {figures[name][-1]:.2f}  "
                    f"(cpu {cpu[name][-1]:.3f} s)")
    return {name: min(v) for name, v in figures.items()}


# -- in-process round trips -------------------------------------------------------------------

def _client_rows(args: argparse.Namespace, which: str) -> dict:
    """One GAP round trip of ``which`` (a client method, PyTrinamic) beside the raw floor, in
    short alternating blocks (``bracket``): the figure is the median of the per-pair ratios
    (each path block's median over the mean of the raw blocks' medians either side)."""
    LineClient = client_class()
    Request = tm("tmclsh.tmcl.frames").Request
    open_serial = tm("tmclsh.link").open_serial

    block = max(50, args.count // 10)
    pairs = args.pairs or 20 * args.rounds
    warm = 200
    frame = gap_frame()
    clock, cpu = time.perf_counter, time.process_time

    def figures(lat: list[float], c0: float) -> Block:
        return {"us": statistics.median(lat) * 1e6, "cpu_us": (cpu() - c0) / block * 1e6}

    def open_path(path: str) -> tuple[Callable[[int], Block], Callable[[], None]]:
        """A block of the path's GAP round trips (the same loops as the raw one's: one call
        timed each), and its close."""
        if which == "pytrinamic":
            from pytrinamic.connections.serial_tmcl_interface import SerialTmclInterface

            iface = SerialTmclInterface(path, datarate=BAUD, timeout_s=1)

            def run_pytrinamic(count: int) -> Block:
                c0, lat = cpu(), []
                for _ in range(count):
                    t0 = clock()
                    iface.get_axis_parameter(1, 0)
                    lat.append(clock() - t0)
                return figures(lat, c0)
            return run_pytrinamic, iface.close

        client = LineClient(open_serial(path, BAUD), module=args.module, timeout=1.0)
        req = Request(1, 6, 1, 0, 0)

        def run_request(count: int) -> Block:
            c0, lat = cpu(), []
            for _ in range(count):
                t0 = clock()
                r = client.request(req)
                lat.append(clock() - t0)
            assert r is not None and r.opcode == 6 and r.ok, r
            return figures(lat, c0)

        def run_execute(count: int) -> Block:
            c0, lat = cpu(), []
            for _ in range(count):
                t0 = clock()
                r = client.execute("GAP 1, 0")
                lat.append(clock() - t0)
            assert r.ok, r
            return figures(lat, c0)

        def close() -> None:
            assert client.stats["timeouts"] == 0, client.stats
            client.close()
        return (run_request if which == "request" else run_execute), close

    def raw_block(_: int) -> Block:
        c0 = cpu()
        return figures(raw.round_trips([frame], block), c0)

    with SimProcess(args.module) as sim, RawPort(sim.path) as raw:
        say(f"{which}: {pairs} pairs of blocks of {block} GAP round trips (raw, {which}, "
            f"raw, ...) on {sim.path}; {load_note()}")
        run, close = open_path(sim.path)
        try:
            raw.round_trips([frame], warm)
            run(warm)
            raws, paths = bracket(pairs, raw_block, lambda _: run(block), args.verbose)
        finally:
            close()
    ratios = spread(pair_ratios(raws, paths, "us", "us"))
    cpu_ratios = spread(pair_ratios(raws, paths, "cpu_us", "cpu_us"))
    floor, us = median_of(raws, "us"), median_of(paths, "us")
    cpu_raw, cpu_path = median_of(raws, "cpu_us"), median_of(paths, "cpu_us")
    say(f"  raw pyserial {floor:.1f} us, {which} {us:.1f} us (medians of the blocks): "
        f"{show_spread(ratios, pairs)}")
    say(f"  CPU per round trip: raw {cpu_raw:.1f} us, {which} {cpu_path:.1f} us: "
        f"{show_spread(cpu_ratios, pairs)}")
    result = {"benchmark": which, "pairs": pairs, "block": block, "floor_us": round(floor, 1),
              "us": round(us, 1), **rounded(ratios), "floor_cpu_us": round(cpu_raw, 1),
              "cpu_us": round(cpu_path, 1), **rounded(cpu_ratios, "cpu_"),
              "load": round(os.getloadavg()[0], 2)}
    del result["ratio"]  # the row's value
    names = {"request": ("Client.request(Request)", 1.15),
             "execute": ('Client.execute("GAP 1, 0")', 1.25),
             "pytrinamic": ("PyTrinamic get_axis_parameter (for comparison)", float("inf"))}
    return row(result, names[which][0], ratios["ratio"], "x floor", names[which][1])


@benchmark("request", "Client.request(Request) round trip vs raw pyserial")
def bench_request(args: argparse.Namespace) -> dict:
    return _client_rows(args, "request")


@benchmark("execute", 'Client.execute("GAP 1, 0") (parse, check, send) vs raw pyserial')
def bench_execute(args: argparse.Namespace) -> dict:
    return _client_rows(args, "execute")


@benchmark("pytrinamic", "PyTrinamic's GAP round trip on the same module vs raw pyserial")
def bench_pytrinamic(args: argparse.Namespace) -> dict:
    return _client_rows(args, "pytrinamic")


# -- scripts ---------------------------------------------------------------------------------

SCRIPT_BUDGET = 35.0  # seconds: a loaded machine ends a script row's pairs early (--pairs: never)
SCRIPT_LINES = (  # the script rows' lines, in order, and the frames they send (built here)
    ("GAP 1, 0", tmcl_frame(6, 1, 0, 0)),
    ("GAP 4, 0", tmcl_frame(6, 4, 0, 0)),
    ("SAP 4, 0, 1000", tmcl_frame(5, 4, 0, 1000)),
    ("GIO 0, 0", tmcl_frame(15, 0, 0, 0)),
)
# The like-for-like floor of a script line: a raw pyserial *process* that sends the script's
# frames in order and writes each reply (hex) to stdout, timed as tmclsh -f is (whole process,
# a 1-frame run subtracted). Timed so, a raw process's round trip measures 1.1-1.4x the
# long-lived benchmark's median one on this VM (same frames, same pyserial calls): a tmclsh
# process pays that too, and it is no cost of tmclsh.
_RAW_SCRIPT = """\
import sys, serial
port, count = sys.argv[1], int(sys.argv[2])
frames = [bytes.fromhex(h) for h in sys.argv[3:]]
ser = serial.serial_for_url(port, baudrate=int(%d), timeout=%r)
write, read, out = ser.write, ser.read, sys.stdout.write
for i in range(count):
    write(frames[i %% len(frames)])
    reply = read(9)
    if len(reply) != 9:
        sys.exit("raw script: read timed out")
    out(reply.hex() + "\\n")
"""
RAW_SCRIPT = _RAW_SCRIPT % (BAUD, 1.0)
# (many processes on two busy cores: one may wait its turn for over a second, which is the
# load's time, not a lost reply; tmclsh's retries would hide such a wait, a raw read cannot)
RAW_UNITS_SCRIPT = _RAW_SCRIPT % (BAUD, 10.0)


def _script_row(args: argparse.Namespace, json_mode: bool) -> dict:
    """Per line of ``tmclsh -f``: (time of an N-line script - time of a 1-line script) / (N-1),
    output to a file. Its floor is the same measured of a raw pyserial script process
    (``RAW_SCRIPT``: the script's frames, each reply written out), run beside it in the same
    block, in alternating order; the row's figure is the median of the per-block ratios.
    Raw blocks between measure the in-process floors for comparison: the issue's GAP round
    trip (median and mean) and the script's own frames in its order."""
    import resource

    n = max(200, 2 * args.count)
    pairs = args.pairs or 4 * args.rounds
    block = max(50, args.count // 2)
    tmp = Path(args.state_dir)
    long_script = tmp / "long.tmcl"
    long_script.write_text("".join(SCRIPT_LINES[i % len(SCRIPT_LINES)][0] + "\n"
                                   for i in range(n)))
    short_script = tmp / "short.tmcl"
    short_script.write_text(SCRIPT_LINES[0][0] + "\n")
    gap = [gap_frame()]
    script_frames = [frame for _, frame in SCRIPT_LINES]
    out_file = tmp / "script.out"
    clock, cpu = time.perf_counter, time.process_time

    def children_cpu() -> float:
        kids = resource.getrusage(resource.RUSAGE_CHILDREN)  # ended children: the tmclsh run
        return kids.ru_utime + kids.ru_stime

    def timed(argv: list[str], env: dict[str, str] | None, lines: int) -> tuple[float, float]:
        """Wall and CPU seconds of one process writing ``lines`` lines to a file."""
        with open(out_file, "w") as out:  # a file: no reader process woken per line
            c0 = children_cpu()
            t0 = clock()
            proc = subprocess.run(argv, stdout=out, stderr=subprocess.PIPE, text=True,
                                  env=env, cwd=args.state_dir, timeout=300)
            took = clock() - t0
            used = children_cpu() - c0
        if proc.returncode != 0 or out_file.read_text().count("\n") != lines:
            raise RuntimeError(f"{argv[1]} run failed: {proc.stderr[-500:]}")
        return took, used

    def run(path: str, script: Path) -> tuple[float, float]:
        """One ``tmclsh -f`` process."""
        argv = tmclsh_cmd("--port", path, "-m", args.module, *(["--json"] if json_mode else []),
                          "-f", str(script))
        lines = n if script is long_script else 1
        return timed(argv, tree_env(args), lines + (0 if json_mode else 1))  # text: a summary

    def run_raw(path: str, count: int) -> tuple[float, float]:
        """One raw pyserial script process of ``count`` round trips."""
        return timed([sys.executable, "-c", RAW_SCRIPT, path, str(count),
                      *(f.hex() for f in script_frames)], None, count)

    def raw_block(i: int) -> Block:
        """The GAP floor (median and mean round trip, CPU per round trip) and the script's
        frames (median time of one pass over the four, per round trip), in alternating order."""
        fig: Block = dict.fromkeys(("us", "mean_us", "script_us", "cpu_us"), 0.0)  # -v's order
        for part in (("gap", "script") if i % 2 == 0 else ("script", "gap")):
            if part == "gap":
                c0 = cpu()
                lat = raw.round_trips(gap, block)
                fig["cpu_us"] = (cpu() - c0) / block * 1e6
                fig["us"] = statistics.median(lat) * 1e6
                fig["mean_us"] = statistics.fmean(lat) * 1e6  # a run's time per line is a mean
            else:
                lat = raw.round_trips(script_frames, block // len(script_frames))
                fig["script_us"] = statistics.median(lat) * 1e6
        return fig

    def path_block(i: int) -> Block:
        """A short and a long run of tmclsh and of the raw script, in an order that turns
        round every block (raw short, tmclsh short, tmclsh long, raw long; then backwards):
        each start-up is subtracted from a run measured beside it, and neither side is
        always first."""
        jobs = [("raw", 1), ("tmclsh", 1), ("tmclsh", n), ("raw", n)]
        runs = {}
        for job in (jobs if i % 2 == 0 else jobs[::-1]):
            who, lines = job
            runs[job] = (run(sim.path, long_script if lines == n else short_script)
                         if who == "tmclsh" else run_raw(sim.path, lines))

        def per_line(who: str, k: int) -> float:
            return (runs[(who, n)][k] - runs[(who, 1)][k]) / (n - 1) * 1e6
        return {"us": per_line("tmclsh", 0), "cpu_us": per_line("tmclsh", 1),
                "raw_us": per_line("raw", 0), "raw_cpu_us": per_line("raw", 1),
                "long_s": runs[("tmclsh", n)][0], "short_s": runs[("tmclsh", 1)][0]}

    with SimProcess(args.module) as sim, RawPort(sim.path) as raw:
        say(f"script{' --json' if json_mode else ''}: {pairs} pairs (raw, then a {n}-line and "
            f"a 1-line script of tmclsh and of raw pyserial, raw, ...; raw blocks of {block} "
            f"round trips) on {sim.path}; {load_note()}")
        run(sim.path, short_script)  # warm the caches
        run_raw(sim.path, 1)
        raw.round_trips(gap + script_frames, 100)
        raws, paths = bracket(pairs, raw_block, path_block, args.verbose,
                              budget=SCRIPT_BUDGET if not args.pairs else float("inf"),
                              least=min(pairs, 8))
    pairs = len(paths)
    proc_ratios = spread([p["us"] / p["raw_us"] for p in paths])
    proc_cpu_ratios = spread([p["cpu_us"] / p["raw_cpu_us"] for p in paths])
    ratios = spread(pair_ratios(raws, paths, "us", "us"))
    mean_ratios = spread(pair_ratios(raws, paths, "us", "mean_us"))
    script_ratios = spread(pair_ratios(raws, paths, "us", "script_us"))
    cpu_ratios = spread(pair_ratios(raws, paths, "cpu_us", "cpu_us"))
    floor, per_line = median_of(raws, "us"), median_of(paths, "us")
    floor_proc, cpu_proc = median_of(paths, "raw_us"), median_of(paths, "raw_cpu_us")
    floor_mean, floor_script = median_of(raws, "mean_us"), median_of(raws, "script_us")
    cpu_raw, cpu_line = median_of(raws, "cpu_us"), median_of(paths, "cpu_us")
    say(f"  raw pyserial script process {floor_proc:.1f} us, tmclsh {per_line:.1f} us per line "
        f"(medians of the blocks): {show_spread(proc_ratios, pairs)}")
    say(f"  CPU per line: raw pyserial script {cpu_proc:.1f} us, tmclsh {cpu_line:.1f} us: "
        f"{show_spread(proc_cpu_ratios, pairs)}")
    say("  in-process floors (the benchmark's own long-lived process):")
    say(f"    raw pyserial GAP median {floor:.1f} us: {show_spread(ratios, pairs)}")
    # the floor is a median round trip, a script line a whole run's mean (its waits on a
    # loaded machine included): the mean of the raw round trips, for a like-for-like look
    say(f"    raw pyserial GAP mean {floor_mean:.1f} us: {show_spread(mean_ratios, pairs)}")
    say(f"    raw pyserial, the script's own frames ({' / '.join(t for t, _ in SCRIPT_LINES)}) "
        f"{floor_script:.1f} us per round trip: {show_spread(script_ratios, pairs)}")
    say(f"    CPU: raw {cpu_raw:.1f} us per round trip: {show_spread(cpu_ratios, pairs)}")
    result = {"benchmark": "script-json" if json_mode else "script", "lines": n,
              "pairs": pairs, "block": block, "us_per_line": round(per_line, 1),
              "raw_script_us": round(floor_proc, 1), **rounded(proc_ratios),
              "raw_script_cpu_us": round(cpu_proc, 1), "cpu_us_per_line": round(cpu_line, 1),
              **rounded(proc_cpu_ratios, "cpu_"),
              "floor_us": round(floor, 1), **rounded(ratios, "gap_"),
              "floor_mean_us": round(floor_mean, 1), **rounded(mean_ratios, "mean_"),
              "script_floor_us": round(floor_script, 1), **rounded(script_ratios, "script_floor_"),
              "floor_cpu_us": round(cpu_raw, 1), **rounded(cpu_ratios, "gap_cpu_"),
              "load": round(os.getloadavg()[0], 2)}
    del result["ratio"]  # the row's value
    name = "tmclsh -f script --json, per line" if json_mode else "tmclsh -f script, per line"
    return row(result, name, proc_ratios["ratio"], "x raw script", 1.3,
               f"{ratios['ratio']:.2f}x the in-process GAP median")


@benchmark("script", "tmclsh -f SCRIPT per line (text output to a file) vs raw pyserial")
def bench_script(args: argparse.Namespace) -> dict:
    return _script_row(args, False)


@benchmark("script-json", "tmclsh -f SCRIPT --json per line vs raw pyserial")
def bench_script_json(args: argparse.Namespace) -> dict:
    return _script_row(args, True)


# -- start-up ---------------------------------------------------------------------------------

def _fastest(argv: list[str], env: dict, runs: int, cwd: str,
             cpu: list[float] | None = None) -> float:
    """The fastest of ``runs`` whole processes (wall seconds); each one's CPU seconds (user
    and system, from the kernel's count for ended children) appended to ``cpu``."""
    best = float("inf")
    for _ in range(runs):
        c0 = _children_cpu()
        t0 = time.perf_counter()
        proc = subprocess.run(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                              cwd=cwd, timeout=60)
        best = min(best, time.perf_counter() - t0)
        if cpu is not None:
            cpu.append(_children_cpu() - c0)
        if proc.returncode != 0:
            raise RuntimeError(f"{argv} failed: {proc.stderr.decode()[-500:]}")
    return best


def _children_cpu() -> float:
    import resource

    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return kids.ru_utime + kids.ru_stime


PROCESS_TARGET = 4.0  # issue 34: a cold -c at most 4x the interpreter importing pyserial


@benchmark("process", 'whole-process tmclsh --port P -c "GAP 1, 0" vs python -c "import serial"')
def bench_process(args: argparse.Namespace) -> dict:
    runs = max(5, args.rounds * 4)
    env = tree_env(args)
    with SimProcess(args.module) as sim:
        argv = tmclsh_cmd("--port", sim.path, "-m", args.module, "-c", "GAP 1, 0")
        _fastest(argv, env, 1, args.state_dir)  # the data cache, the page cache
        cpu: dict[str, list[float]] = {"python": [], "tmclsh": []}
        best = alternate(args.rounds, {
            "python": lambda: _fastest([sys.executable, "-c", "import serial"], env, runs // 2,
                                       args.state_dir, cpu["python"]),
            "tmclsh": lambda: _fastest(argv, env, runs // 2, args.state_dir, cpu["tmclsh"])},
            args.verbose)
    ratio = best["tmclsh"] / best["python"]
    # CPU: the least each process took (the wall clock on a busy machine waits for others)
    cpu_ratio = min(cpu["tmclsh"]) / min(cpu["python"])
    say(f"process: python -c 'import serial' {best['python'] * 1e3:.1f} ms, tmclsh -c "
        f"{best['tmclsh'] * 1e3:.1f} ms: {ratio:.2f}x; CPU {min(cpu['python']) * 1e3:.0f} ms "
        f"and {min(cpu['tmclsh']) * 1e3:.0f} ms: {cpu_ratio:.2f}x ({load_note()})")
    return row({"benchmark": "process", "python_ms": round(best["python"] * 1e3, 1),
                "tmclsh_ms": round(best["tmclsh"] * 1e3, 1), "cpu_ratio": round(cpu_ratio, 3)},
               'tmclsh --port P -m TMCM-1311 -c "GAP 1, 0", whole process', ratio,
               'x python -c "import serial"', PROCESS_TARGET, f"CPU {cpu_ratio:.2f}x")


HEAVY = ("prompt_toolkit", "rich", "pygments", "asyncio", "can")
DUMP_MODULES = """
import atexit, json, runpy, sys
atexit.register(lambda: print("MODULES " + json.dumps(sorted(sys.modules)), file=sys.stderr))
sys.argv = ["tmclsh", *sys.argv[1:]]
runpy.run_module("tmclsh", run_name="__main__", alter_sys=True)
"""


@benchmark("imports", "heavy modules imported on the -c path (a count, not a time)")
def bench_imports(args: argparse.Namespace) -> dict:
    with SimProcess(args.module) as sim:
        proc = subprocess.run([sys.executable, "-c", DUMP_MODULES, "--port", sim.path, "-m",
                               args.module, "-c", "GAP 1, 0"], capture_output=True, text=True,
                              env=tree_env(args), cwd=args.state_dir, timeout=60)
    modules = json.loads(proc.stderr.rstrip().splitlines()[-1][len("MODULES "):])
    heavy = sorted({m.split(".")[0] for m in modules if m.split(".")[0] in HEAVY}
                   | ({"tmclsh.sim"} if any(m.startswith("tmclsh.sim") for m in modules) else set()))
    say(f"imports: {len(modules)} modules on the -c path; heavy: {', '.join(heavy) or 'none'}")
    return row({"benchmark": "imports", "modules": len(modules), "heavy": heavy},
               "heavy modules on that -c path", len(heavy), "modules", 0,
               note=", ".join(heavy) or "none")


REPL_TARGET = 1.4  # issue 34: the first prompt at most 1.4x a bare prompt_toolkit prompt's
# the yardstick: prompt_toolkit's own prompt, the same text, nothing else imported or done
BARE_PROMPT = ("from prompt_toolkit import PromptSession\n"
               "PromptSession().prompt('{module}:1> ')\n")


@benchmark("repl", "REPL: start to first prompt on a pty vs a bare prompt_toolkit "
                   "PromptSession().prompt() (target <= 1.4x)")
def bench_repl(args: argparse.Namespace) -> dict:
    """Seconds from starting ``tmclsh --port P -m TMCM-1311`` on a pseudo-terminal to the
    prompt appearing on it, beside a bare ``PromptSession().prompt()`` showing the same
    prompt on the same kind of terminal, the two alternating (the fastest of several starts
    each); the row is the ratio. Beside it the CPU time each had spent when its prompt
    appeared (the kernel's count of the process's threads, ``/proc/PID/task/*/schedstat``):
    on a busy machine the steadier figure (it leaves out the waits, the module's answers
    to the connect among them)."""
    import pty
    import re
    import select

    cpu_at_prompt: dict[str, list[float]] = {"prompt_toolkit": [], "tmclsh": []}

    def cpu_of(pid: int) -> float:
        """Seconds on a CPU of every thread of ``pid`` so far (nan where Linux does not say)."""
        total = 0
        try:
            for task in os.listdir(f"/proc/{pid}/task"):
                with open(f"/proc/{pid}/task/{task}/schedstat") as f:
                    total += int(f.read().split()[0])
        except (OSError, ValueError, IndexError):
            return float("nan")
        return total / 1e9

    def start(argv: list[str], who: str = "") -> float:
        pid, fd = pty.fork()
        if pid == 0:
            env = tree_env(args, TERM="xterm", COLUMNS="100", LINES="30")
            os.chdir(args.state_dir)
            os.execvpe(argv[0], argv, env)
        t0 = time.perf_counter()
        seen = b""
        took = float("inf")
        try:
            while time.perf_counter() - t0 < 20:
                ready, _, _ = select.select([fd], [], [], 1)
                if not ready:
                    continue
                try:
                    chunk = os.read(fd, 4096)
                except OSError:
                    break
                if b"\x1b[6n" in chunk:
                    os.write(fd, b"\x1b[1;1R")  # answer the cursor position request
                seen += chunk
                if re.search(rb"TMCM-\d+:\d+(\x1b\[[0-9;?]*[a-zA-Z])*>", seen):
                    took = time.perf_counter() - t0
                    if who:
                        cpu_at_prompt[who].append(cpu_of(pid))
                    break
            os.write(fd, b"\x04")  # Ctrl-D: leave
            deadline = time.time() + 5
            while time.time() < deadline:
                done, _ = os.waitpid(pid, os.WNOHANG)
                if done:
                    break
                if select.select([fd], [], [], 0.1)[0]:
                    try:
                        os.read(fd, 4096)
                    except OSError:
                        pass
            else:
                os.kill(pid, 9)
                os.waitpid(pid, 0)
        finally:
            os.close(fd)
        if took == float("inf"):
            raise RuntimeError(f"no prompt within 20 s; the terminal showed {seen[-300:]!r}")
        return took

    runs = max(3, args.rounds * 2)
    bare = [sys.executable, "-c", BARE_PROMPT.format(module=args.module)]
    with SimProcess(args.module) as sim:
        shell = tmclsh_cmd("--port", sim.path, "-m", args.module)
        start(shell)
        start(bare)  # the page cache and the data cache warm for both
        best = alternate(runs, {"prompt_toolkit": lambda: start(bare, "prompt_toolkit"),
                                "tmclsh": lambda: start(shell, "tmclsh")}, args.verbose)
    ratio = best["tmclsh"] / best["prompt_toolkit"]
    cpu = {who: min(v) for who, v in cpu_at_prompt.items()}
    cpu_ratio = cpu["tmclsh"] / cpu["prompt_toolkit"]
    say(f"repl: first prompt after {best['tmclsh']:.3f} s, a bare prompt_toolkit prompt after "
        f"{best['prompt_toolkit']:.3f} s: {ratio:.2f}x (fastest of {runs}); CPU at the prompt "
        f"{cpu['tmclsh'] * 1e3:.0f} ms and {cpu['prompt_toolkit'] * 1e3:.0f} ms: "
        f"{cpu_ratio:.2f}x ({load_note()})")
    return row({"benchmark": "repl", "tmclsh_s": round(best["tmclsh"], 3),
                "prompt_toolkit_s": round(best["prompt_toolkit"], 3),
                "cpu_ratio": round(cpu_ratio, 3)},
               "REPL: start to first prompt", ratio, "x PromptSession().prompt()", REPL_TARGET,
               f"{best['tmclsh']:.3f} s; CPU {cpu_ratio:.2f}x")


# -- program upload ---------------------------------------------------------------------------

@benchmark("upload", ".upload + verify of 2000 instructions vs the same 4000 raw transactions")
def bench_upload(args: argparse.Namespace) -> dict:
    """Seconds to store (132, one frame each answered with status 101, 133) and verify (134
    read-back) a program with ``tmclsh.ops.program.upload``, beside the raw floor: the same frames
    written and their 9-byte replies read with bare pyserial, against the same pty-served
    simulator, in the same run (rounds alternate raw and tmclsh; the figure is the median of
    the rounds' ratios, six times ``--rounds`` of them: with ten, the figure of one run of
    the row scattered by +-0.04 around a median that many runs agree on)."""
    import serial

    asm = tm("tmclsh.tmcl.asm")
    program = tm("tmclsh.ops.program")
    LineClient = client_class()
    load = tm("tmclsh.tmcl.modules").load
    frames = tm("tmclsh.tmcl.frames")
    Control, Instruction, Request = frames.Control, frames.Instruction, frames.Request
    open_serial = tm("tmclsh.link").open_serial

    module = load(args.module)
    n = min(2000, module.program_memory)
    source = "".join(f"    SGP {i % 56}, 2, {i}\n" for i in range(n - 1)) + "    STOP\n"
    prog = asm.assemble(source, module, "<bench>")
    frames = [Request(1, ins.opcode, ins.type, ins.motor, ins.value).to_bytes()
              for ins in prog.instructions]
    start = Request(1, Control.START_DOWNLOAD, 0, 0, 0).to_bytes()
    quit_ = Request(1, Control.QUIT_DOWNLOAD).to_bytes()
    reads = [Request(1, Control.READ_MEMORY, 0, 0, a).to_bytes() for a in range(n)]
    parts: dict[str, list[float]] = {"raw_upload": [], "raw_verify": [], "upload": [],
                                     "verify": []}

    def raw_round(path: str) -> float:
        ser = serial.serial_for_url(path, baudrate=BAUD, timeout=1.0)
        try:
            def rt(frame: bytes) -> bytes:
                ser.write(frame)
                reply = ser.read(9)
                assert len(reply) == 9, reply
                return reply
            t0 = time.perf_counter()
            rt(start)
            for f in frames:
                reply = rt(f)
            rt(quit_)
            t1 = time.perf_counter()
            assert reply[2] == 101, reply  # status: loaded
            got = [rt(f) for f in reads]
            t2 = time.perf_counter()
            stored = [Instruction.from_bytes(r[1:8]) for r in got]
            assert program.same_image(stored, prog.instructions)
        finally:
            ser.close()
        parts["raw_upload"].append(t1 - t0)
        parts["raw_verify"].append(t2 - t1)
        return t2 - t0

    def client_round(path: str) -> float:
        client = LineClient(open_serial(path, BAUD), module=args.module, timeout=1.0)
        try:
            t0 = time.perf_counter()
            result = program.upload(client, prog)
            took = time.perf_counter() - t0
            assert result.verified, result
            assert client.stats["timeouts"] == 0, client.stats
        finally:
            client.close()
        parts["upload"].append(result.upload_seconds)
        parts["verify"].append(result.verify_seconds)
        return took

    rounds = args.pairs or 6 * args.rounds
    with SimProcess(args.module) as sim:
        say(f"upload: {rounds} round(s) of {n} instructions on {sim.path} ({load_note()})")
        figures: dict[str, list[float]] = {}
        best = alternate(rounds, {"raw": lambda: raw_round(sim.path),
                                  "upload": lambda: client_round(sim.path)}, args.verbose,
                         figures)
    # the figure: the median of the rounds' ratios (each round's two runs side by side, as
    # the client rows pair their blocks: this machine's floor drifts within seconds)
    ratio = statistics.median(u / r for r, u in zip(figures["raw"], figures["upload"]))
    low = {k: min(v) for k, v in parts.items()}
    say(f"  raw {2 * n + 2} transactions {best['raw']:.3f} s, upload + verify "
        f"{best['upload']:.3f} s (fastest of {rounds}); median of the rounds' ratios "
        f"{ratio:.3f}x (fastest over fastest {best['upload'] / best['raw']:.3f}x; upload "
        f"{low['upload'] / low['raw_upload']:.2f}x, "
        f"verify {low['verify'] / low['raw_verify']:.2f}x)")
    result = {"benchmark": "upload", "instructions": n, "raw_s": round(best["raw"], 3),
              "upload_s": round(best["upload"], 3),
              "fastest_ratio": round(best["upload"] / best["raw"], 3),
              "upload_ratio": round(low["upload"] / low["raw_upload"], 3),
              "verify_ratio": round(low["verify"] / low["raw_verify"], 3)}
    return row(result, f".upload + verify of {n} instructions", ratio, "x raw", 1.1)


# -- firmware update --------------------------------------------------------------------------

FIRMWARE_SIZE = 64 * 1024  # bytes of the image (the 64 KiB)
FIRMWARE_START = 0x8000  # where the simulated bootloader's memory starts (tmclsh/sim/README.md)
FIRMWARE_PAGE = 0x800
FIRMWARE_POLL = 0.1  # s each 136 to a restarting module is given (bootloader.toml's switch_s)


def _firmware_hex(folder: str, version: str) -> str:
    """A 64 KiB image for the simulated TMCM-1311 carrying ``version``, as an Intel HEX file
    (written by intelhex, as a vendor's tool would)."""
    from intelhex import IntelHex

    data = bytearray((i * 13 + 5) & 0xFF for i in range(FIRMWARE_SIZE))
    data[0x200:0x200 + len(version)] = version.encode()
    path = os.path.join(folder, f"fw-{version}.hex")
    ih = IntelHex()
    ih.puts(FIRMWARE_START, bytes(data))
    ih.write_hex_file(path)
    return path


def _firmware_frames(hex_path: str) -> list[tuple[str, bytes]]:
    """The frames of an update, built here from the issue's table (not by the measured
    tree), in the order ``tmclsh firmware`` sends them: ("rt", frame) for a round trip,
    ("w", frame) for a frame that gets no reply (242, 205)."""
    from intelhex import IntelHex

    ih = IntelHex(hex_path)
    lo, hi = ih.minaddr(), ih.maxaddr() + 1
    ih.padding = 0
    data = ih.tobinstr(start=lo, end=hi - 1)
    frames = [("rt", tmcl_frame(136, 0, 0, 0)), ("rt", tmcl_frame(10, 129, 0, 0)),
              ("rt", tmcl_frame(135, 0, 0, 0)), ("rt", tmcl_frame(6, 3, 0, 0)),
              ("w", tmcl_frame(242, 0x81, 0x92, -0x5C4B3A2A)),
              ("rt", tmcl_frame(136, 0, 0, 0)), ("rt", tmcl_frame(136, 0, 0, 0)),
              ("rt", tmcl_frame(206, 0, 0, 0)), ("rt", tmcl_frame(206, 1, 0, 0)),
              ("rt", tmcl_frame(206, 2, 0, 0)), ("rt", tmcl_frame(200, 0, 0, 0))]
    for page in range(lo, hi, FIRMWARE_PAGE):
        for addr in range(page, min(page + FIRMWARE_PAGE, hi), 4):
            index = (addr - page) // 4
            word = struct.unpack("<i", data[addr - lo:addr - lo + 4].ljust(4, b"\0"))[0]
            frames.append(("rt", tmcl_frame(201, index & 0xFF, index >> 8, word)))
        frames.append(("rt", tmcl_frame(202, 0, 0, page)))
    total = sum(data) & 0xFFFFFFFF
    signed = total - (1 << 32) if total >= 1 << 31 else total
    frames += [("rt", tmcl_frame(203, 0, 0, hi - 1)), ("rt", tmcl_frame(208, 0, 0, hi - lo)),
               ("rt", tmcl_frame(208, 1, 0, signed)), ("w", tmcl_frame(205, 0, 0, 0)),
               ("rt", tmcl_frame(136, 0, 0, 0))]
    return frames


def _firmware_tools(args: argparse.Namespace):
    """The measured tree's update and image reader, or None when it has none."""
    try:
        return tm("tmclsh.ops.firmware"), tm("tmclsh.tmcl.bootloader")
    except ImportError:
        say("firmware: the measured tree has no firmware update")
        return None


def _firmware_process(args: argparse.Namespace, argv: list[str]) -> float:
    t0 = time.perf_counter()
    p = subprocess.run(argv, capture_output=True, text=True, env=tree_env(args),
                       cwd=args.state_dir, timeout=600)
    took = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"{argv[0]} failed: {p.stdout[-300:]} {p.stderr[-300:]}")
    return took


_FIRMWARE_VERSIONS = iter(f"1311V{n}" for n in range(120, 1000))  # a new one every round


@benchmark("firmware", "64 KiB firmware update over a pty at 115200 baud vs a raw pyserial "
                       "loop of the same frames")
def bench_firmware(args: argparse.Namespace) -> dict:
    """Seconds to update the simulated TMCM-1311 (``tmclsh sim --pty``, its own process) with
    a 64 KiB image, the pty opened at 115200 baud, with ``tmclsh.ops.firmware.Update``,
    beside a raw pyserial loop of the same frames built here from the issue's table (each
    round one of each, right beside the other; each writes an image of another version, so
    none finds its work done). A pty moves bytes at no rate of its own: these are the
    round trips' own costs, the harder comparison (on a line paced at 115200 baud both take
    the 25 s the wire takes)."""
    import serial

    tools = _firmware_tools(args)
    if tools is None:
        return {"benchmark": "firmware", "skipped": "no tmclsh.ops.firmware in the tree"}
    firmware, boot = tools
    with tempfile.TemporaryDirectory(prefix="tmclsh-fw-") as folder:

        def raw_round(path: str) -> float:
            frames = _firmware_frames(_firmware_hex(folder, next(_FIRMWARE_VERSIONS)))
            ser = serial.serial_for_url(path, baudrate=BAUD, timeout=1.0)
            try:
                write, read = ser.write, ser.read
                t0, c0 = time.perf_counter(), time.process_time()
                restarting = False
                for kind, frame in frames:
                    write(frame)
                    if kind == "w":  # 242, 205: the module restarts (what reaches it
                        restarting = True  # meanwhile is lost): the next 136 is asked
                        continue  # until answered, FIRMWARE_POLL s each, as tmclsh asks
                    if restarting:
                        ser.timeout = FIRMWARE_POLL
                        reply = read(9)
                        while len(reply) != 9:
                            ser.reset_input_buffer()
                            write(frame)
                            reply = read(9)
                        ser.timeout, restarting = 1.0, False
                        continue
                    reply = read(9)
                    if len(reply) != 9:
                        raise RuntimeError(f"raw update: no reply to {frame.hex()}")
                took = time.perf_counter() - t0
                cpu["raw"].append(time.process_time() - c0)
                assert reply[1:5] == b"1311" and reply[5:6] == b"V", reply  # it runs again
            finally:
                ser.close()
            return took

        def tmclsh_round(path: str) -> float:
            image = boot.read_image(_firmware_hex(folder, next(_FIRMWARE_VERSIONS)))
            update = firmware.Update({"port": path, "baud": BAUD, "timeout": 1.0}, image)
            try:
                t0, c0 = time.perf_counter(), time.process_time()
                result = update.run()
                took = time.perf_counter() - t0
                cpu["tmclsh"].append(time.process_time() - c0)
            finally:
                update.close()
            assert result.written == FIRMWARE_SIZE and not result.nothing_to_do, result
            return took

        with SimProcess(args.module) as sim:
            rounds = args.rounds
            say(f"firmware: {rounds} round(s) of a {FIRMWARE_SIZE // 1024} KiB image on "
                f"{sim.path} ({load_note()})")
            # each round a raw update and a tmclsh one right beside it (in turn first): this
            # machine's round trip drifts within seconds, so the row's figure is the median
            # of the rounds' ratios, not a ratio of two bests measured apart
            ratios, raws, ours = [], [], []
            # each round's CPU seconds of this process (steadier than the wall clock on a
            # busy machine: what the two sides themselves spend, the simulator's apart)
            cpu: dict[str, list[float]] = {"raw": [], "tmclsh": []}
            for rnd in range(rounds):
                if rnd % 2:
                    ours.append(tmclsh_round(sim.path))
                    raws.append(raw_round(sim.path))
                else:
                    raws.append(raw_round(sim.path))
                    ours.append(tmclsh_round(sim.path))
                ratios.append(ours[-1] / raws[-1])
                if args.verbose:
                    say(f"  round {rnd + 1}: raw {raws[-1]:.3f} s (cpu {cpu['raw'][-1]:.3f}), "
                        f"tmclsh {ours[-1]:.3f} s (cpu {cpu['tmclsh'][-1]:.3f}): "
                        f"{ratios[-1]:.2f}x")
    ratio = statistics.median(ratios)
    cpu_ratio = statistics.median(o / r for o, r in zip(cpu["tmclsh"], cpu["raw"]))
    say(f"  raw {min(raws):.3f}..{max(raws):.3f} s, tmclsh {min(ours):.3f}..{max(ours):.3f} s;"
        f" ratio per round {min(ratios):.2f}..{max(ratios):.2f}, median {ratio:.2f}x; "
        f"CPU median {cpu_ratio:.2f}x ({load_note()})")
    result = {"benchmark": "firmware", "bytes": FIRMWARE_SIZE, "raw_s": round(min(raws), 3),
              "tmclsh_s": round(min(ours), 3), "cpu_ratio": round(cpu_ratio, 3),
              **rounded(spread(ratios))}
    return row(result, f"firmware update of {FIRMWARE_SIZE // 1024} KiB", ratio, "x raw", 1.1,
               note=f"median of {rounds} rounds, {min(ratios):.2f}..{max(ratios):.2f}; "
                    f"CPU {cpu_ratio:.2f}x")


@benchmark("firmware-pytrinamic", "64 KiB firmware update: tmclsh firmware vs PyTrinamic's "
                                  "tmclfwupload, whole processes side by side")
def bench_firmware_pytrinamic(args: argparse.Namespace) -> dict:
    """Seconds of a whole ``tmclsh firmware FILE --port PTY --baud 115200 --yes`` process and
    of PyTrinamic's ``tmclfwupload FILE --interface serial_tmcl --port PTY --data-rate
    115200`` (as their users run them; its own 1 s waits included) on the same simulated
    bootloader, alternating, up to 3 rounds; each round writes an image of another version."""
    import shutil

    if _firmware_tools(args) is None:
        return {"benchmark": "firmware-pytrinamic", "skipped": "no firmware update in the tree"}
    tool = shutil.which("tmclfwupload", path=str(Path(sys.executable).parent)) or \
        shutil.which("tmclfwupload")
    if tool is None:
        say("firmware-pytrinamic: PyTrinamic's tmclfwupload is not installed")
        return {"benchmark": "firmware-pytrinamic", "skipped": "no tmclfwupload"}
    with tempfile.TemporaryDirectory(prefix="tmclsh-fw-") as folder, \
            SimProcess(args.module) as sim:
        say(f"firmware-pytrinamic: {min(args.rounds, 3)} round(s) on {sim.path} "
            f"({load_note()})")
        runs = {
            "tmclsh": lambda: _firmware_process(args, tmclsh_cmd(
                "firmware", _firmware_hex(folder, next(_FIRMWARE_VERSIONS)), "--port",
                sim.path, "--baud", str(BAUD), "--yes")),
            "tmclfwupload": lambda: _firmware_process(args, [
                tool, _firmware_hex(folder, next(_FIRMWARE_VERSIONS)), "--interface",
                "serial_tmcl", "--port", sim.path, "--data-rate", str(BAUD)]),
        }
        best = alternate(max(1, min(args.rounds, 3)), runs, args.verbose)
    faster = best["tmclfwupload"] / best["tmclsh"]
    say(f"  tmclsh firmware {best['tmclsh']:.3f} s, tmclfwupload {best['tmclfwupload']:.3f} s:"
        f" tmclsh {faster:.2f}x faster")
    result = {"benchmark": "firmware-pytrinamic", "bytes": FIRMWARE_SIZE,
              "tmclsh_s": round(best["tmclsh"], 3),
              "pytrinamic_s": round(best["tmclfwupload"], 3), "faster": round(faster, 3)}
    return row(result, "tmclsh firmware, time of tmclfwupload's", best["tmclsh"]
               / best["tmclfwupload"], "x", round(1 / 1.8, 3),
               note=f"{faster:.2f}x faster; target at least 1.8x")


# -- scan -------------------------------------------------------------------------------------

# -- watch polling ----------------------------------------------------------------------------

WATCH_EXPRESSIONS = "pos=GAP 1, 0; speed=GAP 3, 0; in0=GIO 0, 0; volts=GIO 8, 1 / 10"


@benchmark("watch", "samples/s of a 4-expression .watch vs the raw pyserial round-trip floor")
def bench_watch(args: argparse.Namespace) -> dict:
    """Samples per second a ``.watch`` of four expressions (four distinct reads) sustains,
    beside the raw floor (one sample is four round trips). No target in the issue's table;
    reported as time per sample over four raw round trips."""
    import io

    LineClient = client_class()
    watch = shell_module("tmclsh.shell.features.watch")
    Output = shell_module("tmclsh.shell.render").Output
    Session = shell_module("tmclsh.shell.lang.session").Session
    open_serial = tm("tmclsh.link").open_serial

    count = args.count // 4 or 1
    frame = gap_frame()
    clock = time.perf_counter

    def run_watch(path: str) -> float:
        client = LineClient(open_serial(path, BAUD), module=args.module, timeout=1.0)
        try:
            session = Session(client, Output(json_mode=True))
            items = watch.parse_items(session, WATCH_EXPRESSIONS)
            stamps: list[float] = []
            with open(os.devnull, "w") as sink:
                def emit(obj: dict) -> None:
                    sink.write(json.dumps(obj) + "\n")
                    stamps.append(clock())

                watch.run_watch(session, items, interval=0, count=count + 1, live=False,
                                keys=watch.Keys(io.StringIO()), emit=emit)
        finally:
            client.close()
        return statistics.median(b - a for a, b in zip(stamps, stamps[1:])) * 1e6

    with SimProcess(args.module) as sim:
        say(f"watch: {args.rounds} round(s) of {count} samples of '{WATCH_EXPRESSIONS}'")
        best = alternate(args.rounds, {
            "raw4": lambda: 4 * statistics.median(raw_latencies(sim.path, frame, 100, count * 4))
            * 1e6,
            "watch": lambda: run_watch(sim.path)}, args.verbose)
    ratio = best["watch"] / best["raw4"]
    say(f"  four raw round trips {best['raw4']:.1f} us, one sample {best['watch']:.1f} us: "
        f"{ratio:.2f}x")
    return {"benchmark": "watch", "floor_us": round(best["raw4"], 1),
            "sample_us": round(best["watch"], 1), "ratio": round(ratio, 3)}


@benchmark("scan", "tmclsh scan of addresses 1..255, one module, 115200 baud (target <= 5 s)")
def bench_scan(args: argparse.Namespace) -> dict:
    """Wall time of a whole ``tmclsh scan --port PTY --baud 115200`` process (the module at
    address 5 of a pty-served simulator, in its own process), median of the rounds. Most of a
    scan is silent addresses, so this measures the per-address wait derived from the link."""

    times = []
    with SimProcess(args.module, 5) as sim:
        for r in range(args.rounds):
            t0 = time.perf_counter()
            p = subprocess.run(tmclsh_cmd("scan", "--port", sim.path, "--baud", str(BAUD),
                                          "--json"), capture_output=True, text=True,
                               env=tree_env(args), cwd=args.state_dir, timeout=120)
            times.append(time.perf_counter() - t0)
            if p.returncode != 0 or '"address": 5' not in p.stdout:
                raise RuntimeError(f"scan failed: {p.stderr.strip()}")
            if args.verbose:
                say(f"  round {r + 1}: {times[-1]:.2f} s")
    med = statistics.median(times)
    say(f"  scan 1..255 @ 115200: {med:.2f} s (target <= 5 s: "
        f"{'met' if med <= 5 else 'NOT met'})")
    return row({"benchmark": "scan", "rounds": args.rounds}, "scan of addresses 1..255", med,
               "s", 5.0)


# -- many modules at once ------------------------------------------------------------------------

UNIT_COUNTS = (8, 32)  # the two figures (--units N measures others)
UNIT_LINES = 500
UNITS_TARGET = 1.1  # issue 34: N units at most 1.1x N raw pyserial processes run together


def _unit_counts(args: argparse.Namespace) -> tuple[int, ...]:
    return tuple(args.units) if getattr(args, "units", None) else UNIT_COUNTS


@benchmark("units", f"{' and '.join(map(str, UNIT_COUNTS))} units vs as many raw pyserial "
                    f"processes run together, a {UNIT_LINES}-line script, each module paced "
                    f"at {BAUD} baud")
def bench_units(args: argparse.Namespace) -> dict:
    """Wall time of ``tmclsh --port P1 ... --port PN -f SCRIPT`` (N units, each its own
    pty-served simulator in its own process, every line paced at 115200 baud: 1.6 ms of wire
    per exchange), whole process, output to a file, against the machine's own floor: N raw
    pyserial processes (``RAW_SCRIPT``: the script's frames, each reply written out) started
    together, each against its own module, timed together from the first start to the last
    end. On two cores the floor is itself well above one process's time (N interpreters
    start, and the N simulators need CPU too): the ratio to it is what tmclsh adds.

    Blocks alternate, raw, tmclsh, raw, ..., raw (``bracket``): each tmclsh block's ratio is
    over the mean of the raw blocks either side, the row's figure the median of those pair
    ratios, for 8 and for 32 units (``--units N`` names others). Beside it, from the same
    blocks: tmclsh's N units over one unit running the same script (wall), and the CPU per
    line per unit of tmclsh's run against the raw processes' (children's rusage, start-up
    subtracted with a 1-line run of each: (long - short) / (N x (lines - 1))). The
    simulators' own CPU is in neither figure (they are the modules)."""
    import resource

    counts = _unit_counts(args)
    pairs = args.pairs or args.rounds
    tmp = Path(args.state_dir)

    def script(name: str, lines: int) -> Path:
        path = tmp / f"units-{name}.tmcl"
        path.write_text("".join(SCRIPT_LINES[i % len(SCRIPT_LINES)][0] + "\n"
                                for i in range(lines)))
        return path

    long_script, short_script = script("long", UNIT_LINES), script("short", 1)
    frames = [frame.hex() for _, frame in SCRIPT_LINES]

    def children_cpu() -> float:
        kids = resource.getrusage(resource.RUSAGE_CHILDREN)
        return kids.ru_utime + kids.ru_stime

    def tmclsh_run(paths: list[str], script_: Path) -> tuple[float, float]:
        """One tmclsh process running ``script_`` on every path's module: wall and CPU s."""
        argv = tmclsh_cmd(*(a for p in paths for a in ("--port", p)), "-m", args.module,
                          "-f", str(script_))
        with open(tmp / "units.out", "w") as out:
            c0, t0 = children_cpu(), time.perf_counter()
            proc = subprocess.run(argv, stdout=out, stderr=subprocess.PIPE, text=True,
                                  env=tree_env(args), cwd=args.state_dir, timeout=600)
            took, used = time.perf_counter() - t0, children_cpu() - c0
        if proc.returncode != 0:
            raise RuntimeError(f"units run failed: {proc.stderr[-500:]}")
        return took, used

    def raw_run(paths: list[str], lines: int) -> tuple[float, float]:
        """One raw pyserial process per path, all started together, timed together."""
        outs = [open(tmp / f"units-raw-{i}.out", "w") for i in range(len(paths))]
        try:
            c0, t0 = children_cpu(), time.perf_counter()
            procs = [subprocess.Popen([sys.executable, "-c", RAW_UNITS_SCRIPT, p, str(lines),
                                       *frames], stdout=out, stderr=subprocess.PIPE,
                                      text=True, cwd=args.state_dir)
                     for p, out in zip(paths, outs)]
            errors = [proc.communicate(timeout=600)[1] for proc in procs]
            took, used = time.perf_counter() - t0, children_cpu() - c0
        finally:
            for out in outs:
                out.close()
        for proc, err in zip(procs, errors):
            if proc.returncode != 0:
                raise RuntimeError(f"raw units run failed: {err[-500:]}")
        return took, used

    sims = [SimProcess(args.module, baud=BAUD) for _ in range(max(counts))]
    result: dict = {"benchmark": "units", "lines": UNIT_LINES,
                    "load_start": round(os.getloadavg()[0], 2)}
    rows: list[dict] = []
    try:
        for n in counts:
            paths = [s.path for s in sims[:n]]
            say(f"units {n}: {pairs} pairs (raw, tmclsh, ..., raw) of {n} raw pyserial "
                f"processes run together and tmclsh with {n} units, {UNIT_LINES}-line and "
                f"1-line scripts, simulators paced at {BAUD} baud; {load_note()}")
            tmclsh_run(paths, short_script)  # warm the caches
            raw_run(paths, 1)

            def raw_block(i: int, paths: list[str] = paths) -> Block:
                jobs = ("short", "long") if i % 2 == 0 else ("long", "short")
                got = {job: raw_run(paths, UNIT_LINES if job == "long" else 1)
                       for job in jobs}
                return {"s": got["long"][0], "lines_s": got["long"][0] - got["short"][0],
                        "cpu": got["long"][1], "cpu_short": got["short"][1]}

            def path_block(i: int, paths: list[str] = paths) -> Block:
                jobs = [("all", long_script), ("one", long_script), ("all", short_script)]
                got = {job: tmclsh_run(paths if job[0] == "all" else paths[:1], job[1])
                       for job in (jobs if i % 2 == 0 else jobs[::-1])}
                long_, short = got[("all", long_script)], got[("all", short_script)]
                return {"s": long_[0], "lines_s": long_[0] - short[0],
                        "one_s": got[("one", long_script)][0], "cpu": long_[1],
                        "cpu_short": short[1]}

            raws, tms = bracket(pairs, raw_block, path_block, args.verbose)
            walls = spread(pair_ratios(raws, tms, "s", "s"))
            lines = spread(pair_ratios(raws, tms, "lines_s", "lines_s"))
            over_one = spread([p["s"] / p["one_s"] for p in tms])
            per_line = n * (UNIT_LINES - 1)
            cpu_raw = (median_of(raws, "cpu") - median_of(raws, "cpu_short")) / per_line
            cpu_tm = (median_of(tms, "cpu") - median_of(tms, "cpu_short")) / per_line
            load = round(os.getloadavg()[0], 2)
            say(f"  {n} raw processes together {median_of(raws, 's'):.3f} s, tmclsh {n} units "
                f"{median_of(tms, 's'):.3f} s: {show_spread(walls, len(tms))}")
            say(f"  start-up left out (a 1-line run's wall subtracted from each): "
                f"{show_spread(lines, len(tms))}")
            say(f"  {n} units over one unit, wall: {show_spread(over_one, len(tms))}; one "
                f"unit {median_of(tms, 'one_s'):.3f} s")
            say(f"  CPU per line per unit: raw process {cpu_raw * 1e6:.1f} us, tmclsh "
                f"{cpu_tm * 1e6:.1f} us; {load_note()}")
            figures = {"units": n, "pairs": len(tms),
                       "raw_s": round(median_of(raws, "s"), 3),
                       "tmclsh_s": round(median_of(tms, "s"), 3), **rounded(walls),
                       "one_unit_s": round(median_of(tms, "one_s"), 3),
                       **rounded(lines, "lines_"), **rounded(over_one, "over_one_"),
                       "cpu_us_raw": round(cpu_raw * 1e6, 1),
                       "cpu_us_tmclsh": round(cpu_tm * 1e6, 1), "load": load}
            del figures["ratio"]  # the row's value
            rows.append(row(figures, f"{n} units on {n} ptys, {UNIT_LINES} lines at {BAUD} "
                                     f"baud, wall", walls["ratio"], "x raw processes",
                            UNITS_TARGET, f"start-up left out {lines['ratio']:.2f}x; "
                                          f"{over_one['ratio']:.2f}x one unit"))
    finally:
        for s in sims:
            s.close()
    result.update(rows[0])
    result["rows"] = rows[1:]
    return result


# -- configuration backup -----------------------------------------------------------------------

@benchmark("save", ".save of a whole module (one GAP/GGP per parameter) vs the same reads raw")
def bench_save(args: argparse.Namespace) -> dict:
    """Seconds for ``.save FILE`` of the module (every readable axis parameter of every
    motor, every global parameter, one request each, the file written atomically), beside
    the raw floor: exactly the same GAP/GGP frames written and their 9-byte replies read with
    bare pyserial against the same pty-served simulator (its own process), in the same run.
    The port is opened at 115200 baud (a pty does not pace bytes, so this measures the
    software path, not the line rate: at 9600 baud each 18-byte round trip adds ~19 ms of
    wire time). Rounds alternate raw and tmclsh; figures are the best round (other work on
    the machine only adds time) and the median round.
    """
    import io
    import tempfile

    import serial

    LineClient = client_class()
    load = tm("tmclsh.tmcl.modules").load
    Request = tm("tmclsh.tmcl.frames").Request
    clone = shell_module("tmclsh.shell.features.clone")
    READ, readable_slots = clone.READ, clone.readable_slots
    Output = shell_module("tmclsh.shell.render").Output
    Session = shell_module("tmclsh.shell.lang.session").Session
    open_serial = tm("tmclsh.link").open_serial

    module = load(args.module)
    frames = [Request(1, READ[kind], number, index, 0).to_bytes()
              for kind, _, number, index in readable_slots(module)]
    times: dict[str, list[float]] = {"raw": [], "save": []}
    tmp = Path(tempfile.mkdtemp(prefix="tmclsh-bench-"))
    target = tmp / "backup.tmcl"

    def raw_round(path: str) -> None:
        ser = serial.serial_for_url(path, baudrate=115200, timeout=1.0)
        try:
            t0 = time.perf_counter()
            for f in frames:
                ser.write(f)
                reply = ser.read(9)
                assert len(reply) == 9, reply
            times["raw"].append(time.perf_counter() - t0)
        finally:
            ser.close()

    def save_round(path: str) -> None:
        client = LineClient(open_serial(path, 115200), module=args.module, timeout=1.0)
        client.version = module.version_string  # as after the connect banner: no 136 here
        try:
            session = Session(client, Output(json_mode=True))
            stdout, sys.stdout = sys.stdout, io.StringIO()
            try:
                t0 = time.perf_counter()
                session.run_line(f".save {target} --yes")  # the same file each round
                times["save"].append(time.perf_counter() - t0)
            finally:
                sys.stdout = stdout
            # (one more read where an answer was the one before it, byte for byte: it may
            # have been a copy, Client._judge; the ratio pays for it)
            assert client.stats["sent"] == len(frames) + client.stats["judged"] \
                and client.stats["timeouts"] == 0, client.stats
        finally:
            client.close()

    try:
        with SimProcess(args.module) as sim:
            say(f"save: {args.rounds} round(s) of a {args.module} backup ({len(frames)} reads) "
                f"on {sim.path} at 115200 baud")
            for rnd in range(args.rounds):
                order = (raw_round, save_round) if rnd % 2 == 0 else (save_round, raw_round)
                for fn in order:
                    fn(sim.path)
    finally:
        for f in tmp.iterdir():
            f.unlink()
        tmp.rmdir()
    best = {k: min(v) for k, v in times.items()}
    med = {k: statistics.median(v) for k, v in times.items()}
    result = {
        "benchmark": "save",
        "module": args.module,
        "transactions": len(frames),
        "rounds": args.rounds,
        "save_s": round(best["save"], 4),
        "raw_s": round(best["raw"], 4),
        "save_median_s": round(med["save"], 4),
        "raw_median_s": round(med["raw"], 4),
        "ratio": round(best["save"] / best["raw"], 3),
        "wire_s_at_9600": round(len(frames) * 18 * 10 / 9600, 2),
    }
    say(f"  .save ({len(frames)} GAP/GGP + file) : {best['save'] * 1000:>7.1f} ms "
        f"(median {med['save'] * 1000:.1f} ms)")
    say(f"  raw pyserial, same frames     : {best['raw'] * 1000:>7.1f} ms "
        f"(median {med['raw'] * 1000:.1f} ms)")
    say(f"  ratio save / raw              : {result['ratio']:.2f}   (wire time alone at 9600 "
        f"baud: {result['wire_s_at_9600']} s)")
    return result


# -- listening in: monitor and bridge --------------------------------------------------------

# a 1 Mbit/s CAN bus carrying nothing but TMCL frames (7 data bytes, standard ids): 111 bits
# a frame without stuff bits (SOF, id, control, 56 data bits, CRC, ACK, EOF, interframe
# space), so at most this many frames a second
SATURATED_BUS = 1_000_000 // 111
MONITOR_TARGET_RATIO = 2.0  # issue 34: at most twice python-can's LogReader on the same file


def _bus_session(n: int) -> list:
    """``n`` CAN frames of a PLC polling a moving axis through python-can's ``Message``
    (built here, not by the measured tree): GAP 1 (position), GAP 3 (speed), GIO 0, 0 and
    a SAP now and then, each answered 0.3 ms later; positions and speeds change, so the
    replies are not the same few frames over and over."""
    import can

    out, t = [], 1_700_000_000.0
    polls = [(6, 1), (6, 3), (15, 0), (5, 4)]
    i = 0
    while len(out) < n:
        cmd, typ = polls[i % len(polls)]
        value = 1000 if cmd == 5 else 0
        reply = {1: i * 37, 3: 51200 - i % 700, 0: i & 1}.get(typ, 1000) if cmd != 5 else 1000
        out.append(can.Message(timestamp=t, arbitration_id=1, is_extended_id=False,
                               data=struct.pack(">BBBi", cmd, typ, 0, value)))
        out.append(can.Message(timestamp=t + 0.0003, arbitration_id=2, is_extended_id=False,
                               data=struct.pack(">BBBi", 1, 100, cmd, reply)))
        t += 0.001
        i += 1
    return out[:n]


@benchmark("monitor-log", "tmclsh monitor --log, text and --json, vs python-can's LogReader "
                          "reading the same log, .asc/.blf/candump (target <= 2x)")
def bench_monitor_log(args: argparse.Namespace) -> dict:
    """Frames a second ``tmclsh monitor --log FILE`` shows, for people and with ``--json``
    (in process, the output written to /dev/null), beside the floor: python-can's
    ``LogReader`` reading the same file and doing nothing with the frames, in the same run,
    rounds alternating. Logs of ``--count`` x 50 frames in three formats python-can writes
    (.blf, the compact binary one; .asc, the common text one; candump's .log). The table's
    row is the worst format and output's best time over python-can's own (issue 34's
    target: at most 2x); each one's ratio, by the clock and by CPU time (steadier on a
    busy machine), and its frames a second are in the note."""
    import contextlib

    import can

    cli = tm("tmclsh.cli.main")
    n = args.count * 50
    frames = _bus_session(n)
    result: dict = {"benchmark": "monitor-log", "frames": n,
                    "saturated_bus_per_s": SATURATED_BUS}
    outputs = {"text": [], "json": ["--json"]}
    with tempfile.TemporaryDirectory(prefix="tmclsh-bench-") as tmp:
        for suffix in (".blf", ".asc", ".log"):
            path = str(Path(tmp) / f"bus{suffix}")
            with can.Logger(path) as log:
                for m in frames:
                    log.on_message_received(m)
            cpu: dict[str, list[float]] = {}

            def timed(name: str, fn: Callable[[], None]) -> Callable[[], float]:
                def run() -> float:
                    c0, t0 = time.process_time(), time.perf_counter()
                    fn()
                    took = time.perf_counter() - t0
                    cpu.setdefault(name, []).append((time.process_time() - c0) / n * 1e6)
                    return took / n * 1e6
                return run

            def floor() -> None:
                count = sum(1 for _ in can.LogReader(path))
                assert count == n, count

            def monitor(extra: list[str]) -> Callable[[], None]:
                def run() -> None:
                    with open(os.devnull, "w") as sink, contextlib.redirect_stdout(sink), \
                            contextlib.redirect_stderr(sink):
                        rc = cli.main(["monitor", "--log", path, *extra])
                    assert rc == 0
                return run

            if suffix == ".blf":  # (imports and first calls outside the measured rounds)
                for extra in outputs.values():
                    monitor(extra)()
            runs = {"python-can": timed("python-can", floor)}
            runs.update({out: timed(out, monitor(extra)) for out, extra in outputs.items()})
            say(f"monitor-log: {args.rounds} round(s) of {n} frames in {suffix}")
            best = alternate(args.rounds, runs, args.verbose)
            key = suffix.lstrip(".")
            result[f"{key}_floor_us"] = round(best["python-can"], 3)
            for out in outputs:
                per_s = 1e6 / best[out]
                ratio = best[out] / best["python-can"]
                cpu_ratio = min(cpu[out]) / min(cpu["python-can"])
                say(f"  {out:<4}: python-can reads a frame in {best['python-can']:.2f} us; "
                    f"tmclsh monitor shows one in {best[out]:.2f} us: {per_s:,.0f} frames/s, "
                    f"{per_s / SATURATED_BUS:.1f}x a saturated 1 Mbit/s bus, {ratio:.2f}x "
                    f"python-can's own reading ({cpu_ratio:.2f}x by CPU time)")
                result.update({f"{key}_{out}_us": round(best[out], 3),
                               f"{key}_{out}_per_s": round(per_s),
                               f"{key}_{out}_ratio": round(ratio, 3),
                               f"{key}_{out}_cpu_ratio": round(cpu_ratio, 3)})
    say(f"  ({load_note()})")
    cases = [f"{k}_{out}" for k in ("asc", "blf", "log") for out in outputs]
    worst = max(cases, key=lambda c: result[f"{c}_ratio"])
    return row(result, "monitor --log (text, --json) vs python-can's LogReader",
               result[f"{worst}_ratio"], "x LogReader", MONITOR_TARGET_RATIO,
               "the worst of " + ", ".join(
                   f"{c.replace('log_', 'candump_')} {result[f'{c}_ratio']}x "
                   f"(cpu {result[f'{c}_cpu_ratio']}x)" for c in cases))


REPLAY_TARGET_US = 50.0  # the figure: at least 20,000 exchanges a second


@benchmark("replay", "tmclsh replay's engine: exchanges/s sent again to the in-process "
                     "simulator (target >= 20,000/s)")
def bench_replay(args: argparse.Namespace) -> dict:
    """Exchanges a second ``ops.replay.replay`` sends again and compares, against the
    in-process simulator, beside the floor: the same requests through ``Client.request``
    in a plain loop, rounds alternating. The capture (``--count`` x 5 exchanges of GAP, GGP
    and GIO, a serial capture as ``monitor -o`` writes it) is read once, outside the
    timing; the row is microseconds an exchange (the target, 50 us, is 20,000/s)."""
    replay = tm("tmclsh.ops.replay")
    capture_mod = tm("tmclsh.ops.capture")
    connect = tm("tmclsh.client.connect").connect
    n = args.count * 5
    client = connect(sim=args.module)
    lines = ["GAP 4, 0", "GAP 1, 0", "GIO 0, 0"]
    with tempfile.TemporaryDirectory(prefix="tmclsh-bench-") as tmp:
        path = str(Path(tmp) / "session.txt")
        writer = capture_mod.CaptureWriter(path)
        remove = client.add_tracer(lambda d, raw, _: writer.write(time.time(), bytes(raw), d)
                                   if d in ("tx", "rx") else None)
        for i in range(n):
            client.execute(lines[i % len(lines)])
        remove()
        writer.close()
        capture = replay.read_capture(path)
    assert len(capture.exchanges) == n, len(capture.exchanges)
    requests = [replay.aim(client, c) for c in capture.exchanges]

    def floor() -> float:
        request = client.request
        t0 = time.perf_counter()
        for r in requests:
            request(r)
        return (time.perf_counter() - t0) / n * 1e6

    def engine() -> float:
        t0 = time.perf_counter()
        result = replay.replay(client, capture)
        took = time.perf_counter() - t0
        assert not result.differences, result.differences[:3]
        return took / n * 1e6

    say(f"replay: {args.rounds} round(s) of {n} exchanges")
    try:
        best = alternate(args.rounds, {"request": floor, "replay": engine}, args.verbose)
    finally:
        client.close()
    per_s = 1e6 / best["replay"]
    floor_per_s = 1e6 / best["request"]
    target_per_s = 1e6 / REPLAY_TARGET_US
    say(f"  Client.request {best['request']:.2f} us an exchange; replay {best['replay']:.2f} "
        f"us: {per_s:,.0f} exchanges/s (target {target_per_s:,.0f}/s)")
    result = {"benchmark": "replay", "exchanges": n, "floor_us": round(best["request"], 3),
              "replay_us": round(best["replay"], 3), "per_s": round(per_s),
              "floor_per_s": round(floor_per_s), "target_per_s": round(target_per_s)}
    return row(result, "replay to the simulator, per exchange", best["replay"], "us",
               REPLAY_TARGET_US, f"{per_s:,.0f}/s, target {target_per_s:,.0f}/s; floor "
               f"Client.request alone {best['request']:.1f} us ({floor_per_s:,.0f}/s)")


BRIDGE_TARGET_US = 200.0  # the figure: at most 0.2 ms added per exchange


@benchmark("bridge", "GAP round trip through tmclsh bridge --pty vs straight to the simulator "
                     "(target: <= 200 us added)")
def bench_bridge(args: argparse.Namespace) -> dict:
    """Microseconds ``tmclsh bridge --pty --port SIM`` (its own process, its lines to
    /dev/null) adds to a raw pyserial GAP round trip, beside the floor: the same raw
    pyserial round trip straight to a simulator, measured side by side. Two simulators of
    the same module in their own processes (the bridge holds one pty, the floor reads the
    other); short alternating blocks (``bracket``), the figure is the median over pairs of
    the bridge block's median minus the mean of the raw blocks' medians either side."""
    block = max(50, args.count // 10)
    pairs = args.pairs or 10 * args.rounds
    frame = gap_frame()
    with SimProcess(args.module) as direct, SimProcess(args.module) as behind:
        with open(os.devnull, "w") as sink:
            proc = subprocess.Popen(tmclsh_cmd("bridge", "--pty", "--port", behind.path,
                                               "--baud", str(BAUD)),
                                    stdout=subprocess.PIPE, stderr=sink, text=True,
                                    env=tree_env(args), cwd=args.state_dir)
            try:
                assert proc.stdout is not None
                endpoint = proc.stdout.readline().strip()
                if not endpoint:
                    raise RuntimeError("the bridge did not start")
                # the bridge's lines are read and dropped (a pipe nobody reads fills up)
                drain = subprocess.Popen(["cat"], stdin=proc.stdout, stdout=sink)
                with RawPort(direct.path) as raw, RawPort(endpoint) as bridged:
                    raw.round_trips([frame], 200)
                    bridged.round_trips([frame], 200)

                    def raw_block(_: int) -> Block:
                        return {"us": statistics.median(raw.round_trips([frame], block)) * 1e6}

                    def bridge_block(_: int) -> Block:
                        return {"us": statistics.median(
                            bridged.round_trips([frame], block)) * 1e6}

                    say(f"bridge: {pairs} pairs of {block} GAP round trips, raw | bridged "
                        f"({load_note()})")
                    raws, paths = bracket(pairs, raw_block, bridge_block, args.verbose)
            finally:
                proc.terminate()
                proc.wait(10)
                drain.wait(10)
    added = [p["us"] - (a["us"] + b["us"]) / 2 for p, a, b in zip(paths, raws, raws[1:])]
    med = statistics.median(added)
    floor = median_of(raws, "us")
    say(f"  straight to the simulator {floor:.1f} us, through the bridge "
        f"{median_of(paths, 'us'):.1f} us: {med:.1f} us added (pairs {min(added):.1f}.."
        f"{max(added):.1f})")
    return row({"benchmark": "bridge", "floor_us": round(floor, 1),
                "bridged_us": round(median_of(paths, "us"), 1),
                "added_us_min": round(min(added), 1), "added_us_max": round(max(added), 1)},
               "bridge: added per GAP exchange", med, "us", BRIDGE_TARGET_US,
               f"{floor:.0f} us straight to the simulator")


# a minimal forwarder, the floor a bridge is held to (issue 34): a pty for the master, the
# module's pty, one select loop copying bytes both ways and nothing else
FORWARDER = r"""
import os, select, sys, tty
m, s = os.openpty()
tty.setraw(s)
print(os.ttyname(s), flush=True)
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)
tty.setraw(fd)
while True:
    for src in select.select([m, fd], [], [])[0]:
        os.write(fd if src == m else m, os.read(src, 4096))
"""
FORWARDER_RATIO = 2.0  # the target: the bridge adds at most twice what it adds


def _started(proc: subprocess.Popen, what: str) -> str:
    assert proc.stdout is not None
    line = proc.stdout.readline().strip()
    if not line:
        raise RuntimeError(f"the {what} did not start")
    return line


def _p99(values: list[float]) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]


@benchmark("bridge-forwarder", "added latency (median, p99) of tmclsh bridge --pty vs a minimal "
                               "Python select-loop forwarder, same run (target: <= 2x)")
def bench_bridge_forwarder(args: argparse.Namespace) -> dict:
    """What ``tmclsh bridge`` (its lines read and dropped) adds to a raw pyserial GAP round
    trip, against what a minimal select-loop forwarder in Python adds, each in front of its
    own simulator, with blocks straight to a third simulator around each (``bracket``).
    Median: a path block's median minus the mean of the raw blocks' either side, the median
    of that over the pairs (this machine's floor drifts within seconds). p99: of all the
    round trips of a path over the run, minus that of all the raw ones (a block of 200 has
    two round trips beyond its p99: a difference of two such blocks is mostly noise)."""
    block = max(50, args.count // 10)
    pairs = args.pairs or 4 * args.rounds
    frame = gap_frame()
    pooled: dict[str, list[float]] = {"raw": [], "forwarder": [], "bridge": []}
    with SimProcess(args.module) as direct, SimProcess(args.module) as fsim, \
            SimProcess(args.module) as bsim, open(os.devnull, "w") as sink:
        fwd = subprocess.Popen([sys.executable, "-c", FORWARDER, fsim.path],
                               stdout=subprocess.PIPE, stderr=sink, text=True)
        bridge = subprocess.Popen(tmclsh_cmd("bridge", "--pty", "--port", bsim.path, "--baud",
                                             str(BAUD)), stdout=subprocess.PIPE, stderr=sink,
                                  text=True, env=tree_env(args), cwd=args.state_dir)
        drain = None
        try:
            fwd_path, bridge_path = _started(fwd, "forwarder"), _started(bridge, "bridge")
            drain = subprocess.Popen(["cat"], stdin=bridge.stdout, stdout=sink)
            with RawPort(direct.path) as raw, RawPort(fwd_path) as f, \
                    RawPort(bridge_path) as b:
                for port in (raw, f, b):
                    port.round_trips([frame], 200)

                def raw_block(_: int) -> Block:
                    lat = raw.round_trips([frame], block)
                    pooled["raw"] += lat
                    return {"us": statistics.median(lat) * 1e6, "p99": _p99(lat) * 1e6}

                def paths_block(_: int) -> Block:
                    out = {}
                    for name, port in (("forwarder", f), ("bridge", b)):
                        lat = port.round_trips([frame], block)
                        pooled[name] += lat
                        out[name] = statistics.median(lat) * 1e6
                        out[name + "-p99"] = _p99(lat) * 1e6
                    return out

                say(f"bridge-forwarder: {pairs} pairs of {block} GAP round trips, raw | "
                    f"forwarder, bridge ({load_note()})")
                raws, paths = bracket(pairs, raw_block, paths_block, args.verbose)
        finally:
            for proc in (bridge, fwd):
                proc.terminate()
                proc.wait(10)
            if drain is not None:
                drain.wait(10)
    added = {name: statistics.median(p[name] - (a["us"] + c["us"]) / 2
                                     for p, a, c in zip(paths, raws, raws[1:]))
             for name in ("forwarder", "bridge")}
    p99 = {name: (_p99(pooled[name]) - _p99(pooled["raw"])) * 1e6
           for name in ("forwarder", "bridge")}
    ratio = added["bridge"] / max(added["forwarder"], 1.0)
    ratio99 = p99["bridge"] / max(p99["forwarder"], 1.0)
    say(f"  added, median: forwarder {added['forwarder']:.1f} us, bridge "
        f"{added['bridge']:.1f} us ({ratio:.2f}x); p99: forwarder {p99['forwarder']:.1f} us, "
        f"bridge {p99['bridge']:.1f} us ({ratio99:.2f}x)")
    result = {"benchmark": "bridge-forwarder",
              "forwarder_added_us": round(added["forwarder"], 1),
              "bridge_added_us": round(added["bridge"], 1),
              "forwarder_added_p99_us": round(p99["forwarder"], 1),
              "bridge_added_p99_us": round(p99["bridge"], 1)}
    result["rows"] = [row({}, "bridge: added p99 / a select-loop forwarder's", ratio99, "x",
                          FORWARDER_RATIO, f"{p99['bridge']:.0f} us vs "
                                           f"{p99['forwarder']:.0f} us")]
    return row(result, "bridge: added median / a select-loop forwarder's", ratio, "x",
               FORWARDER_RATIO, f"{added['bridge']:.0f} us vs {added['forwarder']:.0f} us")


@benchmark("bridge-unread", "timeouts the other master sees while tmclsh bridge's stdout is "
                            "not read, for --count exchanges (target: 0)")
def bench_bridge_unread(args: argparse.Namespace) -> dict:
    """``tmclsh bridge --pty --json`` with its stdout a pipe nobody reads (a paused pager):
    round trips of a raw pyserial master through it, and the replies that did not come
    within a second (after three, the rest are not tried); the lines the bridge dropped,
    from its summary once the pipe is read at the end."""
    n = args.count
    frame = gap_frame()
    with SimProcess(args.module) as behind:
        bridge = subprocess.Popen(tmclsh_cmd("bridge", "--pty", "--port", behind.path, "--baud",
                                             str(BAUD), "--json"), stdout=subprocess.PIPE,
                                  stderr=subprocess.DEVNULL, text=True, env=tree_env(args),
                                  cwd=args.state_dir)
        timeouts = done = 0
        try:
            endpoint = _started(bridge, "bridge")
            with RawPort(endpoint) as port:
                port.ser.timeout = 1.0
                say(f"bridge-unread: {n} exchanges, the bridge's stdout not read ({load_note()})")
                for done in range(1, n + 1):
                    port.ser.write(frame)
                    if len(port.ser.read(9)) < 9:
                        timeouts += 1
                        if timeouts >= 3:
                            break
            bridge.terminate()
            out, _ = bridge.communicate(timeout=60)
        finally:
            if bridge.poll() is None:
                bridge.kill()
                bridge.wait()
    try:
        summary = json.loads(out.splitlines()[-1])["summary"]
    except (ValueError, KeyError, IndexError):
        summary = {}
    dropped = summary.get("dropped_lines")
    say(f"  {done} exchanges, {timeouts} timeouts; the bridge dropped {dropped} lines and "
        f"counted {summary.get('requests')} requests")
    return row({"benchmark": "bridge-unread", "exchanges": done, "timeouts": timeouts,
                "dropped_lines": dropped},
               f"bridge, stdout not read: timeouts in {n} exchanges", timeouts, "", 0,
               f"{dropped} lines dropped, counted")


# -- entry point ------------------------------------------------------------------------------

def print_table(results: list[dict], tree: Path) -> None:
    rows = [x for r in results if "row" in r for x in (r, *r.get("rows", ()))]
    if not rows:
        return
    width = max(len(r["row"]) for r in rows)
    print(f"\n{'path (' + str(tree) + ')':<{width}}  {'measured':>10}  {'target':>8}  unit")
    for r in rows:
        target = "-" if r["target"] == float("inf") else f"<= {r['target']:g}"
        mark = "" if r["target"] == float("inf") else ("  ok" if r["ok"] else "  MISSED")
        note = f"  ({r['note']})" if r.get("note") else ""
        print(f"{r['row']:<{width}}  {r['value']:>10.3f}  {target:>8}  {r['unit']}{mark}{note}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("names", nargs="*", metavar="NAME", help="benchmarks to run (default: all)")
    p.add_argument("--count", type=int, default=2000,
                   help="round trips per round (default 2000; a tenth of that per block in the "
                        "client rows, twice that many lines in the script rows)")
    p.add_argument("--rounds", type=int, default=5, help="rounds per benchmark (default 5)")
    p.add_argument("--pairs", type=int, default=0,
                   help="raw/path block pairs of the client, script, upload and units rows "
                        "(default: 20x --rounds for the client rows; 4x for the script rows, "
                        "fewer once 35 s have passed; 6x for the upload row; --rounds for the "
                        "units row)")
    p.add_argument("--module", default="TMCM-1311", help="simulated module (default TMCM-1311)")
    p.add_argument("--units", type=int, action="append", metavar="N",
                   help="the units row's unit counts, once each (default: 8 and 32)")
    p.add_argument("--tree", type=Path, default=ROOT,
                   help="the tmclsh checkout to measure (default: this one)")
    p.add_argument("-v", "--verbose", action="store_true", help="per-round figures")
    p.add_argument("--json", action="store_true", help="one JSON object per benchmark on stdout")
    p.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    args = p.parse_args(argv)
    if args.list:
        for name, (_, text) in BENCHMARKS.items():
            print(f"{name:<12} {text}")
        return 0
    unknown = [n for n in args.names if n not in BENCHMARKS]
    if unknown:
        p.error(f"unknown benchmark(s) {', '.join(unknown)}; known: {', '.join(BENCHMARKS)}")
    if args.count < 1 or args.rounds < 1 or args.pairs < 0:
        p.error("--count and --rounds must be at least 1, --pairs at least 0")
    if any(n < 1 for n in args.units or ()):
        p.error("--units must be at least 1")
    args.tree = args.tree.resolve()
    sys.path.insert(0, str(args.tree))
    import compileall

    # as installed: byte-compiled (a checkout run with PYTHONDONTWRITEBYTECODE never is)
    compileall.compile_dir(str(args.tree / "tmclsh"), quiet=1)
    results = []
    with tempfile.TemporaryDirectory(prefix="tmclsh-bench-") as state:
        args.state_dir = state
        for name in args.names or list(BENCHMARKS):
            fn, _ = BENCHMARKS[name]
            result = fn(args)
            results.append(result)
            if args.json:
                print(json.dumps(result), flush=True)
    if not args.json:
        print_table(results, args.tree)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
