"""Modules tmclsh has no built-in data for: generic TMCL mode and the user's own module files,
driven through real bytes against a responder written from the manual (tests/responder.py)."""

from __future__ import annotations

import json
import struct

import pytest

from conftest import tmclsh_env
from responder import TcpModule

USER_1161 = """\
[module]
name = "TMCM-1161"
summary = "single axis stepper, described by its owner"
motors = 1
program_memory = 2048
firmware_id = 1161
version_string = "1161V130"
commands_like = "TMCM-1311"

[[axis]]
number = 4
name = "MaxPositioningSpeed"
access = "RWE"
min = 0
max = 2047

[[axis]]
number = 1
name = "ActualPosition"
access = "RW"
"""


@pytest.fixture
def module_1161():
    m = TcpModule(version="1161V130")
    yield m
    m.close()


@pytest.fixture
def config_home(tmp_path):
    """An empty config dir of our own (no user module files unless a test writes them)."""
    home = tmp_path / "config"
    (home / "tmclsh" / "modules").mkdir(parents=True)
    return home


def _env(config_home, **extra):
    return tmclsh_env(XDG_CONFIG_HOME=str(config_home), **extra)


def test_unknown_type_runs_in_generic_mode_by_number(module_1161, config_home, run_tmclsh):
    r = run_tmclsh("--port", module_1161.url, "--json", "-c",
                   "SAP 4, 0, 1234; GAP 4, 0; SGP 77, 0, 5; GGP 77, 0", env=_env(config_home))
    assert r.returncode == 0, r.stderr
    rows = [json.loads(x) for x in r.stdout.splitlines()]
    assert [row["reply"] for row in rows if row["op"] in (6, 10)] == [1234, 5]
    # the module got exactly these frames, after the 136 that named it (its string names no
    # type with data, so it is checked against 136 type 1, which has a checksum)
    assert module_1161.got == [(136, 0, 0, 0), (136, 1, 0, 0), (10, 129, 0, 0), (5, 4, 0, 1234),
                               (6, 4, 0, 0), (9, 77, 0, 5), (10, 77, 0, 0)]
    # told once that checks needing data are skipped
    assert r.stderr.count("no parameter data") == 1
    assert "TMCM-1161" in r.stderr


def test_generic_mode_refuses_names_and_what_does_not_fit_a_byte(module_1161, config_home,
                                                                 run_tmclsh):
    for line, words in (("GAP ActualPosition, 0", "by number"),
                        ("SAP 300, 0, 1", "0..255"),
                        ("SAP 4, 0, 4294967296", "32 bits"),
                        ("RFS START, 0", "by number, 13")):
        before = list(module_1161.got)
        r = run_tmclsh("--port", module_1161.url, "-c", line, env=_env(config_home))
        assert r.returncode == 2, (line, r.stderr)  # refused before anything was sent
        assert words in r.stderr, (line, r.stderr)
        assert "Traceback" not in r.stderr
        assert module_1161.got[len(before):] == [(136, 0, 0, 0), (136, 1, 0, 0), (10, 129, 0, 0)], line  # nothing else sent


def test_motor_numbers_are_bytes_not_the_data_files(module_1161, config_home, run_tmclsh):
    r = run_tmclsh("--port", module_1161.url, "-c", "GAP 1, 5", env=_env(config_home))
    assert r.returncode == 0, r.stderr
    assert module_1161.got[-1] == (6, 1, 5, 0)


def test_forced_generic_names_the_type_from_136(module_1161, config_home, run_tmclsh):
    r = run_tmclsh("--port", module_1161.url, "-m", "generic", "--json", "-c", ".module",
                   env=_env(config_home))
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.splitlines()[-1])["module"] == "TMCM-1161"


def test_banner_and_toolbar_say_numbers_only():
    from tmclsh.client.text import LineClient
    from tmclsh.shell.repl.app import banner
    from tmclsh.shell.render import Output
    from tmclsh.shell.lang.session import Session
    from tmclsh.shell.repl.toolbar import create_toolbar_tokens_func

    m = TcpModule(version="1161V130")
    try:
        from tmclsh.client.bringup import start
        from tmclsh.link import open_serial

        client = start(LineClient(open_serial(m.url), timeout=1))
        session = Session(client, Output())
        assert "TMCM-1161 (no parameter data: numbers only)" in "".join(f[1] for f in banner(session))
        text = "".join(f[1] for f in create_toolbar_tokens_func(session)())
        assert "TMCM-1161 (no parameter data: numbers only)" in text
        client.close()
    finally:
        m.close()


