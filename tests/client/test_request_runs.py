"""A run of requests (``Client.requests``: an upload's frames, its read-back) against a module
written from the manuals (``tests/responder.py``), not the simulator.

A run is the request path's own, request by request: each request goes out once the one
before was answered, nothing goes out after the caller leaves its loop, and a line that
copies a reply late, loses one or garbles one meets the same checks as ``Client.request``
(the same replies, the same suspects, the same counts). Requests are taken from the caller's
iterable as each goes out; what taking one raises comes where that request would have gone,
after the answers before it.
"""

from __future__ import annotations

import pytest

from tmclsh.client.text import LineClient
from tmclsh.link import open_serial
from tmclsh.tmcl.frames import Request

from responder import Module, fields, reply

SGP = 9
WRONG_CHECKSUM = 1
NOISE = bytes((0x55, 0xAA, 0x00))  # (no nine bytes from any of these make a frame)


class FaultyLine(Module):
    """A TMCM-1311 whose SGPs (each writes a value the reply carries back) meet a line
    fault, chosen by value: ``late_copy``: the reply is preceded by a copy of the SGP reply
    before it (a line that repeats a reply, late); ``silent``: the first SGP of this value
    goes unanswered; ``garbled``: the first is answered status 1 (the module saw a bad
    checksum and did nothing)."""

    def __init__(self, fault: str = "", at: frozenset[int] = frozenset()):
        self.fault, self.at = fault, set(at)
        self.last = b""
        super().__init__(version="1311V111")

    def answer(self, raw: bytes) -> bytes | None:
        _, cmd, _, _, value = fields(raw)
        if cmd == SGP and value in self.at and self.fault in ("silent", "garbled"):
            self.at.discard(value)
            return None if self.fault == "silent" else reply(SGP, value, WRONG_CHECKSUM)
        own = super().answer(raw)
        if cmd != SGP or own is None:
            return own
        out = self.last + own if (self.fault == "late_copy" and value in self.at) else own
        if self.fault == "noise" and value in self.at:
            out = NOISE + own
        self.last = own
        return out

    def heard(self) -> list[int]:
        """The value of every SGP that reached the module, in order."""
        return [fields(raw)[4] for raw in self.log if len(raw) == 9 and raw[1] == SGP]


def _client(m: FaultyLine) -> LineClient:
    return LineClient(open_serial(m.path), module="TMCM-1311", timeout=1.0, retries=2)


def _writes(values) -> list[Request]:
    return [Request(1, SGP, 0, 2, v) for v in values]


def test_each_request_goes_once_the_one_before_was_answered_and_none_after_the_caller_stops():
    m = FaultyLine()
    c = _client(m)
    pulled: list[int] = []

    def made():
        for v in range(100, 110):
            pulled.append(v)
            yield Request(1, SGP, 0, 2, v)

    try:
        got = []
        for reply in c.requests(made()):
            got.append(reply.value)
            assert m.heard() == list(range(100, 100 + len(got)))  # one at a time, answered
            assert len(pulled) == len(got)  # (taken as each goes out)
            if len(got) == 4:
                break
        assert got == [100, 101, 102, 103]
        assert m.heard() == [100, 101, 102, 103]  # nothing sent after the caller left
        assert c.request(Request(1, SGP, 0, 2, 7)).value == 7  # the link is as it was
    finally:
        c.close()
        m.close()


@pytest.mark.parametrize("fault", ["late_copy", "silent", "garbled", "noise"])
def test_a_run_meets_a_faulty_line_as_request_by_request_does(fault):
    """The same line fault, driven with ``request`` one at a time and as one run: the same
    replies, the same suspects (by reply number), the same counts, the same frames heard."""
    values = list(range(100, 110)) + [0]  # (the last: a displaced answer is found by the next)
    seen = []
    for way in ("request", "run"):
        m = FaultyLine(fault, frozenset({103, 106}))
        c = _client(m)
        try:
            reqs = _writes(values)
            replies = [c.request(r) for r in reqs] if way == "request" else list(c.requests(reqs))
            seen.append(([r.value for r in replies],
                         sorted(s.seq for s in c._doubts.take_suspects()),
                         {k: c.stats[k] for k in ("sent", "timeouts", "retries", "resyncs",
                                                  "unsolicited", "flushed", "discarded",
                                                  "checksum_errors")},
                         m.heard()))
        finally:
            c.close()
            m.close()
    assert seen[0] == seen[1]
    values_back, suspects, stats, heard = seen[1]
    if fault == "late_copy":
        # the copy is taken for the next answer (no client can tell), and found out
        assert values_back[3] == 102 and values_back[6] == 105 and suspects
    elif fault == "silent":
        assert values_back == values and stats["timeouts"] == 2 and heard.count(103) == 2
    elif fault == "garbled":
        assert values_back == values and stats["retries"] == 2 and heard.count(106) == 2
    else:
        assert values_back == values and stats["discarded"] and heard == values


def test_what_making_a_request_raises_comes_where_that_request_would_have_gone():
    m = FaultyLine()
    c = _client(m)

    def made():
        yield Request(1, SGP, 0, 2, 1)
        yield Request(1, SGP, 0, 2, 2)
        yield Request(1, SGP, 0, 2, 2**40)  # (no 32-bit value: the constructor refuses it)

    try:
        run = c.requests(made())
        assert next(run).value == 1
        assert next(run).value == 2
        with pytest.raises(ValueError, match="32 bits"):
            next(run)
        assert m.heard() == [1, 2]
    finally:
        c.close()
        m.close()


def test_a_timeout_is_refused_before_anything_is_sent():
    m = FaultyLine()
    c = _client(m)
    try:
        with pytest.raises(ValueError, match="timeout"):
            c.requests(_writes([1]), timeout=0)
        assert m.heard() == []
    finally:
        c.close()
        m.close()


def test_a_run_tells_what_an_answer_tells_beyond_itself_as_request_does():
    """What ``after_answer`` takes from an answer, a run takes too (it is asked only of
    answers that may tell something): a module left in download mode stores a run's first
    request instead of executing it, and the run stops there, saying so; a 132 and a 133
    in a run begin and end the download mode the client keeps track of."""
    from responder import DownloadModeModule
    from tmclsh.base.errors import DownloadModeError

    m = DownloadModeModule()
    c = LineClient(open_serial(m.path), module="TMCM-1311", timeout=1.0)
    try:
        m.downloading = False
        assert c.request(Request(1, 6, 1, 0, 0)).value == -5000
        m.downloading = True  # (left so by another program)
        before = len(m.log)
        with pytest.raises(DownloadModeError):
            list(c.requests(_writes([1, 2, 3])))
        assert [fields(raw)[4] for raw in m.log[before:]] == [1]  # nothing after it
        replies = list(c.requests([Request(1, 133, 0, 0, 0), Request(1, 132, 0, 0, 0)]))
        assert [r.status for r in replies] == [100, 100] and c._left_downloading
        assert list(c.requests([Request(1, 133, 0, 0, 0)]))[0].ok and not c._left_downloading
    finally:
        c.close()
        m.close()
