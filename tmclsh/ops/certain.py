"""Reading until the answers are certain: the one loop every reader of values uses.

TMCL replies carry no sequence number, so an answer may have been a late copy of another
request's; the client finds that out only later (``Client.in_doubt``). A reader that states
what it read (an upload's verify, the safety stop's read-back, ``.watch``, ``.expect`` and
``.wait``) reads the doubtful values again, ``CONFIRM_ROUNDS`` times at most, and says what
stays in doubt instead of stating it. Written once here so that the bound, the check and
what is judged each round are the same for all of them, and usable from Python.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Generic, TypeVar

from ..client.ledger import CONFIRM_ROUNDS

K = TypeVar("K")

__all__ = ["Certain", "CONFIRM_ROUNDS", "read_until_certain"]


@dataclass
class Certain(Generic[K]):
    """What ``read_until_certain`` found. ``doubt``: the keys whose last answer is still in
    doubt; ``answered``: the answer each key was last given (``Client._replies`` after it ->
    key); ``taken``: every answer the rounds took, replaced ones too (for ``Doubts.settle``);
    ``again``: rounds read again after the first; ``accepted``: the reading ended because it
    was accepted, not because the rounds ran out."""

    doubt: set[K]
    answered: dict[int, K]
    taken: dict[int, K] = field(default_factory=dict)
    again: int = 0
    accepted: bool = True


def read_until_certain(client, read: Callable[[set[K] | None], Mapping[int, K]], *,
                       again: int = CONFIRM_ROUNDS, confirm: bool = True,
                       confirm_again: bool = True, first: Mapping[int, K] | None = None,
                       accept: Callable[[set[K]], bool] | None = None) -> Certain[K]:
    """Read, judge the answers, read the doubtful ones again (``again`` rounds at most).

    ``read(keys)`` makes the reads (``keys`` None: the first round, else the keys in doubt)
    and returns the answers to judge (``Client._replies`` after each read -> key). A key read
    again replaces its earlier answer; every round judges each key's latest answer, so an
    answer found out later is caught too. ``first``: the first round's answers when the
    reads were already made. ``confirm``: give the first round's last answer the chance to
    be found out (``Client.in_doubt``); ``confirm_again``: the later rounds' (a poll that
    will be followed by another leaves it to the next). ``accept(doubt)`` decides
    whether a round ends the reading (default: nothing is in doubt); it is asked after every
    round, so a reader that wants two certain readings in a row can count them.
    Never raises for a doubt: what stays in doubt is in the result, for the caller to say.
    """
    answered: dict[int, K] = dict(read(None) if first is None else first)
    taken = dict(answered)
    doubt = client.in_doubt(answered, confirm=confirm)
    done = accept(doubt) if accept is not None else not doubt
    rounds = 0
    while not done and rounds < again:
        rounds += 1
        new = dict(read(set(doubt) if doubt else None))
        renewed = doubt | set(new.values())
        answered = {seq: k for seq, k in answered.items() if k not in renewed}
        answered.update(new)
        taken.update(new)
        doubt = client.in_doubt(answered, confirm=confirm_again)
        done = accept(doubt) if accept is not None else not doubt
    return Certain(doubt, answered, taken, rounds, done)
