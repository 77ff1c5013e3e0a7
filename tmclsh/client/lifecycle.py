"""The link's life under a client: reopened after it was lost, reset or used by something
else, switched for another, and closed with the module left as it was found.

Each of these leaves the client's bookkeeping in a state the request path relies on (the
framing the transport makes fresh, what may still arrive forgotten or to be resynchronised,
the module brought up again before the next command), so each is written once here rather
than by whoever reopens or borrows the line: the shell's ``.connect`` and reconnects, a
firmware update, ``scan``, the ASCII mode's switches, a baud rate changed.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from ..base.errors import TransportError
from ..link.base import Transport
from ..tmcl import instructions as isa
from ..tmcl.frames import Request
from ..tmcl.modules import Module
from ..tmcl.modules import load as load_module
from .advice import more_time
from .taps import failed

if TYPE_CHECKING:
    from .core import Client
    from .taps import Taps

_QUIT_DOWNLOAD = isa.download_command("leave")


class Lifecycle:
    """Opening again, resetting, switching and closing the client's link."""

    def __init__(self, client: Client, taps: Taps):
        self._client = client
        self._taps = taps
        # run by close() while the link is still open (the ASCII link restores the mode the
        # module was found in)
        self.close_hooks: list[Callable[[], None]] = []

    # -- opened again -------------------------------------------------------------------
    def reconnect(self, wait: float = 0.0, *, bring_up: bool = True) -> None:
        """``Client.reconnect``."""
        c = self._client
        with c._lock:
            self.reopen(wait)
            c._bring_up_next = bring_up
            c.stats["reconnects"] += 1
            if c._tracers:
                self._taps.note(f"reconnected to {c.describe()}")

    def reopen(self, wait: float = 0.0) -> None:
        """Close and open the transport (``wait``: seconds to keep trying), with nothing of
        the old line kept but what may still arrive on the new one."""
        c = self._client
        c.transport.close()
        deadline = time.monotonic() + wait
        while True:
            try:
                c.transport.open()
                break
            except TransportError:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(min(0.1, max(0.0, deadline - time.monotonic())))
        c._down = False
        # (a module driven in ASCII mode is found again in whichever mode it is in now:
        # bringup.again)
        c._framing = c._binary_framing = c.transport.framing(c)
        c._by_line = False
        c._ledger.reset()  # (an answer still to come may come on the new link too)

    def check_download_next(self) -> None:
        """Download mode may not have ended (a 133 went unanswered, or was interrupted):
        before the next command, ask the module and end it if need be, so that command is
        executed, not stored."""
        self._client._check_download = True

    def lost_check(self, address: int, why: str) -> str:
        """``lost_check`` for the framings (the ASCII link's line check)."""
        return lost_check(self._client, address, why)

    # -- the line used or reset by something else ---------------------------------------
    def absorb(self) -> None:
        """Take in what is pending on the line (the framing's rules): events are kept, all
        else is stale; a reply among it is a late one."""
        c = self._client
        with c._lock:
            c._framing.absorb()

    def clear_input(self) -> None:
        """Forget bytes buffered for the binary framing (the line was in another mode)."""
        c = self._client
        with c._lock:
            c._framing.clear()

    def forget_stale(self) -> None:
        """The line was reset (its baud rate changed): nothing sent before can still arrive."""
        c = self._client
        with c._lock:
            c._framing.clear()
            c._ledger.forget()

    def resync_next(self) -> None:
        """Something else used the line (the module's ASCII mode): whatever is left on it is
        stale, so the next binary request starts with the resynchronisation marker."""
        c = self._client
        with c._lock:
            c._framing.clear()
            c._ledger.mark_dirty()

    # -- left ---------------------------------------------------------------------------
    def close(self) -> None:
        """``Client.close``."""
        c = self._client
        self._taps.stop_poller()
        with c._lock:
            self.leave_link()
            c.transport.close()

    def leave_link(self) -> None:
        """Run the close hooks, leave ASCII mode if entered: the module is left as it was
        found, while the link is still open."""
        c = self._client
        hooks, self.close_hooks = self.close_hooks, []
        for hook in hooks:
            try:
                hook()
            except Exception as exc:
                failed("closing", exc)
        if c._left_downloading and c.transport.is_open:
            self.end_left_download()
        if c.ascii_link is not None:
            try:
                c.ascii_link.close()
            except Exception as exc:
                failed("leaving ASCII mode", exc)

    def end_left_download(self) -> None:
        """133 for a 132 that was sent and never ended (by a line, not an upload)."""
        c = self._client
        c._left_downloading = False
        c._downloading = True  # (what 133 gets while the module stores commands)
        try:
            reply = c.request(Request(c.address, _QUIT_DOWNLOAD, 0, 0, 0))
        except Exception as exc:
            failed("ending download mode (133)", exc)
            return
        finally:
            c._downloading = False
        if reply is not None and reply.ok:
            self._taps.notice(f"the module at address {c.address} was still in download mode "
                              "(a 132 line with no 133 after it): ended it with 133; what was "
                              "sent after the 132 is stored as its program")
        else:
            self._taps.notice(f"the module at address {c.address} is in download mode (a 132 "
                              "line) and did not leave it for 133 "
                              f"(status {reply.status if reply is not None else 'none'})")

    def switch_transport(self, transport: Transport, module: Module | str | None = None) -> None:
        """Go on on another link (the shell's ``.connect``): the old one is left as ``close``
        leaves it (the close hooks run, the module is left in the mode it was found in, the
        port is closed); nothing of it is carried over. The new link starts in binary mode
        with ``module`` (None: not known yet); listeners, tracers and the event poller stay.
        Bring the module up with ``bringup.bring_up`` (136, download mode, ASCII mode)."""
        c = self._client
        mod = load_module(module) if isinstance(module, str) else module
        with c._lock:
            self.leave_link()
            try:
                c.transport.close()
            except Exception:  # the old link may already be gone; that is why we switch
                pass
            c.ascii_link = None
            c.transport = transport
            c.module = mod
            c.version = None
            c.motion.forget()  # (another module, or one that was told nothing yet)
            c._motion_left.clear()  # (another link)
            self.reopen()  # clears buffers and stale-reply bookkeeping, reopens the link
            c._bring_up_next = c._check_download = False  # (what bring_up does)
            c.stats["reconnects"] += 1
            if c._tracers:
                self._taps.note(f"reconnected to {c.describe()}")


def lost_check(client: Client, address: int, why: str) -> str:
    """The words for a line check (after a failure) that got no good answer: the first is a
    lost reply, as a line that loses one now and then does; only a second in a row, with
    no good answer between, is a module that stopped answering, unless answers from it came
    meanwhile, after they were given up: then it answers, too late for the timeout."""
    client._checks_lost += 1
    late = client._late_from.get(address, 0)
    if client._checks_lost == 1:
        client._late_seen = late
        return (f"a reply from address {address} was lost ({why}); the next command checks "
                "the line again")
    if late > client._late_seen:
        # (answers came, after tmclsh had given them up: the module is there, and slow)
        return (f"address {address} answers too late: its replies came after tmclsh had "
                f"stopped waiting for them ({why}); give it more time: {more_time(client)}")
    return f"address {address} stopped answering: {why}"
