#!/usr/bin/env python3
"""tmclsh benchmarks.

    python scripts/bench.py                 # run every benchmark
    python scripts/bench.py client          # run one (or several) by name
    python scripts/bench.py client --count 200 --rounds 1   # a quick smoke run
    python scripts/bench.py --list

Each benchmark is a function registered in ``BENCHMARKS`` with ``@benchmark(name, help)``.
It gets the parsed arguments (``count``, ``rounds``, ``module``, ``json``) and returns a dict
of results; ``main`` prints the dict (one JSON object per line with ``--json``) and the
benchmark prints its own human-readable lines to stderr.

These are measurements, not tests: nothing here fails on a slow machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

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

class SimProcess:
    """``tmclsh sim --pty`` in a subprocess (its own interpreter, so it does not share the
    benchmark's GIL); ``path`` is the pty to open."""

    def __init__(self, module: str = "TMCM-1311", address: int = 1):
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tmclsh", "sim", "--pty", "-m", module,
             "--address", str(address)],
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


def raw_latencies(path: str, frame: bytes, warm: int, count: int) -> list[float]:
    """Seconds per raw pyserial round trip (write ``frame``, read the 9-byte reply), after
    ``warm`` untimed ones: the floor a tmclsh feature is compared with."""
    import serial

    clock = time.perf_counter
    ser = serial.serial_for_url(path, baudrate=9600, timeout=1.0)
    try:
        for _ in range(warm):
            ser.write(frame)
            ser.read(9)
        out = []
        for _ in range(count):
            t0 = clock()
            ser.write(frame)
            reply = ser.read(9)
            out.append(clock() - t0)
    finally:
        ser.close()
    if len(reply) != 9:
        raise RuntimeError(f"raw read timed out (got {reply!r})")
    return out


# -- client round trips -----------------------------------------------------------------------

