"""A message's advice names a setting the way its reader gives it: the command line's option
to someone at a terminal's command line, the shell's own command to someone at tmclsh's
prompt or writing a script in its language (``.address 5``, where ``-a 5`` cannot be typed),
``tmclsh.connect``'s keyword to a program (a test jig in Python told "try --baud 115200" has
no option to give). One table; the messages ask it (``setting``) and never spell an option
themselves. ``tmclsh`` commands to run (``'tmclsh
scan --port P'``) stay as they are: a program's author runs them in a terminal too.
"""

from __future__ import annotations

# setting -> (the command line's option, connect()'s keyword)
_SETTINGS: dict[str, tuple[str, str]] = {
    "baud": ("--baud", "baud"),
    "timeout": ("--timeout", "timeout"),
    "address": ("-a", "address"),
    "host_address": ("--host-address", "host_address"),
    "ascii": ("--ascii", "ascii"),  # (an option without a value: ascii=True)
    "can_id": ("--can-id", "can_id"),
    "reply_id": ("--reply-id", "reply_id"),
}

# setting -> the shell command that sets it for the module in use (on CAN ``.address`` sets
# the CAN id); a setting without one is named by its option at the prompt too
_COMMANDS: dict[str, str] = {
    "address": ".address",
    "can_id": ".address",
    "ascii": ".mode ascii",  # (a command without a value)
}

OPTIONS = "options"  # the advice of a client the command line opened
SHELL = "shell"  # of one the prompt or a script talks through (shell/lang/main.py)
KEYWORDS = "keywords"  # of one a program opened (the default)


def setting(client: object, name: str, value: object = None, *, later: bool = False) -> str:
    """``name`` set to ``value`` (or the setting's bare name), in the words of ``client``'s
    user (``Client.advice``): ``--baud 115200``, ``.address 5`` or ``baud=115200``.
    ``later``: advice for the next run (``--baud 115200 next time``), which the shell's
    user gives on the command line as well."""
    option, keyword = _SETTINGS[name]
    advice = getattr(client, "advice", KEYWORDS)
    if advice == SHELL and not later and name in _COMMANDS:
        command = _COMMANDS[name]
        return command if value is None or value is True else f"{command} {value}"
    if advice in (OPTIONS, SHELL):
        return option if value is None or value is True else f"{option} {value}"
    return keyword if value is None else f"{keyword}={value}"


def more_time(client: object) -> str:
    """A longer timeout to try: twice the client's, at least 2 s."""
    return setting(client, "timeout", f"{max(2 * client.timeout, 2):g}")  # type: ignore[attr-defined]
