"""The client against the simulator: requests and their replies, the special replies (136
string, 134 read-back, 137 none, 138 events), listeners and tracers, idempotence, and the hot
path's framing held to protocol.py's."""

from __future__ import annotations

import threading
import time

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tmclsh.client.core import idempotent
from tmclsh.client.text import LineClient
from tmclsh.base.errors import AsmError, StatusError, TmclTimeoutError, ValidationError
from tmclsh.tmcl.frames import Control, Instruction, Reply, ReplyKind, Request, Status
from tmclsh.link import open_serial
from tmclsh.ops.stop import stop_everything
from conftest import patience

GAP, SAP, GIO, MVP, SGP, GGP, MST = 6, 5, 15, 4, 9, 10, 3


def setup_move(c: LineClient, speed: int = 100_000, accel: int = 2_000_000) -> None:
    c.send(SAP, 4, 0, speed)  # MaxPositioningSpeed
    c.send(SAP, 5, 0, accel)  # MaxAcceleration


# -- plain request/reply -------------------------------------------------------------------------

def test_send_returns_the_reply_to_that_request(client):
    r = client.send(SAP, 1, 0, -5000)
    assert (r.host, r.module, r.status, r.opcode) == (2, 1, Status.OK, SAP)
    r = client.send(GAP, 1, 0)
    assert r.opcode == GAP and r.value == -5000
    assert client.send("GAP", 1, 0).value == -5000  # by mnemonic


def test_execute_checks_the_line_and_the_status(client):
    res = client.execute("SAP ActualPosition, 0, 1234")
    assert res.ok and res.request == Instruction(SAP, 1, 0, 1234)
    assert client.value("GAP ActualPosition, 0") == 1234
    sent = client.stats["sent"]
    with pytest.raises(AsmError, match="no motor 7"):
        client.execute("GAP 1, 7")  # the module has one motor: refused before sending
    with pytest.raises((AsmError, ValidationError)):
        client.execute("FOO 1, 0")
    assert client.stats["sent"] == sent
    # an error status from the module raises StatusError (and is returned with check=False)
    client.execute("SGP 73, 0, 1234")  # lock the configuration EEPROM
    with pytest.raises(StatusError) as exc:
        client.execute("STAP 4, 0")
    assert exc.value.status == Status.EEPROM_LOCKED
    assert client.execute("STAP 4, 0", check=False).reply.status == Status.EEPROM_LOCKED


def test_identify_reads_the_version_string(make_pty_sim):
    sim, path = make_pty_sim("TMCM-351", address=5)
    c = LineClient(open_serial(path), address=5, timeout=0.5)
    try:
        assert c.module is None
        mod = c.require_module()
        assert mod.name == "TMCM-351" and c.version == "0351V103"
    finally:
        c.close()


def test_wrong_address_times_out_quickly(pty_client):
    pty_client.address = 9
    t0 = time.monotonic()
    with pytest.raises(TmclTimeoutError, match="address 9"):
        pty_client.send(GAP, 1, 0)
    assert time.monotonic() - t0 < patience(1.5)  # 3 attempts of 0.2 s plus resynchronisation
    pty_client.address = 1
    assert pty_client.send(GAP, 1, 0).ok  # and the link still works for the real module


def test_replies_for_another_host_are_ignored(make_pty_sim):
    sim, path = make_pty_sim(host_address=7)
    c = LineClient(open_serial(path), module="TMCM-1311", timeout=0.1, retries=0)
    try:
        with pytest.raises(TmclTimeoutError):
            c.send(GAP, 1, 0)
        assert c.stats["discarded"] >= 9
        c.host_address = 7
        assert c.send(GAP, 1, 0).ok
    finally:
        c.close()


def test_factory_default_has_no_reply(client):
    client.send(SAP, 4, 0, 1000)
    client.send(7, 4, 0)  # STAP: store it in EEPROM
    assert client.send(Control.FACTORY_DEFAULT, 0, 0, 1234) is None
    time.sleep(0.05)
    # no reply arrived late either, and the link is in step
    assert client.send(GAP, 1, 0).opcode == GAP
    assert client.stats["discarded"] == 0


