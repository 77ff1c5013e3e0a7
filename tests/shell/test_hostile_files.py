"""Issue 31's files from the field, cut, empty, damaged or hostile, through real ``tmclsh``
processes: module files (``modules check``), config files, HEX files (``firmware``,
``disasm``) and every log ``monitor --log`` reads, made by python-can's own writers and then
cut and damaged. Each ends in one line naming the file (and the line or frame), a non-zero
exit status, never a traceback; memory stays bounded; a SIGTERM during a slow read ends
tmclsh promptly.

The neighbour of test_hostile_inputs.py (typed lines, settings, scripts).
"""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import time
import zlib
from pathlib import Path

import pytest

from conftest import tmclsh_env

MODULE = """[module]
name = "TMCM-9999"
motors = {motors}
program_memory = {memory}
firmware_id = 9999
version_string = "9999V100"
"""
AXIS = '\n[[axis]]\nnumber = {number}\nname = "x"\naccess = "RW"\n'


def _noise(seed: int, n: int) -> bytes:
    return random.Random(seed).randbytes(n)


def module_text(motors: object = 1, memory: object = 2048, extra: str = "") -> str:
    return MODULE.format(motors=motors, memory=memory) + extra


# (file name, text, what the one line says); every one is refused by `modules check`
MODULE_FILES = [
    ("nested.toml", module_text(extra="notes = " + "[" * 5000 + "]" * 5000 + "\n"),
     ":7: values nested more than 16 deep"),
    ("inline.toml", module_text(extra="units = " + "{a = " * 5000 + "1" + "}" * 5000),
     ":7: values nested more than 16 deep"),
    ("dotted.toml", module_text() + "a" + ".a" * 5000 + " = 1\n",
     ":7: values nested more than 16 deep"),
    ("digits.toml", module_text(motors="1" + "0" * 5000), ":3: a number longer than 40 digits"),
    ("motors.toml", module_text(motors=1_000_000_000),
     ":3: [module]: motors must be from 1 to 6"),
    ("memory.toml", module_text(memory=4_000_000_000),
     ":4: [module]: program_memory must be from 1 to 65536"),
    ("hexmotors.toml", module_text(motors="0x" + "f" * 3000),
     ":3: [module]: motors must be from 1 to 6"),
    ("coordinates.toml", module_text(extra="coordinates = 100000000\n"),
     ":7: [module]: coordinates must be from 0 to 256"),
    ("number.toml", module_text(extra=AXIS.format(number=70000)),
     ":9: [[axis]] entry 1 (AP 70000): number must be from 0 to 255"),
    ("count.toml", module_text(extra=AXIS.format(number=200) + "count = 100000000\n"),
     ":12: [[axis]] entry 1 (AP 200): count must be from 1 to 256"),
    ("run.toml", module_text(extra=AXIS.format(number=200) + "count = 100\n"),
     ":12: [[axis]] entry 1 (AP 200): numbers 200..299 go past 255"),
    ("names.toml", module_text(extra=AXIS.format(number=1) + "values = { \""
                               + "9" * 5000 + "\" = \"x\" }\n"),
     ":12: [[axis]] entry 1 (AP 1): values must be a table of texts keyed by numbers"),
    ("empty.toml", "", ":1: no [module] table"),
    ("cut.toml", module_text()[:40], ":4: not valid TOML: Expected '='"),
    ("binary.toml", None, ":1: not a text file"),
]


@pytest.fixture
def env(tmp_path):
    return tmclsh_env(XDG_CONFIG_HOME=str(tmp_path / "config"),
                      XDG_CACHE_HOME=str(tmp_path / "cache"))


def _tmclsh(*args: str, env: dict, cwd, timeout: float = 120):
    return subprocess.run([sys.executable, "-m", "tmclsh", *args], capture_output=True,
                          text=True, errors="replace", timeout=timeout, env=env, cwd=str(cwd))


def _one_line(r, name: str, expected: str | None = None) -> str:
    """Exit status non-zero, stderr one line naming the file, no traceback."""
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr[-2000:]
    rows = [row for row in r.stderr.splitlines() if row.strip()]
    assert r.returncode != 0 and len(rows) == 1, (r.returncode, r.stderr[-2000:])
    assert name in rows[0] and len(rows[0]) < 400, rows[0][:500]
    if expected is not None:
        assert expected in rows[0], rows[0]
    return rows[0]


