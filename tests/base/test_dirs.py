"""The user's directories are where platformdirs puts them, though it is not imported for
the common case (Linux's XDG places): a config file, the history and the data cache do not
move because start-up got faster."""

from __future__ import annotations

import platformdirs
import pytest

from tmclsh.base.dirs import user_dir

KINDS = ("config", "state", "cache")
VARIABLES = ("XDG_CONFIG_HOME", "XDG_STATE_HOME", "XDG_CACHE_HOME")


@pytest.mark.parametrize("env", [
    {},
    {"XDG_CONFIG_HOME": "/x/config", "XDG_STATE_HOME": "/x/state", "XDG_CACHE_HOME": "/x/cache"},
    {"HOME": "/home/someone"},
    {"HOME": "/home/someone", "XDG_CONFIG_HOME": "relative/config", "XDG_CACHE_HOME": " "},
    {"HOME": "relative-home"},
])
@pytest.mark.parametrize("kind", KINDS)
def test_the_same_place_as_platformdirs(monkeypatch, env, kind):
    for var in VARIABLES:
        monkeypatch.delenv(var, raising=False)
    for var, value in env.items():
        monkeypatch.setenv(var, value)
    try:
        expected = getattr(platformdirs, f"user_{kind}_dir")("tmclsh", appauthor=False)
    except RuntimeError:  # (a relative HOME: platformdirs may refuse it, and so may we)
        with pytest.raises(RuntimeError):
            user_dir(kind)
        return
    assert str(user_dir(kind)) == expected
