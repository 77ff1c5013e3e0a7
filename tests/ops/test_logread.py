"""A CAN log read at the reader's pace (issue 34): the plain request/reply pairs of
ops/logread.py say exactly what the general path (``listen.can_log``, a frame at a time) says,
line for line and in the summary, for people and programs; and a log of a module written from
the manuals (tests/responder.py) reads the same both ways."""

from __future__ import annotations

import io
import struct
import time

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tmclsh.cli import main as cli
from tmclsh.link.base import CanFrame
from tmclsh.ops import listen
from tmclsh.ops.filter import Filter
from tmclsh.ops.logread import pairs
from tmclsh.ops.monitor import CanReader, Monitor
from tmclsh.shell.features.monitor import View, show_items
from tmclsh.tmcl.modules import load

from conftest import patience
from responder import CanModule

T0 = 1_700_000_000.0


def request(cmd: int, typ: int = 0, motor: int = 0, value: int = 0) -> bytes:
    return struct.pack(">BBBi", cmd, typ, motor, value)


def answer(cmd: int, value: int, status: int = 100, module: int = 1) -> bytes:
    return struct.pack(">BBBi", module, status, cmd, value)


def shown(frames: list[CanFrame], *, fast: bool, json_mode: bool, hex_bytes: bool = False,
          module: str | None = None, batch: int = 7) -> str:
    """What ``monitor`` writes for these frames, the summary included."""
    monitor = Monitor(load(module) if module else None)
    reader = CanReader(monitor)
    out, err = io.StringIO(), io.StringIO()
    view = View(monitor, json_mode=json_mode, hex_bytes=hex_bytes, stream=out, color="never")
    source = pairs(reader, iter(frames), batch=batch) if fast \
        else listen.can_log(iter(frames), reader)
    filt = Filter((), (), (), monitor)
    for items in source:
        show_items(items, view, filt, monitor.summary, None)
    view.flush()
    view.summary(monitor.summary, err=err)
    return out.getvalue() + err.getvalue()


# the frames a log may hold: plain exchanges and every way a frame is not one
_REQUESTS = [request(6, 1), request(6, 4), request(5, 4, 0, 1000), request(10, 71),
             request(136, 0), request(136, 1), request(139), request(242, 0x81),
             request(200), request(6, 1) + b"\x07", request(134, 0, 0, 3)]
_REPLIES = [answer(6, 5), answer(6, -70000), answer(5, 1000), answer(10, 1, 4),
            answer(6, 5, 128), answer(138, 1, 128), answer(6, 5, 99), answer(200, 0, 2),
            b"1311V111", answer(6, 9) + b"\xaa", b"abcdefgh", answer(10, 3),
            struct.pack(">BBBi", 4, 1, 0, 500), answer(136, 0x051F006F)]


@st.composite
def traffic(draw) -> list[CanFrame]:
    """A log's frames: mostly a request on id 1 and an answer on id 2 shortly after, with
    other ids, kinds of frame, late and missing answers in between."""
    out: list[CanFrame] = []
    t = T0
    for _ in range(draw(st.integers(0, 40))):
        t += draw(st.sampled_from([0.0001, 0.001, 0.01, 1.5]))
        kind = draw(st.integers(0, 9))
        if kind <= 4:
            out.append(CanFrame(t, 1, draw(st.sampled_from(_REQUESTS))))
            if kind <= 3:
                t += draw(st.sampled_from([0.0003, 0.0005, 2.0]))
                out.append(CanFrame(t, draw(st.sampled_from([2, 2, 2, 3])),
                                    draw(st.sampled_from(_REPLIES))))
        elif kind == 5:
            out.append(CanFrame(t, 2, draw(st.sampled_from(_REPLIES))))
        elif kind == 6:
            out.append(CanFrame(t, draw(st.sampled_from([1, 2, 5, 0x300])),
                                draw(st.sampled_from(_REQUESTS + [b"", b"\x01\x02"])),
                                extended=draw(st.booleans()), error=draw(st.booleans()),
                                remote=draw(st.booleans())))
        elif kind == 7:
            out.append(CanFrame(t, 5, draw(st.sampled_from(_REQUESTS))))
        elif kind == 8:
            out.append(CanFrame(t, 1, b"\x06\x01"))
        else:
            out.append(CanFrame(t, 7, draw(st.sampled_from(_REPLIES))))
    return out


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(traffic(), st.booleans(), st.booleans(), st.sampled_from([None, "TMCM-1311"]),
       st.integers(1, 9))
