"""The ledger of answers: which may still arrive that no request waits for, and which answers
already given may have been another request's.

TMCL replies carry no sequence number. A request that timed out or got a damaged reply may
still be answered later, and that late answer looks like the answer to the next request of
the same kind; a line that duplicates replies does the same. So every reply the client
takes is counted here, every answer that may still come is written down (*stale*), and a
reply that arrives when nothing waits for it makes the last answer given a *suspect*.

One ledger per client; everything that asks "is this answer certain?" asks it here:
``Client.in_doubt`` for a reader's own reads (``.watch``, ``.expect``, the safety stop's
read-back, an upload's verify), ``take_suspects`` for the shell's report after a line.
The framing (tmclsh.link.framing) writes to it as it reads the line; nothing here does I/O.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Container
from dataclasses import dataclass

from ..tmcl.frames import Control, Reply, ReplyKind, Request

_NORMAL, _VERSION, _NONE = ReplyKind.NORMAL, ReplyKind.VERSION_STRING, ReplyKind.NONE
_GET_VERSION = int(Control.GET_VERSION)
# how often a reader reads a value again whose answer is in doubt before it says so
CONFIRM_ROUNDS = 3


@dataclass(frozen=True)
class Suspect:
    """A reply already returned that may have been another request's: a reply arrived later
    that no request was waiting for. ``seq`` is ``Ledger.replies`` when it was returned."""

    request: Request
    reply: Reply
    seq: int
    extra: bytes  # the reply that came when none was outstanding (b"": damaged bytes)


class Ledger:
    """Bookkeeping of one line's answers (the client holds its lock around every use)."""

    def __init__(self) -> None:
        # how many normal-layout replies may still arrive, by (address, opcode)
        self.stale: Counter[tuple[int, int]] = Counter()
        self.stale_versions = 0  # 136 type 0 version strings that may still arrive
        # a reply that could look like anything (134) may still arrive, or something else
        # used the line: the next request resynchronises whatever it is
        self.opaque = False
        # download mode only waited for a quiet line (no marker): one follows after it
        self.drained = False
        self.replies = 0  # replies returned so far (Suspect.seq numbers them)
        self.last: tuple[Request, Reply] | None = None  # what a late reply may displace
        self.recent: deque[Reply] = deque(maxlen=4)  # replies taken lately, markers too
        # replies returned earlier that may have answered another request
        self.suspects: deque[Suspect] = deque(maxlen=64)
        self.confirmed = -1  # ``replies`` when the line was last watched for a late answer

    # -- what may still arrive --------------------------------------------------------------
    def dirty(self, downloading: bool) -> bool:
        """Something may still arrive that is no answer to the next request."""
        return bool(self.stale or self.stale_versions or self.opaque
                    or (self.drained and not downloading))

    def mark_dirty(self) -> None:
        """The line may carry anything (another mode used it): resynchronise next time."""
        self.opaque = True

    def forget(self) -> None:
        """Nothing sent before can still arrive (resynchronised, or the line was reset)."""
        self.stale.clear()
        self.stale_versions = 0
        self.opaque = False
        self.drained = False

    def expect_late(self, req: Request, kind: ReplyKind) -> None:
        """``req`` went out and its answer did not come (in time, or whole): it may still."""
        if kind == _NONE:
            return
        if kind == _VERSION:
            # 136 type 0 is answered with a string (a refusal would be a normal frame with
            # an error status, which is not counted here)
            self.stale_versions += 1
            return
        self.stale[(req.address, req.opcode)] += 1
        if kind != _NORMAL:
            self.opaque = True

    def needs_sync(self, req: Request, kind: ReplyKind, downloading: bool) -> bool:
        """Could a late answer be taken for ``req``'s? (Then the line is resynchronised.)"""
        return (self.opaque or kind != _NORMAL or (req.address, req.opcode) in self.stale
                or (self.drained and not downloading))

    def marker(self, address: int) -> tuple[Request, ReplyKind] | None:
        """A harmless request whose reply cannot be taken for a late one: 136 type 1 (a
        normal frame) unless a reply like it may still arrive, else 136 type 0 (a string;
        neither a normal frame nor ASCII text is a host-addressed string); None if both may."""
        if (address, _GET_VERSION) not in self.stale:
            return Request(address, _GET_VERSION, 1, 0, 0), _NORMAL
        if not self.stale_versions:
            return Request(address, _GET_VERSION, 0, 0, 0), _VERSION
        return None

    def late(self, address: int, opcode: int) -> bool:
        """A late normal reply arrived: True if one of its kind was expected (one fewer
        now), False if none was (then it is unsolicited, see ``unsolicited``)."""
        key = (address, opcode)
        n = self.stale.get(key, 0)
        if n > 1:
            self.stale[key] = n - 1
        elif n:
            del self.stale[key]
        else:
            return False
        return True

    def late_version(self) -> bool:
        """A version string arrived that nothing waits for: True if a stale 136 type 0
        still had one coming (one fewer now)."""
        if self.stale_versions:
            self.stale_versions -= 1
            return True
        return False

    def is_version_copy(self, text: str) -> bool:
        """Is ``text`` a version string taken lately (a duplicated 136 reply)?"""
        return any(r.version == text for r in self.recent)

    # -- what was given -----------------------------------------------------------------
    def took(self, req: Request, reply: Reply) -> None:
        """``reply`` was returned as ``req``'s answer."""
        self.replies += 1
        self.last = (req, reply)
        self.recent.append(reply)

    def unsolicited(self, extra: Reply | None, raw: bytes) -> Suspect | None:
        """A reply came when none was outstanding (``extra``; None: bytes that are no frame,
        a damaged reply): a duplicate, or the real answer to the last request, which then
        took another one. The line is dirty and, unless ``extra`` is a copy of the last
        request's reply (the value shown is the one it carries anyway) or of a marker's, the
        last answer is a suspect (returned, once). A copy of an older request's reply proves
        nothing: it may as well be the last request's own answer, displaced by a late copy
        of the one before (GAP 3 of three motors: 5000, 0, then a copy of the 0 taken for
        the third while its 5000 comes late)."""
        self.opaque = True
        last = self.last
        if last is None or extra == last[1] or (
                extra is not None and extra.opcode == _GET_VERSION and extra in self.recent):
            return None
        self.last = None  # reported once
        suspect = Suspect(last[0], last[1], self.replies, raw)
        self.suspects.append(suspect)
        return suspect

    def last_may_be_a_copy(self) -> bool:
        """Whether the last reply taken could be a late copy of the one before it: only a
        reply with the same module address and command is taken for an answer. When it
        could not, no answer still to come can show it to be another request's."""
        recent = self.recent
        return len(recent) >= 2 and (recent[-1].module, recent[-1].opcode) == (
            recent[-2].module, recent[-2].opcode)

    def suspect_seqs(self) -> set[int]:
        return {s.seq for s in self.suspects}

    def take_suspects(self, seqs: Container[int] | None = None) -> list[Suspect]:
        """The suspects (oldest first), each reported once; ``seqs``: only those."""
        if seqs is None:
            out = list(self.suspects)
            self.suspects.clear()
            return out
        out = [s for s in self.suspects if s.seq in seqs]
        keep = [s for s in self.suspects if s.seq not in seqs]
        self.suspects.clear()
        self.suspects.extend(keep)
        return out

    def reset(self) -> None:
        """The link was reopened: whatever comes now says nothing about answers before."""
        self.forget()
        self.last = None
