"""tmclsh.client.ascii without a module: address characters, GP 67 bits, request formatting, the
pure reply parser, echo recognition on canned byte sequences, and the safety of the mode
probes (no byte sequence tmclsh sends while it does not know the mode can execute anything).
"""

from __future__ import annotations

import pytest

from tmclsh.client import ascii as am
from tmclsh.tmcl import instructions as isa
from tmclsh.client.ascii import Echo, LineKind
from tmclsh.client.text import LineClient
from tmclsh.base.errors import AsmError, TmclTimeoutError, ValidationError
from tmclsh.tmcl.modules import load
from tmclsh.tmcl.frames import SERIAL_FRAME_LEN, Reply, Request, checksum
from tmclsh.link.base import StreamTransport

M1311 = load("TMCM-1311")
M351 = load("TMCM-351")


# -- address characters and GP 67 -------------------------------------------------------------

def test_address_characters():
    assert am.address_char(1) == "A"
    assert am.address_char(2) == "B"
    assert am.address_char(3) == "C"
    assert am.address_char(26) == "Z"
    assert am.address_char(0) == "@"
    assert am.char_address("C") == 3
    assert am.char_address(ord("B")) == 2
    for bad in (-1, am.MAX_ADDRESS + 1, 300):
        with pytest.raises(ValidationError):
            am.address_char(bad)
    with pytest.raises(ValidationError):
        am.char_address("1")


def test_gp67_bits():
    assert am.echo_mode(0) == Echo.CHAR
    assert am.echo_mode(0x10) == Echo.LINE
    assert am.echo_mode(0x21) == Echo.NONE
    assert am.echo_mode(0x30) == Echo.UNDOCUMENTED
    assert am.starts_in_ascii(1) and not am.starts_in_ascii(0x30)
    assert am.gp67_value(0, startup="ascii") == 1
    assert am.gp67_value(1, echo="line") == 0x11
    assert am.gp67_value(0x11, echo="none") == 0x21
    assert am.gp67_value(0x21, startup="binary", echo="char") == 0
    # other bits are kept
    assert am.gp67_value(0x0C, startup="ascii", echo=Echo.LINE) == 0x1D
    with pytest.raises(ValidationError):
        am.gp67_value(0, echo="loud")
    with pytest.raises(ValidationError):
        am.gp67_value(0, echo=Echo.UNDOCUMENTED)
    assert am.describe_gp67(0x11) == "start up in ASCII mode, echo the whole line after CR"


# -- requests as command lines -----------------------------------------------------------------

@pytest.mark.parametrize("req, text", [
    (Request(1, 6, 1, 0, 0), "GAP 1, 0"),
    (Request(1, 5, 4, 0, 1000), "SAP 4, 0, 1000"),
    (Request(1, 4, 0, 0, -5000), "MVP ABS, 0, -5000"),
    (Request(1, 4, 1, 0, 0xFFFFEC78), "MVP REL, 0, -5000"),
    (Request(1, 1, 0, 0, 500), "ROR 0, 500"),
    (Request(1, 3, 0, 0, 0), "MST 0"),
    (Request(1, 13, 2, 0, 0), "RFS STATUS, 0"),
    (Request(1, 10, 67, 0, 0), "GGP 67, 0"),
    (Request(1, 9, 76, 0, 5), "SGP 76, 0, 5"),
    (Request(1, 14, 0, 2, 1), "SIO 0, 2, 1"),
    (Request(1, 15, 1, 0, 0), "GIO 1, 0"),
    (Request(1, 30, 1, 0, 777), "SCO 1, 0, 777"),
    (Request(1, 64, 1, 2, 3), "UF0 1, 2, 3"),
    (Request(1, 6, 1, 0, 99), "GAP 1, 0"),  # the don't-care value is not sent
])
def test_format_request(req, text):
    assert am.format_request(req, M1311) == text


def test_format_request_reassembles():
    """What is sent is what the shell would have encoded from the same text."""
    from tmclsh.tmcl import asm

    for text in ("GAP 1, 0", "MVP ABS, 0, -5000", "SAP 4, 0, 1000", "SIO 0, 2, 1", "RFS START, 0"):
        ins = asm.encode(asm.parse_line(text), M1311, direct=True, ascii=True).instruction
        req = Request(1, ins.opcode, ins.type, ins.motor, ins.value)
        assert am.format_request(req, M1311) == text


@pytest.mark.parametrize("opcode", [19, 20, 22, 26, 27, 28, 128, 129, 134, 136, 138, 139])
def test_commands_refused_in_ascii_mode(opcode):
    with pytest.raises(ValidationError, match=r"ASCII mode.*\.mode binary"):
        am.format_request(Request(1, opcode, 0, 0, 0), M1311)


