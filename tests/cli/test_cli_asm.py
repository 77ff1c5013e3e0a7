"""`tmclsh asm` and `tmclsh disasm` as a user runs them: files in, files out, exit status."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

PROGRAM = """\
// move between two positions
Speed = 1000
    SAP 4, 0, Speed
Loop:
    MVP ABS, 0, 10000
    WAIT POS, 0, 0
    MVP ABS, 0, -10000
    WAIT POS, 0, 0
    JA Loop
"""


def tmclsh(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tmclsh", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=60)


@pytest.fixture
def program(tmp_path: Path) -> Path:
    path = tmp_path / "loop.tmc"
    path.write_text(PROGRAM)
    return path


def test_asm_hex_is_seven_lowercase_bytes_per_line(program: Path) -> None:
    out = program.with_suffix(".hex")
    r = tmclsh("asm", str(program), "--hex", "-o", str(out))
    assert r.returncode == 0, r.stderr
    lines = out.read_text().splitlines()
    assert lines == [
        "05 04 00 00 00 03 e8",  # SAP 4, 0, 1000
        "04 00 00 00 00 27 10",  # MVP ABS, 0, 10000
        "1b 01 00 00 00 00 00",  # WAIT POS, 0, 0
        "04 00 00 ff ff d8 f0",  # MVP ABS, 0, -10000
        "1b 01 00 00 00 00 00",
        "16 00 00 00 00 00 01",  # JA Loop (address 1)
    ]


def test_binary_disassembles_to_source_that_reassembles(program: Path, tmp_path: Path) -> None:
    binary = tmp_path / "loop.bin"
    assert tmclsh("asm", str(program), "-o", str(binary)).returncode == 0
    assert binary.stat().st_size == 6 * 8  # TMCL-IDE records: 7 bytes and a checksum
    r = tmclsh("disasm", str(binary))
    assert r.returncode == 0, r.stderr
    assert "JA L0001" in r.stdout and "L0001:" in r.stdout and "MVP ABS, 0, -10000" in r.stdout
    again = tmp_path / "again.tmc"
    again.write_text(r.stdout)
    rebuilt = tmp_path / "again.bin"
    assert tmclsh("asm", str(again), "-o", str(rebuilt)).returncode == 0
    assert rebuilt.read_bytes() == binary.read_bytes()


def test_hex_image_disassembles(program: Path, tmp_path: Path) -> None:
    hexfile = tmp_path / "loop.hex"
    tmclsh("asm", str(program), "--hex", "-o", str(hexfile))
    r = tmclsh("disasm", str(hexfile))
    assert r.returncode == 0 and "WAIT POS, 0, 0" in r.stdout


@pytest.mark.parametrize("name", ["empty.bin", "empty.hex"])
def test_disasm_of_an_empty_image_says_so(name: str, tmp_path: Path) -> None:
    image = tmp_path / name
    image.write_bytes(b"")
    r = tmclsh("disasm", str(image))
    assert r.returncode == 0 and r.stdout == ""
    assert r.stderr == f"{image}: an empty image: no instructions\n"


def test_disasm_of_source_says_it_is_text_and_names_asm(program: Path) -> None:
    r = tmclsh("disasm", str(program))
    assert r.returncode == 1 and r.stdout == ""
    assert r.stderr == (f"tmclsh: {program}: this is text (line 1: '// move between two "
                        "positions'), not a program image: a TMCL-IDE binary image (8-byte "
                        "records) or the --hex text form (7 hex bytes a line); if it is TMCL "
                        "source, `tmclsh asm FILE` makes an image of it\n")


def test_error_has_location_and_no_output_file(tmp_path: Path) -> None:
    src = tmp_path / "bad.tmc"
    src.write_text("SAP 4, 0, 1000\nSAP 140, 0, 9\n")
    out = tmp_path / "bad.bin"
    r = tmclsh("asm", str(src), "-o", str(out))
    assert r.returncode == 1
    assert f"{src}:2:" in r.stderr and "0..8" in r.stderr
    assert not out.exists()
    assert not list(tmp_path.glob("*.tmp"))


def test_missing_source_names_the_file_once(tmp_path: Path) -> None:
    """Was "x.tmc: cannot read x.tmc: no such file" (also in .upload)."""
    src = tmp_path / "pingpong.tmc"
    r = tmclsh("asm", str(src))
    assert r.returncode == 1
    assert r.stderr.strip() == f"tmclsh: cannot read {src}: no such file"


def test_module_option_checks_against_that_module(tmp_path: Path) -> None:
    src = tmp_path / "three.tmc"
    src.write_text("MVP ABS, 2, 1000\n")  # motor 2 exists only on the TMCM-351
    assert tmclsh("asm", str(src), "-m", "TMCM-351", "-o", str(tmp_path / "a.bin")).returncode == 0
    r = tmclsh("asm", str(src), "-m", "TMCM-1311", "-o", str(tmp_path / "b.bin"))
    assert r.returncode == 1 and "motor 2" in r.stderr


def test_missing_file_is_a_clear_error(tmp_path: Path) -> None:
    r = tmclsh("asm", str(tmp_path / "nope.tmc"))
    assert r.returncode == 1 and "cannot read" in r.stderr and "Traceback" not in r.stderr
