"""The one frame decoder (tmcl/decoder.py): bytes in, frames and noise out.

Every reader of the serial framing goes through it (the client, scan, the trace and .decode,
the simulator's receive path, the ASCII probe), so what it takes for a frame is what all of
them take: nine bytes that add up, a TMCL status byte in a reply to our host, and after noise
no other host's frame (likelier noise that happens to add up).
"""

from __future__ import annotations

from hypothesis import assume, given
from hypothesis import strategies as st

from tmclsh.tmcl.decoder import (FRAME, FRAME_PIECE, NOISE, WHOLE, FrameDecoder, is_frame,
                                 is_version_string, pieces)
from tmclsh.tmcl.frames import INT32_MAX, INT32_MIN, Reply, Status, checksum

HOST = 2
byte = st.integers(0, 255)
statuses = st.sampled_from(list(Status))
replies = st.builds(Reply, st.just(HOST), byte, statuses, byte, st.integers(INT32_MIN, INT32_MAX))


def _drain(buf: bytes, host: int | None = HOST) -> tuple[list[Reply], bytes, bytes]:
    """Every frame the decoder finds in ``buf``: (replies, noise, what is left)."""
    dec = FrameDecoder(host)
    dec.feed(buf)
    found, noise = [], b""
    while (piece := dec.next()) is not None:
        kind, raw = piece
        if kind == FRAME_PIECE:
            found.append(Reply.from_frame(raw))
        else:
            assert kind == NOISE and raw
            noise += raw
    return found, noise, bytes(dec.buf)


def _frame_at(buf: bytes, i: int) -> bool:
    """Nine bytes at ``i`` that the decoder must take for a reply."""
    window = buf[i:i + FRAME]
    return len(window) == FRAME and is_frame(window, HOST)


def test_decoder_needs_nine_bytes() -> None:
    frame = Reply(HOST, 1, 100, 6, 711).to_bytes()
    for n in range(FRAME):
        assert _drain(frame[:n]) == ([], b"", frame[:n])
    assert _drain(frame + b"\x00") == ([Reply(HOST, 1, 100, 6, 711)], b"", b"\x00")


@given(st.binary(max_size=40), replies)
def test_decoder_finds_the_frame_after_garbage(garbage: bytes, reply: Reply) -> None:
    stream = garbage + reply.to_bytes()
    # garbage that itself forms a valid frame (1 in 256 * 256/9 per position) is a frame
    assume(not any(_frame_at(stream, i) for i in range(len(garbage))))
    found, noise, rest = _drain(stream)
    assert found == [reply] and noise == garbage and rest == b""


@given(st.lists(replies, min_size=1, max_size=5), st.binary(max_size=12))
def test_decoder_keeps_consecutive_frames(batch: list[Reply], tail: bytes) -> None:
    stream = b"".join(r.to_bytes() for r in batch)
    found, _, _ = _drain(stream + tail)
    assert found[:len(batch)] == batch


def test_decoder_resynchronises_after_a_lost_byte() -> None:
    first, second = Reply(HOST, 1, 100, 6, 711), Reply(HOST, 1, 100, 10, 1)
    damaged = first.to_bytes()[1:]  # the host byte got lost on the line
    found, noise, rest = _drain(damaged + second.to_bytes())
    assert found == [second] and noise == damaged and rest == b""


def test_a_reply_to_us_without_a_tmcl_status_is_noise_a_request_is_not() -> None:
    body = bytes([HOST, 1, 99, 6, 0, 0, 0, 0])
    frame = body + bytes([checksum(body)])
    assert _drain(frame)[0] == []
    assert not is_frame(frame, HOST) and is_frame(frame) and is_frame(frame, HOST, memory=True)
    assert [k for k, _ in pieces(frame)] == [FRAME_PIECE]  # no host: a request, a tap


def test_after_noise_another_hosts_frame_is_noise_too() -> None:
    """A frame for another host met right after noise is likelier noise that adds up; taken
    whole it would swallow the start of the reply behind it."""
    other = Reply(7, 1, 100, 6, 1).to_bytes()
    ours = Reply(HOST, 1, 100, 6, 2).to_bytes()
    assert _drain(other + ours)[0] == [Reply(7, 1, 100, 6, 1), Reply(HOST, 1, 100, 6, 2)]
    found, noise, _ = _drain(b"\xaa" + other + ours)
    assert found == [Reply(HOST, 1, 100, 6, 2)] and noise == b"\xaa" + other


def test_a_window_taken_whole_is_asked_about_once() -> None:
    """``whole`` may count what it accepts (a late version string): the decoder never asks
    twice about one window, also when noise before it comes out first."""
    text = b"\x021311V111"
    asked = []

    def whole(w) -> bool:
        asked.append(bytes(w[:FRAME]))
        return is_version_string(w, HOST)

    dec = FrameDecoder(HOST)
    dec.feed(b"\x55\x66" + text)
    assert dec.next(whole=whole) == (NOISE, b"\x55\x66")
    assert dec.next(whole=whole) == (WHOLE, text)
    assert asked.count(text) == 1 and dec.next(whole=whole) is None


def test_settle_drops_what_cannot_start_a_reply_after_noise() -> None:
    dec = FrameDecoder(HOST)
    dec.feed(b"\x01\x05\x07" + bytes([HOST, 1]))  # noise, then the start of a reply maybe
    assert dec.next() is None  # fewer than nine bytes: nothing to say yet
    dec.feed(b"\x00\x00\x00\x00\x00")  # ten bytes now, and no frame among them
    assert dec.next() == (NOISE, b"\x01\x05")
    assert dec.settle() == (NOISE, b"\x07")
    assert bytes(dec.buf) == bytes([HOST, 1]) + bytes(5)


def test_pieces_of_pasted_bytes_join_adjacent_noise() -> None:
    frame = Reply(HOST, 1, 100, 6, 5).to_bytes()
    bad = bytearray(frame)
    bad[8] ^= 0xFF
    assert list(pieces(bytes(bad) + frame + b"\x01")) == [
        (NOISE, bytes(bad)), (FRAME_PIECE, frame), (NOISE, b"\x01")]
