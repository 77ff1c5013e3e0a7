"""Replies nobody waited for, and the answers they put in doubt.

TMCL replies carry no sequence number, so a reply that arrives when no request waits for it
is evidence: expected (a late answer the ledger wrote down: crossed off), a second module at
the address (``shared.py``), or the real answer to a request that took another reply, which
makes that earlier answer a *suspect*. The framings report such replies here as they read
the line (through the client: ``_late``, ``_noise_unsolicited``, ``_accept_version``);
readers ask here which of their answers are in doubt (``Client.in_doubt``, the one check),
say which they dealt with (``settle``), and the shell takes the rest to report them
(``take_suspects``) and watches the line at the end of a run (``confirm_last``).

The bookkeeping is the ledger's (ledger.py, no I/O); this is the client's side of it, which
holds the client's lock and may look at the line.
"""

from __future__ import annotations

import time
from collections.abc import Container, Mapping
from typing import TYPE_CHECKING, TypeVar

from ..base.errors import ChecksumError, DownloadModeError, TmclTimeoutError
from ..link.framing import name_of
from ..tmcl.frames import Control, Reply, Request
from .ledger import Suspect
from .taps import tell

if TYPE_CHECKING:
    from .core import Client
    from .shared import SharedAddresses
    from .taps import Taps

K = TypeVar("K")

_GET_VERSION = int(Control.GET_VERSION)