def test_refusal_names_alternatives():
    with pytest.raises(ValidationError, match=r"in ASCII mode, RUN does it \(start the stored TMCL program\)"):
        am.format_request(Request(1, 129, 0, 0, 0), M1311)
    with pytest.raises(ValidationError, match="not available on the TMCM-1311"):
        am.format_request(Request(1, 29, 0, 0, 0), M1311)  # SAC: TMCM-351 only
    assert am.format_request(Request(1, 29, 1, 0, 2), M351) == "SAC 1, 0, 2"


def test_ascii_commands_list():
    names = am.ascii_commands(M1311)
    assert names[:3] == ["ROR", "ROL", "MST"]
    assert names[-3:] == list(isa.ASCII_ONLY_COMMANDS)
    assert "SAC" not in names and "SAC" in am.ascii_commands(M351)
    assert "CALC" not in names


def test_command_bytes():
    # spaces after the address character (the manuals allow them) make whole nine-byte blocks
    assert am.command_bytes(1, "GAP 1, 0") == b"A        GAP 1, 0\r"
    assert am.command_bytes(3, "BIN") == b"C    BIN\r"
    with pytest.raises(ValidationError):
        am.command_bytes(1, "GAP 1, 0\rAMST 0")


# -- the reply parser ---------------------------------------------------------------------------

def test_parse_reply():
    assert am.parse_reply(b"BA 100 -5000", 6) == Reply(2, 1, 100, 6, -5000)
    assert am.parse_reply(b"BA 100 0") == Reply(2, 1, 100, 0, 0)
    assert am.parse_reply(b"EC 4 12") == Reply(5, 3, 4, 0, 12)
    assert am.parse_reply(b"BA 100 +7") == Reply(2, 1, 100, 0, 7)
    assert am.parse_reply(b"BA 100 4294967295").value == -1  # unsigned spelling folded
    assert am.parse_reply(b"BA  100   -1 ").value == -1
    assert am.parse_reply(b"BA100 5") == Reply(2, 1, 100, 0, 5)
    for bad in (b"", b"AGAP 1, 0", b"BA ok 1", b"BA 100 99999999999", b"1A 100 0",
                b"BA 1000 0", b"BA 100 -", b"A MST 0"):
        assert am.parse_reply(bad) is None, bad


def test_decode_line_stream():
    buf = bytearray(b"BA 100 -50")
    assert am.decode_line(buf, 6) == (0, None)  # need more
    buf += b"00\r\nBA 100 1\r"
    used, reply = am.decode_line(buf, 6)
    assert used == 14 and reply == Reply(2, 1, 100, 6, -5000)
    del buf[:used]
    assert am.decode_line(buf) == (9, Reply(2, 1, 100, 0, 1))
    assert am.decode_line(b"\nBA 100 1\r") == (1, None)  # an empty line is consumed
    assert am.decode_line(b"AGAP 1, 0\r") == (10, None)  # an echo is no reply


def test_next_line_endings():
    assert am.next_line(b"abc") == (0, None)
    assert am.next_line(b"abc\rdef") == (4, b"abc")
    assert am.next_line(b"abc\r\ndef") == (5, b"abc")
    assert am.next_line(b"abc\ndef") == (4, b"abc")
    assert am.next_line(b"\r") == (1, b"")


# -- echo recognition ---------------------------------------------------------------------------

SENT = b"AGAP 1, 0\r"


@pytest.mark.parametrize("line, kind, value", [
    (b"AGAP 1, 0", LineKind.ECHO, None),  # line echo, or char echo with the CR echoed
    (b"GAP 1, 0", LineKind.ECHO, None),  # an echo without the address character
    (b"agap 1,0", LineKind.ECHO, None),  # spacing and case do not matter
    (b"BA 100 -5000", LineKind.REPLY, -5000),
    (b"AGAP 1, 0BA 100 -5000", LineKind.REPLY, -5000),  # char echo, CR not echoed
    (b"GAP 1, 0BA 100 7", LineKind.REPLY, 7),
    (b"AGAP 1, 0 BA 100 7", LineKind.REPLY, 7),
    (b"hello", LineKind.OTHER, None),
    (b"AGAP 1, 1", LineKind.OTHER, None),  # not what was sent
])
def test_classify_line(line, kind, value):
    got, reply = am.classify_line(line, SENT, 6)
    assert got == kind
    assert (reply.value if reply else None) == value
    if reply is not None:
        assert reply.opcode == 6


