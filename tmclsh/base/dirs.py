"""Where tmclsh keeps the user's files: config, state (the history), cache.

platformdirs knows every platform's places, but importing it costs about 3 ms of every
start (``-c`` included), and on Linux its answer is the XDG variable or its default under
``$HOME``. So that common case is read here, and every other (another platform, a relative
``$HOME`` or XDG path, which platformdirs' versions read differently) is platformdirs' to
answer, as before.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

APP = "tmclsh"
# kind -> (the XDG variable, the default under $HOME), as platformdirs reads them on Linux
_XDG = {"config": ("XDG_CONFIG_HOME", ".config"), "state": ("XDG_STATE_HOME", ".local/state"),
        "cache": ("XDG_CACHE_HOME", ".cache")}


def user_dir(kind: str) -> Path:
    """The user's ``kind`` ("config", "state" or "cache") directory for tmclsh: the path
    platformdirs gives (``user_config_dir("tmclsh", appauthor=False)`` and so on)."""
    variable, default = _XDG[kind]
    if sys.platform == "linux" and "ANDROID_DATA" not in os.environ:
        xdg = os.environ.get(variable, "")
        if os.path.isabs(xdg):
            return Path(xdg, APP)
        home = os.environ.get("HOME", "")
        if not xdg and os.path.isabs(home):
            return Path(home, default, APP)
    import platformdirs

    return Path(getattr(platformdirs, f"user_{kind}_dir")(APP, appauthor=False))