class Doubts:
    """Answers in doubt: found from replies nobody waited for, checked, settled, reported."""

    def __init__(self, client: Client, taps: Taps, sharing: SharedAddresses):
        self._client = client
        self._ledger = client._ledger
        self._lock = client._lock
        self._stats = client.stats
        self._tracers = taps.tracers
        self._discard = taps.discard
        self._second = sharing.second

    # -- what the framings report -------------------------------------------------------
    def late(self, address: int, opcode: int, reply: Reply | None) -> bool:
        """A reply arrived that no request waits for: True if one like it was expected
        (``Ledger.late``), or the line may carry anything; else it is unsolicited."""
        ledger = self._ledger
        if ledger.late(address, opcode, reply):
            self.came_late(address)
            return True
        if ledger.opaque or self._client._downloading:
            # (no doubt cast, but a reply all the same: a second module answers here too)
            self._second(ledger.doubles.extra(address, reply))
            return True
        self.unsolicited(reply)
        return False

    def came_late(self, address: int) -> None:
        """An answer from ``address`` came after its request was given up (counted in
        ``Client._late_from``: the words for a module that does not answer in time)."""
        late = self._client._late_from
        late[address] = late.get(address, 0) + 1

    def noise_unsolicited(self) -> None:
        """Bytes that were no frame came while nothing was outstanding and nothing was
        expected: a damaged reply, possibly the real answer to the last request."""
        downloading = self._client._downloading
        if not self._ledger.dirty(downloading) and not downloading:
            self.unsolicited(None)

    def accept_version(self, window: bytes) -> bool:
        """Nine bytes that are no frame: a version string the ledger expects (a stale 136
        type 0's) or one taken lately (a duplicated 136 reply)? Then they are read whole."""
        if window[0] != self._client.host_address or not all(32 <= b < 127
                                                             for b in window[1:9]):
            return False
        raw = bytes(window[:9])
        ledger = self._ledger
        if ledger.late_version():
            self.came_late(self._client.address)
            self._discard(raw, "stale version string")
            return True
        if ledger.is_version_copy(raw[1:].decode("latin-1")):
            # (a copy is no damaged reply either: the answer may still come, after a
            # module's pause before replying)
            self._stats["unsolicited"] += 1
            ledger.mark_dirty()
            self._discard(raw, "copy of the version string")
            self._second(ledger.doubles.extra_version())
            return True
        if ledger.doubles.asks_version() and not ledger.opaque:
            # another version string right behind the one asked for: a second module
            # answered the same 136 (nothing else sends a host-addressed string)
            self._stats["unsolicited"] += 1
            ledger.mark_dirty()
            self._discard(raw, "a second version string (another module at this address?)")
            self._second(ledger.doubles.extra_version())
            return True
        return False

    def unsolicited(self, extra: Reply | None) -> None:
        """A reply (None: damaged bytes) that nothing waited for and nothing expected: the
        answers it may have displaced become suspects."""
        self._stats["unsolicited"] += 1
        if extra is not None:
            self._second(self._ledger.doubles.extra(extra.module, extra))
        raw = (b"" if extra is None else extra.to_can() if self._client.is_can
               else extra.to_bytes())
        for suspect in self._ledger.unsolicited(extra, raw):
            self._stats["suspect"] += 1
            if self._tracers:
                tell(self._tracers, "note", b"", f"the reply to {name_of(suspect.request)} "
                     "may have been another request's: a reply came that nothing was "
                     "waiting for")

    # -- readers' questions -------------------------------------------------------------
    def last_may_be_a_copy(self) -> bool:
        """Whether the last reply taken could be a late copy of the one before it."""
        with self._lock:
            return self._ledger.last_may_be_a_copy()

    def suspect_seqs(self) -> set[int]:
        """The ``seq`` of every suspect not yet taken (``take_suspects`` still reports them)."""
        with self._lock:  # (the event poller may add one meanwhile)
            return self._ledger.suspect_seqs()

    def take_suspects(self, seqs: Container[int] | None = None) -> list[Suspect]:
        """Replies returned earlier that may have answered another request (oldest first);
        each is reported once. ``seqs``: only those (a caller that read again, or marked the
        values in doubt itself, takes its own; the rest stay to be reported)."""
        with self._lock:  # (the event poller may add one meanwhile)
            return self._ledger.take_suspects(seqs)

    def in_doubt(self, answered: Mapping[int, K], *, confirm: bool = True) -> set[K]:
        """``Client.in_doubt``."""
        if not answered:
            return set()
        c = self._client
        if confirm and c._by_line:
            with self._lock:
                c._framing.absorb()
        elif confirm:
            c.poll()  # what waits already is taken in (nothing is sent, nothing awaited)
            # the exchange only if the last answer may be the reply before it, taken again;
            # not on the simulator in process (whatever follows an answer waits already)
            if not c.transport.simulated and self.last_may_be_a_copy():
                try:
                    c.request(Request(c.address, _GET_VERSION, 1, 0, 0))
                except (TmclTimeoutError, ChecksumError, DownloadModeError):
                    pass  # what it could find is found by the next request's flush as well
        found = self.suspect_seqs()
        return {key for seq, key in answered.items() if seq in found}

    def settle(self, answered: Mapping[int, object]) -> None:
        """The suspects among ``answered`` were dealt with by their reader (read again, or
        said to be in doubt): they are not reported again."""
        if answered:
            self.take_suspects(answered.keys())

    def confirm_last(self) -> None:
        """At the end of a run: was the last reply the answer to its request? A late copy of
        the reply before it (same address and command) would have been taken for it; its
        real answer then comes right behind, when nothing waits for it, and makes the last
        reply a suspect (``take_suspects``). So the line is watched until it has been quiet
        for two frames' wire time (nothing is sent); otherwise, or on the simulator, what is
        already waiting is taken in."""
        c = self._client
        with self._lock:
            if not c.transport.is_open:
                return
            if c._by_line:
                c._framing.absorb(watch=True)
                return
            ledger = self._ledger
            quiet = c._framing.quiet_time()
            if not ledger.last_may_be_a_copy() or ledger.confirmed == ledger.replies:
                quiet = 0.0  # (this reply was watched for already)
            end = time.monotonic() + max(0.5, 10 * quiet)
            while c._framing.absorb(quiet) and quiet and time.monotonic() < end:
                pass
            ledger.confirmed = ledger.replies
        if c._events:
            c._deliver_events()
