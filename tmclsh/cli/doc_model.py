"""What the man page and the completions document, read from where it is defined: the
command line from the argument parser, the shell commands, the modules, the CAN interfaces and
the settings."""

from __future__ import annotations

import argparse
import re
from dataclasses import dataclass, field

PROG = "tmclsh"
SHELLS = ("bash", "zsh", "fish")
# pyserial URL schemes offered where a port is expected
URL_SCHEMES = ("socket://", "rfc2217://", "loop://", "spy://", "hwgrep://")
PORT_GLOBS = ("/dev/ttyUSB*", "/dev/ttyACM*", "/dev/serial/by-id/*")
# what to complete for an option's value, by the option's dest (or a positional's)
VALUE_KINDS = {
    "port": "ports", "can": "can", "sim": "modules", "module": "modules", "profile": "profiles",
    "script": "files", "file": "files", "output": "files", "module_file": "files",
    "save": "files", "expect": "files",
}



# -- the command line, read from the parser ------------------------------------------------

@dataclass
class Option:
    flags: tuple[str, ...]
    dest: str
    help: str
    metavar: str | None  # None: takes no value
    optional: bool = False  # nargs='?': the value may be left out
    choices: tuple[str, ...] | None = None
    excludes: tuple[str, ...] = ()  # flags of the options in its mutually exclusive groups
    kind: str | None = None  # ports | can | modules | profiles | files | choices | None

    @property
    def takes_value(self) -> bool:
        return self.metavar is not None

    @property
    def long(self) -> str:
        return next((f for f in self.flags if f.startswith("--")), self.flags[0])


@dataclass
class Positional:
    name: str
    dest: str
    help: str
    kind: str | None


@dataclass
class Group:
    title: str
    options: list[Option]
    default: bool  # argparse's own options group (not one the program made)
    copy: bool = False  # a subcommand's copy of a group of tmclsh's own (the connection)


@dataclass
class CommandLine:
    name: str  # "" for the top level
    help: str
    groups: list[Group]
    positionals: list[Positional]
    required_choices: list[tuple[Option, ...]] = field(default_factory=list)

    @property
    def options(self) -> list[Option]:
        return [o for g in self.groups for o in g.options]


def _help(action: argparse.Action, prog: str) -> str:
    text = action.help or ""
    if "%" in text:
        params = {k: v for k, v in vars(action).items() if v is not argparse.SUPPRESS}
        params["prog"] = prog
        text = text % params
    return text


def _metavar(action: argparse.Action) -> str:
    if action.metavar is not None:
        return str(action.metavar)
    if action.choices is not None:
        return "{" + ",".join(map(str, action.choices)) + "}"
    return action.dest.upper()


def _read(parser: argparse.ArgumentParser, name: str, help_text: str) -> CommandLine:
    exclusive: dict[int, list[str]] = {}
    required: list[list[argparse.Action]] = []
    for mx in parser._mutually_exclusive_groups:
        flags = [f for a in mx._group_actions for f in a.option_strings]
        for a in mx._group_actions:
            exclusive.setdefault(id(a), []).extend(f for f in flags if f not in a.option_strings)
        if mx.required:
            required.append(list(mx._group_actions))
    made: dict[int, Option] = {}
    groups, positionals = [], []
    for group in parser._action_groups:
        opts = []
        for a in group._group_actions:
            if a.help == argparse.SUPPRESS or isinstance(a, argparse._SubParsersAction):
                continue
            if not a.option_strings:
                positionals.append(Positional(_metavar(a), a.dest, _help(a, parser.prog),
                                              VALUE_KINDS.get(a.dest)))
                continue
            takes = a.nargs != 0 and not isinstance(
                a, (argparse._StoreConstAction, argparse._HelpAction, argparse._VersionAction,
                    argparse._CountAction))
            choices = tuple(map(str, a.choices)) if a.choices is not None else None
            kind = VALUE_KINDS.get(a.dest) if takes else None
            if takes and kind is None and choices:
                kind = "choices"
            opt = Option(tuple(a.option_strings), a.dest, _help(a, parser.prog),
                         _metavar(a) if takes else None, a.nargs == "?", choices,
                         tuple(exclusive.get(id(a), ())), kind)
            made[id(a)] = opt
            opts.append(opt)
        if opts:
            default = group is parser._optionals
            groups.append(Group(group.title or "options", opts, default))
    req = [tuple(made[id(a)] for a in acts if id(a) in made) for acts in required]
    groups.sort(key=lambda g: g.default)  # the program's own groups first, argparse's last
    return CommandLine(name, help_text, groups, positionals, req)


def describe(parser: argparse.ArgumentParser | None = None) -> tuple[CommandLine, list[CommandLine]]:
    """The top-level command line and its subcommands, as plain data."""
    if parser is None:
        from .options import build_parser

        parser = build_parser()
    top = _read(parser, "", parser.description or "")
    subs = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {c.dest: c.help or "" for c in action._choices_actions}
            for name, sub in action.choices.items():
                if helps.get(name) == argparse.SUPPRESS:
                    continue
                subs.append(_read(sub, name, helps.get(name, "")))
    own = {g.title for g in top.groups if not g.default}
    for cmd in subs:
        for g in cmd.groups:
            g.copy = not g.default and g.title in own
    return top, subs


# -- the rest of what is documented ----------------------------------------------------------

def module_names() -> list[str]:
    from ..tmcl.modules import built_in

    return built_in()  # never the generating user's own module files


def can_interfaces() -> list[str]:
    """python-can's interface names (imported here only: generation time, never at start-up)."""
    from can.interfaces import VALID_INTERFACES

    return sorted(VALID_INTERFACES)


def shell_commands() -> list:
    from ..shell.lang import commands

    return commands.all_commands()


def _default_toml() -> tuple[list[tuple[str, str, str]], dict[str, str]]:
    """From default.toml: settings as (key, TOML value, comment) and profile-key descriptions."""
    from ..base.config import CONNECTION_KEYS, default_config_text

    settings: list[tuple[str, str, str]] = []
    keys: dict[str, str] = {}
    comment: list[str] = []
    section = ""
    for raw in default_config_text().splitlines():
        line = raw.strip()
        if line.startswith("[") and not line.startswith("#"):
            section, comment = line, []
        elif line.startswith("#"):
            m = re.match(r"#\s{3}(\w+)\s{2,}(.+?)(?:\s{2,}(.*))?$", line)
            if m and m.group(1) in CONNECTION_KEYS:
                desc = m.group(2)
                keys[m.group(1)] = desc + (f" (e.g. {m.group(3)})" if m.group(3) else "")
            else:
                comment.append(line.lstrip("#").strip())
        elif "=" in line and section == "[settings]":
            key, value = (s.strip() for s in line.split("=", 1))
            settings.append((key, value, " ".join(comment)))
            comment = []
        elif not line:
            comment = []
    return settings, keys
