"""Key bindings of the prompt, pgcli style: ``tmcl_bindings(session)`` returns KeyBindings.

Ctrl-C is the safety key. At the prompt it stops everything and clears the line: the stored
program if it runs (128; a running program would start the motors again), MST to every motor
(whether it moves or not: MST on a motor at rest does nothing), then each motor's actual
speed read back. It says "stopped" only for motors that read 0, and names any that did not. While a command runs, Ctrl-C interrupts it and the REPL
does the same stop (see ``app.py``); both are the one stop, ``stop.py``. Ctrl-D on an empty line leaves.

Tab completes the way pgcli does it: the first Tab inserts the best match and opens the menu
with the others, further Tabs cycle through them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from prompt_toolkit.application import run_in_terminal
from prompt_toolkit.filters import completion_is_selected, has_completions
from prompt_toolkit.key_binding import KeyBindings

if TYPE_CHECKING:
    from ..lang.session import Session


def tmcl_bindings(session: Session) -> KeyBindings:
    kb = KeyBindings()

    @kb.add("c-c")
    def _stop(event) -> None:
        """Stop every motor (at each address ``.address`` left one told to move too),
        clear the line."""
        from ..features.stop import stop_everywhere

        event.current_buffer.reset()
        run_in_terminal(lambda: stop_everywhere(session.client, session.out, "Ctrl-C",
                                                session=session))

    @kb.add("tab", filter=~has_completions)
    def _complete(event) -> None:
        """First Tab: insert the best completion and show the others."""
        buf = event.current_buffer
        if buf.complete_state:
            buf.complete_next()
        else:
            buf.start_completion(select_first=True)

    @kb.add("tab", filter=has_completions)
    def _next(event) -> None:
        buf = event.current_buffer
        state = buf.complete_state
        if state is not None and len(state.completions) == 1 and state.complete_index == 0:
            # the only match is in: another Tab (a bash habit) keeps it, where cycling on
            # would put back the text as typed
            buf.complete_state = None
            return
        buf.complete_next()

    @kb.add("escape", filter=has_completions, eager=True)
    def _cancel(event) -> None:
        event.current_buffer.cancel_completion()

    @kb.add("enter", filter=completion_is_selected)
    def _accept_completion(event) -> None:
        """Enter on a selected completion takes it (the line is not run yet)."""
        buf = event.current_buffer
        buf.complete_state = None

    return kb