@pytest.mark.parametrize("name, text, expected", MODULE_FILES,
                         ids=[m[0] for m in MODULE_FILES])
def test_hostile_module_files_are_refused_in_one_line(name, text, expected, env, tmp_path):
    path = tmp_path / name
    if text is None:
        path.write_bytes(_noise(1, 4000))
    else:
        path.write_text(text)
    r = _tmclsh("modules", "check", name, env=env, cwd=tmp_path)
    _one_line(r, f"{name}{expected}")


def test_the_bounds_still_take_what_modules_have(env, tmp_path):
    """The limits are where the modules are: 6 motors, 65536 instructions, a run of user
    variables to 255, 32-bit values either signed or not."""
    path = tmp_path / "six.toml"
    path.write_text(module_text(motors=6, memory=65536,
                                extra=AXIS.format(number=0) + "min = -2147483648\n"
                                "max = 4294967295\n" + AXIS.format(number=200).replace(
                                    "[[axis]]", "[[global]]") + "count = 56\n"))
    r = _tmclsh("modules", "check", str(path), env=env, cwd=tmp_path)
    assert r.returncode == 0 and r.stdout.rstrip().endswith(": OK"), r.stderr


def test_a_module_file_past_the_bounds_does_not_reach_the_simulator(env, tmp_path):
    """(Was: motors = 1000000000 passed the check and --sim grew to gigabytes.)"""
    path = tmp_path / "motors.toml"
    path.write_text(module_text(motors=1_000_000_000))
    r = _tmclsh("--module-file", str(path), "--sim", "TMCM-9999", "-c", "GAP 1, 0",
                env=env, cwd=tmp_path, timeout=60)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert "motors.toml:3: [module]: motors must be from 1 to 6" in r.stderr


CONFIG_FILES = [
    ("nested.toml", "[settings]\nx = " + "[" * 5000 + "]" * 5000 + "\n",
     ":2: values nested more than 16 deep"),
    ("inline.toml", "[profiles.x]\ny = " + "{a = " * 3000 + "1" + "}" * 3000 + "\n",
     ":2: values nested more than 16 deep"),
    ("digits.toml", "[profiles.x]\ntimeout = 1" + "0" * 5000 + "\n",
     ":2: a number longer than 40 digits"),
    ("cut.toml", "[profiles.x]\ntimeout = [1, 2", None),
    ("binary.toml", None, None),
]


@pytest.mark.parametrize("name, text, expected", CONFIG_FILES,
                         ids=[c[0] for c in CONFIG_FILES])
def test_hostile_config_files_are_refused_in_one_line(name, text, expected, env, tmp_path):
    path = tmp_path / name
    if text is None:
        path.write_bytes(_noise(2, 4000))
    else:
        path.write_text(text)
    r = _tmclsh("--sim", "-c", "GAP 1, 0", env={**env, "TMCLSH_CONFIG": str(path)},
                cwd=tmp_path)
    assert r.returncode == 2
    _one_line(r, name, expected)


# Intel HEX (firmware) and the image forms disasm and .upload take
HEX_FILES = [
    ("empty.hex", b"", "empty.hex:1: the file ends without its end-of-file record"),
    ("cut.hex", b":1000000000000000000000000000000000", "not a valid Intel HEX file"),
    ("long.hex", b":" + b"F" * 5000 + b"\n", "not a valid Intel HEX file"),
    ("digits.hex", b":02000004" + b"9" * 5000 + b"\n", "not a valid Intel HEX file"),
    ("span.hex", b":020000040000FA\n:0100000000FF\n:02000004FFFFFC\n:0100000000FF\n"
     b":00000001FF\n", "the image spans"),
    ("binary.hex", _noise(3, 5000),
     "not an Intel HEX file"),
]