def test_read_memory_reply_layout(client):
    sim = client.transport.simulator
    sim.load_program([Instruction(MVP, 0, 0, 51200), Instruction(28)], start=10)
    r = client.send(Control.READ_MEMORY, 0, 0, 10)
    assert r.stored == Instruction(MVP, 0, 0, 51200)
    assert client.send(Control.READ_MEMORY, 0, 0, 11).stored == Instruction(28)
    assert client.send(GAP, 1, 0).opcode == GAP


def test_version_request_never_takes_a_normal_frame(pty_client):
    # a stale 136 type 1 reply (normal layout, opcode 136) sits on the line; 136 type 0 must
    # still get the string
    pty_client.transport.write(Request(1, Control.GET_VERSION, 1).to_bytes())
    time.sleep(0.05)
    r = pty_client.send(Control.GET_VERSION, 0)
    assert r.version == "1311V111"


# -- 138 events ----------------------------------------------------------------------------------

def test_event_interleaved_with_polling_never_desynchronises(pty_client):
    c = pty_client
    events: list[Reply] = []
    c.add_listener(events.append)
    setup_move(c)
    c.send(SAP, 1, 0, 0)
    assert c.send(MVP, 0, 0, 20000).ok
    r = c.send(Control.TARGET_REACHED_EVENT, 0, 0, 0)  # motor 0
    assert (r.status, r.opcode, r.value) == (Status.OK, Control.TARGET_REACHED_EVENT, 1)
    positions = []
    deadline = time.monotonic() + 5
    while not events and time.monotonic() < deadline:
        r = c.send(GAP, 1, 0)
        assert r.opcode == GAP and r.status == Status.OK
        positions.append(r.value)
    for _ in range(20):  # and after it
        r = c.send(GAP, 1, 0)
        assert r.opcode == GAP and r.value == 20000
    assert len(events) == 1
    ev = events[0]
    assert (ev.status, ev.opcode, ev.value, ev.module) == (Status.EVENT, 138, 1, 1)
    assert len(positions) > 10, "the event came before any polling"
    assert positions == sorted(positions) and positions[0] < 20000
    assert c.stats["timeouts"] == c.stats["discarded"] == c.stats["resyncs"] == 0
    assert c.stats["events"] == 1


def test_event_while_idle_goes_to_listeners_through_the_poller(pty_client):
    c = pty_client
    got = threading.Event()
    seen = []

    def listener(ev: Reply) -> None:
        # a listener may use the client: events are delivered outside the transaction
        seen.append((ev.value, c.send(GAP, 1, 0).value))
        got.set()

    c.add_listener(listener)
    setup_move(c)
    c.send(MVP, 0, 0, 5000)
    c.send(Control.TARGET_REACHED_EVENT, 0, 0, 0)
    c.start_event_poller(0.01)
    try:
        assert got.wait(patience(3)), "no event delivered while idle"
    finally:
        c.stop_event_poller()
    assert seen == [(1, 5000)]


def test_a_poller_that_outlives_its_stop_still_ends_when_another_starts(pty_client):
    """stop_event_poller waits a second; a poller stuck longer (a listener that blocked)
    ran on beside the next one, both taking events from the line."""
    c = pty_client
    stuck = threading.Event()
    calls = 0

    def poll():
        nonlocal calls
        calls += 1
        if calls == 1:
            stuck.set()
            time.sleep(1.5)  # longer than stop_event_poller waits
        return 0

    c.poll = poll  # type: ignore[method-assign]
    c.start_event_poller(0.01)
    assert stuck.wait(patience(2))
    c.stop_event_poller()  # gives up waiting after 1 s
    c.start_event_poller(0.01)
    try:
        time.sleep(1.0)  # the stuck one has returned by now
        alive = [t for t in threading.enumerate() if t.name == "tmclsh-events"]
        assert len(alive) == 1
    finally:
        c.stop_event_poller()


def test_poll_delivers_pending_events_and_unsubscribe_works(pty_client):
    c = pty_client
    events = []
    unsubscribe = c.add_listener(events.append)
    setup_move(c)
    c.send(MVP, 0, 0, 3000)
    c.send(Control.TARGET_REACHED_EVENT, 0, 0, 0)
    c.wait_until(lambda: c.poll() or bool(events), timeout=3, interval=0.01)
    assert len(events) == 1
    unsubscribe()
    c.send(MVP, 0, 0, 0)
    c.send(Control.TARGET_REACHED_EVENT, 0, 0, 0)
    time.sleep(0.3)
    c.poll()
    assert len(events) == 1 and c.stats["events"] == 2


