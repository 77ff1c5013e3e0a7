"""Addresses two modules answer at, as the client tells them.

The counting is the ledger's (``ledger.Doubles``: replies per address against answered
requests, two different 136 answers), because the same rule serves ``scan``. What is here
is the client's side of it: the trace's note where an address was found shared, and the
questions the shell, ``scan`` and an upload ask, each under the client's lock (the event
poller may count a reply meanwhile).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .taps import tell

if TYPE_CHECKING:
    from .core import Client


class SharedAddresses:
    """The client's view of ``ledger.Doubles``."""

    def __init__(self, client: Client):
        self._lock = client._lock
        self._doubles = client._ledger.doubles
        self._tracers = client._tracers

    def second(self, found: int | None) -> None:
        """A reply was counted (``ledger.Doubles``): ``found``, the address found shared
        just now (the trace says so where it happened)."""
        if found is not None and self._tracers:
            tell(self._tracers, "note", b"", shared_text(found))

    @property
    def shared(self) -> frozenset[int]:
        """``Client.shared``."""
        return frozenset(self._doubles.shared)

    def answered_twice(self, address: int, *, lately: bool = False) -> bool:
        """``Client.answered_twice``."""
        with self._lock:
            return self._doubles.seconded(address, lately=lately)

    @property
    def news(self) -> bool:
        """``Client.shared_news``."""
        return bool(self._doubles.new)

    def take(self) -> list[int]:
        """``Client.take_shared``."""
        with self._lock:
            return self._doubles.take()


def shared_text(address: int) -> str:
    """What a shared address means, in words for users (the one wording)."""
    return (f"two modules answer at address {address}: every reply came twice, so every "
            "command reaches both and which answer is shown is chance; give one of them "
            "another address while the other is disconnected")