@benchmark("client", "GAP round trips/s: tmclsh client vs raw pyserial, same pty-served simulator")
def bench_client(args: argparse.Namespace) -> dict:
    """GAP round trips per second through the client, beside raw pyserial writes and reads of
    the same 9-byte frames against the same simulator, in the same run.

    The simulator runs in its own process (``tmclsh sim --pty``). Rounds alternate the
    order of raw and client so both see the same machine load, and every round trip is timed
    on its own. The headline figures are the best round's median for each: other work on
    the machine only ever adds time, and a round it disturbed says nothing about the client
    (``*_all_us`` are the medians over all rounds, for comparison). Two more figures explain
    the result: the raw descriptor floor (``os.write``/``select``/
    ``os.read``, no pyserial) and the simulator's own cost per request (``Simulator.write``
    and ``read`` in process, no pty): when that is most of the raw round trip, the simulator
    is the bottleneck for both.
    """
    import select

    import serial

    from tmclsh.client import Client
    from tmclsh.protocol import Reply, Request
    from tmclsh.sim import Simulator
    from tmclsh.transport import open_serial

    count, rounds = args.count, args.rounds
    frame = Request(1, 6, 1, 0, 0).to_bytes()  # GAP 1, 0 (actual position)
    warm = min(200, count)
    clock = time.perf_counter
    lat: dict[str, list[float]] = {"raw": [], "fd": [], "client": []}

    def run_raw(path: str) -> None:
        ser = serial.serial_for_url(path, baudrate=9600, timeout=1.0)
        try:
            for _ in range(warm):
                ser.write(frame)
                ser.read(9)
            out = lat["raw"]
            for _ in range(count):
                t0 = clock()
                ser.write(frame)
                reply = ser.read(9)
                out.append(clock() - t0)
            assert len(reply) == 9 and Reply.from_bytes(reply).opcode == 6, reply
        finally:
            ser.close()

    def run_fd(path: str) -> None:
        ser = serial.serial_for_url(path, baudrate=9600, timeout=1.0)
        fd = ser.fd
        try:
            out = lat["fd"]
            for i in range(warm + count):
                t0 = clock()
                os.write(fd, frame)
                reply = b""
                while len(reply) < 9:
                    if not select.select((fd,), (), (), 1.0)[0]:
                        raise RuntimeError("raw descriptor read timed out")
                    reply += os.read(fd, 9 - len(reply))
                if i >= warm:
                    out.append(clock() - t0)
            assert Reply.from_bytes(reply).opcode == 6, reply
        finally:
            ser.close()

    def run_client(path: str) -> None:
        client = Client(open_serial(path), module=args.module, timeout=1.0)
        try:
            for _ in range(warm):
                client.send(6, 1, 0)
            out = lat["client"]
            for _ in range(count):
                t0 = clock()
                r = client.send(6, 1, 0)
                out.append(clock() - t0)
            assert r is not None and r.opcode == 6 and r.ok, r
            assert client.stats["timeouts"] == 0, client.stats
        finally:
            client.close()

    runs = {"raw": run_raw, "fd": run_fd, "client": run_client}
    rounds_med: dict[str, list[float]] = {name: [] for name in runs}
    with SimProcess(args.module) as sim:
        say(f"client: {rounds} round(s) of {count} GAP round trips on {sim.path} "
            "(simulator in a subprocess)")
        for rnd in range(rounds):
            order = list(runs) if rnd % 2 == 0 else list(reversed(runs))
            for name in order:
                before = len(lat[name])
                runs[name](sim.path)
                rounds_med[name].append(statistics.median(lat[name][before:]) * 1e6)
                if args.verbose:
                    say(f"  round {rnd + 1} {name:<6}: median {rounds_med[name][-1]:.1f} us")

    # the simulator alone: what one request costs it, without pty and pyserial
    simulator = Simulator(args.module)
    try:
        for _ in range(warm):
            simulator.write(frame)
            simulator.read(0)
        sim_lat = []
        for _ in range(count):
            t0 = clock()
            simulator.write(frame)
            out = simulator.read(0)
            sim_lat.append(clock() - t0)
        assert len(out) == 9, out
    finally:
        simulator.close()

    med = {k: min(v) for k, v in rounds_med.items()}
    pooled = {k: statistics.median(v) * 1e6 for k, v in lat.items()}
    sim_us = statistics.median(sim_lat) * 1e6
    result = {
        "benchmark": "client",
        "count": count,
        "rounds": rounds,
        "raw_per_s": round(1e6 / med["raw"]),
        "client_per_s": round(1e6 / med["client"]),
        "raw_us": round(med["raw"], 1),
        "client_us": round(med["client"], 1),
        "overhead_pct": round((med["client"] / med["raw"] - 1) * 100, 1),
        "target_pct": 30,
        "raw_all_us": round(pooled["raw"], 1),
        "client_all_us": round(pooled["client"], 1),
        "overhead_all_pct": round((pooled["client"] / pooled["raw"] - 1) * 100, 1),
        "fd_floor_us": round(med["fd"], 1),
        "client_over_fd_pct": round((med["client"] / med["fd"] - 1) * 100, 1),
        "sim_us": round(sim_us, 1),
        "sim_share_of_raw_pct": round(sim_us / med["raw"] * 100, 1),
    }
    say(f"  raw pyserial     : {result['raw_per_s']:>7} round trips/s  ({med['raw']:.1f} us each)")
    say(f"  tmclsh client    : {result['client_per_s']:>7} round trips/s  "
        f"({med['client']:.1f} us each)")
    say(f"  client overhead over raw pyserial: {result['overhead_pct']:+.1f} % (target <= 30 %; "
        f"over all rounds {result['overhead_all_pct']:+.1f} %)")
    say(f"  raw descriptor floor (no pyserial): {med['fd']:.1f} us; client "
        f"{result['client_over_fd_pct']:+.1f} % over it")
    say(f"  simulator alone: {sim_us:.1f} us per request = "
        f"{result['sim_share_of_raw_pct']:.0f} % of the raw pyserial round trip")
    return result


# -- watch polling --------------------------------------------------------------------------

WATCH_EXPRESSIONS = "pos=GAP 1, 0; speed=GAP 3, 0; in0=GIO 0, 0; volts=GIO 8, 1 / 10"


