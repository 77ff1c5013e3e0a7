#!/usr/bin/env python3
"""Wrong values under the simulator's faults: how many does ``tmclsh -f`` show, and are they
flagged where they are shown?

The simulated TMCM-1311 runs in this process on a pty; its user variables (GGP n, 2) and a few
axis parameters hold distinct values, set on a clean line. Then the faults are switched on
(``--mix``, as ``tmclsh sim --faults`` takes them) and ``tmclsh -f`` runs in its own process:
a script reading those values in an order that makes runs of the same command (the case where
a displaced answer is taken for the next one) and changes command now and then. Every value it
shows is compared with the one the module holds:

* ``wrong, in line``: wrong, and its own line or record says it is in doubt;
* ``wrong, later``: wrong, and only a warning after it says so (the issue's "printed before
  judged");
* ``wrong, unflagged``: wrong and never said: must be 0;
* ``right, flagged``: a false alarm (the value was right; costs a re-run, not trust).

``--load`` runs two busy processes beside it (the 2-core machine, loaded), as a CI box is.
Not a test (it takes minutes); tests/client/test_judged_answers.py runs a short version.

``--ascii`` measures the module's ASCII mode instead (``tmclsh --ascii -f``): a proxy between
tmclsh and the simulator (tests/asciiproxy.py, which imports nothing of tmclsh) delays,
duplicates and changes the module's reply lines (``--mix`` in the proxy's kinds: delay, dup,
dup-late, flip); ``--echo`` sets the module's echo mode (GP 67). ASCII replies carry no
checksum: a flipped digit is a valid reply, found out only by reading again.
tests/client/test_ascii_proxy.py runs a short version.

``--api`` reads through the Python API instead (``tmclsh.connect()`` and
``LineClient.execute`` in a process of its own, with ``--ascii`` too): a value is flagged in
line when its ``Result.in_doubt`` says so, later when ``Doubts.take_suspects`` names it after
a later read, or ``Doubts.confirm_last`` at the end.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tmclsh.client.text import LineClient  # noqa: E402
from tmclsh.link import open_serial  # noqa: E402
from tmclsh.sim import Simulator  # noqa: E402
from tmclsh.sim.faults import parse_rates  # noqa: E402
from tmclsh.sim.serve import serve_pty  # noqa: E402

MIXES = (
    "dup-late=0.1,delay=0.05,garbage=0.05,truncate=0.05",  # the mix
    "dup-late=0.1,drop=0.05",
    "dup=0.1,dup-late=0.1",
    "drop=0.05,corrupt=0.05,dup=0.05,dup-late=0.05,delay=0.02,garbage=0.05,truncate=0.05",
)
ASCII_MIXES = (
    "delay=0.1",
    "dup=0.1,dup-late=0.1",
    "flip=0.05",
    "delay=0.03,dup=0.03,dup-late=0.05,flip=0.03",
)
ECHO = {"char": 0, "line": 16, "none": 32}  # GP 67 (bank 0) bits 5/4
ARM = "GGP 255, 2"  # the run's first line: the proxy's faults begin with it
VARIABLES = 24  # user variables read (GGP n, 2)
AXIS = {4: 11111, 5: 22222, 6: 100, 7: 50}  # axis parameters read (GAP n, 0), with their values


def truth() -> dict[str, int]:
    """The line -> the value the module holds."""
    values = {f"GGP {n}, 2": 100_000 + 7_919 * n for n in range(VARIABLES)}
    values.update({f"GAP {n}, 0": v for n, v in AXIS.items()})
    return values


def script(reads: int, rng: random.Random) -> list[str]:
    """Runs of one command (2..12 reads of GGP or GAP), then the other: runs are where a
    displaced answer is taken for the next; a change of command is where it shows."""
    ggp = [f"GGP {n}, 2" for n in range(VARIABLES)]
    gap = [f"GAP {n}, 0" for n in AXIS]
    out: list[str] = []
    while len(out) < reads:
        pool = ggp if rng.random() < 0.7 else gap
        out += [rng.choice(pool) for _ in range(rng.randint(2, 12))]
    return out[:reads]


def setup(path: str, gp67: int | None = None) -> None:
    c = LineClient(open_serial(path), module="TMCM-1311", timeout=0.5)
    try:
        if gp67 is not None:
            c.execute(f"SGP 67, 0, {gp67}")
        for line, value in truth().items():
            op, rest = line.split(" ", 1)
            c.execute(f"S{op[1:]} {rest}, {value}")
        for line, value in truth().items():
            assert c.execute(line).reply.value == value, line
    finally:
        c.close()


def judge(records: list[dict], values: dict[str, int]) -> dict[str, int]:
    """Count the outcomes of one run's JSON records (see the module docstring)."""
    counts = dict.fromkeys(("reads", "wrong, in line", "wrong, later", "wrong, unflagged",
                            "right, flagged", "not answered"), 0)
    shown: list[tuple[str, int, bool]] = []  # (line, right?, flagged in its record)
    for rec in records:
        line = rec.get("line")
        if rec.get("suspect"):
            # a warning after the fact: the latest shown read of that line is flagged late
            for i in range(len(shown) - 1, -1, -1):
                if shown[i][0] == line:
                    shown[i] = (shown[i][0], shown[i][1], shown[i][2] or "late")
                    break
            continue
        if line not in values:
            continue
        if "error" in rec and "reply" not in rec:
            counts["not answered"] += 1
            continue
        if "reply" not in rec:
            continue
        counts["reads"] += 1
        flagged = bool(rec.get("in_doubt"))
        shown.append((line, rec["reply"] == values[line], flagged))
    for _line, right, flagged in shown:
        if right:
            counts["right, flagged"] += bool(flagged)
        elif flagged == "late":
            counts["wrong, later"] += 1
        elif flagged:
            counts["wrong, in line"] += 1
        else:
            counts["wrong, unflagged"] += 1
    return counts