def test_user_module_file_is_found_and_checked_against(module_1161, config_home, run_tmclsh):
    (config_home / "tmclsh" / "modules" / "mine.toml").write_text(USER_1161)
    ok = run_tmclsh("--port", module_1161.url, "--json", "-c",
                    "SAP MaxPositioningSpeed, 0, 2000; GAP MaxPositioningSpeed, 0",
                    env=_env(config_home))
    assert ok.returncode == 0, ok.stderr
    assert "no parameter data" not in ok.stderr
    assert json.loads(ok.stdout.splitlines()[-1])["reply"] == 2000
    sent = len(module_1161.got)
    bad = run_tmclsh("--port", module_1161.url, "-c", "SAP MaxPositioningSpeed, 0, 5000",
                     env=_env(config_home))
    assert bad.returncode == 2 and "0..2047" in bad.stderr
    assert module_1161.got[sent:] == [(136, 0, 0, 0), (10, 129, 0, 0)]  # the range came from the user's file


def test_module_file_option(module_1161, config_home, tmp_path, run_tmclsh):
    path = tmp_path / "elsewhere.toml"
    path.write_text(USER_1161)
    r = run_tmclsh("--port", module_1161.url, "--module-file", str(path), "-c",
                   "GAP ActualPosition, 0", env=_env(config_home))
    assert r.returncode == 0, r.stderr
    assert module_1161.got[-1] == (6, 1, 0, 0)


@pytest.mark.parametrize("broken, line, words", [
    (USER_1161.replace("min = 0", 'min = "zero"'), 14, "min must be an integer"),
    (USER_1161.replace('access = "RW"\n', ""), 17, "lacks access"),
    (USER_1161.replace("motors = 1", "motors = 1 1"), 4, "not valid TOML"),
    (USER_1161.replace("firmware_id = 1161\n", ""), 1, "lacks firmware_id"),
    (USER_1161.replace('access = "RW"', 'access = "RX"'), 20, "access must be one of"),
    (USER_1161 + "colour = 3\n", 21, "unknown key 'colour'"),
])
def test_a_broken_module_file_is_one_line_and_the_shell_goes_on(
        broken, line, words, module_1161, config_home, run_tmclsh):
    path = config_home / "tmclsh" / "modules" / "mine.toml"
    path.write_text(broken)
    r = run_tmclsh("--port", module_1161.url, "-c", "GAP 4, 0", env=_env(config_home))
    assert r.returncode == 0, r.stderr  # went on, in generic mode
    warning = [x for x in r.stderr.splitlines() if str(path) in x]
    assert len(warning) == 1 and f"{path}:{line}:" in warning[0] and words in warning[0], r.stderr
    assert "Traceback" not in r.stderr
    check = run_tmclsh("modules", "check", str(path), env=_env(config_home))
    assert check.returncode == 1 and f"{path}:{line}:" in check.stderr


def test_modules_lists_where_each_comes_from(config_home, run_tmclsh):
    (config_home / "tmclsh" / "modules" / "mine.toml").write_text(USER_1161)
    r = run_tmclsh("modules", "--json", env=_env(config_home))
    assert r.returncode == 0, r.stderr
    rows = {row["module"]: row for row in map(json.loads, r.stdout.splitlines())}
    assert rows["TMCM-1311"]["source"] == "built in"
    assert rows["TMCM-1161"]["source"].endswith("mine.toml")
    assert rows["TMCM-1161"]["version_string"] == "1161V130"
    text = run_tmclsh("modules", env=_env(config_home)).stdout
    assert "generic" in text and "mine.toml" in text


def test_modules_check_accepts_the_shipped_files(run_tmclsh):
    from tmclsh.tmcl.modules import built_in
    from pathlib import Path
    import tmclsh.tmcl.modules

    folder = Path(tmclsh.tmcl.modules.__file__).parent
    for name in built_in():
        path = folder / (name.lower().replace("-", "") + ".toml")
        r = run_tmclsh("modules", "check", str(path))
        assert r.returncode == 0 and "OK" in r.stdout, r.stderr


def test_responder_frames_are_the_manuals():
    """The responder itself: a hand-made frame gets the manual's reply bytes."""
    import socket

    m = TcpModule(version="1161V130")
    try:
        s = socket.create_connection(("127.0.0.1", int(m.url.rsplit(":", 1)[1])))
        body = bytes([1, 5, 4, 0]) + struct.pack(">i", 1000)  # SAP 4, 0, 1000
        s.sendall(body + bytes([sum(body) & 0xFF]))
        reply = s.recv(9)
        assert reply[:4] == bytes([2, 1, 100, 5]) and sum(reply[:8]) & 0xFF == reply[8]
        s.close()
    finally:
        m.close()


