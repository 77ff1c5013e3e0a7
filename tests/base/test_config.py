"""Configuration: precedence (option > environment > profile > default), profiles, settings
merged over the packaged default.toml, and clear errors for anything unknown or mistyped."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from tmclsh.cli import main as cli
from tmclsh.base import config
from tmclsh.client import connect as connection
from tmclsh.base.config import Config, load_config, load_settings, parse_config, resolve
from tmclsh.base.errors import TmclError, ValidationError

BENCH = """\
[settings]
editing_mode = "vi"
history_size = 50

[profiles.bench]
port = "/dev/ttyACM0"
baud = 115200
address = 3
module = "TMCM-1311"
ascii = true
timeout = 2

[profiles.can]
can = "socketcan:can0"
can_id = 5
reply_id = 6
"""


@pytest.fixture(autouse=True)
def clean_env(monkeypatch, tmp_path):
    """No TMCLSH_* or NO_COLOR from the developer's shell; config and state under tmp."""
    for var in list(config.ENVIRONMENT) + ["TMCLSH_CONFIG", "NO_COLOR"]:
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))


@pytest.fixture()
def bench(tmp_path) -> Config:
    path = tmp_path / "config" / "tmclsh" / "config.toml"
    path.parent.mkdir(parents=True)
    path.write_text(BENCH)
    return load_config()