# The API path's reader, run as ``python -c`` (it imports only the tmclsh of the tree measured):
# argv port, script file, timeout, "ascii" or "binary"; one JSON record a line, as --json's.
API_READER = """
import json, sys
import tmclsh
from tmclsh.base.errors import TmclError

port, path, timeout, mode = sys.argv[1:5]
client = tmclsh.connect(port=port, module="TMCM-1311", timeout=float(timeout),
                        ascii=mode == "ascii")
read_as = {}  # reply seq -> the line it answered


def later():
    for s in client._doubts.take_suspects():
        print(json.dumps({"line": read_as.get(s.seq), "suspect": True}))


try:
    for line in open(path).read().splitlines():
        try:
            result = client.execute(line)
        except TmclError as exc:
            print(json.dumps({"line": line, "error": str(exc)}))
            if not client.connected:
                client.reconnect(1.0)
            continue
        read_as[client._replies] = line
        rec = {"line": line, "reply": result.value}
        if result.in_doubt:
            rec["in_doubt"] = True
        print(json.dumps(rec))
        later()
    client._doubts.confirm_last()
    later()
finally:
    client.close()
"""


def ascii_rates(text: str) -> dict[str, float]:
    """``"delay=0.1,flip=0.05"`` -> the proxy's rates."""
    from asciiproxy import KINDS

    rates = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        kind, _, p = part.partition("=")
        if kind not in KINDS:
            raise SystemExit(f"{kind!r}: the proxy's kinds are {', '.join(KINDS)}")
        rates[kind] = float(p)
    return rates


def trial(mix: str, reads: int, seed: int, *, ascii_echo: str | None = None,
          tree: Path = ROOT, api: bool = False) -> tuple[dict[str, int], float]:
    """One run of ``reads`` reads under ``mix``; ``ascii_echo``: in ASCII mode through the
    proxy, with that echo mode. ``tree``: the checkout whose tmclsh runs (before/after).
    ``api``: read through the Python API (``API_READER``) instead of ``tmclsh -f``."""
    sim = Simulator("TMCM-1311")
    server = serve_pty(sim)
    proxy = None
    try:
        setup(server.path, None if ascii_echo is None else ECHO[ascii_echo])
        port, extra = server.path, []
        if ascii_echo is None:
            sim.faults.rng = random.Random(seed)
            sim.faults.rates = parse_rates(mix)
        else:
            sys.path.insert(0, str(ROOT / "tests"))
            from asciiproxy import AsciiProxy

            proxy = AsciiProxy(server.path, rates=ascii_rates(mix), seed=seed,
                               arm_on=ARM.encode())
            port, extra = proxy.path, ["--ascii"]
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "reads.tmcl"
            lines = script(reads, random.Random(seed))
            if proxy is not None:
                lines.insert(0, ARM)
            path.write_text("\n".join(lines) + "\n")
            env = dict(os.environ, PYTHONPATH=str(tree))
            start = time.monotonic()
            if api:
                command = [sys.executable, "-c", API_READER, port, str(path), "0.3",
                           "ascii" if extra else "binary"]
            else:
                command = [sys.executable, "-m", "tmclsh", "--port", port, "-m", "TMCM-1311",
                           "--timeout", "0.3", *extra, "-f", str(path), "--keep-going",
                           "--json"]
            run = subprocess.run(command, capture_output=True, text=True, env=env, cwd=tmp,
                                 timeout=3600)
            took = time.monotonic() - start
        records = []
        for text in run.stdout.splitlines():
            with contextlib.suppress(ValueError):
                records.append(json.loads(text))
        return judge(records, truth()), took
    finally:
        sim.faults.rates = {}
        if proxy is not None:
            proxy.close()
        server.close()
        sim.close()


@contextlib.contextmanager
def loaded(on: bool):
    """Two busy processes beside the trial (the machine's two cores taken)."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
             for _ in range(2 if on else 0)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reads", type=int, default=2000, help="reads per mix (default 2000)")
    ap.add_argument("--mix", action="append", help="a fault mix (repeatable; default: four)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--load", action="store_true", help="two busy processes beside it")
    ap.add_argument("--ascii", action="store_true",
                    help="the module's ASCII mode, through a proxy that mangles its replies")
    ap.add_argument("--echo", choices=tuple(ECHO), default="char",
                    help="with --ascii: the module's echo mode (default char)")
    ap.add_argument("--api", action="store_true",
                    help="read through the Python API (tmclsh.connect) instead of tmclsh -f")
    ap.add_argument("--tree", type=Path, default=ROOT,
                    help="the checkout whose tmclsh runs (default this one)")
    args = ap.parse_args()
    worst = 0
    with loaded(args.load):
        for mix in args.mix or (ASCII_MIXES if args.ascii else MIXES):
            counts, took = trial(mix, args.reads, args.seed,
                                 ascii_echo=args.echo if args.ascii else None, tree=args.tree,
                                 api=args.api)
            worst = max(worst, counts["wrong, unflagged"])
            print(f"{mix}  ({took:.0f} s{', loaded' if args.load else ''})")
            print("    " + ", ".join(f"{k}: {v}" for k, v in counts.items()), flush=True)
    return 1 if worst else 0


if __name__ == "__main__":
    sys.exit(main())