def test_a_failing_listener_does_not_break_the_link(client):
    def bad(ev):
        raise RuntimeError("listener bug")

    client.add_listener(bad)
    client.send(Control.TARGET_REACHED_EVENT, 0, 0, 0)  # at target already: event at once
    time.sleep(0.05)
    assert client.send(GAP, 1, 0).ok
    assert client.stats["events"] == 1


# -- tracers -------------------------------------------------------------------------------------

def test_tracer_sees_every_frame(pty_client):
    c = pty_client
    seen = []
    remove = c.add_tracer(lambda d, raw, dec: seen.append((d, bytes(raw))))
    c.send(GAP, 1, 0)
    assert [d for d, _ in seen] == ["tx", "rx"]
    assert seen[0][1] == Request(1, GAP, 1, 0).to_bytes()
    assert len(seen[1][1]) == 9
    c.sim.faults.garbage = b"\x55\xaa"
    c.send(GAP, 1, 0)
    assert ("drop", b"\x55\xaa") in seen
    remove()
    n = len(seen)
    c.send(GAP, 1, 0)
    assert len(seen) == n


def test_a_sent_only_tracer_is_told_each_request_before_it_goes_and_nothing_else(pty_client):
    c = pty_client
    sent, everything = [], []

    def watch(d, raw, dec):
        # told before the write: the module has not answered yet
        sent.append((d, bytes(raw), dec, c.stats["sent"]))

    remove = c.add_tracer(watch, sent_only=True)
    assert c._tracing
    c.send(GAP, 1, 0)
    c.sim.faults.garbage = b"\x55\xaa"  # a drop, which only a full tracer hears of
    c.send(SAP, 4, 0, 100)
    assert [(d, raw, n) for d, raw, _, n in sent] == [
        ("tx", Request(1, GAP, 1, 0).to_bytes(), 0), ("tx", Request(1, SAP, 4, 0, 100).to_bytes(), 1)]
    assert [dec for _, _, dec, _ in sent] == [Request(1, GAP, 1, 0), Request(1, SAP, 4, 0, 100)]
    # beside a full tracer: both, each as it asked
    c.add_tracer(lambda d, raw, dec: everything.append(d))
    c.send(GAP, 1, 0)
    assert len(sent) == 3 and everything == ["tx", "rx"]
    remove()
    c.send(GAP, 1, 0)
    assert len(sent) == 3


def test_a_sent_only_tracer_given_opcodes_is_called_for_those_commands_only(pty_client):
    c = pty_client
    starts, every = [], []
    remove_starts = c.add_tracer(lambda d, raw, dec: starts.append(dec.opcode), sent_only=True,
                                 opcodes={SAP, MVP})
    c.send(GAP, 1, 0)
    c.send(SAP, 4, 0, 100)
    assert starts == [SAP]  # GAP never reached it
    # beside a tracer that wants everything, it may be told of more (a tracer checks)
    remove_every = c.add_tracer(lambda d, raw, dec: every.append(dec.opcode), sent_only=True)
    c.send(GAP, 1, 0)
    assert every == [GAP] and starts == [SAP, GAP]
    remove_every()  # and once that one is gone, its filter is back
    c.send(GAP, 1, 0)
    c.send(MVP, 0, 0, 0)
    assert every == [GAP] and starts == [SAP, GAP, MVP]
    remove_starts()
    c.send(SAP, 4, 0, 100)
    assert starts == [SAP, GAP, MVP] and not c._tracing
    with pytest.raises(ValueError):
        c.add_tracer(lambda *a: None, opcodes={GAP})  # a filter for what is sent only


# -- idempotence and helpers ---------------------------------------------------------------------

def test_idempotent_commands():
    assert idempotent(Request(1, GAP, 1, 0))
    assert idempotent(Request(1, SAP, 4, 0, 100))
    assert idempotent(Request(1, MVP, 0, 0, 100))  # ABS
    assert not idempotent(Request(1, MVP, 1, 0, 100))  # REL moves again
    assert not idempotent(Request(1, 13, 0, 0))  # RFS START restarts the search
    assert idempotent(Request(1, 13, 2, 0))  # RFS STATUS
    assert not idempotent(Request(1, 19, 0, 0, 1))  # CALC changes the accumulator
    assert not idempotent(Request(1, Control.RUN_APPLICATION))
    assert not idempotent(Request(1, Control.TARGET_REACHED_EVENT))
    assert not idempotent(Request(1, 199))  # unknown: never repeated
    assert idempotent(Request(1, 201, 3, 0, 7))  # the bootloader's write buffer: same word
    assert not idempotent(Request(1, 242, 0x81, 0x92, 0xA3B4C5D6))  # no reply to wait for
    assert not idempotent(Request(1, GAP, 1, 0), downloading=True)


