"""The ways a simulated link misbehaves on demand: counted faults a test sets, random ones
``tmclsh sim --faults`` sets, and what each kind does (for ``--help`` and the docs)."""

from __future__ import annotations

import random
from dataclasses import dataclass, field

RANDOM_DELAY = (0.2, 2.0)  # s a reply hit by the random "delay" fault is held back


@dataclass
class Faults:
    """Switches a test flips to make the link misbehave; counters count down per reply.

    ``drop_next``: the next N requests are executed but their replies are not sent.
    ``lose_next``: the next N requests addressed to the module are lost before it sees them
    (not executed, no reply). ``corrupt_next``: one bit flipped in a random byte (never the
    last one) of the next N replies. ``truncate_next``: only the first half of the next N
    replies is sent. ``garbage``: bytes sent once, just before the next reply. ``delay``:
    seconds added before every reply. ``dup_next``: the next N replies are sent twice, back
    to back; ``dup_late_next``: a copy of each of the next N replies is held back and sent
    when the next request has arrived, before its reply (a repeater or an RS485 echo that
    lags). The 138 event counts as a reply.

    ``rates`` makes the link misbehave at random: a probability per reply for each kind in
    ``RATE_KINDS`` (``tmclsh sim --faults``), drawn from ``rng``.
    """

    corrupt_next: int = 0
    drop_next: int = 0
    delay: float = 0.0
    garbage: bytes = b""
    truncate_next: int = 0
    lose_next: int = 0
    dup_next: int = 0
    dup_late_next: int = 0
    rates: dict[str, float] = field(default_factory=dict)
    rng: random.Random = field(default_factory=lambda: random.Random(0), repr=False)

    def roll(self, kind: str) -> bool:
        """Does the random fault ``kind`` hit this reply?"""
        p = self.rates.get(kind)
        return bool(p) and self.rng.random() < p  # type: ignore[operator]

    def take(self, counter: str, kind: str) -> bool:
        """The counted fault ``counter`` (counted down) or else the random ``kind``."""
        n = getattr(self, counter)
        if n > 0:
            setattr(self, counter, n - 1)
            return True
        return bool(self.rates) and self.roll(kind)

    def lose(self) -> bool:
        """Is the request arriving now lost before the module sees it (``lose_next``)?"""
        if self.lose_next > 0:
            self.lose_next -= 1
            return True
        return False


#: random faults per reply (``Faults.rates``), with what each does, for --help and the docs
RATE_KINDS = {
    "drop": "the reply is not sent (the command was executed)",
    "corrupt": "one bit of the reply flipped",
    "truncate": "only the first half of the reply is sent",
    "delay": f"the reply is held back {RANDOM_DELAY[0]:g}..{RANDOM_DELAY[1]:g} s "
             "(and the replies behind it)",
    "garbage": "1..8 bytes of noise before the reply",
    "dup": "the reply is sent twice, back to back",
    "dup-late": "a copy of the reply follows once the next request has arrived",
}


def parse_rates(text: str) -> dict[str, float]:
    """``"drop=0.1,dup=0.05"`` -> rates; ValueError (one line, for users) on bad input."""
    rates: dict[str, float] = {}
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        kind, sep, prob = part.partition("=")
        kind = kind.strip().lower()
        if not sep or kind not in RATE_KINDS:
            raise ValueError(f"{part!r} is not KIND=PROBABILITY (kinds: "
                             f"{', '.join(RATE_KINDS)})")
        try:
            p = float(prob)
        except ValueError:
            p = -1.0
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"{kind}={prob.strip()}: the probability must be a number "
                             "from 0 to 1")
        rates[kind] = p
    if not rates:
        raise ValueError("no faults given (e.g. drop=0.1,dup=0.05; kinds: "
                         f"{', '.join(RATE_KINDS)})")
    return rates
