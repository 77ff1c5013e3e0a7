"""Source maps of uploaded programs, kept in the user's cache directory.

The module's memory holds instructions only: labels and comments are gone once a program is
uploaded. So each upload from a file leaves its source text here, keyed by a hash of the
image's bytes; when a program read back from a module (``.dump``) has the same bytes at the
same address, its original source can be shown instead of generated labels. The cache is a
convenience: a missing, unreadable or full cache directory never stops an upload or a dump.

The directory is platformdirs' ``user_cache_dir("tmclsh")`` (``$XDG_CACHE_HOME/tmclsh`` on
Linux), in ``programs/``, one JSON file per image.

An upload from an image file (``.bin``, ``.hex``) is kept too, without text (``image``): the
last upload of an image names the file it came from, never an older source of the same bytes.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from .frames import Instruction

log = logging.getLogger(__name__)

KEEP = 200  # source maps kept; the oldest go first
_VERSION = 1


def cache_dir() -> Path:
    from platformdirs import user_cache_dir

    return Path(user_cache_dir("tmclsh")) / "programs"


def image_key(instructions: Sequence[Instruction]) -> str:
    """The hash of the image's bytes (7 per instruction, as sent and as read back)."""
    h = hashlib.sha256()
    for ins in instructions:
        h.update(ins.to_bytes())
    return h.hexdigest()


@dataclass(frozen=True)
class SourceMap:
    """One upload: which source text made the image at ``origin`` on which module type."""

    key: str
    module: str
    origin: int
    count: int
    file: str
    text: str
    uploaded: str  # local time, ``2026-12-01 19:50``
    image: bool = False  # uploaded from an image file: no source text, no labels


def save(instructions: Sequence[Instruction], module: str, origin: int, file: str | Path,
         text: str, *, image: bool = False) -> Path | None:
    """Keep the source of an upload (``image``: the file was an image, ``text`` empty); the
    file written, or None if the cache cannot be written (logged, not raised)."""
    key = image_key(instructions)
    entry = SourceMap(key, module, origin, len(instructions), str(Path(file).resolve()),
                      "" if image else text, time.strftime("%Y-%m-%d %H:%M"), image)
    folder = cache_dir()
    path = folder / f"{key}.json"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"version": _VERSION, **asdict(entry)}), encoding="utf-8")
        tmp.replace(path)
        _prune(folder)
    except OSError as exc:
        log.warning("source map not kept in %s: %s", folder, exc)
        return None
    return path


def lookup(instructions: Sequence[Instruction], module: str, origin: int) -> SourceMap | None:
    """The upload that made exactly this image at ``origin`` on this module type, if kept."""
    if not instructions:
        return None
    key = image_key(instructions)
    try:
        data = json.loads((cache_dir() / f"{key}.json").read_text(encoding="utf-8"))
        entry = SourceMap(**{k: data[k] for k in SourceMap.__dataclass_fields__
                             if k in data or k != "image"})
    except (OSError, ValueError, KeyError, TypeError):
        return None  # not kept, or a damaged file: generated labels, as without a cache
    if (data.get("version") != _VERSION or entry.key != key or entry.module != module
            or entry.origin != origin or entry.count != len(instructions)):
        return None
    return entry


def _prune(folder: Path) -> None:
    files = sorted(folder.glob("*.json"), key=lambda p: p.stat().st_mtime, reverse=True)
    for old in files[KEEP:]:
        old.unlink(missing_ok=True)