def test_classify_without_sent_line():
    assert am.classify_line(b"AGAP 1, 0")[0] == LineKind.OTHER
    assert am.classify_line(b"BA 100 0")[0] == LineKind.REPLY


def test_reply_summary():
    assert am.reply_summary(Reply(2, 1, 100, 6, -5000)) == "ok, value -5000"
    assert am.reply_summary(Reply(2, 1, 2, 0, 0)) == "error 2: invalid command"


# -- the probes cannot execute anything -----------------------------------------------------------

@pytest.mark.parametrize("address", range(0, am.MAX_ADDRESS + 1))
def test_probe_bytes_are_harmless(address):
    frame = am.probe_frame(address)
    req = Request.from_bytes(frame)
    assert (req.address, req.opcode, req.type) == (address, 136, 1)
    # in ASCII mode: no CR/LF to end a line and no backspace/DEL to edit one mid-frame
    assert not set(frame[1:]) & set(b"\r\n\x08\x7f")
    # in binary mode: the ASCII probe (the end of line, then the GGP 67 line) holds no valid
    # frame, and it is whole nine-byte blocks: a module that frames in nines stays in step
    probe = am.ascii_probe_bytes(address)
    assert not am.has_valid_frame(probe) and len(probe) % SERIAL_FRAME_LEN == 0
    assert am.ascii_probe_line(address)[0] == 0x40 + address
    assert am.END_LINE.startswith(b"\r") and len(am.END_LINE) == SERIAL_FRAME_LEN


@pytest.mark.parametrize("address", range(1, am.MAX_ADDRESS + 1))
@pytest.mark.parametrize("text", ["GAP 1, 0", "BIN", "MVP ABS, 0, -2147483648", "SGP 67, 0, 33"])
def test_every_command_line_is_whole_blocks_without_a_frame(address, text):
    line = am.command_bytes(address, text)
    assert len(line) % SERIAL_FRAME_LEN == 0 and not am.has_valid_frame(line)
    assert line[0] == 0x40 + address and line.endswith(text.encode() + b"\r")
    assert set(line[1:-len(text) - 1]) <= {0x20}  # only spaces added, after the address


def test_has_valid_frame():
    good = Request(1, 6, 1, 0, 0).to_bytes()
    assert am.has_valid_frame(b"xx" + good + b"yy")
    assert not am.has_valid_frame(good[:-1] + bytes(((good[-1] + 1) & 0xFF,)))
    assert checksum(good[:8]) == good[8] and len(good) == SERIAL_FRAME_LEN


# -- transact on canned byte sequences ------------------------------------------------------------

class Canned(StreamTransport):
    """Bytes in, canned bytes out: each write queues the next scripted answer (a test double
    for echo handling, not a module)."""

    def __init__(self, answers: list[bytes], chunk: int | None = None, pending: bytes = b""):
        super().__init__("canned://")
        self.answers = list(answers)
        self.written: list[bytes] = []
        self.rx = bytearray(pending)
        self.chunk = chunk

    def open(self) -> None:
        pass

    def close(self) -> None:
        pass

    @property
    def is_open(self) -> bool:
        return True

    def write(self, data: bytes) -> None:
        self.written.append(bytes(data))
        if self.answers:
            self.rx += self.answers.pop(0)

    def read(self, size: int, timeout: float | None) -> bytes:
        n = min(size, self.chunk or size)
        out = bytes(self.rx[:n])
        del self.rx[:n]
        return out

    def pending(self) -> int:
        return min(len(self.rx), self.chunk or len(self.rx))


def _link(transport: Canned, **kw) -> tuple[LineClient, am.AsciiLink]:
    client = LineClient(transport, module="TMCM-1311", timeout=0.05, retries=0, **kw)
    link = am.AsciiLink(client, found=am.Mode.ASCII)
    client.ascii_link = link
    return client, link


@pytest.mark.parametrize("answer", [
    b"AGAP 1, 0\rBA 100 -5000\r",  # character echo, CR echoed (and line echo)
    b"AGAP 1, 0BA 100 -5000\r",  # character echo, CR not echoed
    b"AGAP 1, 0\r\nBA 100 -5000\r\n",  # CRLF everywhere
    b"GAP 1, 0\rBA 100 -5000\r",  # echo without the address character
    b"BA 100 -5000\r",  # no echo
    b"\nBA 100 -5000\r",
], ids=["char-cr", "char-no-cr", "crlf", "no-addr-echo", "none", "leading-lf"])
@pytest.mark.parametrize("chunk", [None, 1])
def test_transact_skips_echo(answer, chunk):
    t = Canned([answer], chunk=chunk)
    client, _ = _link(t)
    reply = client.request(Request(1, 6, 1, 0, 0))
    assert reply == Reply(2, 1, 100, 6, -5000)
    assert t.written == [am.command_bytes(1, "GAP 1, 0")]


