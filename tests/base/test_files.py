"""tmclsh.base.files: reads stop at their limit, writes are all or nothing."""

from __future__ import annotations

import io
import os

import pytest

from tmclsh.base import files
from tmclsh.base.errors import TmclError


def test_read_stops_at_the_limit_on_an_endless_file():
    with pytest.raises(files.FileError, match=r"^/dev/zero: image larger than 4 KiB; not read$"):
        files.read_bytes("/dev/zero", 4096, "image")


def test_read_errors_name_the_path_and_the_reason(tmp_path):
    with pytest.raises(files.FileError, match=f"cannot read {tmp_path}: it is a directory"):
        files.read_bytes(tmp_path)
    with pytest.raises(files.FileError, match="no such file"):
        files.read_bytes(tmp_path / "none")
    (tmp_path / "bin").write_bytes(b"\xff\xfe")
    with pytest.raises(files.FileError, match="not a text file"):
        files.read_text(tmp_path / "bin")
    assert issubclass(files.FileError, TmclError)


def test_read_tail_gives_the_last_whole_lines_and_refuses_what_is_no_file(tmp_path):
    path = tmp_path / "log"
    path.write_bytes(b"first line\nsecond\nthird\n")
    assert files.read_tail(path, 100) == b"first line\nsecond\nthird\n"
    assert files.read_tail(path, 13) == b"second\nthird\n"  # exactly at a line's start
    assert files.read_tail(path, 12) == b"third\n"  # 'econd' cut: dropped
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)  # opening it would wait for a writer
    for what in (fifo, "/dev/zero", tmp_path):
        with pytest.raises(files.FileError, match="not a regular file"):
            files.read_tail(what, 100, "history")
    with pytest.raises(files.FileError, match="no such file"):
        files.read_tail(tmp_path / "none", 100)


def test_read_lines_limits_the_line_count(tmp_path):
    p = tmp_path / "s.tmcl"
    p.write_text("GAP 1, 0\n" * 11)
    assert len(files.read_lines(p, max_lines=11)) == 11
    with pytest.raises(files.FileError, match="script longer than 10 lines"):
        files.read_lines(p, max_lines=10)


def test_stream_lines_yields_as_lines_arrive_and_refuses_endless_ones():
    assert list(files.stream_lines(io.StringIO("a\nb\r\nc"))) == ["a", "b", "c"]
    endless = io.StringIO("ok\n" + "x" * 1000)
    got = files.stream_lines(endless, "<stdin>", max_line=100)
    assert next(got) == "ok"
    with pytest.raises(files.FileError, match="<stdin>:2: line longer than 100 characters"):
        next(got)


def test_write_replaces_the_file_only_when_complete(tmp_path):
    p = tmp_path / "out.txt"
    p.write_text("old")
    p.chmod(0o640)
    files.write_file(p, "new")
    assert p.read_text() == "new"
    assert p.stat().st_mode & 0o777 == 0o640  # the mode of the file it replaced
    assert os.listdir(tmp_path) == ["out.txt"]


def test_a_failing_write_leaves_the_old_file_and_no_temporary(tmp_path):
    p = tmp_path / "out.txt"
    p.write_text("old")
    with pytest.raises(files.FileError, match=f"cannot write {p}"):
        files.write_file(p, "half \udc80 written")  # cannot be encoded: fails mid-write
    assert p.read_text() == "old"
    assert os.listdir(tmp_path) == ["out.txt"]


def test_a_failing_rename_leaves_the_old_file(tmp_path, monkeypatch):
    p = tmp_path / "out.txt"
    p.write_text("old")

    def refuse(src, dst):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(os, "replace", refuse)
    with pytest.raises(files.FileError, match=f"cannot write {p}: Permission denied"):
        files.write_file(p, "new")
    assert p.read_text() == "old" and os.listdir(tmp_path) == ["out.txt"]


def test_streaming_writer_commits_or_aborts(tmp_path):
    p = tmp_path / "log.csv"
    p.write_text("old")
    with files.atomic_writer(p) as fh:
        fh.write("a\n")
        fh.flush()
        assert p.read_text() == "old"  # not in place until committed
    assert p.read_text() == "a\n"
    with pytest.raises(RuntimeError):
        with files.atomic_writer(p) as fh:
            fh.write("b\n")
            raise RuntimeError("the watch failed")
    assert p.read_text() == "a\n" and os.listdir(tmp_path) == ["log.csv"]


def test_devices_and_missing_folders(tmp_path):
    with pytest.raises(files.FileError, match="cannot write /dev/full: No space left on device"):
        files.write_file("/dev/full", "x" * 100_000)
    files.write_file(os.devnull, "x")  # a device is written as it is, not replaced
    assert os.path.exists(os.devnull) and not os.path.isfile(os.devnull)
    with pytest.raises(files.FileError, match=f"no such folder {tmp_path / 'no'}$"):
        files.write_file(tmp_path / "no" / "x", "x")
    with pytest.raises(files.FileError, match="it is a directory"):
        files.write_file(tmp_path, "x")


# -- TOML bounds (issue 31) -----------------------------------------------------------------

def test_toml_limits_finds_the_line_and_skips_strings_and_comments():
    from tmclsh.base.files import MAX_DEPTH, toml_limits

    ok = ('a = "[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[["\n'
          "b = '''\n" + "{" * 40 + "\n'''  # " + "[" * 40 + "\n"
          'c = """x\\"""' + "9" * 60 + '"""\n'
          "d = 1.5\ne = 1979-05-27T07:32:00.999Z\n[f.g]\nh = [[1, 2], [3]]\n")
    assert toml_limits(ok) is None
    assert toml_limits(ok + "x = " + "[" * (MAX_DEPTH + 1)) == (
        10, f"values nested more than {MAX_DEPTH} deep")
    assert toml_limits(ok + "x = " + "{a=" * 500) == (10, f"values nested more than {MAX_DEPTH} deep")
    assert toml_limits(ok + "x" + ".x" * 100 + " = 1") == (10, f"values nested more than {MAX_DEPTH} deep")
    assert toml_limits(ok + "x = 1" + "0" * 5000) == (10, "a number longer than 40 digits")
    assert toml_limits("x = 1" + "_0" * 30) == (1, "a number longer than 40 digits")
    assert toml_limits("x = " + "[" * MAX_DEPTH + "]" * MAX_DEPTH) is None


def test_bounded_read_turns_a_runaway_allocation_into_one_error():
    import pytest

    from tmclsh.base.files import FileError, bounded_read

    with pytest.raises(FileError, match=r"^x.blf: reading the CAN log needs more than 64 MiB"):
        with bounded_read("x.blf", "CAN log", limit=64 * 1024 * 1024):
            bytearray(1024 * 1024 * 1024)
    bytearray(256 * 1024 * 1024)  # the bound is gone after the block
