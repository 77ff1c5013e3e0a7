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
The framings (tmclsh.link.framing) write to it as they read the line, and so does the ASCII
framing (tmclsh.link.ascii) on the module's ASCII command line, whose replies name no command
(``by_command`` false): there any late reply may be taken for any request; nothing here does
I/O. Which addresses two modules answer at is counted here too (``Doubles``), from the same
replies.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Container
from dataclasses import dataclass

from ..tmcl.frames import Control, Reply, ReplyKind, Request, Status

_NORMAL, _VERSION, _NONE = ReplyKind.NORMAL, ReplyKind.VERSION_STRING, ReplyKind.NONE
_GET_VERSION = int(Control.GET_VERSION)
_OK = int(Status.OK)
_ANY = -1  # the command of a reply that names none (an ASCII line)
# how often a reader reads a value again whose answer is in doubt before it says so
CONFIRM_ROUNDS = 3
# how many answers in a row from one address must each have come twice (as many replies again
# as requests) before two modules that agree are said to share it (``Doubles``): a line that
# copies replies at a rate p copies this many within as many requests at about p to this power
SHARED_AFTER = 8
_TWICE = 2 * SHARED_AFTER  # (asked per answer)


@dataclass(frozen=True)
class Suspect:
    """A reply already returned that may have been another request's: a reply arrived later
    that no request was waiting for. ``seq`` is ``Ledger.replies`` when it was returned."""

    request: Request
    reply: Reply
    seq: int
    extra: bytes  # the reply that came when none was outstanding (b"": damaged bytes)


class Doubles:
    """Which addresses two modules answer at: the one rule (the client's, and ``scan``'s).

    Two modules given one address both answer every request: each request brings two replies
    from that address, whether the two agree or not, and whatever the offset between them
    (the second may even be taken for the next request's answer, whose own replies then come
    when nothing waits). Two kinds of evidence, both counted from replies, not matched:

    * two different answers to 136 type 1 (a checksummed frame naming the module type and
      firmware version) from one address, within a few requests: a module always gives the
      same one, and a line's copy of it is the same too, so two modules of another type or
      firmware are found at the first line check;
    * two modules that agree (one type, one firmware) are found by counting: the address's
      last ``SHARED_AFTER`` answered requests brought twice as many replies. A line that
      copies a frame now and then (a repeater, a noisy RS485 line: the simulator's ``dup``
      and ``dup-late`` faults) brings one more reply per copy, not one per request, and the
      line check that follows a copy (136) is one more request most likely answered once."""

    def __init__(self) -> None:
        self.last: Request | None = None  # the request last answered
        self.replies: dict[int, int] = {}  # replies from each address, taken or not
        # the reply count before each of the last answers from each address
        self.marks: dict[int, deque[int]] = {}
        # the last 136 type 1 answers from each address: (reply count, value)
        self.versions: dict[int, deque[tuple[int, int]]] = {}
        self.shared: set[int] = set()  # addresses two modules were found to answer at
        self.new: list[int] = []  # found and not yet taken (``take``)

    def answered(self, req: Request, reply: Reply | None = None) -> int | None:
        """``req`` was answered (a marker too), with ``reply``. The address, when found
        shared just now. (Once per request: kept short.)"""
        addr = req.address
        marks = self.marks.get(addr)
        if marks is None:
            marks = self.marks[addr] = deque(maxlen=SHARED_AFTER)
        n = self.replies.get(addr, 0)
        marks.append(n)
        self.replies[addr] = n + 1
        self.last = req
        if reply is not None and reply.opcode == _GET_VERSION and self._version_differs(
                addr, reply):
            return self._found(addr)
        if n + 1 - marks[0] >= _TWICE and len(marks) == SHARED_AFTER:
            return self._found(addr)
        return None

    def extra(self, address: int, reply: Reply | None = None) -> int | None:
        """A reply from ``address`` came that nothing waited for. The address, when found
        shared just now."""
        n = self.replies[address] = self.replies.get(address, 0) + 1
        if reply is not None and self._version_differs(address, reply):
            return self._found(address)
        marks = self.marks.get(address)
        if marks is not None and len(marks) == SHARED_AFTER and n - marks[0] >= 2 * SHARED_AFTER:
            return self._found(address)
        return None

    def extra_version(self) -> int | None:
        """A version string came that nothing waited for, right after a 136 type 0 answer:
        one more reply from the address asked (``extra``)."""
        if not self.asks_version():
            return None
        return self.extra(self.last.address)  # type: ignore[union-attr]

    def _version_differs(self, addr: int, reply: Reply) -> bool:
        """Is ``reply`` a 136 type 1 answer (a normal frame: a string answers type 0) other
        than one from ``addr`` within the last few requests?"""
        if not (reply.opcode == _GET_VERSION and reply.status == _OK and reply.version is None):
            return False
        seen = self.versions.get(addr)
        if seen is None:
            seen = self.versions[addr] = deque(maxlen=4)
        now = self.replies[addr]
        seen.append((now, reply.value))
        return len({v for n, v in seen if now - n <= 2 * SHARED_AFTER}) > 1

    def _found(self, addr: int) -> int | None:
        if addr in self.shared:
            return None
        self.shared.add(addr)
        self.new.append(addr)
        return addr

    def seconded(self, address: int, *, lately: bool = False) -> bool:
        """Has the last answer from ``address`` had another reply behind it (``lately``:
        any of its last ``SHARED_AFTER``)? Not yet a finding: asking again tells more."""
        marks = self.marks.get(address)
        if not marks:
            return False
        n = self.replies.get(address, 0)
        return n - marks[0] > len(marks) if lately else n - marks[-1] >= 2

    def asks_version(self) -> bool:
        """Was the last answer a version string (136 type 0)? Then a second one may come."""
        last = self.last
        return last is not None and last.opcode == _GET_VERSION and last.type == 0

    def forget_versions(self) -> None:
        """The link was reopened: the module there may be another one now."""
        self.versions.clear()

    def take(self) -> list[int]:
        """The addresses found shared since last asked, each told once."""
        out, self.new = self.new, []
        return out


