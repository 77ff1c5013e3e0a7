"""Where settings come from: command line, then environment, then the selected profile of
``$XDG_CONFIG_HOME/tmclsh/config.toml``, then built-in defaults (first value found wins)."""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from .errors import ValidationError

# environment variable -> setting name
ENVIRONMENT = {
    "TMCLSH_PORT": "port",
    "TMCLSH_BAUD": "baud",
    "TMCLSH_CAN": "can",
    "TMCLSH_MODULE": "module",
    "TMCLSH_ADDRESS": "address",
    "TMCLSH_PROFILE": "profile",
}
CONNECTION_KEYS = ("port", "baud", "can", "can_id", "reply_id", "sim", "module", "address",
                   "host_address", "ascii", "timeout", "retries")
SETTING_KEYS = ("color", "editing_mode", "history_size", "confirm")
INT_KEYS = {"baud", "address", "host_address", "can_id", "reply_id", "retries", "history_size"}


def config_dir() -> Path:
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "tmclsh"


def state_dir() -> Path:
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "tmclsh"


def config_file() -> Path:
    return Path(os.environ.get("TMCLSH_CONFIG") or config_dir() / "config.toml")


@dataclass
class Config:
    path: Path
    settings: dict = field(default_factory=dict)
    profiles: dict[str, dict] = field(default_factory=dict)


def load_config(path: Path | None = None) -> Config:
    path = path or config_file()
    if not path.is_file():
        return Config(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValidationError(f"{path}: {exc}") from None
    settings = dict(data.get("settings", {}))
    unknown = set(settings) - set(SETTING_KEYS)
    if unknown:
        raise ValidationError(f"{path}: unknown setting(s) {', '.join(sorted(unknown))}; "
                              f"known: {', '.join(SETTING_KEYS)}")
    profiles = {}
    for name, prof in data.get("profiles", {}).items():
        bad = set(prof) - set(CONNECTION_KEYS)
        if bad:
            raise ValidationError(f"{path}: profile {name!r} has unknown key(s) "
                                  f"{', '.join(sorted(bad))}; known: {', '.join(CONNECTION_KEYS)}")
        profiles[name] = dict(prof)
    return Config(path, settings, profiles)


def from_environment(env: dict[str, str] | None = None) -> dict:
    env = os.environ if env is None else env
    out = {}
    for var, key in ENVIRONMENT.items():
        if env.get(var):
            val = env[var]
            if key in INT_KEYS:
                try:
                    out[key] = int(val, 0)
                except ValueError:
                    raise ValidationError(f"{var}={val!r} is not a number") from None
            else:
                out[key] = val
    return out


def resolve(cli: dict, config: Config, env: dict[str, str] | None = None) -> dict:
    """Merge connection settings: explicit options > environment > profile.

    Connection kinds exclude each other: if the command line names one (port, can, sim), the
    environment's and profile's other kinds are ignored.
    """
    envs = from_environment(env)
    profile_name = cli.get("profile") or envs.get("profile")
    profile: dict = {}
    if profile_name:
        if profile_name not in config.profiles:
            known = ", ".join(sorted(config.profiles)) or "none defined"
            raise ValidationError(f"no profile {profile_name!r} in {config.path} ({known})")
        profile = config.profiles[profile_name]
    merged: dict = {}
    for source in (profile, envs, {k: v for k, v in cli.items() if v is not None}):
        if any(k in source for k in ("port", "can", "sim")):
            for k in ("port", "can", "sim"):
                merged.pop(k, None)
        merged.update(source)
    merged.pop("profile", None)
    return merged