@pytest.mark.parametrize("name, data, expected", HEX_FILES, ids=[h[0] for h in HEX_FILES])
def test_hostile_hex_files_are_refused_in_one_line(name, data, expected, env, tmp_path):
    (tmp_path / name).write_bytes(data)
    r = _tmclsh("--sim", "firmware", "--check", name, env=env, cwd=tmp_path)
    _one_line(r, name, expected)
    r = _tmclsh("disasm", name, env=env, cwd=tmp_path)
    if r.returncode != 0 or r.stderr:  # (an empty image is no instructions, said as such)
        assert "Traceback" not in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr


# -- logs --------------------------------------------------------------------------------

FORMATS = [".asc", ".blf", ".csv", ".log", ".trc", ".db", ".mf4"]


def _write_log(path: Path) -> None:
    """A log of TMCL requests and replies written by python-can's own writer for its
    suffix (a tmclsh capture for ``.cap``)."""
    if path.suffix == ".cap":
        lines = ["# tmclsh capture of a serial line\n"]
        lines += [f"{1700000000 + i / 100:.6f} 01 06 04 00 00 00 00 00 0b\n" for i in range(20)]
        path.write_text("".join(lines))
        return
    import can

    if path.suffix == ".mf4":
        pytest.importorskip("asammdf")
    with can.Logger(str(path)) as log:
        for i in range(40):
            data = bytes([6, 1, 0, 0, 0, 0, 0]) if i % 2 == 0 else bytes([1, 1, 100, 6, 0, 0, 3])
            log.on_message_received(can.Message(timestamp=1700000000 + i / 100,
                                                arbitration_id=1 + i % 2, data=data,
                                                is_extended_id=False))


