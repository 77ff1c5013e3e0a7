"""PyTrinamic's own example programs, as test input (they ship in its source release only).

The wheel a ``pip install`` brings has no ``examples/``; the source release of the same version
has them. They are found, in this order, in ``$TMCLSH_PYTRINAMIC_EXAMPLES`` (a PyTrinamic
checkout's ``examples/``), in pytest's cache (``.pytest_cache/d/pytrinamic/``), or fetched once
into that cache with ``pip download`` of the installed version's source release. When none of
these works (no network, no pip) the tests that need them skip, saying why.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

import pytest


def cache_folder(request: pytest.FixtureRequest) -> Path:
    """pytest's cache folder for the examples (kept between runs), or a temporary one when
    the cache is off (``-p no:cacheprovider``): then they are fetched again."""
    cache = getattr(request.config, "cache", None)
    if cache is not None:
        return cache.mkdir("pytrinamic")
    return request.getfixturevalue("tmp_path_factory").mktemp("pytrinamic")


def examples_dir(cache: Path) -> Path:
    """The ``examples/`` folder of the installed PyTrinamic's version (or skip the test);
    ``cache``: a folder that outlives the run (``config.cache.mkdir``)."""
    given = os.environ.get("TMCLSH_PYTRINAMIC_EXAMPLES")
    if given:
        path = Path(given)
        if not (path / "modules").is_dir():
            pytest.skip(f"TMCLSH_PYTRINAMIC_EXAMPLES={given} has no modules/ folder")
        return path
    from importlib.metadata import version

    ver = version("pytrinamic")
    target = cache / f"pytrinamic-{ver}" / "examples"
    if (target / "modules").is_dir():
        return target
    try:
        _fetch(ver, target)
    except (OSError, subprocess.SubprocessError, tarfile.TarError, ValueError) as exc:
        pytest.skip(f"PyTrinamic {ver}'s example programs are not at hand and could not be "
                    f"fetched ({exc}); set TMCLSH_PYTRINAMIC_EXAMPLES to its examples/ folder")
    return target


def _fetch(ver: str, target: Path) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps",
                        "--no-binary", ":all:", f"pytrinamic=={ver}", "-d", tmp],
                       check=True, timeout=180, capture_output=True)
        archives = list(Path(tmp).glob("*.tar.gz"))
        if not archives:
            raise ValueError("pip brought no source archive")
        staging = Path(tmp) / "x"
        with tarfile.open(archives[0]) as tar:
            members = [m for m in tar.getmembers() if "/examples/" in m.name and m.isfile()
                       and ".." not in Path(m.name).parts and not m.name.startswith("/")]
            tar.extractall(staging, members=members)
        found = next(staging.glob("*/examples"))
        target.parent.mkdir(parents=True, exist_ok=True)
        partial = target.parent / f"{target.parent.name}.{os.getpid()}.part"
        shutil.copytree(found, partial)
        try:
            partial.rename(target)
        except OSError:  # another run got there first
            shutil.rmtree(partial, ignore_errors=True)
