"""A write that moves the module (its address, host address, CAN ids, baud rate) is followed:
the module's answer is taken from where it now answers, the client talks to it there, and no
earlier answer falls into doubt. Modules written here from the manual's tables
(tests/responder.py), which move the way a module does: at once, answering the write from the
new place (as the trace of a TMCM-1311 shows for ``SGP 66, 0, 3``) or from the old one.
"""

from __future__ import annotations

import termios

import can
import pytest

from responder import OK, CanModule, PtyModule, reply

from tmclsh.client.text import LineClient
from tmclsh.link import open_can, open_serial
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session

SGP = 9


class Moving(PtyModule):
    """Takes a new address, host address or baud rate at once (GP 66, 76, 65), answering the
    write itself from the new place, or (``from_old``) from the old one."""

    from_old = False

    def answer(self, raw):
        addr, cmd, typ, bank = raw[0], raw[1], raw[2], raw[3]
        if addr != self.address:
            return None
        value = int.from_bytes(raw[4:8], "big", signed=True)
        if cmd == SGP and bank == 0 and typ in (65, 66, 76):
            self.got.append((cmd, typ, bank, value))
            old_address, old_host = self.address, self.host
            if typ == 66:
                self.address, self.addresses = value, frozenset({value})
            elif typ == 76:
                self.host = value
            else:
                self.speed = {0: termios.B9600, 7: termios.B115200}[value]
            if self.from_old:
                return reply(cmd, value, OK, old_address, old_host)
            return reply(cmd, value, OK, self.address, self.host)
        return super().answer(raw)


@pytest.fixture
def moving():
    made = []

    def make(**kw):
        made.append(Moving(version="1311V111", **kw))
        return made[-1]

    yield make
    for m in made:
        m.close()


def session(m, baud=9600) -> Session:
    c = LineClient(open_serial(m.path, baud), module="TMCM-1311", timeout=0.3, retries=1)
    c.version = "1311V111"
    return Session(c, Output(), yes=True)


@pytest.mark.parametrize("from_old", [False, True], ids=["answers from 3", "answers from 1"])
def test_a_new_address_is_followed(moving, capsys, from_old):
    m = moving()
    m.from_old = from_old
    s = session(m)
    try:
        s.run_line("GAP 4, 0")
        s.run_line("SGP SerialAddress, 0, 3")
        s.run_line("GAP 4, 0")  # at the new address
        said = capsys.readouterr()
        assert s.client.address == 3 and m.address == 3
        assert "ok: SerialAddress set to 3" in said.out
        assert "answers at address 3 now" in said.err
        # (a program's client: told connect()'s keyword for its next run, not an option)
        assert "(address=3 next time)" in said.err, said.err
        assert "stopped answering" not in said.err and "another request" not in said.err
        assert s.client.stats["suspect"] == 0 and s.stats.suspects == 0
    finally:
        s.client.close()


def test_a_new_host_address_is_followed(moving, capsys):
    m = moving()
    s = session(m)
    try:
        s.run_line("SGP SerialHostAddress, 0, 5")
        assert s.client.host_address == 5
        s.run_line("GAP 4, 0")
        said = capsys.readouterr().err
        assert "replies to host address 5 now" in said
        assert "(host_address=5 next time)" in said, said
    finally:
        s.client.close()


def test_the_shell_is_told_the_option_for_its_next_run(moving, capsys):
    """At the prompt or in a script the advice is the shell's own command where it has one
    (``.address 3``), but what to give the next run is the command line's option."""
    from tmclsh.client.advice import SHELL

    m = moving()
    s = session(m)
    s.client.advice = SHELL
    try:
        s.run_line("SGP SerialAddress, 0, 3")
        said = capsys.readouterr().err
        assert "answers at address 3 now" in said and "(-a 3 next time)" in said, said
    finally:
        s.client.close()


def test_a_new_baud_rate_taken_at_once_is_followed(moving, capsys):
    m = moving(speed=termios.B9600)
    s = session(m, 9600)
    try:
        s.run_line("SGP 65, 0, 7")
        assert s.client.transport.baudrate == 115200
        s.run_line("GAP 4, 0")
        assert "answers at 115200 baud now" in capsys.readouterr().err
    finally:
        s.client.close()


def test_new_can_ids_are_followed(capsys):
    bus = can.Bus(interface="virtual", channel="reach-ids")
    m = CanModule(bus, version="1311V111")
    c = LineClient(open_can("virtual:reach-ids"), module="TMCM-1311", timeout=0.3)
    s = Session(c, Output(), yes=True)

    def serve_moved(command, type_, motor, value, respond=m.respond):
        # the module takes the new ids at once (the reply to the write on the new reply id)
        if command == SGP and motor == 0 and type_ in (70, 71):
            m.got.append((command, type_, motor, value))
            if type_ == 70:
                m.reply_id = value
            else:
                m.can_id = value
            return OK, value
        return respond(command, type_, motor, value)

    m.respond = serve_moved
    try:
        s.run_line("SGP CANReplyID, 0, 7")
        s.run_line("SGP CANID, 0, 9")
        s.run_line("GAP 4, 0")
        assert (c.reply_id, c.can_id) == (7, 9)
        err = capsys.readouterr().err
        assert "replies on CAN id 7 now" in err and "listens on CAN id 9 now" in err
    finally:
        c.close()
        m.close()