@benchmark("watch", "samples/s of a 4-expression .watch vs the raw pyserial round-trip floor")
def bench_watch(args: argparse.Namespace) -> dict:
    """Samples per second a ``.watch`` of four expressions (four distinct reads) sustains
    against the pty-served simulator, beside the raw round-trip floor measured in the same run
    (pyserial writes a 9-byte GAP and reads the 9-byte reply).

    One sample costs four round trips, so the floor is raw round trips/s divided by four; the
    ratio is watch samples/s over that floor (1.0: the watch adds nothing to the round trips).
    The watch runs as in a pipe: no interval, one JSON object per sample (written to
    /dev/null), no live table. Rounds alternate raw and watch. Like ``client``, every round
    trip and every sample is timed on its own and the figures are medians, which a busy
    machine disturbs far less than totals; the mean rate of the watch is reported beside.
    """
    import io

    from tmclsh.client import Client
    from tmclsh.protocol import Request
    from tmclsh.shell import watch
    from tmclsh.shell.render import Output
    from tmclsh.shell.session import Session
    from tmclsh.transport import open_serial

    count, rounds = args.count, args.rounds
    warm = min(200, count)
    frame = Request(1, 6, 1, 0, 0).to_bytes()  # GAP 1, 0
    clock = time.perf_counter
    lat: dict[str, list[float]] = {"raw": [], "watch": []}
    mean_rates: list[float] = []

    def run_raw(path: str) -> None:
        lat["raw"] += raw_latencies(path, frame, warm, count)

    def run_watch(path: str) -> None:
        client = Client(open_serial(path), module=args.module, timeout=1.0)
        try:
            session = Session(client, Output(json_mode=True))
            items = watch.parse_items(session, WATCH_EXPRESSIONS)
            stamps: list[float] = []
            with open(os.devnull, "w") as sink:
                def emit(obj: dict) -> None:
                    sink.write(json.dumps(obj) + "\n")
                    stamps.append(clock())

                watch.run_watch(session, items, interval=0, count=warm, live=False,
                                keys=watch.Keys(io.StringIO()), emit=emit)
                stamps.clear()
                result = watch.run_watch(session, items, interval=0, count=count + 1,
                                         live=False, keys=watch.Keys(io.StringIO()), emit=emit)
            lat["watch"] += [b - a for a, b in zip(stamps, stamps[1:])]
            mean_rates.append(_per_second(stamps[-1] - stamps[0], len(stamps) - 1))
            assert result.samples == count + 1 and client.stats["timeouts"] == 0, client.stats
        finally:
            client.close()

    runs = {"raw": run_raw, "watch": run_watch}
    with SimProcess(args.module) as sim:
        say(f"watch: {rounds} round(s) of {count} raw GAP round trips and {count} samples of "
            f"'{WATCH_EXPRESSIONS}' on {sim.path} (simulator in a subprocess)")
        for rnd in range(rounds):
            for name in (list(runs) if rnd % 2 == 0 else list(reversed(runs))):
                before = len(lat[name])
                runs[name](sim.path)
                if args.verbose:
                    say(f"  round {rnd + 1} {name:<5}: median "
                        f"{statistics.median(lat[name][before:]) * 1e6:.1f} us")

    raw = 1 / statistics.median(lat["raw"])
    samples = 1 / statistics.median(lat["watch"])
    floor = raw / 4
    result = {
        "benchmark": "watch",
        "count": count,
        "rounds": rounds,
        "expressions": 4,
        "watch_samples_per_s": round(samples, 1),
        "watch_mean_samples_per_s": round(statistics.median(mean_rates), 1),
        "raw_round_trips_per_s": round(raw),
        "floor_samples_per_s": round(floor, 1),
        "ratio": round(samples / floor, 3),
    }
    say(f"  raw pyserial round trips : {raw:>8.0f}/s  -> floor {floor:.0f} samples/s "
        "(4 round trips each)")
    say(f"  .watch of 4 expressions  : {samples:>8.1f} samples/s (median sample; mean rate "
        f"{result['watch_mean_samples_per_s']:.1f}/s)")
    say(f"  ratio watch / floor      : {samples / floor:.2f}")
    return result


# -- program upload ---------------------------------------------------------------------------

@benchmark("upload", "program upload and verify, instructions/s: tmclsh.program vs raw pyserial")
def bench_upload(args: argparse.Namespace) -> dict:
    """Instructions per second stored (132, one frame each answered with status 101, 133)
    and verified (134 read-back) by ``tmclsh.program.upload``, beside the raw floor: the same
    frames written and their 9-byte replies read with bare pyserial, against the same
    pty-served simulator, in the same run (rounds alternate raw and tmclsh).
    """
    import serial

    from tmclsh import asm, program
    from tmclsh.client import Client
    from tmclsh.modules import load
    from tmclsh.protocol import Control, Instruction, Request
    from tmclsh.transport import open_serial

    module = load(args.module)
    n = min(args.count, module.program_memory)
    source = "".join(f"    SGP {i % 56}, 2, {i}\n" for i in range(n - 1)) + "    STOP\n"
    prog = asm.assemble(source, module, "<bench>")
    frames = [Request(1, ins.opcode, ins.type, ins.motor, ins.value).to_bytes()
              for ins in prog.instructions]
    start = Request(1, Control.START_DOWNLOAD, 0, 0, 0).to_bytes()
    quit_ = Request(1, Control.QUIT_DOWNLOAD).to_bytes()
    reads = [Request(1, Control.READ_MEMORY, 0, 0, a).to_bytes() for a in range(n)]
    times: dict[str, list[float]] = {"raw_upload": [], "raw_verify": [], "upload": [],
                                     "verify": []}

    def raw_round(path: str) -> None:
        ser = serial.serial_for_url(path, baudrate=9600, timeout=1.0)
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
            times["raw_upload"].append(time.perf_counter() - t0)
            assert reply[2] == 101, reply  # status: loaded
            t0 = time.perf_counter()
            got = [rt(f) for f in reads]
            times["raw_verify"].append(time.perf_counter() - t0)
            stored = [Instruction.from_bytes(r[1:8]) for r in got]
            assert program.same_image(stored, prog.instructions)
        finally:
            ser.close()

    def client_round(path: str) -> None:
        client = Client(open_serial(path), module=args.module, timeout=1.0)
        try:
            result = program.upload(client, prog)
            assert result.verified, result
            times["upload"].append(result.upload_seconds)
            times["verify"].append(result.verify_seconds)
            assert client.stats["timeouts"] == 0, client.stats
        finally:
            client.close()

    with SimProcess(args.module) as sim:
        say(f"upload: {args.rounds} round(s) of {n} instructions on {sim.path}")
        for rnd in range(args.rounds):
            order = (raw_round, client_round) if rnd % 2 == 0 else (client_round, raw_round)
            for fn in order:
                fn(sim.path)

    med = {k: statistics.median(v) for k, v in times.items()}
    per_s = {k: round(_per_second(v, n)) for k, v in med.items()}
    result = {
        "benchmark": "upload",
        "instructions": n,
        "rounds": args.rounds,
        "upload_per_s": per_s["upload"],
        "verify_per_s": per_s["verify"],
        "raw_upload_per_s": per_s["raw_upload"],
        "raw_verify_per_s": per_s["raw_verify"],
        "upload_overhead_pct": round((med["upload"] / med["raw_upload"] - 1) * 100, 1),
        "verify_overhead_pct": round((med["verify"] / med["raw_verify"] - 1) * 100, 1),
    }
    say(f"  upload (132, frames, 133): {per_s['upload']:>6} instructions/s   raw floor "
        f"{per_s['raw_upload']:>6}/s   ({result['upload_overhead_pct']:+.1f} %)")
    say(f"  verify (134 read-back)   : {per_s['verify']:>6} instructions/s   raw floor "
        f"{per_s['raw_verify']:>6}/s   ({result['verify_overhead_pct']:+.1f} %)")
    return result


