"""The bootloader's facts and firmware images (tmcl/bootloader.py), held against the issue's
table and against what PyTrinamic's own updater sends for the same HEX file."""

from __future__ import annotations

import io

import pytest

from bootmodel import hex_image
from tmclsh.tmcl import bootloader as bl
from tmclsh.tmcl import instructions as isa


def test_the_facts_are_the_tables():
    f = bl.facts()
    assert f.key == (0x81, 0x92, 0xA3B4C5D6)
    assert (f.address, f.baud, f.can_bitrate) == (1, 115200, 1_000_000)
    assert 0x7FF in f.can_other_reply_ids
    assert f.info == {"page_size": 0, "start": 1, "size": 2}
    assert f.length == {"length": 0, "checksum": 1}
    assert isa.reply_kind(242, 0) == isa.reply_kind(205, 0) == isa.ReplyKind.NONE
    assert isa.reply_kind(200, 0) == isa.ReplyKind.NORMAL


def test_word_layout():
    # word 0x1234 of a page: byte offset 0x48D0; low byte of the index in type, high in motor
    assert bl.word_fields(0x1234 * 4) == {"type": 0x34, "motor": 0x12}
    assert bl.word_offset({"type": 0x34, "motor": 0x12}) == 0x1234 * 4
    assert bl.word_at(b"\x01\x02\x03\x04", 0) == 0x04030201  # read little-endian
    assert bl.word_at(b"\x01\x02", 0) == 0x0201  # past the end: the fill byte
    assert bl.value_bytes(0x04030201) == b"\x01\x02\x03\x04"
    assert bl.checksum(b"\xff" * 0x1010102) == (0xFF * 0x1010102) & 0xFFFFFFFF


def test_bootloader_strings():
    assert bl.bootloader_string(1311, 100) == "1311B100"
    assert bl.bootloader_string(351, 103) == "351B1.03"


def test_an_image_with_a_gap_is_refused_naming_the_record_after_it():
    """A hole between records inside the image: the file does not say what belongs there,
    and the bootloader's checksum would cover it."""
    from intelhex import IntelHex

    ih = IntelHex()
    ih.puts(0x8000, b"abcd1311V112")
    ih.puts(0x8010, b"\x01\x02\x03")
    out = io.StringIO()
    ih.write_hex_file(out)
    lines = out.getvalue().splitlines()
    after = next(n for n, line in enumerate(lines, 1) if line.startswith(":038010"))
    with pytest.raises(bl.ImageError, match=rf"^gaps.hex:{after}: a gap before this record: "
                       r"the file gives nothing for 0x0000800C..0x0000800F \(4 bytes\)"):
        bl.image_from_hex(out.getvalue(), "gaps.hex")


def test_a_hex_file_cut_at_a_record_boundary_is_refused():
    """Every record it holds is valid; only the end-of-file record is missing (intelhex
    reads such a file without a word)."""
    lines = hex_image("1311V112", 200, 0x4000).splitlines()
    assert lines[-1] == ":00000001FF"
    bl.image_from_hex("\n".join(lines) + "\n", "whole.hex")  # (the whole file is taken)
    cut = "\n".join(lines[:-3]) + "\n\n"
    with pytest.raises(bl.ImageError, match=rf"^cut.hex:{len(lines) - 3}: the file ends "
                       r"without its end-of-file record \(:00000001FF\): it is cut short"):
        bl.image_from_hex(cut, "cut.hex")


def test_overlapping_records_are_refused_naming_the_line():
    lines = hex_image("1311V112", 64, 0x4000).splitlines()  # line 1: the upper address
    again = lines[:4] + [lines[2]] + lines[4:]  # the record of line 3 once more, as line 5
    with pytest.raises(bl.ImageError, match=r"^x.hex:5: not a valid Intel HEX file: the "
                       r"record gives 0x00004010 again \(it overlaps an earlier record\)"):
        bl.image_from_hex("\n".join(again) + "\n", "x.hex")