def test_transact_drops_other_hosts_modules_and_stale_input():
    """A reply waiting before the request is a late one: the line is brought back in step
    (GGP 76, whose answer is the host address) before the request goes out, as the binary
    link does with 136."""
    t = Canned([b"AGGP 76, 0\rBA 100 2\r",
                b"AGAP 1, 0\rCA 100 1\rBC 100 2\rnoise\rBA 100 3\r"], pending=b"BA 100 9\r")
    client, link = _link(t)
    seen = []
    client.add_tracer(lambda d, raw, x: seen.append((d, str(x))))
    assert client.request(Request(1, 6, 1, 0, 0)).value == 3
    assert t.written == [am.command_bytes(1, "GGP 76, 0"), am.command_bytes(1, "GAP 1, 0")]
    drops = [x for d, x in seen if d == "drop"]
    assert drops == ["late reply to an earlier command", "reply for host 3 (C)",
                     "reply from address 3", "not a reply"]
    assert link.stats["dropped_lines"] == 4


def test_address_3_and_host_5():
    t = Canned([b"CGAP 1, 0\rEC 100 42\r"])
    client, _ = _link(t, address=3, host_address=5)
    assert client.request(Request(3, 6, 1, 0, 0)) == Reply(5, 3, 100, 6, 42)
    assert t.written == [am.command_bytes(3, "GAP 1, 0")]


def test_error_status_is_a_reply():
    t = Canned([b"BA 3 0\r"])
    client, _ = _link(t)
    reply = client.request(Request(1, 6, 1, 0, 0))
    assert reply.status == 3 and not reply.ok


def test_timeout_then_late_reply_is_not_taken():
    t = Canned([b"AGAP 1, 0\r", b"AGAP 2, 0\rBA 100 2\r"])
    client, link = _link(t)
    with pytest.raises(TmclTimeoutError, match="no ASCII reply"):
        client.request(Request(1, 6, 1, 0, 0))
    t.rx += b"BA 100 1\r"  # the late reply to the first request
    assert client.request(Request(1, 6, 2, 0, 0)).value == 2


def test_refused_commands_send_nothing():
    t = Canned([])
    client, _ = _link(t)
    with pytest.raises(ValidationError):
        client.request(Request(1, 136, 0, 0, 0))
    with pytest.raises(ValidationError, match=r"ASCII mode.*\.mode binary"):
        client.execute("135 0, 0, 0")  # a raw command number: get application status
    with pytest.raises(AsmError):
        client.execute("CALC ADD, 1")
    assert t.written == []


def test_run_and_stop_program():
    # STOP's answer is byte for byte RUN's: on ASCII it may be a late copy of it, so the
    # line is brought back in step (GGP 76, answered with the host address) before the next
    t = Canned([b"ARUN\rBA 100 0\r", b"ASTOP\rBA 100 0\r", b"AGGP 76, 0\rBA 100 2\r",
                b"ARUN\rBA 6 0\r"])
    client, link = _link(t)
    assert link.run().opcode == 129
    assert link.stop_program().opcode == 128
    with pytest.raises(Exception, match="RUN: module answered status 6"):
        link.run()
    assert t.written == [am.command_bytes(1, text) for text in ("RUN", "STOP", "GGP 76, 0", "RUN")]


def test_reply_part():
    assert am.reply_part(b"AGAP 1, 0BA 100 -5000") == b"BA 100 -5000"
    assert am.reply_part(b"BA 100 7") == b"BA 100 7"
    assert am.reply_part(b"hello") == b"hello"


def test_attach_refused_without_an_ascii_interface():
    t = Canned([])
    client = LineClient(t, module="TMCM-1640", timeout=0.05)
    with pytest.raises(ValidationError, match="TMCM-1640 has no ASCII mode"):
        am.AsciiLink.attach(client)
    assert t.written == [] and client.ascii_link is None


def test_attach_refused_over_can():
    from tmclsh.link.base import CanTransport

    class Can(CanTransport):
        def open(self): pass
        def close(self): pass
        is_open = True
        def send(self, arbitration_id, data): raise AssertionError("nothing may be sent")
        def recv(self, timeout): return None

    client = LineClient(Can("virtual:x"), module="TMCM-1311")
    with pytest.raises(ValidationError, match="not available over CAN"):
        am.AsciiLink.attach(client)
