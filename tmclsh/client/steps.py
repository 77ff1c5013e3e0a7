"""The request path's steps, each written once, taken by both ways requests go: one at a time
(``Client.request``, core.py) and a run of them (``Client.requests``: an upload's frames,
its read-back, thousands at the line's pace).

Before a request goes out, what waits on the line is taken in and a line that may still
bring an earlier answer is resynchronised (``clear_line``); the framing's ``exchange`` sends
it and checks the reply (address, host, command, checksum, layout); the answer is written
into the ledger and judged when it may be a copy (``take_answer``); what it tells beyond
itself is taken once the link is released (``after_answer``). A run goes through the same
steps with what it does not change looked up once, and takes the next request from its
caller while the module answers (``_Ahead``); an attempt of a run's that is not plain (a
failure, a reply that is no plain answer) is carried on by ``Client._request``'s own loop
of attempts, as its first, and anything unusual before it (a bring-up or download check
due, the ASCII line, the link down) is left to ``Client.request`` whole.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from typing import TYPE_CHECKING

from ..base.errors import DownloadModeError, TransportError
from ..link.framing import name_of
from ..tmcl import instructions as isa
from ..tmcl.frames import Control, Reply, ReplyKind, Request, Status
from .motion import watched_opcodes

if TYPE_CHECKING:
    from .core import Client

_NORMAL = ReplyKind.NORMAL
_FIRST_CONTROL = int(Control.STOP_APPLICATION)  # only control commands have other layouts
_LOADED = int(Status.LOADED)
_WRONG_CHECKSUM = int(Status.WRONG_CHECKSUM)
_QUIT_DOWNLOAD = isa.download_command("leave")
_ENTER_DOWNLOAD = isa.download_command("enter")
_MOTION = watched_opcodes()  # what may start or stop a motor (client/motion.py)


def reply_kind(req: Request) -> ReplyKind:
    """How ``req``'s answer is laid out (a normal frame for every command below 128)."""
    op = req.opcode
    return _NORMAL if op < _FIRST_CONTROL else isa.reply_kind(op, req.type)


def clear_line(client: Client, req: Request, kind: ReplyKind, timeout: float) -> bool:
    """Before ``req`` goes out: what waits is taken in (``Client._flush_input``), and a
    line that may still bring an answer ``req``'s could be taken for is resynchronised
    (``Client._resync``: True, the line is clear now)."""
    ledger = client._ledger
    if client._framing.waiting():
        client._flush_input()
    downloading = client._downloading
    if ledger.dirty(downloading):
        if ledger.needs_sync(req, kind, downloading):
            client._resync(req.address, timeout)
            return True
    elif ledger.run and time.monotonic() - client._answered_at >= timeout:
        # quiet for a whole timeout, nothing expected: an answer displaced before now would
        # have come (it counts as lost after a timeout)
        ledger.in_step()
    return False


def take_answer(client: Client, req: Request, reply: Reply, timeout: float,
                retries: int) -> Reply:
    """``reply`` taken as ``req``'s answer: written into the ledger (counted, and for two
    modules at one address), and judged first when it may be a copy (``Client._judge``)."""
    ledger = client._ledger
    copy = ledger.took(req, reply, copy=None, downloading=client._downloading)
    found = ledger.doubles.answered(req, reply)
    if found is not None:
        client._second(found)
    client._answered_at = time.monotonic()
    if copy and not client._judging:
        return client._judge(req, reply, timeout, retries)
    return reply


def after_answer(client: Client, req: Request, reply: Reply | None) -> None:
    """What an answer tells beyond itself, once the link is released: a motor set moving
    or stopped (motion.py), download mode begun or ended by a command of the user's, a
    command stored instead of executed (raised)."""
    if reply is None:
        return
    op = req.opcode
    if op in _MOTION and not client._downloading:
        client.motion.take(client.module, req, reply.status)
    if op >= _FIRST_CONTROL and (op == _QUIT_DOWNLOAD or op == _ENTER_DOWNLOAD) and reply.ok:
        # (a typed 132 with no 133 after it; asked of 132 and 133 alone: an upload's verify
        # sends thousands of 134)
        if op == _QUIT_DOWNLOAD:
            client._left_downloading = False
        elif not client._downloading:
            client._left_downloading = True
    if reply.status == _LOADED and not client._downloading:
        raise DownloadModeError(
            _LOADED, reply,
            f"the module is in download mode (it stores commands instead of executing "
            f"them): {name_of(req)} was stored in program memory, not executed; "
            "the line 133 (quit download mode) ends it")


def run(client: Client, reqs: Iterable[Request], timeout: float, retries: int
        ) -> Iterator[Reply | None]:
    """``Client.requests``: each request by the steps above, what a run does not change
    looked up once, the next request taken while the module answers."""
    lock = client._lock
    framing = client._framing
    exchange = framing.exchange
    carry = client._request
    ahead = _Ahead(reqs)
    take = ahead.take
    while (req := ahead.next()) is not None:
        op = req.opcode
        kind = _NORMAL if op < _FIRST_CONTROL else isa.reply_kind(op, req.type)
        plain = False
        try:
            with lock:
                if (client._framing is framing and not (
                        client._bring_up_next or client._check_download or client._by_line
                        or client._down) and client.transport.is_open):
                    plain = True
                    first: tuple[bool, object] | None = None
                    try:
                        synced = clear_line(client, req, kind, timeout)
                    except BaseException as exc:
                        first = (False, exc)  # (nothing of req went out)
                    else:
                        framing.meanwhile = take
                        try:
                            reply = exchange(req, kind, timeout, synced)
                        except BaseException as exc:
                            first = (True, exc)
                        else:
                            if reply is None or reply.status == _WRONG_CHECKSUM:
                                first = (True, reply)
                        finally:
                            framing.meanwhile = None
                    try:
                        if first is None:
                            reply = take_answer(client, req, reply, timeout, retries)
                        else:
                            reply = carry(req, timeout, retries, first)
                    except TransportError:
                        client._down = True
                        raise
            if plain:
                after_answer(client, req, reply)
        finally:
            if plain and client._events:
                client._deliver_events()
        yield reply if plain else client.request(req, timeout=timeout, retries=retries)


class _Ahead:
    """The requests of a run, the next one taken from the caller's iterable, and its frame
    made, while the module answers the one before (the framing calls ``take`` once the
    request is written: ``SerialFraming.meanwhile``), so that the time between a reply and
    the next request is the client's checks alone. What taking one raised is raised where
    that request would have gone; a Ctrl-C is not held back."""

    __slots__ = ("_reqs", "_next", "_error")

    def __init__(self, reqs: Iterable[Request]):
        self._reqs: Iterator[Request] | None = iter(reqs)
        self._next: Request | None = None
        self._error: Exception | None = None

    def take(self) -> None:
        # (called by the run's own exchange only: the framing's hook is set while the run
        # holds the link)
        if self._next is not None or self._reqs is None or self._error is not None:
            return
        try:
            req = next(self._reqs)
            req.to_bytes()  # (kept by the request: its frame is ready when it goes)
        except StopIteration:
            self._reqs = None
        except Exception as exc:
            self._error = exc
        else:
            self._next = req

    def next(self) -> Request | None:
        """The next request (None: the run is over)."""
        req = self._next
        if req is not None:  # (taken while the module answered: the common case)
            self._next = None
            return req
        self.take()
        if self._error is not None:
            self._reqs = None
            error, self._error = self._error, None
            raise error
        req, self._next = self._next, None
        return req