def test_plain_pairs_say_what_the_general_path_says(frames, json_mode, hex_bytes, module,
                                                     batch):
    general = shown(frames, fast=False, json_mode=json_mode, hex_bytes=hex_bytes,
                    module=module)
    fast = shown(frames, fast=True, json_mode=json_mode, hex_bytes=hex_bytes, module=module,
                 batch=batch)
    assert fast == general


def test_a_polled_log_is_read_in_pairs_not_frame_by_frame(monkeypatch):
    """A master polling one module: the reader's general path sees only what is no plain
    pair (here the 136 exchange that names the module), and the lines come out as before."""
    frames = [CanFrame(T0, 1, request(136, 0)), CanFrame(T0 + 0.0004, 2, b"1311V111")]
    for i in range(2000):
        t = T0 + 0.01 + i * 0.001
        frames += [CanFrame(t, 1, request(6, 1 + i % 3)),
                   CanFrame(t + 0.0003, 2, answer(6, i * 37 - 5000))]
    general = shown(frames, fast=False, json_mode=False, batch=512)
    calls = []
    feed = CanReader.feed
    monkeypatch.setattr(CanReader, "feed", lambda self, *a, **kw: calls.append(a) or
                        feed(self, *a, **kw))
    assert shown(frames, fast=True, json_mode=False, batch=512) == general
    assert len(calls) == 2  # (the 136 exchange: it tells the monitor the module's type)
    assert "ActualPosition" in general  # (worded by what the 136 answer named)


# -- a module written from the manuals, logged by python-can ----------------------------------

def _session(path, eighth: str | None) -> list[tuple[int, int, int, int]]:
    """A master's requests to ``CanModule`` on a virtual bus, every frame both ways written
    to ``path`` by python-can's Logger; what the module was asked."""
    channel = f"tmclsh-logread-{path.suffix[1:]}-{eighth}"
    module_bus = can.Bus(interface="virtual", channel=channel)
    master = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    module = CanModule(module_bus, version="1311V111", eighth=eighth)
    asked = [(136, 0, 0, 0), (136, 1, 0, 0)] + [
        (cmd, typ, 0, value) for i in range(60)
        for cmd, typ, value in ((5, 4, 1000 + i), (6, 4, 0), (6, 1, 0), (10, 71, 0), (7, 0, i))]
    asked.append((201, 0, 0, 0))  # a command the module does not know: status 2
    try:
        with can.Logger(str(path)) as log:
            for cmd, typ, motor, value in asked:
                out = can.Message(timestamp=time.time(), arbitration_id=1,
                                  data=request(cmd, typ, motor, value), is_extended_id=False)
                master.send(out)
                log.on_message_received(out)
                got = master.recv(patience(5))
                assert got is not None, "the module did not answer"
                log.on_message_received(got)
    finally:
        module.close()
        master.shutdown()
    return asked


@pytest.mark.parametrize("suffix,eighth", [(".blf", None), (".asc", "sum"), (".log", "zero")])
def test_a_log_of_a_module_from_the_manuals_reads_the_same_both_ways(tmp_path, capsys,
                                                                       monkeypatch, suffix,
                                                                       eighth):
    from tmclsh.ops import logread

    path = tmp_path / f"bus{suffix}"
    asked = _session(path, eighth)
    taken = []
    monkeypatch.setattr(logread, "pairs", lambda *a, **kw: taken.append(1) or pairs(*a, **kw))
    runs = {}
    for name, extra in (("json", ["--json"]), ("text", []), ("hex", ["--hex"])):
        # (--count: the general path, frame by frame, to choose where to stop)
        for path_taken, more in (("pairs", []), ("general", ["--count", "100000"])):
            before = len(taken)
            assert cli.main(["monitor", "--log", str(path), *extra, *more]) == 0
            assert len(taken) - before == (path_taken == "pairs")
            got = capsys.readouterr()
            runs[name, path_taken] = (got.out, got.err)
    for name in ("json", "text", "hex"):
        assert runs[name, "pairs"] == runs[name, "general"], name
    out = runs["json", "pairs"][0]
    assert out.count('"frame": "request"') == len(asked)
    assert out.count('"frame": "reply"') == len(asked)
    assert '"value": 1059' in out and '"error": "invalid command"' in out
    assert '"summary"' in out
    assert "TMCM-1311" in runs["text", "pairs"][1]  # (learnt from the 136 answers)
