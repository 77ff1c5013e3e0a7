"""A module's link identity is its own (issue 31): a backup saved at one address, restored
or replayed onto a module at another, leaves the second module's address, baud rate, CAN
settings and ASCII mode as they were and says so; ``--with-link`` moves it, and tmclsh
follows it there.

Driven against ``tests/responder.py`` (a module written from the manual's frame tables, not
the simulator): a value store for SAP/SGP/GAP/GGP that, like a real module, answers at the
address GP 66 was last set to.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tmclsh.base.errors import ValidationError
from tmclsh.client.text import LineClient
from tmclsh.link import open_serial
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session

from responder import CanModule, PtyModule

SGP, GGP = 9, 10
# TMCM-1311 bank 0: baud rate, address, ASCII mode, CAN bit rate, reply id, id, telegram
# pause, host address (manual §10.1), with values that differ between the two modules
LINK_A = {65: 0, 66: 1, 67: 0, 69: 8, 70: 2, 71: 1, 75: 0, 76: 2}
LINK_B = {65: 7, 66: 5, 67: 1, 69: 5, 70: 12, 71: 11, 75: 15, 76: 2}
MAX_CURRENT = (6, 0, False)  # AP 6, motor 0: a configuration value the clone carries


class Moving(PtyModule):
    """A module that takes a new serial address (SGP 66) at once and answers there, as the
    manual's GP 66 says ("the module (target) address for RS485")."""

    def respond(self, command: int, type_: int, motor: int, value: int):
        ans = super().respond(command, type_, motor, value)
        if command == SGP and type_ == 66 and motor == 0 and ans[0] == 100:
            self.address = value
            self.addresses = frozenset({value})
        return ans


def _module(link: dict[int, int], max_current: int) -> Moving:
    m = Moving(version="1311V111", address=link[66])
    for number, value in link.items():
        m.values[(number, 0, True)] = value
    m.values[MAX_CURRENT] = max_current
    m.values[(4, 0, False)] = 1000  # a speed, so that the backup holds one in range
    return m


def _session(module: Moving, **kw) -> tuple[LineClient, Session]:
    client = LineClient(open_serial(module.path), module="TMCM-1311", timeout=0.5, retries=1,
                        address=module.address)
    return client, Session(client, Output(), yes=True, **kw)


@pytest.fixture
def backup_of_a(tmp_path) -> Path:
    """A backup of module A at address 1 (MaxCurrent 100)."""
    a = _module(LINK_A, 100)
    client, s = _session(a)
    path = tmp_path / "a.tmcl"
    try:
        s.run_line(f".save {path}")
    finally:
        client.close()
        a.close()
    return path


def _link_writes(module: Moving) -> list[tuple[int, int]]:
    return [(t, v) for c, t, m, v in module.got if c == SGP and m == 0 and t in LINK_B]


def test_save_writes_the_link_identity_in_a_section_of_its_own(backup_of_a):
    text = backup_of_a.read_text(encoding="utf-8")
    head, _, link = text.partition("// -- link identity:")
    assert link, "no link identity section"
    assert re.search(r"^SGP SerialAddress, 0, 1\b", link, re.M)
    assert re.search(r"^SGP CANID, 0, 1\b", link, re.M)
    assert re.search(r"^SGP TelegramPauseTime, 0, 0\b", link, re.M)
    assert not re.search(r"^SGP (SerialAddress|RS485BaudRate|CANID|ASCIIMode)\b", head, re.M)
    assert re.search(r"^SAP MaxCurrent, 0, 100\b", head, re.M)


