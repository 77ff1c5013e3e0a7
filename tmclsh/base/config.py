"""Where settings come from.

Connection settings (port, baud, address, ...) are resolved from the command line, then the
environment (``TMCLSH_PORT``, ...), then the selected profile of the config file, then the
built-in defaults: the first value found wins (python-can's ``load_config`` order).

Shell settings (colour, editing mode, history size, confirmations) come from the ``[settings]``
table of the config file merged over the packaged, commented ``default.toml``, which is also
the single list of setting names, their types and their defaults.

The config file is ``$TMCLSH_CONFIG`` if set, else ``config.toml`` in the platform's config
directory (platformdirs): ``$XDG_CONFIG_HOME/tmclsh/config.toml`` (``~/.config/tmclsh/``) on
Linux. Unknown keys, unknown profiles and values of the wrong
type are errors that name the file, the key and what is allowed.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

from . import limits
from .dirs import user_dir
from .canspec import LINK_DEFAULTS
from .errors import UsageError, ValidationError
from .limits import SettingError

# environment variable -> connection setting
ENVIRONMENT = {
    "TMCLSH_PORT": "port",
    "TMCLSH_BAUD": "baud",
    "TMCLSH_CAN": "can",
    "TMCLSH_CAN_ID": "can_id",
    "TMCLSH_REPLY_ID": "reply_id",
    "TMCLSH_MODULE": "module",
    "TMCLSH_ADDRESS": "address",
    "TMCLSH_ASCII": "ascii",
    "TMCLSH_TIMEOUT": "timeout",
    "TMCLSH_RETRIES": "retries",
    "TMCLSH_HOST_ADDRESS": "host_address",
    "TMCLSH_PROFILE": "profile",
}
# variables that are not connection settings, for the man page
OTHER_ENVIRONMENT = {
    "TMCLSH_CONFIG": "the config file to read instead of $XDG_CONFIG_HOME/tmclsh/config.toml",
    "XDG_CONFIG_HOME": "base of the config file's directory (default ~/.config)",
    "XDG_STATE_HOME": "base of the history's directory (default ~/.local/state)",
    "NO_COLOR": "when set (to anything), no colours unless the color setting is \"always\"",
}

# connection setting -> type (what a profile or variable may hold)
CONNECTION_TYPES: dict[str, type] = {
    "port": str, "baud": int, "can": str, "bitrate": int, "can_id": int, "reply_id": int, "sim": str,
    "module": str, "address": int, "host_address": int, "ascii": bool, "timeout": float,
    "retries": int,
}
CONNECTION_KEYS = tuple(CONNECTION_TYPES)
# the connection kinds: one source names at most one, and the strongest source decides
KINDS = ("port", "can", "sim")
# used when no option, variable or profile sets them (port/can/sim: see connection.open_transport;
# the link's own: canspec.LINK_DEFAULTS, the one table every way of opening a link reads)
LINK_KEYS = ("baud", "address", "host_address")
CONNECTION_DEFAULTS: dict[str, object] = {
    **{k: LINK_DEFAULTS[k] for k in LINK_KEYS}, "ascii": False, "timeout": 1.0, "retries": 2,
}
# allowed values of string settings
SETTING_CHOICES: dict[str, tuple[str, ...]] = {
    "color": ("auto", "always", "never"),
    "editing_mode": ("emacs", "vi"),
}
_TRUE = ("1", "true", "yes", "on")
_FALSE = ("0", "false", "no", "off", "")


def config_dir() -> Path:
    """The platform's config directory: $XDG_CONFIG_HOME/tmclsh (~/.config/tmclsh) on Linux,
    ~/Library/Application Support/tmclsh on macOS, %LOCALAPPDATA%\\tmclsh on Windows."""
    return user_dir("config")


def state_dir() -> Path:
    """Where the history is kept: $XDG_STATE_HOME/tmclsh (~/.local/state/tmclsh) on Linux,
    the platform's own place elsewhere."""
    return user_dir("state")


def config_file() -> Path:
    return Path(os.environ.get("TMCLSH_CONFIG") or config_dir() / "config.toml")


def history_file() -> Path:
    return state_dir() / "history"


# -- the packaged default -----------------------------------------------------------------

def default_config_text() -> str:
    """The commented default configuration (``tmclsh/default.toml``)."""
    from .datafiles import package_files

    return package_files(__package__).joinpath("default.toml").read_text("utf-8")


@cache
def _default_settings() -> dict:
    from .datafiles import load_toml

    return dict(load_toml(__package__, "default.toml")["settings"])


def default_settings() -> dict:
    """Every shell setting with its default value, from ``default.toml``."""
    return dict(_default_settings())