def test_the_simulator_refuses_generic_mode(run_tmclsh):
    r = run_tmclsh("--sim", "generic", "-c", "GAP 1, 0")
    assert r.returncode == 3 and "needs a module's data" in r.stderr
    assert run_tmclsh("sim", "-m", "generic", "--tcp", "127.0.0.1:0").returncode == 2


def test_a_user_module_can_be_simulated(config_home, run_tmclsh):
    (config_home / "tmclsh" / "modules" / "mine.toml").write_text(USER_1161)
    r = run_tmclsh("--sim", "TMCM-1161", "-c", "SAP MaxPositioningSpeed, 0, 2047; GAP 4, 0",
                   env=_env(config_home))
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[-1] == "MaxPositioningSpeed = 2047"


def test_version_string_must_be_what_136_answers(config_home, tmp_path, run_tmclsh):
    path = tmp_path / "short.toml"
    path.write_text(USER_1161.replace('"1161V130"', '"1161V1"'))
    r = run_tmclsh("modules", "check", str(path), env=_env(config_home))
    assert r.returncode == 1 and f"{path}:7:" in r.stderr and "8" in r.stderr


def test_unknown_command_in_generic_mode_points_to_numbers(module_1161, config_home,
                                                          run_tmclsh):
    r = run_tmclsh("--port", module_1161.url, "-c", "XYZZY 1, 2", env=_env(config_home))
    assert r.returncode == 2 and "by number" in r.stderr
    assert module_1161.commands() == [136, 136, 10]  # 136 (string, type 1), GGP 129 at connect


def test_forced_generic_on_a_documented_module_does_not_say_it_has_no_data(config_home,
                                                                           run_tmclsh):
    """`-m generic` on a TMCM-1311 (a module with data): the notice and the refusal of a name
    say that generic mode was chosen, and how to get the names back, not that the data is
    missing."""
    m = TcpModule(version="1311V111")
    try:
        r = run_tmclsh("--port", m.url, "-m", "generic", "-c", "GAP ActualPosition, 0",
                       env=_env(config_home))
    finally:
        m.close()
    assert r.returncode == 2, r.stderr
    assert "no parameter data" not in r.stderr and "has no parameter data" not in r.stderr
    assert r.stderr.count("generic mode (-m generic)") == 2, r.stderr
    assert "leave -m generic out to use the TMCM-1311's parameter data" in r.stderr
    assert [g[0] for g in m.got] == [136, 10]  # the name was refused before anything was sent


def test_a_module_file_without_end_is_refused_unread(config_home, tmp_path, run_tmclsh):
    """`modules check /dev/zero` (or --module-file) grew until a MemoryError traceback."""
    huge = tmp_path / "huge.toml"
    with open(huge, "wb") as fh:
        fh.truncate(17 * 1024 * 1024)  # sparse: no disk used
    r = run_tmclsh("modules", "check", str(huge), env=_env(config_home))
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert r.stderr.strip() == f"tmclsh: {huge}: module file larger than 16 MiB; not read"
    r = run_tmclsh("modules", "check", str(tmp_path / "none.toml"), env=_env(config_home))
    assert r.stderr.strip() == f"tmclsh: cannot read {tmp_path / 'none.toml'}: no such file"


def test_params_in_generic_mode_says_there_is_no_list(module_1161, config_home, run_tmclsh):
    """Was "no axis or global parameter of the TMCM-1161 matches ''"."""
    r = run_tmclsh("--port", module_1161.url, "-c", ".params", env=_env(config_home))
    assert r.returncode == 1
    assert ("error: TMCM-1161 (no parameter data: numbers only): there is no list of its "
            "parameters; read one by number") in r.stderr
    assert "matches ''" not in r.stderr
    assert [g[0] for g in module_1161.got] == [136, 136, 10]  # nothing read for it


def test_a_key_outside_any_table_is_not_called_a_table():
    from tmclsh.tmcl.modules.schema import ModuleFileError, parse

    with pytest.raises(ModuleFileError, match=r"^mine.toml:1: name = \.\.\. outside any table "
                                              r"\(module keys go under \[module\]\)"):
        parse('name = "TMCM-1161"\n', "mine.toml")
    with pytest.raises(ModuleFileError, match=r"^mine.toml:1: unknown table \[foo\]"):
        parse("[foo]\nx = 1\n", "mine.toml")