def test_restore_onto_another_address_leaves_its_link_alone(backup_of_a, capsys):
    b = _module(LINK_B, 50)
    client, s = _session(b)
    try:
        capsys.readouterr()
        s.run_line(f".restore {backup_of_a}")  # no error: exit 0 in -c
        said = capsys.readouterr().out
        assert b.values[MAX_CURRENT] == 100  # the configuration came over
        assert _link_writes(b) == []  # and nothing of its place on the line was written
        assert {n: b.values[(n, 0, True)] for n in LINK_B} == LINK_B
        assert b.address == 5 and client.address == 5
        assert "left alone" in said and "SerialAddress = 1" in said and "CANID = 1" in said
        assert "not restored" not in said and "reconnect" not in said
        # .diff says the same, and finds nothing else
        s.run_line(f".diff {backup_of_a}")
        said = capsys.readouterr().out
        assert "left alone" in said and "no differences" in said
        # with the option it compares the link too
        s.run_line(f".diff {backup_of_a} --with-link")
        said = capsys.readouterr().out
        assert "SerialAddress" in said and "left alone" not in said
    finally:
        client.close()
        b.close()


def test_restore_with_link_moves_the_module_and_follows_it(backup_of_a, capsys):
    b = _module(LINK_B, 50)
    client, s = _session(b, interactive=True)
    asked: list[str] = []
    s.yes = False
    s.ask = lambda question: asked.append(question) or True
    try:
        capsys.readouterr()
        s.run_line(f".restore {backup_of_a} --with-link")
        out = capsys.readouterr()
        said = out.out + out.err
        # the question named each link parameter it would change, old and new
        assert len(asked) == 1
        for name, old, new in (("SerialAddress", 5, 1), ("RS485BaudRate", 7, 0),
                               ("CANID", 11, 1), ("CANReplyID", 12, 2), ("ASCIIMode", 1, 0),
                               ("TelegramPauseTime", 15, 0), ("CANBitRate", 5, 8)):
            assert f"{name} (GP " in asked[0] and f"{old} -> {new}" in asked[0], name
        # written, the module moved, and tmclsh followed it there
        assert {n: b.values[(n, 0, True)] for n in LINK_A} == LINK_A
        assert b.address == 1 and client.address == 1
        assert "answers at address 1 now" in said
        # the address last but for what may cut the link; read back where it answers now
        writes = [(c, t) for c, t, m, v in b.got if c in (5, SGP)]
        assert writes.index((5, 6)) < writes.index((SGP, 66))
        reads_after = b.got[[g[:2] for g in b.got].index((SGP, 66)):]
        assert (GGP, 66, 0, 0) in reads_after
        # CAN ids over a serial line cut nothing: no word of reconnecting, no failure
        assert "reconnect" not in said and "not restored" not in said
        assert client.value("GAP MaxCurrent, 0") == 100
    finally:
        client.close()
        b.close()


def test_replayed_backup_leaves_link_alone_unless_with_link(backup_of_a, run_tmclsh):
    b = _module(LINK_B, 50)
    try:
        p = run_tmclsh("--port", b.path, "-a", "5", "--yes", "-f", str(backup_of_a),
                       timeout=120)
        assert p.returncode == 0, p.stdout + p.stderr
        said = p.stdout + p.stderr
        assert "left alone" in said and "SerialAddress = 1" in said
        assert b.values[MAX_CURRENT] == 100
        assert _link_writes(b) == []
        assert {n: b.values[(n, 0, True)] for n in LINK_B} == LINK_B and b.address == 5

        p = run_tmclsh("--port", b.path, "-a", "5", "--yes", "--with-link", "-f",
                       str(backup_of_a), timeout=120)
        assert p.returncode == 0, p.stdout + p.stderr
        said = p.stdout + p.stderr
        assert "answers at address 1 now" in said and "left alone" not in said
        assert b.address == 1
        assert {n: b.values[(n, 0, True)] for n in LINK_A} == LINK_A
    finally:
        b.close()


# -- a module known by names only ----------------------------------------------------------

NAMES_ONLY = """\
[module]
name = "TMCM-1161"
motors = 1
program_memory = 2048
firmware_id = 1161
version_string = "1161V000"
commands_like = "generic"
any_io = true
origin = "PyTrinamic 0.2.26, names and numbers only"

[[axis]]
number = 4
name = "MaxVelocity"
access = "RWE"
state = true

[[axis]]
number = 6
name = "MaxCurrent"
access = "RWE"
state = true

[[global]]
number = 66
bank = 0
name = "SerialAddress"
access = "RWE"
state = true
"""


