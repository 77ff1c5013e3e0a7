"""The package's TOML data files (instruction set, module tables), parsed once per machine.

Parsing the TOML is most of what loading costs (7 ms for one module's table, against 0.3 ms to
read the same data back with ``marshal``), and ``-c`` pays it on every start. So the parsed data
is kept in the user's cache directory under the file's content hash (with the Python version):
an edited data file has another hash and is parsed again; a cache that cannot be read or
written is skipped, never an error.
"""

from __future__ import annotations

import marshal
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from importlib.resources.abc import Traversable

try:  # the module hashlib takes it from, without loading OpenSSL (2 ms at start-up)
    from _blake2 import blake2b
except ImportError:  # pragma: no cover - not CPython
    from hashlib import blake2b

_FORMAT = f"{sys.implementation.cache_tag}-m{marshal.version}"


def package_files(package: str) -> Traversable:
    """``importlib.resources.files(package)``, but the package's folder itself when it is one
    on disk (as installed or checked out): importing ``importlib.resources`` (with
    ``zipfile``) costs 2 ms of every start-up, and a ``Path`` reads the same files."""
    module = sys.modules.get(package)
    if module is None:
        import importlib

        module = importlib.import_module(package)
    where = getattr(module, "__file__", None)
    if where:
        folder = Path(where).parent
        if folder.is_dir():
            return folder
    from importlib import resources  # a package inside a zip file

    return resources.files(package)


def cache_dir() -> Path:
    from .dirs import user_dir

    return user_dir("cache") / "data"


def load_toml(package: str, name: str, check: Callable[[str], None] | None = None) -> dict:
    """The parsed TOML file ``name`` of ``package`` (a dict of plain values).

    ``check(text)`` runs when the file is parsed, before it is cached: a file that fails it
    raises, and one that passed is not checked again while its content is the same."""
    def parse(text: str) -> dict:
        import tomllib  # only when the cache misses

        if check is not None:
            check(text)
        return tomllib.loads(text)

    raw = package_files(package).joinpath(name).read_bytes()
    return parsed(raw, Path(name).stem, parse)


def parsed(raw: bytes, stem: str, parse: Callable[[str], dict], salt: bytes = b"") -> dict:
    """``parse(text)`` of the UTF-8 bytes ``raw``, kept under their content hash (and
    ``salt``: whatever else the result depends on, such as the rules that check it), so the
    same bytes are parsed once per machine. ``parse`` raises for a file it refuses; nothing is
    kept then."""
    key = raw + b"\0" + salt if salt else raw
    digest = blake2b(key, digest_size=16, person=b"tmclsh-data").hexdigest()
    path = cache_dir() / f"{stem}-{digest}-{_FORMAT}.marshal"
    try:
        data = marshal.loads(path.read_bytes())
        if isinstance(data, dict):
            return data
    except (OSError, ValueError, EOFError, TypeError):
        pass
    data = parse(raw.decode("utf-8"))
    _store(path, data)
    return data


def _store(path: Path, data: dict) -> None:
    try:
        blob = marshal.dumps(data)
    except ValueError:  # a value marshal cannot hold (a TOML date): parse each time
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
        tmp.write_bytes(blob)
        os.replace(tmp, path)  # another process may write the same file: both are whole
    except OSError:
        pass
