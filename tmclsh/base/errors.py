"""The one exception tree of tmclsh.

Every layer raises these, so the shell can turn any failure into a one-line message and a
script can stop with FILE:LINE. They also inherit from the builtins a Python caller expects
(``TmclTimeoutError`` is a ``TimeoutError``, ``ValidationError`` a ``ValueError``).
"""

from __future__ import annotations


# The exit statuses of every tmclsh command (the man page's EXIT STATUS says the same).
EXIT_OK = 0  # everything passed
EXIT_FAILED = 1  # a line or check failed, or an answer was in doubt
EXIT_USAGE = 2  # refused before anything was sent: the command line, a line the module refuses
EXIT_CONNECT = 3  # no module to talk to
EXIT_INTERRUPTED = 130  # Ctrl-C (128 + SIGINT)


class TmclError(Exception):
    """Base of every tmclsh error."""


class TransportError(TmclError, OSError):
    """The byte link failed: port vanished, bus down, write refused."""


class TmclTimeoutError(TmclError, TimeoutError):
    """No (complete) reply arrived before the deadline."""


class ChecksumError(TmclError):
    """A reply arrived whose checksum does not match its bytes."""


class FrameError(TmclError, ValueError):
    """Bytes that cannot be a frame of the expected kind."""


class ValidationError(TmclError, ValueError):
    """Input refused before anything was sent: unknown name, value out of range, ..."""


class UsageError(ValidationError):
    """The command line itself is wrong (a malformed --can, an unknown profile): exit 2."""


class RangeError(ValidationError):
    """A value outside what the module accepts: a parameter's range, a port's, a coordinate."""


class StatusError(TmclError):
    """The module answered with an error status (1-6)."""

    def __init__(self, status: int, reply: object = None, message: str | None = None):
        self.status = status
        self.reply = reply
        # the reply says what its status means (the protocol layer knows the texts)
        text = getattr(reply, "status_text", None) or f"status {status}"
        super().__init__(message or f"module answered status {status}: {text}")


class DownloadModeError(StatusError):
    """Status 101 outside an upload: the module stored the command instead of executing it."""


class ConnectError(TmclError):
    """No module to talk to: none found, several found, or the one named did not answer
    (exit status 3)."""


class InBootloaderError(ConnectError):
    """The module answers from its bootloader (136 says ``1311B100``): a firmware update did
    not complete, and it runs no firmware while it is there (``tmclsh firmware``)."""

    def __init__(self, message: str, version: str = ""):
        self.version = version
        super().__init__(message)


class NoAnswerError(ConnectError, TmclTimeoutError):
    """Nothing answered at connect (or only garbled replies came): the message says what was
    tried and what to try next."""


class ModuleGoneError(ConnectError):
    """With ``--keep-going``, line after line got no answer (the link stayed lost, or the
    module stayed silent): the module is taken to be gone and the rest is not sent, as when
    there was none at the start (exit status 3)."""


class AsmError(ValidationError):
    """An error in TMCL source text, with its location (1-based line and column).

    A line refused before anything was sent, so a ``ValidationError`` as the API documents;
    a value out of range is an ``AsmRangeError``, also a ``RangeError``."""

    def __init__(self, message: str, line: int | None = None, col: int | None = None,
                 file: str | None = None, kind: str = "syntax"):
        # "syntax": the text is not TMCL; "range": a value the module does not accept;
        # "check": well-formed, but refused for this module (read-only, no such motor, ...)
        self.kind = kind
        self.message = message
        self.line = line
        self.col = col
        self.file = file
        super().__init__(self.located())

    def located(self) -> str:
        where = []
        if self.file:
            where.append(self.file)
        if self.line is not None:
            where.append(str(self.line))
            if self.col is not None:
                where.append(str(self.col))
        return f"{':'.join(where)}: {self.message}" if where else self.message


class AsmRangeError(AsmError, RangeError):
    """A value in TMCL source text outside what the module accepts (``SAP 140, 0, 12``).

    Both classes, so ``except RangeError`` (what the API documents for a refused value) and
    ``except AsmError`` (what scripts written before it caught) see it."""


def exit_status(exc: BaseException) -> int:
    """The exit status a run ends with when ``exc`` ends it, for every entry point alike:
    Ctrl-C 130, a refused command line 2 (and an error that says it was refused before
    anything was sent, ``exit_status``), no module 3, anything else 1."""
    if isinstance(exc, KeyboardInterrupt):
        return EXIT_INTERRUPTED
    if isinstance(exc, UsageError):
        return EXIT_USAGE
    if isinstance(exc, ConnectError):
        return EXIT_CONNECT
    own = getattr(exc, "exit_status", None)
    return own if isinstance(own, int) else EXIT_FAILED