def test_an_image_knows_the_line_of_each_address():
    img = bl.image_from_hex(hex_image("1311V112", 64, 0x4000), "x.hex")
    assert [img.line_at(a) for a in (0x4000, 0x400F, 0x4010, 0x403F, 0x4040)] == [
        2, 2, 3, 5, None]
    assert img.where(0x4020) == "x.hex:4" and img.where(0x9999) == "x.hex"


def test_an_image_ending_mid_word_is_filled_and_paged():
    from intelhex import IntelHex

    ih = IntelHex()
    ih.puts(0x8000, b"abcd1311V112\0\0\0\0\x01\x02\x03")
    out = io.StringIO()
    ih.write_hex_file(out)
    img = bl.image_from_hex(out.getvalue(), "short.hex")
    assert (img.start, img.length, img.end) == (0x8000, 19, 0x8013)
    assert img.checksum == sum(img.data)
    assert [v.text for v in img.versions] == ["1311V112"]
    assert img.version_for(1311).number == 112 and img.version_for(1640) is None
    pages = list(img.pages(8))
    assert [p.address for p in pages] == [0x8000, 0x8008, 0x8010]
    assert pages[-1].size == 3 and pages[-1].words == ((0, 0, 0x030201),)


def test_version_strings_in_an_image():
    assert [v.text for v in bl.versions_in(b"\x00351V1.04\x00")] == ["351V1.04"]
    assert [v.text for v in bl.versions_in(b"x0351V103y")] == ["0351V103"]
    assert bl.versions_in(b"21311V1123") == ()  # digits around it: no version string
    assert [v.type_number for v in bl.versions_in(b"1311V112..1640V210..1311V112")] == [
        1311, 1640]


@pytest.mark.parametrize("text, why", [
    (":0000000", "not a valid Intel HEX file"),
    (":00000001FF\n", "holds no data"),
    (":020000000102FA\n", "x.hex:1: .*checksum is wrong"),
    (":0100000001FE\n:01000000FF0000\n", "not a valid Intel HEX file"),
])
def test_bad_hex_files(text, why):
    with pytest.raises(bl.ImageError, match=why):
        bl.image_from_hex(text, "x.hex")


def test_an_image_spanning_too_far_is_refused():
    from intelhex import IntelHex

    ih = IntelHex()
    ih[0x0] = 1
    ih[0x08000000] = 2
    out = io.StringIO()
    ih.write_hex_file(out)
    with pytest.raises(bl.ImageError, match="a record far from the others"):
        bl.image_from_hex(out.getvalue(), "far.hex")


def test_what_pytrinamics_updater_sends_for_the_same_file(tmp_path, monkeypatch):
    """PyTrinamic's firmware_update, given a stand-in interface that records what it sends,
    sends exactly the words, pages, checksum and length ``Image`` lays out."""
    pytest.importorskip("pytrinamic")
    from pytrinamic.cli import tmclfwupload

    page, start, size = 0x400, 0x10000, 0x20000
    path = tmp_path / "fw.hex"
    path.write_text(hex_image("1311V131", 5003, start))
    image = bl.read_image(str(path))
    sent = []

    class Reply:
        def __init__(self, value):
            self.value = value

    class Recorder:
        def get_version_string(self, module_id=None):
            return "1311B100"

        def send(self, command, type_, motor, value):
            sent.append((command, type_, motor, value & 0xFFFFFFFF))
            if command == 206:
                return Reply((page, start, size)[type_])
            if command == 203:
                return Reply(image.checksum)
            return Reply(0)

        def send_start_app(self):
            sent.append((205, 0, 0, 0))

    monkeypatch.setattr(tmclfwupload.time, "sleep", lambda s: None)
    assert tmclfwupload.firmware_update(Recorder(), str(path)) is None
    ours = []
    for p in image.pages(page):
        ours += [(201, t, m, v) for t, m, v in p.words] + [(202, 0, 0, p.address)]
    theirs = [s for s in sent if s[0] in (201, 202)]
    assert theirs == ours
    assert [s for s in sent if s[0] in (203, 208, 205)] == [
        (203, 0, 0, image.end - 1), (208, 0, 0, image.length), (208, 1, 0, image.checksum),
        (205, 0, 0, 0)]
