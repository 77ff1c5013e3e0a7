"""The one way tmclsh asks a yes/no question: ``QUESTION [y/N] `` answered with a line.

Every confirmation (EEPROM writes, factory reset, program download, leaving the ASCII
terminal) asks through here, so the keys are the same everywhere: ``y`` or ``yes`` and Enter
agrees, Enter alone takes the default (the capital letter), anything else is no. The answer
ends with Enter, so no keystroke is left over to show up as an empty prompt afterwards.
"""

from __future__ import annotations

YES = ("y", "yes")


def hint(default: bool = False) -> str:
    return "[Y/n]" if default else "[y/N]"


def answer_means_yes(answer: str, default: bool = False) -> bool:
    text = answer.strip().lower()
    return default if not text else text in YES


def ask_yes_no(question: str, default: bool = False) -> bool:
    """Ask on the terminal; Ctrl-C and Ctrl-D take the default (no, unless said otherwise)."""
    from prompt_toolkit import prompt

    try:
        answer = prompt(f"{question} {hint(default)} ")
    except (EOFError, KeyboardInterrupt):
        return default
    return answer_means_yes(answer, default)