def test_the_safety_stop_stops_every_motor(make_pty_sim):
    sim, path = make_pty_sim("TMCM-351")
    c = LineClient(open_serial(path), module="TMCM-351", timeout=0.5)
    try:
        for m in range(3):
            c.send(1, 0, m, 500)  # ROR
        time.sleep(0.05)
        assert all(c.send(GAP, 3, m).value != 0 for m in range(3))  # actual speed
        report = stop_everything(c)  # the one safety stop (ops/stop.py)
        assert report.ok and report.stopped == [0, 1, 2]
        assert all(c.send(GAP, 2, m).value == 0 for m in range(3))  # target speed
        assert all(c.send(GAP, 3, m).value == 0 for m in range(3))  # actual speed
    finally:
        c.close()


def test_wait_until_times_out_with_tmcl_timeout(client):
    t0 = time.monotonic()
    with pytest.raises(TmclTimeoutError):
        client.wait_until(lambda: False, timeout=0.1, interval=0.01)
    assert time.monotonic() - t0 < patience(1)
    client.wait_until(lambda: True, timeout=0)


def test_raw_factory_reset_line_has_no_value(client):
    assert client.execute("137 0, 0, 1234").reply is None
    with pytest.raises(ValidationError, match="no reply"):
        client.value("137 0, 0, 1234")


# -- the hot path's short cuts in protocol.py are exact -----------------------------------------------------

@given(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255), st.integers(0, 255),
       st.integers(-(2**31), 2**32 - 1))
def test_frame_is_address_instruction_checksum(address, opcode, type_, motor, value):
    req = Request(address, opcode, type_, motor, value)
    body = bytes((address,)) + req.instruction.to_bytes()
    assert req.to_bytes() == body + bytes((sum(body) & 0xFF,))


@given(st.integers(0, 255), st.integers(0, 255), st.sampled_from([int(s) for s in Status]),
       st.integers(0, 255), st.integers(-(2**31), 2**31 - 1))
def test_fast_reply_is_reply_from_bytes(host, module, status, opcode, value):
    raw = Reply(host, module, status, opcode, value).to_bytes()
    assert Reply.from_frame(raw) == Reply.from_bytes(raw)


@given(st.integers(0, 255), st.binary(min_size=7, max_size=7), st.integers(0, 255))
def test_fast_memory_reply_is_reply_from_bytes(host, stored, module):
    body = bytes((host,)) + stored
    raw = body + bytes((sum(body) & 0xFF,))
    fast = Reply.from_memory_frame(raw, module, 134)
    assert fast == Reply.from_bytes(raw, ReplyKind.MEMORY, module=module, opcode=134)
    assert fast.stored == Instruction.from_bytes(stored)


def test_timeouts_must_be_positive(client):
    with pytest.raises(ValueError, match="positive"):
        client.send(GAP, 1, 0, timeout=0)
    with pytest.raises(ValueError, match="positive"):
        client.timeout = None
    with pytest.raises(ValueError):
        LineClient(client.transport, timeout=-1)


@given(st.one_of(st.integers(-5, 300), st.just(True), st.just(1.0)),
       st.one_of(st.integers(-5, 300), st.sampled_from(list(Control))),
       st.integers(-5, 300), st.integers(-5, 300),
       st.one_of(st.integers(-(2**32), 2**33), st.just(2**31), st.just(-(2**31) - 1)))
def test_fast_request_is_the_validated_request(address, opcode, type_, motor, value):
    try:
        want = Request(address, opcode, type_, motor, value)
    except ValueError as exc:
        with pytest.raises(ValueError, match=str(exc).split(" must")[0]):
            Request.make(address, opcode, type_, motor, value)
        return
    got = Request.make(address, opcode, type_, motor, value)
    assert got == want and hash(got) == hash(want)
    assert (got.address, got.opcode, got.type, got.motor, got.value) == \
        (want.address, want.opcode, want.type, want.motor, want.value)
