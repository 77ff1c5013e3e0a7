"""The two ways tmclsh talks to a module, binary TMCL frames and the module's ASCII command
line, as facts: what differs between them for those who only show or use the link (the
prompt, the toolbar, the banner, the completer, a check that reads twice).

Each framing carries its mode (``SerialFraming.mode``, ``CanFraming.mode``,
``AsciiFraming.mode``) and ``Client.mode`` is the one in use, so nothing outside the client
and the link asks which mode it is in: it reads the fact it needs. A mode is a ``str``
("binary", "ascii"), so ``client.mode == "ascii"``, ``str(client.mode)`` and JSON keep
working in users' scripts. Which commands a mode carries is the instruction set's
(``commands`` names the key of ``instructions.toml``); whether one request can go on the
link as it is now is the framing's ``refusal``, asked through ``Client.refusal``.
"""

from __future__ import annotations

from typing import Any


class LinkMode(str):
    """One mode and its facts; compares, hashes and prints as its name. There are two,
    ``BINARY`` and ``ASCII``, and a copy of one is the same object."""

    label: str  # the word the toolbar shows
    marked: bool  # not the usual mode: the prompt and the banner name it, the toolbar lights it
    commands: str | None  # the instruction set's key for the commands it carries (None: all)
    checksummed: bool  # every reply carries a checksum (a changed digit is caught)

    def __new__(cls, name: str, *, label: str, marked: bool, commands: str | None,
                checksummed: bool) -> LinkMode:
        self = super().__new__(cls, name)
        vars(self).update(label=label, marked=marked, commands=commands,
                          checksummed=checksummed)
        return self

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"a link mode's facts are fixed ({name})")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"a link mode's facts are fixed ({name})")

    def __reduce__(self) -> tuple:
        return named, (str(self),)

    def __repr__(self) -> str:
        return f"LinkMode({str(self)!r})"

    def offers(self, spec: Any) -> bool:
        """Does the command (an instruction set entry) exist in this mode? The instruction
        set says, under the key ``commands`` names; every command exists where it names none."""
        return self.commands is None or bool(getattr(spec, self.commands, False))


BINARY = LinkMode("binary", label="binary", marked=False, commands=None, checksummed=True)
# the manuals' ASCII interface (TMCM-1311 §4.4): the commands marked ``ascii`` in the
# instruction set, replies as text without a checksum
ASCII = LinkMode("ascii", label="ASCII", marked=True, commands="ascii", checksummed=False)

MODES = {str(m): m for m in (BINARY, ASCII)}


def named(name: str) -> LinkMode:
    """The mode called ``name`` ("binary" or "ascii")."""
    try:
        return MODES[name]
    except KeyError:
        raise ValueError(f"no link mode {name!r}: binary or ascii") from None
