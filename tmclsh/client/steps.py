"""The request path's steps, each written once, taken by both ways requests go: one at a time
(``Client.request``, core.py) and a run of them (``Client.requests``: an upload's frames,
its read-back, thousands at the line's pace).

Before a request goes out, what waits on the line is taken in and a line that may still
bring an earlier answer is resynchronised (``clear_line``); the framing's ``exchange`` sends
it and checks the reply (address, host, command, checksum, layout); the answer is written
into the ledger and judged when it may be a copy (``take_answer``); what it tells beyond
itself is taken once the link is released (``after_answer``). A run goes through the same
steps with what it does not change looked up once, and without the layers of a single
request's entry (its arguments checked, its own loop of attempts): what a run adds between
one reply and the next request is its checks. An attempt of a run's that is not plain (a
failure, a reply that is no plain answer) is carried on by ``Client._request``'s own loop
of attempts, as its first, and anything unusual before it (a bring-up or download check
due, the ASCII line, the link down) is left to ``Client.request`` whole.

(Work between writing a request and waiting for its reply is no gain: measured on a pty,
what the client does there delays the reply by as much, so a run's requests are best made
before it starts, as an upload makes its frames.)
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
    copy = ledger.took(req, reply, None, client._downloading)  # (copy asked there)
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
    looked up once."""
    lock = client._lock
    framing = client._framing
    exchange = framing.exchange
    carry = client._request
    for req in reqs:
        kind = reply_kind(req)
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
                        try:
                            reply = exchange(req, kind, timeout, synced)
                        except BaseException as exc:
                            first = (True, exc)
                        else:
                            if reply is None or reply.status == _WRONG_CHECKSUM:
                                first = (True, reply)
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
