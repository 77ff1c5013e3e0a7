"""A message's advice names a setting the way its reader gives it: the command line's option
to someone at the shell or the command line, ``tmclsh.connect``'s keyword to a program (a
test jig in Python told "try --baud 115200" has no option to give). One table; the messages
ask it (``setting``) and never spell an option themselves. ``tmclsh`` commands to run (``'tmclsh
scan --port P'``) stay as they are: a program's author runs them in a terminal too.
"""

from __future__ import annotations

# setting -> (the command line's option, connect()'s keyword)
_SETTINGS: dict[str, tuple[str, str]] = {
    "baud": ("--baud", "baud"),
    "timeout": ("--timeout", "timeout"),
    "address": ("-a", "address"),
    "ascii": ("--ascii", "ascii"),  # (an option without a value: ascii=True)
    "can_id": ("--can-id", "can_id"),
    "reply_id": ("--reply-id", "reply_id"),
}

OPTIONS = "options"  # the advice of a client the command line or the shell opened
KEYWORDS = "keywords"  # of one a program opened (the default)


def setting(client: object, name: str, value: object = None) -> str:
    """``name`` set to ``value`` (or the setting's bare name), in the words of ``client``'s
    user (``Client.advice``): ``--baud 115200`` or ``baud=115200``."""
    option, keyword = _SETTINGS[name]
    if getattr(client, "advice", KEYWORDS) == OPTIONS:
        return option if value is None or value is True else f"{option} {value}"
    return keyword if value is None else f"{keyword}={value}"


def more_time(client: object) -> str:
    """A longer timeout to try: twice the client's, at least 2 s."""
    return setting(client, "timeout", f"{max(2 * client.timeout, 2):g}")  # type: ignore[attr-defined]
