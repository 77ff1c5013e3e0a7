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
    from ..lang.session import Session

Fragments = list[tuple[str, str]]


def program_state_text(session: Session) -> str | None:
    """The stored program's state as the prompt and toolbar show it (``run``, ``step @12``)."""
    state = session.state.program_state
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
        return toolbar_fragments(session, _columns())

    return get_toolbar_tokens


# An item is its forms from the fullest to the shortest; an empty form drops the item.
Item = list[Fragments]
SEP = ("class:bottom-toolbar.dim", " | ")

_HINTS: Item = [
    [("class:bottom-toolbar.key", "Tab"), ("class:bottom-toolbar.dim", " complete  "),
     ("class:bottom-toolbar.key", "^C"), ("class:bottom-toolbar.dim", " stop motors  "),
     ("class:bottom-toolbar.key", "^D"), ("class:bottom-toolbar.dim", " quit")],
    [("class:bottom-toolbar.key", "^C"), ("class:bottom-toolbar.dim", " stop motors  "),
     ("class:bottom-toolbar.key", "^D"), ("class:bottom-toolbar.dim", " quit")],
    [("class:bottom-toolbar.key", "^C"), ("class:bottom-toolbar.dim", " stop motors")],
    [("class:bottom-toolbar.key", "^C"), ("class:bottom-toolbar.dim", " stop")],
    [],
]

# What goes first when the terminal is narrow (least useful first): each step shortens one
# item to its next form. The connection and the module never go.
_SHRINK = ("hints", "hints", "hints", "trace_off", "mode", "program", "retry", "hints",
           "connection", "trace_on")


def toolbar_fragments(session: Session, columns: int) -> Fragments:
    """The toolbar for a terminal ``columns`` wide: every item that fits, whole words only
    (prompt_toolkit would cut the line at the edge: ``^D qu`` looks broken)."""
    from ..features.trace import trace_enabled

    c = session.client
    items: dict[str, Item] = {}
    if not c.connected:
        where = c.describe()
        items["connection"] = [[("class:bottom-toolbar.off", f" DISCONNECTED {where} ")],
                               [("class:bottom-toolbar.off", " DISCONNECTED ")]]
        items["retry"] = [[("class:bottom-toolbar", " .connect to retry ")], []]
    elif c.transport.simulated:
        items["connection"] = [[("class:bottom-toolbar.sim", " SIMULATED ")]]
    else:
        where = c.describe()
        short = where.split(" @ ")[0]  # `/dev/ttyUSB0 @ 115200`: the port alone
        items["connection"] = [[("class:bottom-toolbar.on", f" {where} ")],
                               [("class:bottom-toolbar.on", f" {short} ")]]
    mod = c.module.label if c.module is not None else "module ?"
    items["module"] = [[("class:bottom-toolbar", f"{mod} @{c.address}")]]
    mode = c.mode  # a marked mode (ASCII) is lit and kept; the usual one goes early
    items["mode"] = ([[("class:bottom-toolbar.on", mode.label)]] if mode.marked
                     else [[("class:bottom-toolbar", mode.label)], []])
    if trace_enabled(session):
        items["trace_on"] = [[("class:bottom-toolbar.on", "trace on")], []]
    else:
        items["trace_off"] = [[("class:bottom-toolbar.dim", "trace off")], []]
    state = program_state_text(session)
    if state:
        style = ("class:bottom-toolbar.on" if state.startswith(("run", "step"))
                 else "class:bottom-toolbar")
        items["program"] = [[(style, f"program {state}")], [(style, state)]]
    items["hints"] = _HINTS
    form = dict.fromkeys(items, 0)

    def build() -> Fragments:
        out: Fragments = []
        for name, forms in items.items():
            if name == "retry":  # it belongs to the connection, without a separator
                out.extend(forms[form[name]])
                continue
            frags = forms[form[name]]
            if frags:
                if out:
                    out.append(SEP)
                out.extend(frags)
        return out

    out = build()
    for name in _SHRINK:
        if _width(out) <= columns:
            return out
        if name in form and form[name] + 1 < len(items[name]):
            form[name] += 1
            out = build()
    return _whole_words(out, columns)


def _width(fragments: Fragments) -> int:
    return sum(len(text) for _, text in fragments)


def _whole_words(fragments: Fragments, columns: int) -> Fragments:
    """The last resort: fragments from the end go, then words, never half a word."""
    out = list(fragments)
    while out and _width(out) > columns:
        style, text = out.pop()
        room = columns - _width(out)
        words = text.rstrip().split(" ")
        while words and len(" ".join(words)) > room:
            words.pop()
        if words and any(words):
            out.append((style, " ".join(words)))
            break
    while out and out[-1] == SEP:
        out.pop()
    return out


def _columns() -> int:
    from prompt_toolkit.application import get_app_or_none

    app = get_app_or_none()
    try:
        return app.output.get_size().columns if app is not None else 200
    except Exception:  # the terminal's size is a nicety; never let it break the toolbar
        return 200