SETTING_KEYS = tuple(_default_settings())


# -- reading the file ---------------------------------------------------------------------

@dataclass
class Config:
    path: Path
    settings: dict = field(default_factory=dict)
    profiles: dict[str, dict] = field(default_factory=dict)


def _type_name(t: type) -> str:
    return {str: "a string", int: "an integer", float: "a number", bool: "true or false"}[t]


def _check_value(where: str, key: str, value: object, want: type) -> object:
    """Check a TOML value's type (an int is a valid float); return it converted."""
    ok = isinstance(value, want) and not (want is int and isinstance(value, bool))
    if want is float and isinstance(value, int) and not isinstance(value, bool):
        value, ok = float(value), True
    if not ok:
        raise SettingError(f"{where}: {key} must be {_type_name(want)}, got {value!r}")
    return _check_range(where, key, value)


def _check_range(where: str, key: str, value: object) -> object:
    """Numbers against the one table of limits (``limits.LIMITS``), strings against their
    choices; the same check the command line and the variables make."""
    if key in limits.LIMITS:
        return limits.check(key, value, f"{where} {key}")
    choices = SETTING_CHOICES.get(key)
    if choices is not None and value not in choices:
        raise SettingError(f"{where}: {key} must be one of {', '.join(choices)}, got {value!r}")
    if key in KINDS and not value:
        raise SettingError(f"{where}: {key} must not be empty")
    return value


def _unknown(where: str, what: str, bad: set, known: tuple[str, ...]) -> ValidationError:
    return SettingError(f"{where}: unknown {what} {', '.join(sorted(map(str, bad)))}; "
                           f"known: {', '.join(known)}")


def parse_config(text: str, path: Path) -> Config:
    """Parse and check the text of a config file (``path`` is only for messages)."""
    if not text.strip():  # an empty file (TMCLSH_CONFIG=/dev/null): nothing to parse
        return _config_from({}, path)
    import tomllib  # here: without a config file a start-up does not load it

    from .files import toml_limits

    beyond = toml_limits(text)
    if beyond is not None:
        raise SettingError(f"{path}:{beyond[0]}: {beyond[1]}")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SettingError(f"{path}: {exc}") from None
    return _config_from(data, path)


def _config_from(data: dict, path: Path) -> Config:
    """The settings and profiles of a config file's data, checked."""
    extra = set(data) - {"settings", "profiles"}
    if extra:
        raise _unknown(str(path), "table(s)", extra, ("settings", "profiles"))
    raw_settings = data.get("settings", {})
    if not isinstance(raw_settings, dict):
        raise SettingError(f"{path}: settings must be a table ([settings])")
    bad = set(raw_settings) - set(SETTING_KEYS)
    if bad:
        raise _unknown(f"{path} [settings]", "setting(s)", bad, SETTING_KEYS)
    defaults = _default_settings()
    settings = {k: _check_value(f"{path} [settings]", k, v, type(defaults[k]))
                for k, v in raw_settings.items()}
    raw_profiles = data.get("profiles", {})
    if not isinstance(raw_profiles, dict):
        raise SettingError(f"{path}: profiles must be tables ([profiles.NAME])")
    profiles: dict[str, dict] = {}
    for name, prof in raw_profiles.items():
        where = f"{path} [profiles.{name}]"
        if not isinstance(prof, dict):
            raise SettingError(f"{where}: a profile must be a table of settings")
        bad = set(prof) - set(CONNECTION_KEYS)
        if bad:
            raise _unknown(where, "key(s)", bad, CONNECTION_KEYS)
        profiles[name] = {k: _check_value(where, k, v, CONNECTION_TYPES[k]) for k, v in prof.items()}
        kinds = [k for k in KINDS if k in prof]
        if len(kinds) > 1:
            raise SettingError(f"{where}: {' and '.join(kinds)} exclude each other; keep one")
    return Config(path, settings, profiles)


MAX_CONFIG = 1024 * 1024  # bytes of a config file


def load_config(path: Path | None = None) -> Config:
    """Read the config file; a missing file is an empty config, a bad one an error (a
    directory where the file should be too: it is never silently ignored)."""
    from .files import FileError, bounded_read, read_text

    path = path or config_file()
    try:
        if not path.exists() and not path.is_symlink():
            return Config(path)
        if path.is_dir():
            raise SettingError(f"{path}: the config file is a directory")
        # /dev/null (no config) and pipes (<(...)) are read like files, bounded
        text = read_text(path, MAX_CONFIG, "config file")
    except FileError as exc:
        raise SettingError(str(exc)) from None
    except OSError as exc:  # a path the OS refuses to look at (too long, no permission)
        raise SettingError(f"cannot read {path}: {exc.strerror}") from None
    if not text.strip():
        # nothing for a parser to read (TMCLSH_CONFIG=/dev/null, an empty file): no guard
        # is set up for it (a watching thread, a pipe, the memory limit), at every start
        return parse_config(text, path)
    with bounded_read(str(path), "config file"):
        return parse_config(text, path)


