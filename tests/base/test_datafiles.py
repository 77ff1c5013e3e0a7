"""Parsed data files come from the cache only while the file is unchanged; a cache that is
damaged or cannot be written changes nothing but the speed."""

from __future__ import annotations

import sys
import tomllib

import pytest

from tmclsh.base import datafiles


@pytest.fixture
def package(tmp_path, monkeypatch):
    """A package ``tmcl_data_test`` with one data file, and a cache folder of its own."""
    root = tmp_path / "src" / "tmcl_data_test"
    root.mkdir(parents=True)
    (root / "__init__.py").write_text("")
    (root / "table.toml").write_text('[module]\nname = "A"\nvalues = [1, 2, 3]\n')
    monkeypatch.syspath_prepend(str(tmp_path / "src"))
    cache = tmp_path / "cache"
    monkeypatch.setattr(datafiles, "cache_dir", lambda: cache)
    yield root, cache
    sys.modules.pop("tmcl_data_test", None)


def test_the_packaged_files_read_back_as_parsed(tmp_path, monkeypatch):
    from importlib import resources

    monkeypatch.setattr(datafiles, "cache_dir", lambda: tmp_path)
    for package, name in [("tmclsh.tmcl", "instructions.toml"), ("tmclsh.tmcl.modules", "tmcm1311.toml"),
                          ("tmclsh.base", "default.toml")]:
        parsed = tomllib.loads(resources.files(package).joinpath(name).read_text("utf-8"))
        assert datafiles.load_toml(package, name) == parsed  # parsed and stored
        assert datafiles.load_toml(package, name) == parsed  # from the cache
    assert len(list(tmp_path.glob("*.marshal"))) == 3


def test_an_edited_file_is_parsed_again(package):
    root, cache = package
    assert datafiles.load_toml("tmcl_data_test", "table.toml")["module"]["values"] == [1, 2, 3]
    (root / "table.toml").write_text('[module]\nname = "A"\nvalues = [4]\n')
    assert datafiles.load_toml("tmcl_data_test", "table.toml")["module"]["values"] == [4]
    assert len(list(cache.glob("table-*.marshal"))) == 2


def test_a_damaged_cache_is_parsed_over(package):
    _, cache = package
    datafiles.load_toml("tmcl_data_test", "table.toml")
    (entry,) = cache.glob("table-*.marshal")
    entry.write_bytes(b"\x00garbage")
    assert datafiles.load_toml("tmcl_data_test", "table.toml")["module"]["name"] == "A"
    entry.write_bytes(b"")
    assert datafiles.load_toml("tmcl_data_test", "table.toml")["module"]["name"] == "A"


def test_a_cache_that_cannot_be_written_is_skipped(package, monkeypatch, tmp_path):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the cache folder would be")
    monkeypatch.setattr(datafiles, "cache_dir", lambda: blocker / "data")
    assert datafiles.load_toml("tmcl_data_test", "table.toml")["module"]["values"] == [1, 2, 3]


def test_bad_toml_is_still_an_error(package):
    root, _ = package
    (root / "table.toml").write_text("[module\n")
    with pytest.raises(tomllib.TOMLDecodeError):
        datafiles.load_toml("tmcl_data_test", "table.toml")
