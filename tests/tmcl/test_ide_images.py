"""TMCL-IDE binary images: 8-byte records (command, type, motor/bank, value MSB first, then the
8-bit sum of those seven), as PyTrinamic's LoadTMCLBinary reads them 8 bytes at a time. The
files here are built and read with struct, independently of tmclsh's code."""

from __future__ import annotations

import struct
from pathlib import Path

# (command, type, motor, value): SAP 4, 0, 1000 / MVP ABS, 0, -500 / WAIT POS, 0, 0 /
# JA 1 / STOP
PROGRAM = [(5, 4, 0, 1000), (4, 0, 0, -500), (27, 1, 0, 0), (22, 0, 0, 1), (28, 0, 0, 0)]
SOURCE = "SAP 4, 0, 1000\nLoop: MVP ABS, 0, -500\nWAIT POS, 0, 0\nJA Loop\nSTOP\n"


def build(records) -> bytes:
    out = b""
    for cmd, typ, mot, val in records:
        rec = struct.pack(">BBBi", cmd, typ, mot, val)
        out += rec + bytes([sum(rec) & 0xFF])
    return out


def parse(data: bytes) -> list[tuple[int, int, int, int]]:
    """The LoadTMCLBinary way: 8 bytes at a time, checksum checked."""
    assert len(data) % 8 == 0
    out = []
    for i in range(0, len(data), 8):
        rec = data[i:i + 8]
        assert sum(rec[:7]) & 0xFF == rec[7], f"record {i // 8 + 1}"
        out.append(struct.unpack(">BBBi", rec[:7]))
    return out


def test_asm_writes_records_an_independent_reader_parses(tmp_path: Path, run_tmclsh):
    src = tmp_path / "p.tmc"
    src.write_text(SOURCE)
    out = tmp_path / "p.bin"
    r = run_tmclsh("asm", str(src), "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert parse(out.read_bytes()) == PROGRAM


def test_disasm_reads_a_file_built_independently(tmp_path: Path, run_tmclsh):
    image = tmp_path / "ide.bin"
    image.write_bytes(build(PROGRAM))
    r = run_tmclsh("disasm", str(image))
    assert r.returncode == 0, r.stderr
    lines = [x.split("//")[0].strip() for x in r.stdout.splitlines() if x.strip()]
    assert lines == ["SAP 4, 0, 1000", "L0001:", "MVP ABS, 0, -500", "WAIT POS, 0, 0",
                     "JA L0001", "STOP"]


def test_a_bad_checksum_names_the_record_and_the_expected_sum(tmp_path: Path, run_tmclsh):
    data = bytearray(build(PROGRAM))
    data[2 * 8 + 7] ^= 0x01  # record 3's checksum
    bad = tmp_path / "bad.bin"
    bad.write_bytes(bytes(data))
    expected = sum(data[16:23]) & 0xFF
    r = run_tmclsh("disasm", str(bad))
    assert r.returncode == 1
    assert "record 3" in r.stderr and f"expected {expected:#04x}" in r.stderr
    assert str(bad) in r.stderr and "Traceback" not in r.stderr
    up = run_tmclsh("--sim", "--trace", "-c", f".upload {bad} --yes")
    assert up.returncode == 1 and "record 3" in up.stderr
    sent = [line.split("tx> ", 1)[1].split() for line in up.stderr.splitlines()
            if "tx> " in line]
    assert sent and all(frame[1] != "84" for frame in sent)  # download mode (132) never entered


def test_upload_an_ide_image_and_dump_it_back(tmp_path: Path, run_tmclsh):
    image = tmp_path / "ide.bin"
    image.write_bytes(build(PROGRAM))
    back, text = tmp_path / "back.bin", tmp_path / "back.hex"
    r = run_tmclsh("--sim", "-c", f".upload {image} --yes\n.dump -o {back}\n.dump {text}")
    assert r.returncode == 0, r.stderr
    assert parse(back.read_bytes()) == PROGRAM  # what the simulated module stored, 8 at a time
    hex_lines = text.read_text().splitlines()
    assert [bytes.fromhex(x) for x in hex_lines] == [struct.pack(">BBBi", *p) for p in PROGRAM]
