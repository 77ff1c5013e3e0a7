"""tmclsh: a shell, ASCII terminal, assembler and simulator for Trinamic TMCL modules, and the
same client as a Python library.

```python
import tmclsh

with tmclsh.connect(sim="TMCM-1311") as c:      # or port="/dev/ttyACM0", can="socketcan:can0"
    print(c.module.name, c.version)
    c.execute("SAP MaxPositioningSpeed, 0, 1000")
    print(c.value("GAP ActualPosition, 0"))
```

Every name listed here is the API: the client (`connect`, `LineClient`, what it returns),
the error classes (every one a `TmclError`; a value refused before sending is a
`RangeError`, any other line refused before sending a `ValidationError`), and the
operations a script needs without the shell: a module's configuration (backup, compare,
restore), several modules at once, expressions and watch samples, a line's inventory,
replaying a capture, replacing a module, firmware, scanning a line or bus, stored programs, the safety stop, reading CAN
logs and another master's traffic. Anything not
listed is private to tmclsh and may change between releases.

`import tmclsh` loads none of it: each name is imported the first time it is used, so the
command line starts as fast as before.
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"
"""This release of tmclsh (also ``tmclsh --version``)."""

# name -> (module, attribute in it): imported on first use (``__getattr__`` below)
_LAZY: dict[str, tuple[str, str]] = {
    # the client and what it returns
    "connect": ("tmclsh.client.connect", "connect"),
    "LineClient": ("tmclsh.client.text", "LineClient"),
    "Result": ("tmclsh.client.text", "Result"),
    "Reply": ("tmclsh.tmcl.frames", "Reply"),
    "Status": ("tmclsh.tmcl.frames", "Status"),
    # the error tree
    **{name: ("tmclsh.base.errors", name) for name in (
        "TmclError", "TransportError", "TmclTimeoutError", "ChecksumError", "FrameError",
        "ValidationError", "UsageError", "RangeError", "StatusError", "DownloadModeError",
        "ConnectError", "InBootloaderError", "NoAnswerError", "AsmError", "AsmRangeError")},
    "SettingError": ("tmclsh.base.limits", "SettingError"),
    # firmware: read and check an image, update a module over its bootloader
    "read_firmware": ("tmclsh.tmcl.bootloader", "read_image"),
    "FirmwareUpdate": ("tmclsh.ops.firmware", "FirmwareUpdate"),
    "FirmwareError": ("tmclsh.ops.firmware", "FirmwareError"),
    "ImageRefused": ("tmclsh.ops.firmware", "ImageRefused"),
    "ImageError": ("tmclsh.tmcl.bootloader", "ImageError"),
    # scanning a serial line or a CAN bus
    "scan_modules": ("tmclsh.ops.scan", "scan"),
    "Found": ("tmclsh.ops.scan", "Found"),
    # stored programs: assemble, upload and verify, read back, run, stop, status
    "load_program": ("tmclsh.tmcl.asm", "load_program"),
    "upload_program": ("tmclsh.ops.program", "upload"),
    "read_program": ("tmclsh.ops.program", "read_program"),
    "verify_program": ("tmclsh.ops.program", "verify_image"),
    "run_program": ("tmclsh.ops.program", "run"),
    "stop_program": ("tmclsh.ops.program", "stop"),
    "program_status": ("tmclsh.ops.program", "status"),
    "UploadError": ("tmclsh.ops.program", "UploadError"),
    # the safety stop: program and every motor stopped, read back
    "stop_everything": ("tmclsh.ops.stop", "stop_everything"),
    "StopReport": ("tmclsh.ops.stop", "StopReport"),
    # logs and traffic another master sends
    "read_can_log": ("tmclsh.link.canlog", "read_log"),
    "LogWriter": ("tmclsh.link.canlog", "LogWriter"),
    "Monitor": ("tmclsh.ops.monitor", "Monitor"),
    "CanReader": ("tmclsh.ops.monitor", "CanReader"),
    "SerialTap": ("tmclsh.ops.monitor", "SerialTap"),
    "Filter": ("tmclsh.ops.filter", "Filter"),
    # a module's configuration: read it, its backup file, compare, restore (link identity
    # left alone unless asked), without a shell
    "read_configuration": ("tmclsh.ops.backup", "read_configuration"),
    "write_backup": ("tmclsh.ops.backup", "write_backup"),
    "read_backup": ("tmclsh.ops.backup", "read_backup"),
    "compare_backup": ("tmclsh.ops.backup", "compare"),
    "restore_backup": ("tmclsh.ops.backup", "restore"),
    "store_backup": ("tmclsh.ops.backup", "store"),
    "Configuration": ("tmclsh.ops.backup", "Configuration"),
    "Backup": ("tmclsh.ops.backup", "Backup"),
    "BackupFileError": ("tmclsh.ops.backup", "BackupFileError"),
    # reading until the answers are certain (what .watch, .expect and a verify rely on)
    "read_until_certain": ("tmclsh.ops.certain", "read_until_certain"),
    # several modules at once: a function run on each unit, the stop reaching every one
    "run_units": ("tmclsh.ops.units", "run"),
    "Unit": ("tmclsh.ops.units", "Unit"),
    # expressions and watch samples on a client
    "evaluate": ("tmclsh.ops.expr", "evaluate"),
    "watch_items": ("tmclsh.ops.watch", "parse_items"),
    "watch_sample": ("tmclsh.ops.watch", "poll"),
    # what should answer on a line, and how the line differs
    "read_inventory": ("tmclsh.ops.inventory", "read_inventory"),
    "compare_inventory": ("tmclsh.ops.inventory", "compare"),
    # a captured session sent again, the replies compared
    "read_capture": ("tmclsh.ops.replay", "read_capture"),
    "replay": ("tmclsh.ops.replay", "replay"),
    # a module replaced in the field
    "Replacement": ("tmclsh.ops.replace", "Replacement"),
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    """Import an API name the first time it is used, so ``import tmclsh`` stays cheap."""
    where = _LAZY.get(name)
    if where is None:
        raise AttributeError(f"module 'tmclsh' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(where[0]), where[1])
    globals()[name] = value  # once: the next use is a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