class Ledger:
    """Bookkeeping of one line's answers (the client holds its lock around every use)."""

    def __init__(self) -> None:
        # replies name their command (binary frames): a late reply is taken only for a
        # request of its own command. False on the ASCII line, whose replies name none
        self.by_command = True
        # how many normal-layout replies may still arrive, by (address, opcode)
        self.stale: Counter[tuple[int, int]] = Counter()
        self.stale_versions = 0  # 136 type 0 version strings that may still arrive
        # a reply that could look like anything (134) may still arrive, or something else
        # used the line: whatever arrives says nothing, the next request resynchronises
        self.opaque = False
        # a reply came that nothing waited for: the next request resynchronises, and what
        # arrives meanwhile is still evidence (a copy of the last answer, arriving first,
        # must not hide the real answer behind it)
        self.out_of_step = False
        # download mode only waited for a quiet line (no marker): one follows after it
        self.drained = False
        self.replies = 0  # replies returned so far (Suspect.seq numbers them)
        # the answers given since the last point where requests and replies were known to
        # be in step, all to one (address, command): a displaced reply is taken for the next
        # request only when it has the same address and command, so a run of them is how
        # far one late reply can shift the answers. (seq, request, reply), newest last.
        self.run: deque[tuple[int, Request, Reply]] = deque(maxlen=64)
        self.copy_at = 0  # the seq in the run of the latest answer that may be a copy
        # replies taken lately, markers too, with the request each answered (None: a marker)
        self.recent: deque[tuple[Request | None, Reply]] = deque(maxlen=4)
        self.crossed: deque[Reply] = deque(maxlen=4)  # late replies lately crossed off
        # replies returned earlier that may have answered another request
        self.suspects: deque[Suspect] = deque(maxlen=64)
        self.found = 0  # suspects found so far (a reader judging answers asks what came since)
        self.doubted: deque[int] = deque(maxlen=16)  # answers returned in doubt (``doubt``)
        self.confirmed = -1  # ``replies`` when the line was last watched for a late answer
        self.doubles = Doubles()  # second answers: two modules at one address (not reset)

    def _key(self, address: int, opcode: int) -> tuple[int, int]:
        """What a late reply could be taken for: its address and command (any on ASCII)."""
        return (address, opcode if self.by_command else _ANY)

    def _same(self, a: Reply | None, b: Reply | None) -> bool:
        """The same answer on the wire (on ASCII the command is the request's, not the
        reply's: it is not compared)."""
        if self.by_command or a is None or b is None:
            return a == b
        return (a.host, a.module, a.status, a.value) == (b.host, b.module, b.status, b.value)

    @property
    def last(self) -> tuple[Request, Reply] | None:
        """The last answer given, while a late reply may still show it to be displaced."""
        return self.run[-1][1:] if self.run else None

    # -- what may still arrive --------------------------------------------------------------
    def dirty(self, downloading: bool) -> bool:
        """Something may still arrive that is no answer to the next request."""
        return bool(self.stale or self.stale_versions or self.opaque or self.out_of_step
                    or (self.drained and not downloading))

    def why_dirty(self) -> str:
        """Why the line is checked before the next request, in words true of each cause
        (the trace's note, the words of a check that fails)."""
        if self.stale or self.stale_versions:
            return "after an answer that did not come, or came damaged"
        if self.out_of_step:
            # (a reply nothing waited for, or an answer byte for byte the one before)
            return "after a reply that may have been another request's"
        if self.opaque:
            return "after traffic that cannot be paired with requests"
        return "after download mode"

    def mark_dirty(self) -> None:
        """The line may carry anything (another mode used it): resynchronise next time."""
        self.opaque = True

    def forget(self) -> None:
        """Nothing sent before can still arrive (resynchronised, or the line was reset)."""
        self.stale.clear()
        self.stale_versions = 0
        self.opaque = self.out_of_step = False
        self.drained = False
        self.in_step()

    def in_step(self) -> None:
        """Requests and replies are known to be in step (a marker's reply came, or two reads
        agreed): no later reply can show an answer before this point to be displaced."""
        self.run.clear()
        self.copy_at = 0

    def expect_late(self, req: Request, kind: ReplyKind) -> None:
        """``req`` went out and its answer did not come (in time, or whole): it may still."""
        if kind == _NONE:
            return
        if kind == _VERSION:
            # 136 type 0 is answered with a string (a refusal would be a normal frame with
            # an error status, which is not counted here)
            self.stale_versions += 1
            return
        self.stale[self._key(req.address, req.opcode)] += 1
        if kind != _NORMAL:
            self.opaque = True

    def needs_sync(self, req: Request, kind: ReplyKind, downloading: bool) -> bool:
        """Could a late answer be taken for ``req``'s? (Then the line is resynchronised.)"""
        return (self.opaque or self.out_of_step or kind != _NORMAL
                or self._key(req.address, req.opcode) in self.stale or (self.drained and not downloading))

    def marker(self, address: int) -> tuple[Request, ReplyKind] | None:
        """A harmless request whose reply cannot be taken for a late one: 136 type 1 (a
        normal frame) unless a reply like it may still arrive, else 136 type 0 (a string;
        neither a normal frame nor ASCII text is a host-addressed string); None if both may."""
        if (address, _GET_VERSION) not in self.stale:
            return Request(address, _GET_VERSION, 1, 0, 0), _NORMAL
        if not self.stale_versions:
            return Request(address, _GET_VERSION, 0, 0, 0), _VERSION
        return None

    def late(self, address: int, opcode: int, reply: Reply | None = None) -> bool:
        """A late normal reply arrived: True if one of its kind was expected (one fewer
        now), False if none was (then it is unsolicited, see ``unsolicited``)."""
        key = self._key(address, opcode)
        n = self.stale.get(key, 0)
        if n > 1:
            self.stale[key] = n - 1
        elif n:
            del self.stale[key]
        else:
            return False
        if reply is not None:
            self.crossed.append(reply)  # (a copy of it may follow: it proves nothing)
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
        return any(r.version == text for _, r in self.recent)

    # -- what was given -----------------------------------------------------------------
    def may_be_a_copy(self, req: Request, reply: Reply) -> bool:
        """Is ``reply``, about to be returned for ``req``, byte for byte the reply taken just
        before, for another request (same module and command, other type, motor or value)?
        Then it may be a copy of that one (a line that repeats replies, late), and ``req``'s
        own answer is behind it. Only the last: a copy comes right behind its reply, and one
        of an older reply would have come during the exchange between. A copy of the same
        request's answer is no such doubt: it answers the same question."""
        if not self.recent:
            return False
        r, rep = self.recent[-1]
        if rep.value != reply.value:
            return False  # (the common case, asked per request: both sames compare values)
        # (a marker's reply, r None, names its command on the binary link, and no other
        # request takes it; an ASCII reply names none: a copy of it is taken for anything)
        return self._same(rep, reply) and (r is not None or not self.by_command) and r != req

    def took(self, req: Request, reply: Reply, copy: bool | None = False,
             downloading: bool = False) -> bool:
        """``reply`` was returned as ``req``'s answer (``copy``: ``may_be_a_copy`` said so;
        None: asked here, never while ``downloading``, whose frames are stored, not read).
        Returns ``copy``. (Once per request: the client's common case is one call.)"""
        if copy is None:
            recent = self.recent
            copy = False
            if not downloading and recent and recent[-1][1].value == reply.value:
                copy = self.may_be_a_copy(req, reply)
        self.replies += 1
        run = self.run
        if run:
            # (``_key`` unrolled: once per request)
            before = run[-1][1]
            if before.address != req.address or (self.by_command
                                                 and before.opcode != req.opcode):
                self.in_step()  # (a late reply of the run before cannot be taken for this one)
        run.append((self.replies, req, reply))
        if copy:
            self.copy_at = self.replies
        self.recent.append((req, reply))
        return copy

    def took_a_copy(self) -> bool:
        """Was the answer just returned taken as one that may be a copy (``took``)? Then it
        cannot confirm another answer: two copies agree with each other."""
        return self.copy_at == self.replies != 0

    def took_marker(self, marker: Request, reply: Reply) -> None:
        """A marker's reply came: everything sent before it was answered before it."""
        self.recent.append((None, reply))

    def unsolicited(self, extra: Reply | None, raw: bytes) -> list[Suspect]:
        """A reply came when none was outstanding (``extra``; None: bytes that are no frame,
        a damaged reply): a duplicate, or the real answer to a request that took another
        reply. The line is out of step (resynchronised before the next request). Unless
        ``extra`` is a copy of the last answer, of a late reply crossed off, or of a
        marker's (the values shown carry what they carry anyway), the answers it may have
        displaced are suspects, each returned once: from the latest that may be a copy
        (``may_be_a_copy``) on, else every answer since requests and replies were last known
        to be in step (one late reply shifts a whole run of the same command). A damaged
        reply names only the last answer, or those from a possible copy on. A copy of an
        older request's reply proves nothing by itself: it may as well be the last one's
        own answer, displaced by a late copy of the one before (GAP 3 of three motors: 5000,
        0, then a copy of the 0 taken for the third while its 5000 comes late)."""
        self.out_of_step = True
        last = self.last
        if last is None or self._same(extra, last[1]) or (extra is not None and (
                any(self._same(extra, r) for r in self.crossed)
                or (self.by_command and extra.opcode == _GET_VERSION
                    and any(r == extra for _, r in self.recent)))):
            return []
        if self.copy_at:
            shifted = [e for e in self.run if e[0] >= self.copy_at and e[0] not in self.doubted]
        elif extra is None:
            shifted = [self.run[-1]]
        else:
            shifted = [e for e in self.run if e[0] not in self.doubted]
        self.in_step()  # (reported once; the next request resynchronises)
        out = [Suspect(r, rep, seq, raw) for seq, r, rep in shifted]
        self.suspects.extend(out)
        self.found += len(out)
        return out

    def doubt(self, req: Request, reply: Reply, seq: int) -> None:
        """An answer its reader could not make certain (two reads never agreed)."""
        self.suspects.append(Suspect(req, reply, seq, b""))
        self.doubted.append(seq)  # (said with the answer: not again when more evidence comes)
        self.found += 1

    def clear_suspects(self, first: int, last: int) -> None:
        """The suspects numbered ``first`` ..``last`` were settled by the one who asked."""
        keep = [s for s in self.suspects if not first <= s.seq <= last]
        self.suspects.clear()
        self.suspects.extend(keep)

    def last_may_be_a_copy(self) -> bool:
        """Whether the last reply taken could be a late copy of the one before it: only a
        reply with the same module address and command is taken for an answer. When it
        could not, no answer still to come can show it to be another request's."""
        recent = self.recent
        return len(recent) >= 2 and self._key(recent[-1][1].module, recent[-1][1].opcode) == (
            self._key(recent[-2][1].module, recent[-2][1].opcode))

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
        """The link was reopened: it starts in binary frames, until an ASCII link takes it
        again. An answer still to come when the link was lost may still arrive on the new
        one (the module answers late, an adapter or a device server kept it): then the first
        request resynchronises, as on a line that may carry anything."""
        late = self.dirty(False)
        self.forget()
        self.by_command = True
        self.doubles.forget_versions()
        self.opaque = late