def test_paths_follow_xdg(tmp_path, monkeypatch):
    assert config.config_file() == tmp_path / "config" / "tmclsh" / "config.toml"
    assert config.history_file() == tmp_path / "state" / "tmclsh" / "history"
    monkeypatch.setenv("TMCLSH_CONFIG", str(tmp_path / "other.toml"))
    assert config.config_file() == tmp_path / "other.toml"
    monkeypatch.delenv("XDG_CONFIG_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.delenv("TMCLSH_CONFIG")
    assert config.config_file() == tmp_path / "home" / ".config" / "tmclsh" / "config.toml"


def test_missing_file_is_an_empty_config():
    cfg = load_config()
    assert cfg.profiles == {} and cfg.settings == {}
    assert resolve({}, cfg, env={}) == config.CONNECTION_DEFAULTS


# -- precedence ---------------------------------------------------------------------------

def test_defaults_when_nothing_is_given():
    got = resolve({"port": None, "baud": None, "profile": None}, Config(Path("x")), env={})
    assert got == {"baud": 9600, "address": 1, "host_address": 2, "ascii": False,
                   "timeout": 1.0, "retries": 2}
    assert not any(k in got for k in config.KINDS)  # cli then looks for a module / the simulator


def test_profile_beats_default(bench):
    got = resolve({"profile": "bench"}, bench, env={})
    assert got["port"] == "/dev/ttyACM0"
    assert got["baud"] == 115200 and got["address"] == 3 and got["ascii"] is True
    assert got["timeout"] == 2.0 and isinstance(got["timeout"], float)
    assert got["host_address"] == 2  # not in the profile: default
    assert "profile" not in got


def test_environment_beats_profile(bench):
    env = {"TMCLSH_BAUD": "57600", "TMCLSH_ADDRESS": "0x05", "TMCLSH_ASCII": "no",
           "TMCLSH_TIMEOUT": "0.5"}
    got = resolve({"profile": "bench"}, bench, env=env)
    assert got["baud"] == 57600 and got["address"] == 5 and got["ascii"] is False
    assert got["timeout"] == 0.5
    assert got["port"] == "/dev/ttyACM0"  # the profile still gives what the environment does not


def test_option_beats_environment(bench):
    env = {"TMCLSH_BAUD": "57600", "TMCLSH_PORT": "/dev/ttyUSB1"}
    got = resolve({"profile": "bench", "baud": 19200, "port": "/dev/ttyUSB2"}, bench, env=env)
    assert got["baud"] == 19200 and got["port"] == "/dev/ttyUSB2"


def test_profile_from_environment(bench):
    got = resolve({}, bench, env={"TMCLSH_PROFILE": "can"})
    assert got["can"] == "socketcan:can0" and got["can_id"] == 5 and got["reply_id"] == 6
    # an option names another profile: the option wins
    got = resolve({"profile": "bench"}, bench, env={"TMCLSH_PROFILE": "can"})
    assert got["port"] == "/dev/ttyACM0" and "can" not in got


def test_connection_kinds_exclude_each_other(bench):
    # the profile says port, the command line says CAN: the port is dropped
    got = resolve({"profile": "bench", "can": "virtual:x"}, bench, env={})
    assert got["can"] == "virtual:x" and "port" not in got
    # the environment names a port over a CAN profile
    got = resolve({}, bench, env={"TMCLSH_PROFILE": "can", "TMCLSH_PORT": "loop://"})
    assert got["port"] == "loop://" and "can" not in got and got["can_id"] == 5
    # --sim beats both
    got = resolve({"sim": "TMCM-351"}, bench, env={"TMCLSH_PORT": "loop://", "TMCLSH_PROFILE": "can"})
    assert got["sim"] == "TMCM-351" and "port" not in got and "can" not in got


def test_empty_variables_count_as_unset(bench):
    got = resolve({"profile": "bench"}, bench, env={"TMCLSH_PORT": "", "TMCLSH_BAUD": ""})
    assert got["port"] == "/dev/ttyACM0" and got["baud"] == 115200


def test_cli_resolves_through_config(bench, monkeypatch):
    monkeypatch.setenv("TMCLSH_ADDRESS", "7")
    args = cli.build_parser().parse_args(["--profile", "bench", "--baud", "38400"])
    got = connection.connection_settings(args)
    assert got["port"] == "/dev/ttyACM0" and got["baud"] == 38400 and got["address"] == 7
    args = cli.build_parser().parse_args(["--profile", "bench", "-a", "9", "--ascii"])
    got = connection.connection_settings(args)
    assert got["address"] == 9 and got["ascii"] is True


# -- errors -------------------------------------------------------------------------------

def test_unknown_profile_names_the_known_ones(bench):
    with pytest.raises(ValidationError, match=r"no profile 'lab'.*known: bench, can"):
        resolve({"profile": "lab"}, bench, env={})
    with pytest.raises(ValidationError, match="none defined"):
        resolve({}, Config(Path("c.toml")), env={"TMCLSH_PROFILE": "lab"})


def test_unknown_profile_is_an_error_exit(bench, capsys):
    assert cli.main(["--profile", "lab", "-c", "GAP 1, 0"]) == cli.EXIT_USAGE  # a usage error
    assert "no profile 'lab'" in capsys.readouterr().err


@pytest.mark.parametrize("text, message", [
    ("[profiles.x]\nbaudrate = 9600\n", r"\[profiles\.x\]: unknown key\(s\) baudrate; known: port, baud"),
    ("[settings]\ncolour = 'never'\n", r"unknown setting\(s\) colour; known: color, editing_mode"),
    ("[colors]\nprompt = 'red'\n", r"unknown table\(s\) colors; known: settings, profiles"),
    ("[profiles.x]\nbaud = '9600'\n", r"baud must be an integer, got '9600'"),
    ("[profiles.x]\naddress = 300\n", r"\[profiles\.x\] address: must be a whole number from 0 to 255, got 300"),
    ("[profiles.x]\nascii = 1\n", r"ascii must be true or false, got 1"),
    ("[profiles.x]\ntimeout = 0\n",
     r"\[profiles\.x\] timeout: must be a number of seconds from 0\.001 to 60, got 0\.0"),
    ("[profiles.x]\nport = 'a'\ncan = 'virtual:b'\n", r"port and can exclude each other"),
    ("[profiles]\nx = 3\n", r"a profile must be a table"),
    ("[settings]\nediting_mode = 'nano'\n", r"editing_mode must be one of emacs, vi, got 'nano'"),
    ("[settings]\nhistory_size = -1\n", r"history_size: must be a whole number from 0 to 1000000, got -1"),
    ("[settings]\nconfirm = 'yes'\n", r"confirm must be true or false"),
    ("[settings\n", r"config\.toml: "),  # TOML syntax error, with the file name
])
def test_bad_config_files(tmp_path, text, message):
    path = tmp_path / "config.toml"
    path.write_text(text)
    with pytest.raises(ValidationError, match=message):
        load_config(path)


def test_errors_are_tmcl_errors():
    assert issubclass(ValidationError, TmclError)  # so cli prints one line and exits 1


@pytest.mark.parametrize("env, message", [
    ({"TMCLSH_BAUD": "fast"}, r"TMCLSH_BAUD: must be one of 9600, .*, got 'fast'"),
    ({"TMCLSH_ADDRESS": "256"}, r"TMCLSH_ADDRESS: must be a whole number from 0 to 255, got '256'"),
    ({"TMCLSH_ASCII": "maybe"}, r"TMCLSH_ASCII='maybe' must be true or false"),
    ({"TMCLSH_TIMEOUT": "-1"}, r"TMCLSH_TIMEOUT: must be a number of seconds from 0\.001 to 60"),
])
def test_bad_environment(env, message):
    with pytest.raises(ValidationError, match=message):
        resolve({}, Config(Path("x")), env=env)


def test_not_utf8(tmp_path):
    path = tmp_path / "config.toml"
    path.write_bytes(b"[settings]\ncolor = '\xff'\n")
    with pytest.raises(ValidationError, match="not UTF-8"):
        load_config(path)


# -- settings -----------------------------------------------------------------------------

def test_settings_default_from_default_toml():
    s = load_settings(Config(Path("x")), env={})
    assert s == {"color": "auto", "editing_mode": "emacs", "history_size": 1000, "confirm": True,
                 "pager": True}
    assert tuple(s) == config.SETTING_KEYS


def test_user_settings_override_defaults(bench):
    s = load_settings(bench, env={})
    assert s["editing_mode"] == "vi" and s["history_size"] == 50
    assert s["color"] == "auto" and s["confirm"] is True


def test_no_color(bench, tmp_path):
    assert load_settings(bench, env={"NO_COLOR": "1"})["color"] == "never"
    always = parse_config('[settings]\ncolor = "always"\n', tmp_path / "c.toml")
    assert load_settings(always, env={"NO_COLOR": "1"})["color"] == "always"


def test_load_settings_reads_the_config_file(bench):
    assert load_settings()["editing_mode"] == "vi"


def test_settings_do_not_leak_between_calls():
    a = load_settings(Config(Path("x")), env={})
    a["history_size"] = 1
    assert load_settings(Config(Path("x")), env={})["history_size"] == 1000


# -- the packaged default.toml ------------------------------------------------------------

def test_default_toml_is_a_valid_config(tmp_path):
    text = config.default_config_text()
    cfg = parse_config(text, tmp_path / "default.toml")
    assert cfg.settings == config.default_settings()


def test_default_toml_examples_are_valid_when_uncommented(tmp_path):
    text = config.default_config_text()
    examples = []
    for line in text.splitlines():
        m = re.match(r"# (\[profiles\.\w+\]|\w+ = .*)$", line)
        if m:
            examples.append(m.group(1))
    uncommented = "\n".join(examples)
    cfg = parse_config(uncommented, tmp_path / "c.toml")
    assert set(cfg.profiles) == {"bench", "rs485", "can", "remote"}


def test_default_toml_documents_every_profile_key():
    text = config.default_config_text()
    for key in config.CONNECTION_KEYS:
        assert re.search(rf"^#\s+{key}\s{{2,}}\S", text, re.M), f"{key} undocumented in default.toml"


def test_every_variable_names_a_connection_setting():
    for var, key in config.ENVIRONMENT.items():
        assert key in config.CONNECTION_KEYS or key == "profile", var


def test_python_m_tmclsh_config(tmp_path, bench):
    run = lambda *a: subprocess.run([sys.executable, "-m", "tmclsh.base.config", *a],  # noqa: E731
                                    capture_output=True, text=True, timeout=60)
    out = run("--default")
    assert out.returncode == 0 and out.stdout == config.default_config_text()
    out = run("--profiles")
    assert out.stdout.split() == ["bench", "can"]
    out = run()
    assert out.returncode == 0 and 'editing_mode = "vi"' in out.stdout
    assert "[profiles.bench]" in out.stdout
    config.config_file().write_text("[settings]\nbogus = 1\n")
    out = run()
    assert out.returncode == 1 and "unknown setting(s) bogus" in out.stderr


def test_an_empty_config_is_read_without_the_guard_a_parser_needs(tmp_path, monkeypatch):
    """The guard around a config file's parser (a watching thread, a pipe, the memory
    limit: base/files.bounded_read) is for text a parser reads; an empty file (the
    TMCLSH_CONFIG=/dev/null of scripts and tests) is read at every start without it."""
    from contextlib import contextmanager

    from tmclsh.base import files

    guarded: list[str] = []

    @contextmanager
    def counting(name, what="file", limit=files.MAX_READ_MEMORY):
        guarded.append(name)
        yield

    monkeypatch.setattr(files, "bounded_read", counting)
    empty = tmp_path / "empty.toml"
    empty.write_text("\n  \n")
    assert load_config(empty).settings == {} and guarded == []
    full = tmp_path / "full.toml"
    full.write_text('[settings]\ncolor = "never"\n')
    assert load_config(full).settings["color"] == "never" and guarded == [str(full)]