def test_save_of_a_module_known_by_names_only_fails_unless_names_only(tmp_path, run_tmclsh):
    """Such a backup restored 0 parameters and reported success; now it says what it could
    not save and fails, unless --names-only asks for the values as comments."""
    data = tmp_path / "tmcm1161.toml"
    data.write_text(NAMES_ONLY, encoding="utf-8")
    module = PtyModule(version="1161V130")
    module.values[MAX_CURRENT] = 77
    backup = tmp_path / "b.tmcl"
    try:
        module.got.clear()
        p = run_tmclsh("--port", module.path, "--module-file", str(data), "-c",
                       f".save {backup}")
        assert p.returncode != 0, p.stdout
        assert "by name only" in p.stderr and "MaxCurrent" in p.stderr
        assert "--names-only" in p.stderr and not backup.exists()
        assert not [g for g in module.got if g[0] == 6]  # nothing read for a backup
        p = run_tmclsh("--port", module.path, "--module-file", str(data), "-c",
                       f".save {backup} --names-only")
        assert p.returncode == 0, p.stderr
        text = backup.read_text(encoding="utf-8")
        assert "// MaxCurrent = 77" in text and not re.search(r"^S[AG]P ", text, re.M)
        assert "by name only" in p.stdout + p.stderr
    finally:
        module.close()


# -- over CAN: the ids are followed, the bit rate is what cuts the link --------------------------

class MovingOnCan(CanModule):
    """A module on python-can's virtual bus that takes a new CAN id (GP 71) and reply id
    (GP 70) at once, as the manual describes them."""

    def respond(self, command: int, type_: int, motor: int, value: int):
        ans = super().respond(command, type_, motor, value)
        if command == SGP and motor == 0 and ans[0] == 100:
            if type_ == 71:
                self.can_id = value
            elif type_ == 70:
                self.reply_id = value
        return ans


def test_restore_with_link_over_can_says_reconnect_only_for_the_bit_rate(
        backup_of_a, monkeypatch, tmp_path, capsys):
    import can

    from tmclsh.cli import main as cli

    monkeypatch.setenv("TMCLSH_CONFIG", str(tmp_path / "none.toml"))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))
    for var in ("TMCLSH_CAN", "TMCLSH_PORT", "TMCLSH_PROFILE", "CAN_INTERFACE", "CAN_CHANNEL",
                "CAN_BITRATE"):
        monkeypatch.delenv(var, raising=False)
    b = MovingOnCan(can.Bus(interface="virtual", channel="clone-link"), can_id=11,
                    reply_id=12, version="1311V111")
    for number, value in LINK_B.items():
        b.values[(number, 0, True)] = value
    b.values[MAX_CURRENT] = 50
    try:
        capsys.readouterr()
        rc = cli.main(["--can", "virtual:clone-link", "--can-id", "11", "--reply-id", "12",
                       "-y", "-c", f".restore {backup_of_a}"])
        said = "".join(capsys.readouterr())
        assert rc == 0, said
        assert "left alone" in said and (b.can_id, b.reply_id) == (11, 12)
        assert b.values[MAX_CURRENT] == 100
        b.values[MAX_CURRENT] = 50
        rc = cli.main(["--can", "virtual:clone-link", "--can-id", "11", "--reply-id", "12",
                       "-y", "-c", f".restore {backup_of_a} --with-link"])
        said = "".join(capsys.readouterr())
        assert rc == 0, said
        assert (b.can_id, b.reply_id) == (1, 2)
        assert "listens on CAN id 1 now" in said and "replies on CAN id 2 now" in said
        reconnect = [ln for ln in said.splitlines() if "reconnect" in ln]
        assert len(reconnect) == 1 and reconnect[0].startswith("CANBitRate is now 8"), said
        writes = [t for c, t, m, v in b.got if c == SGP]
        assert writes[-1] == 69  # the bit rate after everything else
    finally:
        b.close()