def profile_names(config: Config | None = None) -> list[str]:
    """The profiles defined in the config file, sorted (for completion and messages)."""
    return sorted((config or load_config()).profiles)


# -- environment and resolution -------------------------------------------------------------

def from_environment(env: dict[str, str] | None = None) -> dict:
    """Connection settings from ``TMCLSH_*`` variables (empty variables count as unset)."""
    env = os.environ if env is None else env
    out: dict = {}
    for var, key in ENVIRONMENT.items():
        val = env.get(var)
        if not val:
            continue
        want = CONNECTION_TYPES.get(key, str)
        if key in limits.LIMITS:  # the very check --timeout, --baud, ... make
            out[key] = limits.parse(key, val, var)
            continue
        if want is bool:
            if val.strip().lower() not in _TRUE + _FALSE:
                raise SettingError(f"{var}={val[:40]!r} must be {_type_name(want)}")
            value: object = val.strip().lower() in _TRUE
        else:
            value = val
        out[key] = value
    return out


def resolve(cli: dict, config: Config, env: dict[str, str] | None = None) -> dict:
    """Merge connection settings: options > environment > profile > built-in defaults.

    ``cli`` holds the command-line values, ``None`` meaning "not given". The connection kinds
    (port, can, sim) exclude each other: the strongest source that names one of them decides,
    and the weaker sources' kinds are dropped. The result has every key of
    ``CONNECTION_DEFAULTS``; port/can/sim are absent when no source names one (the caller then
    looks for an attached module or starts the simulator).
    """
    envs = from_environment(env)
    profile_name = cli.get("profile") or envs.get("profile")
    profile: dict = {}
    if profile_name:
        if profile_name not in config.profiles:
            known = ", ".join(sorted(config.profiles)) or "none defined"
            raise UsageError(f"no profile {profile_name!r} in {config.path} (known: {known})")
        profile = config.profiles[profile_name]
    merged: dict = {**CONNECTION_DEFAULTS, **{k: LINK_DEFAULTS[k] for k in LINK_KEYS}}
    for source in (profile, envs, {k: v for k, v in cli.items() if v is not None}):
        if any(k in source for k in KINDS):
            for k in KINDS:
                merged.pop(k, None)
        merged.update(source)
    merged.pop("profile", None)
    return merged


def load_settings(config: Config | None = None, env: dict[str, str] | None = None) -> dict:
    """Shell settings: the packaged defaults, overridden by the config file's ``[settings]``.

    ``NO_COLOR`` (https://no-color.org) turns ``color = "auto"`` into ``"never"``; an explicit
    ``"always"`` in the file still wins.
    """
    env = os.environ if env is None else env
    config = load_config() if config is None else config
    settings = default_settings()
    settings.update(config.settings)
    if settings["color"] == "auto" and env.get("NO_COLOR"):
        settings["color"] = "never"
    return settings


def _toml(value: object) -> str:
    import json

    return json.dumps(value)


def main(argv: list[str] | None = None) -> int:
    """``python -m tmclsh.base.config [--default | --profiles | --check]``."""
    import argparse
    import sys

    p = argparse.ArgumentParser(prog="python -m tmclsh.base.config",
                                description="Show tmclsh's configuration.")
    what = p.add_mutually_exclusive_group()
    what.add_argument("--default", action="store_true", help="print the commented default config")
    what.add_argument("--profiles", action="store_true", help="list the profile names, one a line")
    what.add_argument("--check", action="store_true", help="check the config file (default)")
    args = p.parse_args(argv)
    if args.default:
        sys.stdout.write(default_config_text())
        return 0
    try:
        config = load_config()
        if args.profiles:
            for name in profile_names(config):
                print(name)
            return 0
        settings = load_settings(config)
    except ValidationError as exc:
        print(f"tmclsh: {exc}", file=sys.stderr)
        return 1
    state = "found" if config.path.is_file() else "not found, using defaults"
    print(f"# {config.path} ({state})")
    print("[settings]")
    for key, value in settings.items():
        print(f"{key} = {_toml(value)}")
    for name in profile_names(config):
        print(f"\n[profiles.{name}]")
        for key, value in config.profiles[name].items():
            print(f"{key} = {_toml(value)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
