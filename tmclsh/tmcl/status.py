"""Reply status codes and their texts.

Kept apart from the frames so that the error tree (which words a ``StatusError``) and the
protocol (which decodes the status byte) can both read them without importing each other.
"""

from __future__ import annotations

from enum import IntEnum


class Status(IntEnum):
    """Reply status codes (manuals, "Status Codes") plus the 138 event status."""

    WRONG_CHECKSUM = 1
    INVALID_COMMAND = 2
    WRONG_TYPE = 3
    INVALID_VALUE = 4
    EEPROM_LOCKED = 5
    COMMAND_NOT_AVAILABLE = 6
    OK = 100
    LOADED = 101
    EVENT = 128


STATUS_TEXT = {
    Status.WRONG_CHECKSUM: "wrong checksum",
    Status.INVALID_COMMAND: "invalid command",
    Status.WRONG_TYPE: "wrong type",
    Status.INVALID_VALUE: "invalid value",
    Status.EEPROM_LOCKED: "configuration EEPROM locked",
    Status.COMMAND_NOT_AVAILABLE: "command not available",
    Status.OK: "ok",
    Status.LOADED: "loaded into program memory",
    Status.EVENT: "target position reached (event)",
}


def status_text(status: int) -> str:
    try:
        return STATUS_TEXT[Status(status)]
    except ValueError:
        return f"unknown status {status}"


OK_STATUSES = frozenset({int(Status.OK), int(Status.LOADED), int(Status.EVENT)})


def status_ok(status: int) -> bool:
    return status in OK_STATUSES
