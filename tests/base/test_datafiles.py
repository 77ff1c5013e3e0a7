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


def test_a_users_module_file_is_checked_once_per_content(tmp_path, monkeypatch):
    """A user's module file (forty of them after 'modules import pytrinamic --all') is parsed
    and checked once; read again unchanged it comes from the cache, edited it is checked again
    and a mistake in it is still one line naming the file and the line."""
    from tmclsh.tmcl.modules import ModuleFileError, read_file, schema

    monkeypatch.setattr(datafiles, "cache_dir", lambda: tmp_path / "cache")
    checked = []
    real = schema.parse
    monkeypatch.setattr(schema, "parse", lambda text, where: checked.append(where) or
                        real(text, where))
    path = tmp_path / "tmcm1161.toml"
    text = ('[module]\nname = "TMCM-1161"\nmotors = 1\nprogram_memory = 2048\n'
            'firmware_id = 1161\nversion_string = "1161V130"\n\n'
            '[[axis]]\nnumber = 4\nname = "MaxPositioningSpeed"\naccess = "RWE"\n')
    path.write_text(text)
    assert read_file(path).axis(4).name == "MaxPositioningSpeed"
    assert read_file(path).axis(4).name == "MaxPositioningSpeed"
    assert checked == [str(path)]
    path.write_text(text.replace('access = "RWE"', 'access = "RWX"'))
    with pytest.raises(ModuleFileError, match=r"tmcm1161\.toml:11: .*access must be one of"):
        read_file(path)
    with pytest.raises(ModuleFileError):  # a refused file is not kept: refused every time
        read_file(path)
    assert len(checked) == 3