def _damaged(data: bytes) -> dict[str, tuple[bytes, bool]]:
    """Cut and damaged forms of a log: name -> (bytes, whether nothing of it is readable:
    then the run must fail)."""
    rnd = random.Random(len(data))
    out = {"empty": (b"", True), "cut-head": (data[:1], True), "zeros": (bytes(len(data)), True),
           "ff": (b"\xff" * len(data), True), "cut-half": (data[:len(data) // 2], False),
           "cut-end": (data[:-7], False)}
    for k in range(3):
        flipped = bytearray(data)
        for _ in range(1 + 4 * k):
            flipped[rnd.randrange(len(flipped))] = rnd.randrange(256)
        out[f"flip{k}"] = (bytes(flipped), False)
    return out


@pytest.mark.parametrize("suffix", FORMATS + [".cap"])
def test_damaged_logs_end_in_one_line(suffix, env, tmp_path):
    good = tmp_path / f"good{suffix}"
    _write_log(good)
    r = _tmclsh("monitor", "--log", good.name, env=env, cwd=tmp_path)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr[-1000:]
    for name, (data, unreadable) in _damaged(good.read_bytes()).items():
        path = tmp_path / f"{name}{suffix}"
        path.write_bytes(data)
        r = _tmclsh("monitor", "--log", path.name, env=env, cwd=tmp_path)
        assert "Traceback" not in r.stderr, (name, r.stderr[-2000:])
        errors = [row for row in r.stderr.splitlines() if row.startswith("tmclsh:")]
        if unreadable:
            _one_line(r, path.name)
        elif r.returncode != 0:  # read up to the damage: one error, then the summary of it
            assert len(errors) == 1 and path.name in errors[0], (name, r.stderr)
            assert r.stderr.startswith(errors[0]), (name, r.stderr)
        else:
            assert not errors, (name, r.stderr)


def _blf_bomb(path: Path, inflated: int) -> None:
    """A .blf whose one container inflates to ``inflated`` bytes of zeros (a thousandth of
    that on the disk): python-can inflates a container whole."""
    import can
    from can.io import blf

    head_file = path.with_name("head.blf")
    with can.Logger(str(head_file)) as log:
        log.on_message_received(can.Message(timestamp=1.0, arbitration_id=1, data=b"\1" * 7))
    head = head_file.read_bytes()
    head = head[:blf.FILE_HEADER_STRUCT.unpack_from(head)[1]]
    z = zlib.compressobj(9)
    chunk = bytes(1 << 20)
    body = b"".join(z.compress(chunk) for _ in range(inflated >> 20)) + z.flush()
    size = blf.OBJ_HEADER_BASE_STRUCT.size + blf.LOG_CONTAINER_STRUCT.size + len(body)
    obj = blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", blf.OBJ_HEADER_BASE_STRUCT.size, 1, size,
                                          blf.LOG_CONTAINER)
    obj += blf.LOG_CONTAINER_STRUCT.pack(blf.ZLIB_DEFLATE, inflated) + body + bytes(size % 4)
    path.write_bytes(head + obj)


GIB = 1024 * 1024 * 1024


def test_a_log_that_inflates_to_gigabytes_is_refused_in_bounded_memory(env, tmp_path):
    """(Was: 2 GiB resident and a traceback.) The child's peak is measured alone, by a
    Python that runs only it."""
    bomb = tmp_path / "bomb.blf"
    _blf_bomb(bomb, 2 * GIB)
    measure = ("import resource, subprocess, sys\n"
               "r = subprocess.run([sys.executable, '-m', 'tmclsh', 'monitor', '--log', "
               "'bomb.blf'], capture_output=True, text=True)\n"
               "sys.stderr.write(r.stderr)\n"
               "print(r.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n")
    r = subprocess.run([sys.executable, "-c", measure], capture_output=True, text=True,
                       env=env, cwd=str(tmp_path), timeout=300)
    status, peak_kib = map(int, r.stdout.split())
    r.returncode = status
    line = _one_line(r, "bomb.blf: ")  # the bound's MemoryError, or zlib's own refusal
    assert "of memory" in line or "allocate" in line, line
    assert peak_kib * 1024 < GIB, f"peak {peak_kib // 1024} MiB"


def _terminate_while_reading(args: list[str], env: dict, cwd: Path, busy) -> tuple[int, float, str]:
    """Start tmclsh, wait (generously) until ``busy(pid)`` says it is reading, SIGTERM it,
    and return its status, the seconds it took to end after the signal, and its stderr."""
    p = subprocess.Popen([sys.executable, "-m", "tmclsh", *args], env=env, cwd=str(cwd),
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not busy(p.pid) and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert p.poll() is None, "ended before it was signalled"
        sent = time.monotonic()
        p.send_signal(signal.SIGTERM)
        p.wait(60)
        took = time.monotonic() - sent
        return p.returncode, took, p.stderr.read() if p.stderr else ""
    finally:
        p.kill()
        p.wait()


def _resident_mib(pid: int) -> int:
    try:
        return int(Path(f"/proc/{pid}/statm").read_text().split()[1]) * 4096 // (1 << 20)
    except (OSError, ValueError, IndexError):
        return 0


@pytest.mark.skipif(not Path("/proc/self/statm").exists(), reason="reads /proc")
def test_sigterm_ends_a_log_read_stuck_in_c(env, tmp_path):
    """While python-can inflates a container (one long call into zlib, where Python's own
    signal handler cannot run) a SIGTERM still ends tmclsh, with the signal's status.
    (Was: it ran on to the end of the call and exited 0 with a summary.)"""
    bomb = tmp_path / "bomb.blf"
    _blf_bomb(bomb, 2 * GIB)
    status, took, err = _terminate_while_reading(
        ["monitor", "--log", "bomb.blf"], env, tmp_path,
        busy=lambda pid: _resident_mib(pid) > 150)  # inflating
    assert "Traceback" not in err, err
    assert status != 0, err
    assert took < 10, f"{took:.1f} s after SIGTERM"  # 0.5 s on an idle machine


def test_sigterm_ends_a_slow_module_file_load(env, tmp_path):
    """A 13 MB module file (tomllib takes seconds): SIGTERM ends tmclsh while it loads."""
    big = tmp_path / "big.toml"
    notes = "".join(f'  "note {i} {"x" * 20}",\n' for i in range(300_000))
    big.write_text(module_text(extra=f"notes = [\n{notes}]\n"))
    status, took, err = _terminate_while_reading(
        ["--module-file", str(big), "--sim", "-c", "GAP 1, 0"], env, tmp_path,
        busy=lambda pid: _resident_mib(pid) > 60)
    assert "Traceback" not in err, err
    assert status in (143, -signal.SIGTERM), (status, err)
    assert took < 10, f"{took:.1f} s after SIGTERM"
