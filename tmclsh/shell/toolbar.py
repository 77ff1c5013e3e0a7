"""The bottom toolbar, pgcli style: a factory that takes the session and returns the callable
prompt_toolkit redraws.

It shows the connection (port, CAN bus or SIMULATED), module type and address, mode
(binary/ASCII), trace on/off and, when the debugger has set it, the program state. It never
talks to the device: everything comes from the client's attributes and ``session.state``
(the debugger keeps ``program_state`` there), so a redraw costs nothing on the bus.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .session import Session

Fragments = list[tuple[str, str]]


def _program_state(session: Session) -> str | None:
    state = session.state.get("program_state")
    if state is None:
        return None
    if isinstance(state, dict):  # {"state": "run", "pc": 12}
        text = str(state.get("state", ""))
        if state.get("pc") is not None:
            text += f" @{state['pc']}"
        return text
    return str(getattr(state, "name", state)).lower()


def create_toolbar_tokens_func(session: Session) -> Callable[[], Fragments]:
    """``bottom_toolbar=create_toolbar_tokens_func(session)``."""

    def get_toolbar_tokens() -> Fragments:
        from .trace import trace_enabled

        c = session.client
        out: Fragments = []
        sep = ("class:bottom-toolbar.dim", " | ")
        if not c.connected:
            out.append(("class:bottom-toolbar.off", f" DISCONNECTED {c.describe()} "))
            out.append(("class:bottom-toolbar", " .connect to retry "))
        elif c.transport.simulated:
            out.append(("class:bottom-toolbar.sim", " SIMULATED "))
        else:
            out.append(("class:bottom-toolbar.on", f" {c.describe()} "))
        out.append(sep)
        mod = c.module.label if c.module is not None else "module ?"
        out.append(("class:bottom-toolbar", f"{mod} @{c.address}"))
        out.append(sep)
        ascii_mode = c.mode == "ascii"
        out.append(("class:bottom-toolbar.on" if ascii_mode else "class:bottom-toolbar",
                    "ASCII" if ascii_mode else "binary"))
        out.append(sep)
        on = trace_enabled(session)
        out.append(("class:bottom-toolbar.on" if on else "class:bottom-toolbar.dim",
                    f"trace {'on' if on else 'off'}"))
        state = _program_state(session)
        if state:
            out.append(sep)
            style = ("class:bottom-toolbar.on" if state.startswith(("run", "step"))
                     else "class:bottom-toolbar")
            out.append((style, f"program {state}"))
        # the key hints, as many as fit: a cut-off toolbar (`^D qu`) looks broken
        room = _columns() - sum(len(text) for _, text in out) - len(sep[1])
        for hints in _HINTS:
            if sum(len(k) + len(t) for k, t in hints) <= room:
                if hints:
                    out.append(sep)
                for key, text in hints:
                    out.append(("class:bottom-toolbar.key", key))
                    out.append(("class:bottom-toolbar.dim", text))
                break
        return out

    return get_toolbar_tokens


_HINTS = (
    (("Tab", " complete  "), ("^C", " stop motors  "), ("^D", " quit")),
    (("^C", " stop motors  "), ("^D", " quit")),
    (("^C", " stop"),),
    (),
)


def _columns() -> int:
    from prompt_toolkit.application import get_app_or_none

    app = get_app_or_none()
    try:
        return app.output.get_size().columns if app is not None else 200
    except Exception:  # the terminal's size is a nicety; never let it break the toolbar
        return 200