@benchmark("scan", "tmclsh scan of addresses 1..255, one module, 115200 baud (target <= 5 s)")
def bench_scan(args: argparse.Namespace) -> dict:
    """Wall time of a whole ``tmclsh scan --port PTY --baud 115200`` process (the module at
    address 5 of a pty-served simulator, in its own process), median of the rounds. Most of a
    scan is silent addresses, so this measures the per-address wait derived from the link."""

    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    times = []
    with SimProcess(args.module, 5) as sim:
        for r in range(args.rounds):
            t0 = time.perf_counter()
            p = subprocess.run([sys.executable, "-m", "tmclsh", "scan", "--port", sim.path,
                                "--baud", "115200", "--json"], capture_output=True, text=True,
                               env=env, cwd=str(ROOT), timeout=120)
            times.append(time.perf_counter() - t0)
            if p.returncode != 0 or '"address": 5' not in p.stdout:
                raise RuntimeError(f"scan failed: {p.stderr.strip()}")
            if args.verbose:
                say(f"  round {r + 1}: {times[-1]:.2f} s")
    med = statistics.median(times)
    say(f"  scan 1..255 @ 115200: {med:.2f} s (target <= 5 s: "
        f"{'met' if med <= 5 else 'NOT met'})")
    return {"benchmark": "scan", "rounds": args.rounds, "seconds": round(med, 2),
            "target_s": 5.0, "met": med <= 5}


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

    from tmclsh.client import Client
    from tmclsh.modules import load
    from tmclsh.protocol import Request
    from tmclsh.shell.clone import READ, readable_slots
    from tmclsh.shell.render import Output
    from tmclsh.shell.session import Session
    from tmclsh.transport import open_serial

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
        client = Client(open_serial(path, 115200), module=args.module, timeout=1.0)
        client.version = module.version_string  # as after the connect banner: no 136 here
        try:
            session = Session(client, Output(json_mode=True))
            stdout, sys.stdout = sys.stdout, io.StringIO()
            try:
                t0 = time.perf_counter()
                session.run_line(f".save {target}")
                times["save"].append(time.perf_counter() - t0)
            finally:
                sys.stdout = stdout
            assert client.stats["sent"] == len(frames) and client.stats["timeouts"] == 0, \
                client.stats
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


# -- entry point ------------------------------------------------------------------------------

def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("names", nargs="*", metavar="NAME", help="benchmarks to run (default: all)")
    p.add_argument("--count", type=int, default=5000, help="iterations per round (default 5000)")
    p.add_argument("--rounds", type=int, default=5, help="rounds per benchmark (default 5)")
    p.add_argument("--module", default="TMCM-1311", help="simulated module (default TMCM-1311)")
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
    if args.count < 1 or args.rounds < 1:
        p.error("--count and --rounds must be at least 1")
    for name in args.names or list(BENCHMARKS):
        fn, _ = BENCHMARKS[name]
        result = fn(args)
        if args.json:
            print(json.dumps(result), flush=True)
        else:
            print(f"{name}: " + ", ".join(f"{k}={v}" for k, v in result.items() if k != "benchmark"),
                  flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
