"""The man page and the bash, zsh and fish completions, generated, never typed.

Everything listed comes from where it is defined: options and subcommands from
``options.build_parser()``, shell commands from the dot-command registry (``shell.commands``),
TMCL instructions from ``instructions``, module names from ``modules.available()``, settings
and profile keys from ``default.toml`` and ``config``, CAN interfaces from python-can's
``can.interfaces.VALID_INTERFACES`` (imported here, at generation time only). The committed
files are checked against this generator by the tests, so they cannot drift.

    python -m tmclsh.cli.docs            regenerate man/tmclsh.1 and completions/* (scripts/gen-docs)
    python -m tmclsh.cli.docs --check    exit 1 and name the stale files if any is out of date
    python -m tmclsh.cli.docs man|bash|zsh|fish   print one of them

Serial ports and profile names change on the user's machine, so the scripts look them up when
completing: ports by globbing ``/dev/tty{USB,ACM}*`` and ``/dev/serial/by-id/*``, profiles by
reading the ``[profiles.NAME]`` headers of the config file (no Python start-up per keystroke).
"""

from __future__ import annotations

import argparse
import re
import shlex
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from .. import __version__

PROG = "tmclsh"
SHELLS = ("bash", "zsh", "fish")
# generated file (relative to the repository root) -> what makes it
OUTPUTS = {
    "man/tmclsh.1": "man",
    "completions/tmclsh": "bash",
    "completions/_tmclsh": "zsh",
    "completions/tmclsh.fish": "fish",
}
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


# -- roff -----------------------------------------------------------------------------------

def _inline(text: str) -> str:
    """Escape text for roff inside a line: backslashes and option hyphens."""
    text = text.replace("\\", "\\e")
    return re.sub(r"(?<![\w.])-", r"\\-", text)


def _esc(text: str) -> str:
    """Escape running text for roff; lines starting with a dot or quote are protected."""
    return "\n".join("\\&" + ln if ln[:1] in (".", "'") else ln
                     for ln in _inline(text).split("\n"))


def _prose(text: str) -> str:
    """Escape help text, setting `code spans` in bold."""
    parts = text.split("`")
    if len(parts) % 2 == 0:  # an unpaired backtick: leave them all as they are
        return _esc(text)
    out = "".join(_b(p) if i % 2 else _inline(p) for i, p in enumerate(parts))
    return "\\&" + out if out[:1] in (".", "'") else out


def _b(text: str) -> str:
    return f"\\fB{_inline(text)}\\fR"


def _i(text: str) -> str:
    return f"\\fI{_inline(text)}\\fR"


def _opt_tag(o: Option, all_flags: bool = True) -> str:
    flags = ", ".join(_b(f) for f in (o.flags if all_flags else (o.long,)))
    if o.metavar is None:
        return flags
    value = _i(o.metavar)
    return f"{flags} [{value}]" if o.optional else f"{flags} {value}"


def _opt_usage(o: Option) -> str:
    flag = o.flags[0] if len(o.flags[0]) == 2 and len(o.flags) > 1 else o.long
    if o.metavar is None:
        return _b(flag)
    value = f"[{_i(o.metavar)}]" if o.optional else _i(o.metavar)
    return f"{_b(flag)} {value}"


def _sentence(text: str) -> str:
    text = text.strip()
    if not text:
        return text
    first = text.split(None, 1)[0]
    if not first.startswith(("python-", "pyserial")):  # names keep their case
        text = text[0].upper() + text[1:]
    return text if text.endswith((".", "!", "?")) else text + "."


def _summarised(g: Group) -> bool:
    """A subcommand's copy of a group of tmclsh's own options (the connection options) is
    named, not listed; a group the subcommand has for itself is listed."""
    return g.copy


def _usage(cmd: CommandLine) -> str:
    """One synopsis line of a subcommand."""
    parts = [_b(f"{PROG} {cmd.name}".strip())]
    parts += [_i(p.name) for p in cmd.positionals]
    required = {id(o) for grp in cmd.required_choices for o in grp}
    for g in cmd.groups:
        if _summarised(g):
            parts.append(f"[{_i(g.title.split()[0])}]")
            continue
        for o in g.options:
            if o.dest == "help" or id(o) in required:
                continue
            parts.append(f"[{_opt_usage(o)}]")
    for grp in cmd.required_choices:
        parts.append("(" + " | ".join(_opt_usage(o) for o in grp) + ")")
    return " ".join(parts)


def _option_extra(o: Option) -> list[str]:
    from ..base.config import CONNECTION_KEYS, ENVIRONMENT

    extra = []
    if o.kind == "modules":
        extra.append("Modules: " + ", ".join(module_names()) + ".")
    if o.choices and not all(c in o.help for c in o.choices):
        extra.append("One of: " + ", ".join(o.choices) + ".")
    env = [var for var, key in ENVIRONMENT.items() if key == o.dest]
    if env:
        extra.append(f"Environment: {', '.join(env)}.")
    if o.dest in CONNECTION_KEYS and o.dest != "profile":
        extra.append(f"Profile key: {o.dest}.")
    if o.excludes:
        extra.append("Excludes " + ", ".join(o.excludes) + ".")
    return extra


def _options_block(options: Iterable[Option], *, top: bool) -> list[str]:
    out = []
    for o in options:
        out += [".TP", _opt_tag(o)]
        if o.help:
            out.append(_esc(_sentence(o.help)))
        extra = _option_extra(o) if top else (
            ["Modules: " + ", ".join(module_names()) + "."] if o.kind == "modules" else [])
        if extra:
            out.append(_esc(" ".join(extra)))
    return out


def _synopsis(top: CommandLine, subs: list[CommandLine]) -> list[str]:
    lines: list[str] = []
    conn = " ".join(f"[{_i(g.title.split()[0])}]" for g in top.groups if not g.default)

    def line(text: str) -> None:
        if lines:
            lines.append(".br")
        lines.append(text)

    line(f"{_b(PROG)} {conn}")
    for g in top.groups:
        if not g.default:
            continue
        for o in g.options:
            if o.dest in ("help", "version"):
                continue
            prefix = f" {conn}" if o.excludes else ""
            line(f"{_b(PROG)}{prefix} {_opt_usage(o)}")
    for s in subs:
        line(_usage(s))
    return lines


_SUB_NOTES = {
    "asm": "Source lines are TMCL as in the TMCL-IDE: labels (NAME:), constants "
           "(#define NAME VALUE or NAME = VALUE), #include \"FILE\", comments after // or #. "
           "Errors name FILE:LINE:COLUMN and no output file is written.",
    "disasm": "FILE (or - for standard input) is a TMCL-IDE binary image or hex text as "
              "written by asm --hex (see PROGRAM IMAGES).",
    "modules": "Lists each module tmclsh has data for, with its version string and where the "
               "data comes from: built in, or the path of a user's module file (see MODULE "
               "FILES). Exit status 1 when a user's file cannot be used (each named on "
               "standard error). modules check FILE validates one file: exit 0 and a summary "
               "if tmclsh can use it, else 1 and one line naming the file, the line and what "
               "is wrong. modules import pytrinamic NAME (TMCM1260) writes a module file from "
               "the installed PyTrinamic's class for that module (pip install "
               "'tmclsh[pytrinamic]'): its motors and its axis and global parameter names and "
               "numbers (named as the built-in modules are, MinimumSpeed, with PyTrinamic's "
               "minimumSpeed kept as an alias), nothing else (ranges, units and access are not known, so values are "
               "checked as 32-bit numbers and the module decides). The file goes to the config "
               "directory's modules/ (or -o FILE, - for standard output); tmclsh then knows the "
               "module by its 136 answer and names it with the data's origin. --all imports "
               "every class PyTrinamic has, except the modules tmclsh has built in from their "
               "manuals (a class standing for several modules, such as TMCM123x_0_1 for the "
               "TMCM-1230 and TMCM-1231, gives a file for each); a file that an import did not "
               "write is never replaced. tmclsh -m NAME --sim simulates such a module: its "
               "motor moves by PyTrinamic's names (MaxVelocity, PositionReachedFlag) at the "
               "simulator's own start values, in position units per second, and any I/O port "
               "answers.",
    "sim": "The first line on standard output is the pseudo-terminal's path or the endpoint; "
           "connect to it with --port PATH, --port socket://HOST:PORT or --can IFACE:CHANNEL. "
           "Runs until interrupted. --address 1,2,3 serves a module at each address on one "
           "line, as on an RS485 bus (an address given twice answers twice); --baud N paces "
           "the line at that rate, 10 bits a byte both ways. "
           "--pty needs Linux or macOS; --tcp and --can work on "
           "Windows too. Exit status 2 for a malformed argument, 3 when the server cannot "
           "start (address in use, no such CAN interface).",
    "ports": "The USB ids are shown; ports whose vendor is Trinamic (0x2A3C) are marked TRINAMIC.",
    "scan": "Sends command 136 (firmware version) to each address and prints those that answer, "
            "then a summary on standard error; a progress bar while it runs on a terminal. The "
            "wait per address comes from the link (the wire time of request and reply at the "
            "baud rate, plus a margin); addresses that answered late or garbled are asked again, "
            "slower. When nothing answers in binary, the addresses are asked in ASCII mode "
            "(--ascii: those silent in binary even when others answered); a module found so is "
            "marked ASCII mode and left in it. An address where every reply comes twice is "
            "said to have two modules on it (JSON: \"answers\": 2). --baud auto scans at "
            "each baud rate global parameter 65 can select, and once only where the rate has "
            "no effect (TCP, a module's own USB port, or modules found at one rate answering "
            "at the next). A module in its bootloader (a firmware update did not "
            "complete) is marked, with the tmclsh firmware command that completes it. Exit "
            "status 3 when nothing answers. --save INVENTORY writes what answered as an "
            "inventory, --expect INVENTORY compares the line with one (see LINE INVENTORY): "
            "exit 0 match, 1 differences, 3 nothing answered.",
    "firmware": "Writes the firmware image FILE.hex (Intel HEX, as the vendor ships it) to the "
                "module over its TMCL bootloader. The image is read whole before anything is "
                "sent, and refused with FILE:LINE and the fault when a record is damaged, when "
                "the end-of-file record is missing (a file cut short), when two records give "
                "the same address, or when the records leave a gap inside the image (the file "
                "would not say what belongs there). Before anything is written it is refused "
                "when its version string (such as 1311V112) names another module type than "
                "the module's own, and, where the module data gives the application memory "
                "(firmware_start, firmware_size in a module file), when it does not fit there. "
                "A downgrade (an older version than the module runs) is named in the question, "
                "in --check and in the last line (JSON: \"change\": \"downgrade\"). "
                "Then, after the question (or --yes; without a terminal to answer, --yes is "
                "needed), a running program and turning motors are stopped (the safety stop), "
                "and command 242 restarts the module into its bootloader, which "
                "answers at address 1, 115200 baud (a USB module leaves the bus and comes back "
                "under the same port name); 206 asks its memory, and an image that does not "
                "start where the memory does or does not fit is refused before the erase, "
                "naming the line of the first record outside it, and 205 starts the module's "
                "firmware again, which is said; 200 erases, 201 and 202 write the image "
                "page by page, 203 compares the memory's checksum with the image's, 208 writes "
                "length and checksum, 205 starts the new firmware, whose version is read back. "
                "On a terminal a bar shows the bytes written, the rate and the time left; with "
                "--json each step is one object on standard output and the result one more. "
                "The last line names the old and the new version. --check says what would "
                "happen and writes nothing (whether the image fits is known from the module "
                "data where it gives the memory, else from the bootloader only: --check does "
                "not restart a running module to ask). "
                "Interrupted anywhere (Ctrl-C, SIGTERM, a lost link, a module that stops "
                "answering), tmclsh says where the module stands and, unless it runs its "
                "firmware, the exact command that completes the update; before the erase, a "
                "module it restarted is sent back to its firmware first. Run again, the same "
                "command finds the module in its bootloader (also at address 1, 115200 baud "
                "when it does not answer where asked) and completes the update: when the "
                "memory already holds the image (203 agrees) it only finishes it, otherwise it "
                "erases and writes again. A module that already runs the image's version is "
                "left alone. Exit status 0 when updated (or nothing to do), 1 when refused or "
                "stopped, 2 for an unreadable image or a missing --yes (nothing sent), 3 when "
                "no module answers, 130 when interrupted.",
    "replace": "Replaces a module in the field: the new module (--to) gets the old one's "
               "firmware version, settings and stored program, in five steps, each reported "
               "as done, skipped, failed, stopped or not run. identify: the old module (--from "
               "a port, or can:IFACE:CHANNEL; or a backup file .save wrote, with its "
               ".program.tmcl beside it when the header names one) is read: type, firmware, "
               "every setting (values outside the manual's ranges as it holds them), the "
               "stored program; the new one is identified, also when left in its bootloader "
               "by an update that broke off. Another module type is refused unless --force, "
               "which carries the settings by parameter name where the units agree (as "
               ".restore --force) and leaves the firmware alone. firmware: when the new "
               "module runs another version, the image --firmware names is written as "
               "tmclsh firmware writes it (it must carry the old module's version); without "
               "one the step says which image is needed and stops, nothing written. "
               "configuration: what differs is written (SAP/SGP, read back) and stored "
               "(STAP/STGP); the new module's link identity (address, baud rate, CAN ids, "
               "ASCII start-up) stays its own unless --with-link. program: the old program is "
               "uploaded (132, 133) and verified (134), unless the new module holds it "
               "already. verify: every setting and the program are read back from the new "
               "module and compared with the old module's, and its firmware version. The "
               "old module is only ever read. One report on standard output (a table on a "
               "terminal; with --json one object: \"replace\", \"steps\" with \"step\", "
               "\"outcome\", \"text\", and \"resume\" and \"exit\"); each step's line on "
               "standard error as it ends. Interrupted at any step (Ctrl-C, SIGTERM, a lost "
               "link) or stopped by a failed step, tmclsh says where both modules stand and "
               "the one command that completes the job: the same command with --yes, which "
               "skips what is done already. Without a terminal to answer the question, --yes "
               "is needed. Exit status 0 when replaced and verified, 1 when a step failed, 2 "
               "for bad arguments (nothing sent), 3 when a module does not answer, 130 when "
               "interrupted.",
    "monitor": "Listens and sends nothing, ever. One line per exchange (time, address or CAN "
               "id, the request with parameter names, the reply with its status in words, "
               "the time between them), one line for each event, reply without its request, "
               "run of noise, partial frame, ASCII text line and other CAN frame; with "
               "--json one object per frame. Replies are paired with their requests by "
               "module address and command (on CAN by the reply id); a request unanswered "
               "after --timeout is shown so. Each module's type is learnt from its 136 "
               "answers in the traffic, so parameter names appear once a master asked for "
               "it (or at once with -m). On a serial tap the frames are found by their "
               "checksum as tmclsh finds its own; after noise a frame is taken only if it "
               "fits the traffic so far, and bytes left when the line goes quiet are a "
               "partial frame. Commands tmclsh has no data for are shown by number, never "
               "dropped. Ctrl-C or SIGTERM ends it with a summary (frames, errors, status "
               "counts, the slowest exchange) on standard error, or a last {\"summary\": "
               "...} object. Exit status 0; 1 when the adapter goes away or a log cannot "
               "be read on (after the summary of what came before); 3 when the port or bus "
               "cannot be opened.",
    "bridge": "Another program connects to the pseudo-terminal or TCP port as to the module; "
              "every frame it sends and every byte the module answers is forwarded unchanged "
              "(on --can: the request's seven instruction bytes to the module's CAN id, the "
              "reply back as a serial frame) and shown as monitor shows it, ASCII mode as "
              "text lines. The first line on standard output is the pseudo-terminal's path "
              "or HOST:PORT, as for sim: PyTrinamic's serial interface opens a device path, "
              "not a URL, so give it --pty; --tcp is for programs that take socket:// URLs. "
              "A request whose checksum is wrong is shown as such, paired with the module's "
              "status-1 answer. It runs until interrupted; then, as tmclsh does "
              "for its own commands, it stops a motor or stored program the traffic "
              "started, ends download mode and leaves ASCII mode the traffic entered, and "
              "prints the summary; -o keeps the frames of that closing stop too. Forwarding comes first: what is shown is read on another "
              "thread, and when nothing reads the output (a paused pager, a full pipe) lines "
              "are dropped and counted (\"dropped_lines\" in the JSON summary), never "
              "frames; the counts stay whole. A request that answers nothing by design "
              "(137, 242, 205) is no error, and requests sent ahead of their replies are "
              "each paired with their own. Exit status 0; 1 when the module's link goes away; 3 "
              "when the module's port or bus cannot be opened or the bridge cannot serve.",
    "replay": "Reads CAPTURE (a serial capture written by monitor -o or bridge -o, a "
              "python-can log of any format it reads, candump's screen lines, or a --log-dir "
              "transcript), pairs each request with its reply as monitor does, and sends "
              "every request again, in order, to the module at the address (on CAN the id) "
              "it went to: a capture of several modules replays each at its own. Each is "
              "sent as soon as the one before is answered, or with --as-captured at its "
              "time in the capture. Every exchange whose status or value differs from the "
              "capture is shown in a table (the command, the captured and the new reply, "
              "both latencies in ms), then one line of totals; with --json one object per "
              "difference and a last one with the totals and \"exit\". Commands that only "
              "read (GAP, GGP, GIO, 134-136, as the instruction set marks them) are sent "
              "freely; a capture holding any that write, store or move is refused, naming "
              "them, unless --yes, which names them before anything is sent. A replay that "
              "sent any of them ends with the safety stop, whatever ends it (Ctrl-C too). "
              "Replies of eight data bytes on CAN (a TMCM-1260) are read as seven. Exit "
              "status 0 no differences; 1 differences, or the link lost; 2 a capture that "
              "cannot be read, or writes without --yes (nothing sent); 3 no module; 130 "
              "Ctrl-C.",
}


def _details(text: str) -> list[str]:
    """A command's details: indented lines are examples (kept as typed), the rest paragraphs."""
    out: list[str] = []
    para: list[str] = []
    example: list[str] = []

    def flush() -> None:
        if para:
            out.extend([".IP", _prose(" ".join(" ".join(para).split()))])
            para.clear()
        if example:
            out.extend([".IP", ".nf", *("\\&" + _inline(ln) for ln in example), ".fi"])
            example.clear()

    for line in text.strip("\n").splitlines():
        if line.startswith((" ", "\t")) and line.strip():
            if para:
                flush()
            example.append(line.strip())
        elif not line.strip():
            flush()
        else:
            if example:
                flush()
            para.append(line)
    flush()
    return out


def _category_layout() -> tuple[tuple[str, ...], dict[str, str]]:
    """The order and titles of the command categories, as ``.help`` shows them."""
    from ..shell.lang.commands import CATEGORIES

    return tuple(name for name, _ in CATEGORIES), dict(CATEGORIES)


def _shell_commands_section() -> list[str]:
    cmds = shell_commands()
    out = [".SH SHELL COMMANDS",
           "Shell commands start with a dot and own the rest of their line. "
           "Every one has help (" + _b(".help") + " " + _i("command") + ") and completion."]
    if not cmds:
        return out + [".PP", "(No shell commands are registered in this build.)"]
    order, titles = _category_layout()
    present = {c.category for c in cmds}
    categories = [c for c in order if c in present] + sorted(present - set(order))
    for cat in categories:
        title = titles.get(cat, cat[:1].upper() + cat[1:])
        out.append(f".SS {_esc(title)}")
        for c in (c for c in cmds if c.category == cat):
            syntax = c.syntax.strip()
            rest = syntax[len(c.name):].strip() if syntax.lower().startswith(c.name) else syntax
            out += [".TP", f"{_b(c.name)} {_inline(rest)}".rstrip(), _prose(_sentence(c.help))]
            also = []
            if c.aliases:
                also.append("Also " + ", ".join(c.aliases) + ".")
            if c.bare:
                also.append(f"Also accepted without the dot ({c.name.lstrip('.')}).")
            if also:
                out.append(_esc(" ".join(also)))
            if c.details:
                out += _details(c.details)
    return out


def _instructions_section() -> list[str]:
    from ..tmcl.instructions import all_instructions

    names = module_names()
    out = [".SH TMCL INSTRUCTIONS",
           "The instructions the shell, the assembler and the simulator know (the opcode in "
           "parentheses). Symbolic types are listed in the type slot; " + _i("parameter") +
           " takes a number or a parameter name of the module (" + _b(".param") +
           " lists them)."]
    for s in all_instructions():
        notes = []
        if set(names) - set(s.modules):
            notes.append("only on " + ", ".join(sorted(s.modules)))
        if not s.direct:
            notes.append("in programs only")
        text = f"({s.opcode}) {_sentence(s.summary)}"
        if notes:
            text = text[:-1] + "; " + "; ".join(notes) + "."
        out += [".TP", f"{_b(s.mnemonic)} {_esc(s.syntax[len(s.mnemonic):].strip())}".rstrip(),
                _esc(text)]
    return out


_DESCRIPTION = f"""\
.SH DESCRIPTION
{_b(PROG)} is an interactive shell for Trinamic TMCL motor-control modules
({{modules}}). At its prompt a TMCL command such as {_b("SAP 4, 0, 1000")} or
{_b("GAP ActualPosition, 0")} is checked against the module's parameter database, sent, and
the reply is decoded; shell commands (starting with a dot) show help, watch live values, run
scripts, talk to the module's ASCII mode, and upload, run and single-step programs stored on the
module. The same lines can be given with {_b("-c")} or replayed from a file with {_b("-f")}.
.PP
Without a connection option (or a profile or variable naming one) {_b(PROG)} uses the one
attached Trinamic USB module if exactly one is found. With none attached, the interactive
shell starts the built-in simulator of a TMCM-1311 (of the {_b("-m")} module when one is
given, as {_b("--sim")} alone does), labelled SIMULATED in the banner and the
toolbar; runs nobody watches ({_b("-c")}, {_b("-f")}, standard input that is not a terminal,
{_b("scan")}) never fall back to it: they exit with status 3 ({_b("--sim")} asks for the
simulator). Two or more Trinamic USB modules attached without {_b("--port")} are named, and
{_b(PROG)} exits with status 3, in every mode.
.PP
At connect the module is asked, not assumed: its type with command 136 (a contradicting
{_b("-m")} is an error naming both types); a module found in download mode (an upload cut
short) is brought out of it with 133, with a notice, as after a reconnect; a module that
answers only in its ASCII mode is driven through it, with a notice. When nothing answers, the
message says what was tried and the likely causes, most likely first.
.PP
Every module on a shared line hears every byte. What {_b(PROG)} sends in ASCII (the probe
for a module in ASCII mode at connect, in {_b("scan")} and after {_b(".address")}, and the
lines of {_b("--ascii")}) is whole nine\\-byte blocks, none of them a valid frame: a command
line gets spaces after its address character ({_b("A        GAP 1, 0")}), so a binary
module on the same line, which counts what it hears in nine\\-byte frames, stays in step
and answers at its own address afterwards. The {_b(".ascii")} terminal sends what is typed.
.PP
Bad input never reaches the module: an unknown mnemonic, a wrong type, a value out of the
parameter's range, a write to a read-only parameter or a motor the module does not have each
gets a one-line error naming what is wrong and what is allowed, and nothing is sent. Writes to
the EEPROM, restoring factory defaults and replacing the stored program ask first, unless
{_b("--yes")} is given.
.PP
The module has the last word on what it holds: a value outside the manual's range is shown as
the reply carries it (signed, unless the data calls the parameter an unsigned 32\\-bit
quantity) with the range it lies outside ({_b("outside_range")} in JSON). {_b("!")} before a
TMCL line sends its value as typed, whatever the data says of its range
({_b("!SAP 140, 0, 12")}); everything else is checked as usual and the module's answer decides.
{_b(".save")} marks values outside the manual's ranges so (on a fresh module they are often
unset defaults; the file's head names them, each line's comment gives the range, and the
shell says so once a run); {_b(".restore")} writes them back, and refuses other such values
unless {_b("--force")}.
"""

_LANGUAGE = f"""\
.SH SHELL LANGUAGE
The interactive prompt, {_b("-c")} and {_b("-f")} share one language.
.IP \\(bu 2
A TMCL line as in the TMCL-IDE's direct mode: a mnemonic and up to three comma-separated
operands, {_i("type")}, {_i("motor")} (or bank) and {_i("value")}, e.g.
{_b("MVP ABS, 0, 90000")}, {_b("SAP 4, 0, 1000")}, {_b("GIO 0, 0")}.
Mnemonics and names are case-insensitive.
.IP \\(bu 2
Numbers in decimal or hex ({_b("$1F")}, {_b("0x1F")}); symbolic types ({_b("ABS REL COORD")},
{_b("START STOP STATUS")}, {_b("TICKS POS")}, ...); parameter names in the type slot
({_b("GAP ActualPosition, 0")}). Any command number can be sent raw as well.
.IP \\(bu 2
A command takes the operands it uses ({_b("GAP 4, 0")}), or all three fields with 0 in the ones
it does not use ({_b("GAP 4, 0, 0")}, as the manuals write it); an operand in a field the
command does not use ({_b("GAP 4, 0, 5")}) is refused and nothing is sent. The raw form
({_b("6 4, 0, 5")}) sends every field as written.
.IP \\(bu 2
Shell commands start with a dot ({_b(".help")}, {_b(".param")}, {_b(".watch")}, ...);
{_b("help")}, {_b("?")} and {_b("quit")} also work bare ({_b("help")} or {_b("?")} alone is the
overview).
.IP \\(bu 2
Lines are separated by newlines or {_b(";")}, at the prompt, with {_b("-c")} and in scripts:
{_b("help 4; help 5")} is two lines, a {_b(";")} inside quotes ({_b('.echo "a;b"')}) is not a
separator. Only a command that owns the rest of its line takes the {_b(";")}: {_b(".watch")}
separates its expressions with it ({_b(".watch a=GAP 1, 0; b=GIO 0, 0")} is one command) and
{_b(".decode")} its pasted bytes, up to a {_b(";")} that another dot-command follows
({_b(".decode 01 06 ...; .decode 02 06 ...")} is two); put other lines after those on a new
line.
.IP \\(bu 2
{_b("//")} and {_b("#")} start a comment that runs to the end of the line ({_b("#")} at the start of
a word, outside quotes: {_b("GAP 1, 0 # where it is")}). Empty lines are ignored.
.IP \\(bu 2
Questions (EEPROM writes, factory reset, program download, leaving {_b(".ascii")}) are answered
with a line: {_b("y")} and Enter agrees, Enter alone takes the default shown in capitals
({_b("[y/N]")}), anything else is no. Outside the interactive prompt nothing is asked: such
commands are refused unless {_b("--yes")} is given.
.IP \\(bu 2
Scripts stop at the first error, reported as {_i("FILE")}:{_i("LINE")}, unless
{_b("--keep-going")} is given.
.IP \\(bu 2
With {_b("--json")} every result is one JSON object on a line of standard output, e.g.
{_b('{"line": "GAP 1, 0", "op": 6, "type": 1, "motor": 0, "value": 0, "status": 100, "reply": -5000}')};
an error gives {_b('{"line": ..., "error": "..."}')}; a check ({_b(".expect")}, {_b(".wait")})
has the same fields passed or failed ({_b('"check"')}, {_b('"passed": true|false')},
{_b('"values"')}), and no module to talk to (exit status 3) gives
{_b('{"line": null, "error": "...", "exit": 3}')} besides the line on standard error (the
subcommands' errors too: {_b("scan")}, {_b("firmware")}, {_b("monitor")} and {_b("bridge")} end
with the same object, their own fields before {_b('"error"')}).
On the built-in simulator every object also has {_b('"simulated": true')} (and a script's
summary line says SIMULATED). A 138 target-reached message is an object of its own, in order
with the results: {_b('{"event": 138, "motors": [0], "t": 1.25}')} (seconds since the start).
An answer that may have been another request's (a reply came later that no request was
waiting for) is reported as {_b('{"line": ..., "suspect": true, "warning": "..."}')} and fails
the run. Two modules at one address (every request brings two replies from there, or two
different 136 answers: the client counts, the prompt and {_b("scan")} say the same) are
reported once as {_b('{"address": 1, "duplicate": true, "warning": "..."}')}, fail the run
(a unit: failed, with that reason, and {_b('"duplicate": true')} in its summary), and
{_b(".upload")} refuses to write there. Status messages go to standard error.
.IP \\(bu 2
Ctrl-C interrupts: everything is stopped (see {_b("Ctrl-C")} below) and, outside the
interactive prompt, {_b(PROG)} exits with status 130. A script that ends while a motor turns
or the stored program runs leaves them so, with a note on standard error (with {_b("--json")}
also {_b('{"left_running": {...}}')} on standard output). A motor the run told to turn
({_b("ROR 0, 1000")}, a rotation left, a position move, a target speed written) and did not stop counts as
left turning even while its speed reads 0 (it has not started yet, or it stalls).
.IP \\(bu 2
A lost link fails the line it was lost on, with the reason; with {_b("--keep-going")} the
script goes on: lines that need no module run as always ({_b(".sleep")} still sleeps), and
a line that needs the module waits for the link to come back (its timeout times its
attempts) before it is given up, not run. After 4 lines in a row got no answer (the link
stayed lost, or the module stayed silent) with nothing from the module in between, the
module is taken to be gone: the rest is not run and the exit status is 3, as for no module
(with several units, that unit alone ends so: "no module").
.SS Keys at the prompt
.TP
{_b("Tab")}
Completes mnemonics, symbolic types, parameter names (with their number, range and unit) and
shell commands with their arguments; inside expressions ({_b(".watch")} {_i("NAME")}{_b("=")},
{_b(".wait")}, {_b(".expect")}, {_b(".if")}, {_b(".let")}, {_b(".display")}, {_b("${...}")}) the
read commands with their parameters, motors and ports, variables and functions.
Completion never asks the module.
.TP
{_b("Ctrl-C")}
Stops everything and clears the line: the stored program if it runs (128; a running program
would start the motors again), then MST to every motor, then each motor's actual speed read
back until it is 0. Only motors that read 0 are called stopped; any other is named.
.TP
{_b("Ctrl-D")}
Leaves the shell, like {_b(".quit")}. While a motor turns or the stored program runs, it
asks first: 1 stop everything first, 2 leave it running, or 3 cancel; the number chooses (or
the arrows and Enter), and the selection starts on 1 every time. A motor the shell told to
turn and did not stop counts, even while its speed reads 0 (a stalled motor).
.SS Keys in .watch
.TP
{_b("s")} or space
Stops everything as Ctrl-C does and keeps watching.
.TP
{_b("Ctrl-C")}
Stops everything and ends the watch.
.TP
{_b("q")} or Esc
Ends the watch quietly; motors keep running.
.PP
A lost link shows as {_b("link lost:")} {_i("REASON")} in the table; the watch keeps trying to
reconnect and samples again once the link is back.
.TP
{_b("Enter")} on an empty line
Repeats the last {_b(".step")}.
.PP
Output longer than the terminal ({_b(".help")}, {_b(".params")}, {_b(".list")}, {_b(".dump")},
a long {_b("help")}) is shown through {_b("$PAGER")} (default {_b("less")}; {_b("q")} leaves
it), never in a pipe, with {_b("-c")} or {_b("-f")}; the {_b("pager")} setting turns it off.
.SS Keys in the ASCII terminal (.ascii)
.TP
{_b("Ctrl-]")}, or {_b(".quit")} typed as a line
Back to the shell (asks whether to send {_b("BIN")}). A {_b("BIN")} typed by the user is
noticed: the module talks binary frames again and the terminal returns to the shell.
.TP
{_b("Ctrl-C")}
Stops all motors (in {_b("--raw")}: first erases the line typed so far).
.TP
{_b("Ctrl-T")} then {_b("e")}, {_b("h")}, {_b("t")}, {_b("f")}, {_b("u")} or {_b("?")}
The menu, as in tio: local echo on/off, hex view of what arrives on/off, timestamps on/off,
log the session to a file ({_b("f")} again stops), send a file line by line (blank and comment
lines left out, each reply waited for), this list. {_b("Ctrl-T Ctrl-T")} sends Ctrl-T in
{_b("--raw")}.
"""

_EXAMPLES = f"""\
.SH EXAMPLES
Start the shell on the simulator, without hardware:
.PP
.RS 4
.nf
{_b("tmclsh --sim")}
.fi
.RE
.PP
Read the position of motor 0 of the module on a USB port, as JSON:
.PP
.RS 4
.nf
{_b('tmclsh --port /dev/ttyACM0 --json -c "GAP ActualPosition, 0"')}
.fi
.RE
.PP
Module 3 on an RS485 bus at 115200 baud; set the maximum speed and move:
.PP
.RS 4
.nf
{_b('tmclsh --port /dev/ttyUSB0 --baud 115200 -a 3 -c "SAP 4, 0, 1000; MVP REL, 0, 5000"')}
.fi
.RE
.PP
A module on a CAN bus, and a remote bench behind ser2net (RFC 2217):
.PP
.RS 4
.nf
{_b("tmclsh --can socketcan:can0 --can-id 1 --reply-id 2")}
{_b("tmclsh --port rfc2217://bench.local:4001")}
.fi
.RE
.PP
Replay a setup script on the module of the profile {_i("bench")}, for CI:
.PP
.RS 4
.nf
{_b("tmclsh --profile bench --yes -f setup.tmcl")}
.fi
.RE
.PP
Assemble a program and look at the result; find the modules on a bus:
.PP
.RS 4
.nf
{_b("tmclsh asm blink.tmc --hex -o blink.hex")}
{_b("tmclsh disasm blink.hex")}
{_b("tmclsh scan --port /dev/ttyUSB0")}
.fi
.RE
.PP
Update the firmware of the module on a USB port, asking before the erase; run the same
command again to complete an update that broke off:
.PP
.RS 4
.nf
{_b("tmclsh firmware TMCM-1311_V1.12.hex --port /dev/ttyACM0")}
{_b("tmclsh firmware TMCM-1311_V1.12.hex --port /dev/ttyACM0 --check")}
.fi
.RE
.PP
Replace a module in the field: the old one on one USB port, the new one on another; its
firmware brought to the old version, its settings and program copied, all read back:
.PP
.RS 4
.nf
{_b("tmclsh replace --from /dev/ttyACM0 --to /dev/ttyACM1 --firmware TMCM-1311_V1.10.hex")}
{_b("tmclsh replace --from old-module.tmcl --to /dev/ttyACM1 --yes --json")}
.fi
.RE
.PP
What is my PLC sending? Listen to the CAN bus, or to an RS485 adapter on the line, and keep
a log; read it again later, only the position reads:
.PP
.RS 4
.nf
{_b("tmclsh monitor --can socketcan:can0 -o plc.blf")}
{_b("tmclsh monitor --port /dev/ttyUSB1 --baud 115200 -m TMCM-1311")}
{_b("tmclsh monitor --log plc.blf --param ActualPosition")}
.fi
.RE
.PP
Reproduce what the PLC did: capture it through the bridge, then send the capture to the
module again and see every reply that differs (writes and moves only with --yes):
.PP
.RS 4
.nf
{_b("tmclsh bridge --pty --port /dev/ttyACM0 -o plc.txt")}
{_b("tmclsh replay plc.txt --port /dev/ttyACM0")}
{_b("tmclsh replay plc.blf --can socketcan:can0 --as-captured --yes")}
.fi
.RE
.PP
Put tmclsh between the TMCL-IDE (or any program) and the module, and watch every frame:
.PP
.RS 4
.nf
{_b("tmclsh bridge --tcp 127.0.0.1:7000 --port /dev/ttyACM0")}
.fi
.RE
.PP
Serve a simulated module on a pseudo-terminal and connect to it:
.PP
.RS 4
.nf
{_b("tmclsh sim --pty")}        (prints e.g. /dev/pts/5)
{_b("tmclsh --port /dev/pts/5")}
.fi
.RE
.PP
Test your own code against a misbehaving module (the same seed, the same faults):
.PP
.RS 4
.nf
{_b("tmclsh sim --pty --faults drop=0.1,corrupt=0.05,delay=0.02,garbage=0.05,dup=0.05 --faults-seed 1")}
.fi
.RE
.PP
Load the completions into the running shell:
.PP
.RS 4
.nf
{_b("source <(tmclsh --completions bash)")}
.fi
.RE
"""


def _exit_status() -> list[str]:
    from ..base.errors import EXIT_CONNECT, EXIT_FAILED, EXIT_OK, EXIT_USAGE

    rows = [
        (EXIT_OK, "Success."),
        (EXIT_FAILED, "A TMCL or shell command failed (a rejected line, an error status from "
                     "the module, a timeout), an answer of -c or -f stayed in doubt (the line "
                     "and a warning say which; the run goes on), two modules answer at the "
                     "address (a warning names it), a script stopped at an "
                     "error, asm or disasm "
                     "failed, a file could not be written (the message names it and why), "
                     "scan found no module, or a module file that cannot be used (tmclsh "
                     "modules)."),
        (EXIT_USAGE, "Usage: an unknown option or a bad option value (a malformed --can, an "
                     "unknown --profile), a bad environment variable, profile or config file "
                     "(each checked against the same LIMITS); or a script given with -f that "
                     "was not run (nothing was sent): it cannot be read, no such file, a "
                     "syntax error, a value out of range or another line the module would "
                     "refuse; the same for the lines of -c (each TMCL line, and each shell "
                     "command's arguments, checked before the first is sent) and for the file of a .diff or .restore in -c "
                     "(CONFIGURATION BACKUPS) when nothing else of the run was sent."),
        (EXIT_CONNECT, "No module to talk to: a run that is not interactive (-c, -f, standard "
                       "input not a terminal, scan) was given no connection and found no "
                       "module (--sim simulates one); two or more Trinamic USB modules are "
                       "attached and no --port picks one; the port or CAN bus cannot be "
                       "opened; nothing answers at connect (command 136) or scan finds no "
                       "module; -m names another type than the module reports; with "
                       "--keep-going, the module is gone (4 lines in a row got no answer, "
                       "the rest is not run); or tmclsh sim cannot start its server."),
        (130, "Interrupted with Ctrl-C (the program and the motors were stopped first). "
              "With several units (SEVERAL MODULES): 0 when every unit passed, 1 when any "
              "failed, 3 when a unit had no module."),
        (129, "Hung up (SIGHUP: the terminal or SSH session went away)."),
        (143, "Terminated (SIGTERM). On both signals tmclsh still ends download mode and "
              "leaves ASCII mode if it had entered it, before exiting."),
    ]
    out = [".SH EXIT STATUS"]
    for code, text in rows:
        out += [".TP", _b(str(code)), _esc(text)]
    return out


def _limits() -> list[str]:
    from ..base.files import (MAX_DEPTH as MAX_NESTING, MAX_DIGITS, MAX_FILE, MAX_LINE,
                              MAX_LINES, MAX_READ_MEMORY, SIGNAL_GRACE, size_text)
    from ..base.limits import LIMITS
    from ..shell.lang.expr import MAX_DEPTH, MAX_LENGTH, MAX_LITERAL, MAX_OPERATORS

    out = [".SH LIMITS",
           "Every number a user sets is checked against one table, whether it comes from an "
           "option, an environment variable, a profile or a shell command; a value outside "
           "it is refused with one line naming the setting and the range, and nothing is "
           "sent."]
    for key, lim in LIMITS.items():
        out += [".TP", _b(key), _esc(_sentence(f"{lim.describe()}: {lim.what}"))]
    out += [".PP",
            _esc(f"Files: scripts, sources, programs, CSV files and config files are read up "
                 f"to {size_text(MAX_FILE)} ({MAX_LINES:,} lines for a script, "
                 f"{MAX_LINE:,} characters a line, also for -f - which runs each line as it "
                 "arrives); program images up to the module's program memory. Larger ones "
                 f"are refused unread. Expressions: at most {MAX_LENGTH} characters, "
                 f"{MAX_OPERATORS} operators and {MAX_DEPTH} levels of nesting; number "
                 f"literals at most {MAX_LITERAL} digits. Every file "
                 "tmclsh writes (asm -o, scan --save, .record, .watch --csv, .dump, .echo >) is written "
                 "beside its target and renamed over it when complete, so a failed write "
                 "leaves the old file as it was."),
            ".PP",
            _esc(f"Data files from the field (module files, the config file, Intel HEX "
                 f"images, CAN logs and serial captures for monitor --log) may be cut, empty "
                 f"or damaged: each is refused with one line naming the file and the line, "
                 f"or the frame of a log. TOML files nest at most {MAX_NESTING} levels and "
                 f"hold numbers of at most {MAX_DIGITS} digits; a module file's counts are "
                 "those modules have (see modules check). A reader of a log or image may "
                 f"grow tmclsh by {size_text(MAX_READ_MEMORY)} at most, and a SIGTERM or "
                 f"SIGHUP ends tmclsh within {SIGNAL_GRACE:g} s whatever it is reading. A log "
                 "without a single frame is an error (exit status 1).")]
    return out


def _configuration() -> list[str]:
    from ..base.config import ENVIRONMENT, OTHER_ENVIRONMENT

    settings, keys = _default_toml()
    out = [".SH CONFIGURATION",
           "The config file is TOML. Unknown tables, keys and profiles, and values of the "
           "wrong type, are errors. Print the commented default with " +
           _b("python3 -m tmclsh.base.config --default") + " and check your file with " +
           _b("python3 -m tmclsh.base.config") + ".",
           ".SS Settings",
           "In the " + _b("[settings]") + " table:"]
    for key, value, comment in settings:
        out += [".TP", f"{_b(key)} = {_esc(value)}", _esc(_sentence(comment))]
    out += [".SS Profiles",
            "A table " + _b("[profiles.") + _i("NAME") + _b("]") + " per profile, selected with " +
            _b("--profile") + " " + _i("NAME") + " or " + _b("TMCLSH_PROFILE") + ". "
            "Command-line options win over environment variables, which win over the "
            "profile, which wins over the built-in defaults. " + _b("port") + ", " +
            _b("can") + " and " + _b("sim") + " exclude each other: the strongest source that "
            "names one of them decides. Keys:"]
    for key, desc in keys.items():
        out += [".TP", _b(key), _esc(_sentence(desc))]
    out += [".PP", "For example:", ".PP", ".RS 4", ".nf",
            "[profiles.bench]", 'port = "/dev/ttyACM0"', "",
            "[profiles.rs485]", 'port = "/dev/ttyUSB0"', "baud = 115200", "address = 3",
            ".fi", ".RE"]
    out += [".SH ENVIRONMENT"]
    for var, key in ENVIRONMENT.items():
        what = "the profile to use" if key == "profile" else keys.get(key, key)
        out += [".TP", _b(var), _esc(_sentence(f"{what}; like --{key.replace('_', '-')}"
                                               if key != "ascii" else
                                               f"{what}; 1/true/yes or 0/false/no"))]
    for var, text in OTHER_ENVIRONMENT.items():
        out += [".TP", _b(var), _esc(_sentence(text))]
    return out


_BACKUPS = f"""\
.SH CONFIGURATION BACKUPS
{_b(".save")} {_i("FILE")} writes a module's configuration as a tmclsh script, so the same file
is a backup, a record of what changed and a way to set up a replacement module:
.PP
.nf
// tmclsh configuration backup of a TMCM\\-1311 (.save); ...
// module: TMCM\\-1311
// firmware: 1311V111
// address: 1
// connection: /dev/ttyACM0 at 9600 baud (binary)
// date: 2026\\-12\\-01 19:40:00 UTC
// program: backup.program.tmcl        (only with \\-\\-program)

// \\-\\- axis parameters, motor 0
// ActualPosition = 51200 µsteps (state, not restored; AP 1, µsteps: ...)
SAP MaxPositioningSpeed, 0, 51200  // AP 4, pps: Speed limit for positioning ...
// \\-\\- global parameters, bank 2
SGP 0, 2, 0  // GP 0: UserVariable #0
.fi
.PP
The {_b("// key: value")} lines of the header are read back by {_b(".diff")} and
{_b(".restore")}: {_b("module")} decides whether the file is another module type's.
Each {_b("SAP")}/{_b("SGP")} line is one writable configuration parameter of one motor or
bank, by name (a run of user variables by number), with its number, unit and meaning after
{_b("//")}. Read\\-only values and motion state (parameters marked {_b("state")} in the module
data: target and actual position and speed, counters, writes that start a move or an
initialisation) are comments and are never written back.
.PP
A clone carries the configuration, not the module's place on its line. Its link identity
(parameters marked {_b("link")} in the module data: serial address, baud rate, host address,
CAN ids, bit rate and secondary address, ASCII start\\-up mode, telegram pause, serial
heartbeat, interface selection) is written in a last section of its own,
{_b("// -- link identity: where this module sits on its line")}. {_b(".restore")},
{_b(".diff")} and a replayed backup ({_b("-f")} or {_b(".source")} of a file whose first line
is the backup header) leave those lines alone and name them ("left alone, the module's own
place on its line"), so a backup of the module at address 1 restored onto the one at address
5 leaves it at address 5. {_b("--with-link")} ({_b(".restore")}, {_b(".diff")}, and
{_b("tmclsh -f")} {_i("FILE")} {_b("--with-link")}) carries them: {_b(".restore")} asks naming
each that changes, old and new, writes them after everything else and follows a new
address, host address or CAN id as a typed {_b("SGP")} is ("the module answers at address N
now"), then reads them back there. A setting that may cut the link in use with nothing to
follow (marked {_b("breaks")}: the CAN bit rate on CAN, the ASCII echo while talking ASCII,
the interface selection) is written last and not read back: reconnect with it.
.PP
A backup replayed with {_b("-f")} stops, as any script, at the first line the module refuses,
and then points to {_b("--keep-going")} (replay the rest) and {_b(".restore")} (write what
differs, listing every refusal); another module type's backup is refused before anything is
sent, saying whose backup it is and pointing to {_b(".restore")} {_i("FILE")} {_b("--force")}.
.PP
A module known by parameter names only (a module file imported from PyTrinamic: no ranges,
every parameter {_b("state")}) has nothing a backup could restore: {_b(".save")} names what it
could not save and fails; {_b(".save")} {_i("FILE")} {_b("--names-only")} writes the values as
comments all the same.
.PP
{_b(".diff")} and {_b(".restore")} accept any script of {_b("SAP")}/{_b("SGP")} lines (by
name or number, or as raw command 5 or 9; several on a line split by {_b(";")} as in {_b("-f")}), checked
whole against the module's data as typed commands would be, before anything is sent.
Comments ({_b("//")}, {_b("#")}) and blank lines are all a file may hold besides: any other
line (a typo, another TMCL command, a shell command, a line with {_b("${...}")}, a label), a
value out of range, a read\\-only parameter or a motor the module lacks is an error naming
{_i("FILE")}{_b(":")}{_i("LINE")}, as {_b("-f")} says it, and in {_b("-c")} the exit status is 2
when nothing was sent; so is a file with no SAP/SGP line at all, or longer than a script
may be. For a parameter set twice the last line counts. Parameters are compared by
number and motor/bank; a backup of another module type is carried over by name with
{_b("--force")} (parameters the module lacks, motors it does not have and values outside its
ranges are skipped and listed). A module without parameter data compares by number.
.PP
{_b(".save")} over a file that exists asks first (naming the module and date its header
gives); in {_b("-c")} and {_b("-f")} it is refused unless {_b("--yes")}.
.PP
Replaying the file with {_b("tmclsh -f")} {_i("FILE")} {_b("--yes")} writes every line but
the link identity's (global parameters of bank 0 go straight to EEPROM, hence {_b("--yes")}); {_b(".restore")}
writes only what differs. With {_b("--program")} the stored program is read back and written
as source to {_i("FILE")}{_b(".program.tmcl")} (the suffix of {_i("FILE")} replaced), which
{_b(".upload")} puts back; {_b(".restore")} does not upload it.
"""


_UNITS = f"""\
.SH SEVERAL MODULES
A test jig or a production line runs the same {_b("-c")} lines or {_b("-f")} script on every
module it holds. Each (link, address) pair is a unit: {_b("--port")} given again (modules on
their own ports), {_b("--all")} (every Trinamic USB module attached), {_b("--address")}
{_i("LIST")} (modules on one RS485 line), {_b("--can-id")} {_i("LIST")} (modules on one CAN
bus; {_b("--reply-id")} one for all or one each); a {_i("LIST")} is {_b("1,2,5")}, a range
{_b("1-8")} or both. Several ports with several addresses make every pair a unit. The prompt
takes one module; {_b("-f -")} is read once, so several units need a script file.
.PP
Units on different links run at the same time; units on one line or bus take turns (it
carries one exchange at a time), in the order given. Each unit has its own session: its own
variables, among them {_b("unit")} (1, 2, ...), {_b("port")} (the port, CAN bus or simulated
module, text: {_b("${port}")} puts it into a line) and {_b("address")} (the CAN id on CAN),
which a run of one module has too; its own checks and counts; its lines checked against its
own module type before anything is sent to it (a line its type refuses fails that unit
before its run). A unit that has no module, loses its link or fails a line fails alone;
{_b("--keep-going")} works for each as for one module.
.PP
On a terminal a live table shows every unit: link and address, module and firmware, the
line reached of how many (the file's line numbers, as in its errors' FILE:LINE), checks passed
and failed, errors, the result, the time and the last error; what a unit says on standard error is printed above it, with the unit in front; its
results are not (see {_b("--log-dir")}). In a pipe or a file every line starts with its unit,
{_b("[2 /dev/ttyACM1]")} or {_b("[3 /dev/ttyUSB0 @3]")}. With {_b("--json")} every object
starts with {_b('"unit"')} and {_b('"port"')} and {_b('"address"')} (on CAN
{_b('"can"')} and {_b('"can_id"')}, for a simulated module {_b('"sim"')}), and
each unit ends with a summary object: {_b('"summary": true')}, {_b('"result"')}
(passed, failed, refused, no module, stopped, not run), {_b('"exit"')} (the exit status
of the unit alone), {_b('"module"')}, {_b('"firmware"')}, {_b('"line"')},
{_b('"of"')}, {_b('"commands"')}, {_b('"checks_passed"')},
{_b('"checks_failed"')}, {_b('"errors"')}, {_b('"error"')} (the last one) and
{_b('"seconds"')}. One summary table ends the run (on standard error under
{_b("--json")}). {_b("--log-dir")} {_i("DIR")} writes one transcript per unit,
{_b("unit-01-dev-ttyACM0.log")}: every frame sent and answered as {_b("--trace")} shows it and
every line the unit showed, each with the time.
.PP
Exit status: 0 when every unit passed, 1 when any failed, 3 when a unit had no module (the
last line on standard error names them), 2 when every unit refused the lines before anything
was sent. Ctrl\\-C, SIGTERM and SIGHUP stop every unit that runs, each stopping its module's
program and motors as one run does and saying so; units not started yet are not started.
.PP
Fresh modules all answer at address 1: on a shared line give them their addresses one at a
time (plug one in, {_b("SGP 66, 0,")} {_i("N")}, plug in the next); {_b("tmclsh scan")} then
says if two still answer at one address.
"""


_WINDOWS_CONFIG = "%LOCALAPPDATA%\\tmclsh"
_INVENTORY = f"""\
.SH LINE INVENTORY
{_b("tmclsh scan")} {_b("--save")} {_i("INVENTORY")} writes what answered as a TOML file, one
{_b("[[module]]")} entry per module; {_b("tmclsh scan")} {_b("--expect")} {_i("INVENTORY")}
compares the line with it after a module was swapped or the line rewired:
.PP
.nf
[[module]]
address = 1                # can_id = 1 on a CAN bus
type = "TMCM\\-1311"         # or the type number of a module tmclsh does not know
firmware = "1311V111"      # exactly; or lowest = "1311V110": that or newer
mode = "binary"            # or "ascii"
backup = "axis1.tmcl"      # optional: a .save file its settings must match
.fi
.PP
The inventory is read (at most 1 MiB) and checked whole before anything is sent: an unknown
key, a module type tmclsh does not know, an address named twice or outside {_b("--from")}..{_b("--to")}
is one error line and exit status 2. A backup is named relative to the inventory's folder.
.PP
Every difference is named: {_b("missing")} (nothing answered), {_b("extra")} (a module the
inventory does not name), {_b("doubled")} (two modules answer at one address; nothing else
is compared there), {_b("bootloader")} (a firmware update did not complete), {_b("type")}
(another type; its firmware is not compared), {_b("firmware")}, {_b("mode")} (in ASCII mode
where binary was expected, or the reverse) and {_b("settings")} (parameters that differ from
the backup, each named with its saved and live value). On a terminal they are a table; in a
pipe one line each ({_b("differs:")} ...), then the count; with {_b("--json")} the scan's rows,
one object per difference ({_b("difference")}, {_b("address")} or {_b("can_id")},
{_b("text")}, {_b("expected")}, {_b("found")}; {_b("settings")} for a backup's) and a last
{{"inventory", "match", "differences"}}. Exit status 0 when the line matches, 1 for any
difference, 3 when nothing answered.
.PP
Nothing is sent that a scan does not send, save that the inventory's addresses silent in
binary are asked in ASCII mode (as {_b("--ascii")} asks every silent address; a module in
ASCII mode is saved by {_b("--ascii")} {_b("--save")}), and that a backup's parameters are
read, never written, from the module it is named for, and only when that module is the type
named, alone at its address, in binary mode and out of its bootloader. From Python:
{_b("tmclsh.ops.inventory")} ({_b("read_inventory")}, {_b("inventory_text")},
{_b("compare")} -> {_b("Check")}).
"""


_PYTHON = f"""\
.SH PYTHON API
The shell's client is a Python API too.
{_b("tmclsh.connect()")} opens a module as the command line does: the one Trinamic USB module
attached (none or several is a {_b("ConnectError")} saying what to give), {_b("port=")} (a
device or a URL), {_b("can=")} ({_i("IFACE:CHANNEL")}), or the simulator only when asked,
{_b("sim=")}; further arguments {_b("module")}, {_b("address")}, {_b("host_address")},
{_b("timeout")}, {_b("retries")}, {_b("baud")}, {_b("bitrate")}, {_b("can_id")},
{_b("reply_id")}, {_b("ascii")} (a value out of range is refused before anything is opened).
The client is a context manager.
.TP
{_b("c.execute(")}{_i("line")}{_b(")")}
A TMCL line as at the prompt, checked against the module's data first; returns a result with
{_b(".value")}, {_b(".reply")} and {_b(".ok")}; {_b("StatusError")} when the module answers
with an error status. {_b("!")} before the line sends its value as typed.
.TP
{_b("c.value(")}{_i("line")}{_b(")")}
The reply's value of a line ({_b('c.value("GAP ActualPosition, 0")')}).
.TP
{_b("c.send(")}{_i("opcode, type, motor, value")}{_b(")")}
A raw command, no checks; the reply's status is returned, not raised.
.PP
Every error is a {_b("TmclError")}: {_b("TmclTimeoutError")} (also a TimeoutError) when the
module does not answer, {_b("TransportError")} when the link is lost, {_b("RangeError")} for a
value the module does not accept and {_b("ValidationError")} for any other line refused before
anything was sent. They, the client and the operations a script needs without the shell
(firmware, scan, stored programs, the stop, CAN logs and traffic) import from
{_b("tmclsh")}; its {_b("__all__")} lists them, and anything else is private. Module paths of
earlier releases ({_b("tmclsh.errors")}, {_b("tmclsh.protocol")}, ...) still import, with a
DeprecationWarning naming the new place. \\fBscripts/api\\-docs\\fR in the source tree builds
the reference from the docstrings; {_b("examples/")} holds the first tasks as scripts.
"""

_FILES = f"""\
.SH FILES
.TP
{_i("$XDG_CONFIG_HOME")}{_b("/tmclsh/config.toml")}
The config file (default {_b("~/.config/tmclsh/config.toml")}; {_b("TMCLSH_CONFIG")} overrides).
On macOS the directory is {_b("~/Library/Application Support/tmclsh")}, on Windows
{_b(_WINDOWS_CONFIG)} (the platform's config directory).
.TP
{_i("$XDG_CONFIG_HOME")}{_b("/tmclsh/modules/*.toml")}
Module files of your own (see MODULE FILES), in the same config directory.
.TP
{_i("$XDG_STATE_HOME")}{_b("/tmclsh/history")}
Command history of the interactive prompt (default {_b("~/.local/state/tmclsh/history")}; the
platform's state directory elsewhere), cut to {_b("history_size")} entries at each start; only
its newest few MiB are read, and anything but a regular file is left alone (the history is
then kept in memory).
.TP
{_i("$XDG_CACHE_HOME")}{_b("/tmclsh/programs/")}
The source of each program uploaded with {_b(".upload")}, keyed by a hash of its image, so
that {_b(".dump")} can show the original labels and comments while the module's memory holds
exactly that image (default {_b("~/.cache/tmclsh/programs/")}; the user cache directory of
the platform elsewhere). Safe to delete.
.TP
{_i("$XDG_CACHE_HOME")}{_b("/tmclsh/data/")}
The instruction set and module tables as parsed at the first start (default
{_b("~/.cache/tmclsh/data/")}); kept under each data file's content hash, safe to delete.
.TP
{_i("prefix")}{_b("/share/bash-completion/completions/tmclsh")}
.TQ
{_i("prefix")}{_b("/share/zsh/site-functions/_tmclsh")}
.TQ
{_i("prefix")}{_b("/share/fish/vendor_completions.d/tmclsh.fish")}
The completions for bash, zsh and fish, installed with the package ({_i("prefix")} is the
virtual environment or the installation prefix). Recent bash\\-completion versions find them
next to the tmclsh they complete, fish when {_i("prefix")}{_b("/share")} is in
{_b("XDG_DATA_DIRS")} (a system or user install). zsh finds them in a system prefix; for a
virtual environment add {_b("fpath=(")}{_i("prefix")}{_b("/share/zsh/site-functions $fpath)")}
to {_b("~/.zshrc")} before {_b("compinit")}, and for fish add
{_b("set -p fish_complete_path")} {_i("prefix")}{_b("/share/fish/vendor_completions.d")}.
Or load them from tmclsh itself: {_b("tmclsh --completions")} {_i("SHELL")}.
.TP
{_i("prefix")}{_b("/share/man/man1/tmclsh.1")}
This manual. An editable install ({_b("pip install -e")}) installs no manual, so
{_b("man tmclsh")} cannot find it: read it with {_b("tmclsh --man")} (formatted by
{_b("man")}, plain text in a pipe), or
{_b("man ./man/tmclsh.1")} in the source tree.
"""


def _module_files() -> list[str]:
    from ..tmcl.modules.schema import IO_KEYS, MEANINGS, MODULE_KEYS, PARAMETER_KEYS

    out = [".SH MODULE FILES",
           "A module tmclsh has no data for still works: when its 136 answer names another "
           "type (" + _b("1161V130") + "), or with " + _b("-m generic") + ", the shell runs in "
           "generic mode: banner and toolbar say " + _b("TMCM-1161 (no parameter data: "
           "numbers only)") + ", commands go by number with the commands every documented "
           "module has, types and motors are checked as bytes and values as 32 bits, names "
           "of parameters are refused, and ranges, read-only parameters and motor numbers are "
           "not checked (said once at the start).",
           ".PP",
           "To give tmclsh the data, write a module file: TOML in the same form as the "
           "built-in ones, in the config directory's " + _b("modules/") + " (every " +
           _b("*.toml") + " there is read) or named with " + _b("--module-file") + " " +
           _i("PATH") + ". A module is matched by its " + _b("version_string") + ", then by " +
           _b("firmware_id") + ", like the built-in ones. Each file is checked when it is "
           "read; a mistake is one line naming the file and the line, and tmclsh goes on "
           "without that file. Check one with " + _b("tmclsh modules check") + " " +
           _i("FILE") + ". The tables and their keys (* required):"]
    for title, keys, meaning in (("[module]", MODULE_KEYS, MEANINGS["module"]),
                                 ("[[axis]] and [[global]], one per parameter", PARAMETER_KEYS,
                                  MEANINGS["axis"]),
                                 ("[[io]], one per I/O port", IO_KEYS, MEANINGS["io"])):
        out += [".TP", _b(title),
                _esc(", ".join(k + ("*" if req else "") for k, (_, req) in keys.items()) + ".")]
        for key, text in meaning.items():
            out += [".RS 4", ".TP", _b(key), _esc(_sentence(text)), ".RE"]
    out += [".PP", "For example:", ".PP", ".RS 4", ".nf",
            "[module]", 'name = "TMCM\\-1161"', "motors = 1", "program_memory = 2048",
            "firmware_id = 1161", 'version_string = "1161V130"', 'commands_like = "TMCM\\-1311"',
            "", "[[axis]]", "number = 4", 'name = "MaxPositioningSpeed"', 'access = "RWE"',
            "min = 0", "max = 2047", ".fi", ".RE",
            ".PP", "The full schema, with every optional key, is tmclsh/tmcl/modules/SCHEMA.md in "
            "the source."]
    return out


_IMAGES = f"""\
.SH PROGRAM IMAGES
.TP
{_b("Binary (.bin)")}
The TMCL\\-IDE's image, as its assembler writes it and PyTrinamic's LoadTMCLBinary reads it:
one 8\\-byte record per instruction: command, type, motor or bank, value (4 bytes, most
significant first), then a checksum, the 8\\-bit sum of those seven bytes.
{_b("asm")} writes it, {_b("disasm")}, {_b(".upload")} and {_b(".source-map")} read it, and
{_b(".dump")} {_i("FILE")}{_b(".bin")} writes what the module holds. A record whose checksum is
wrong is refused, naming the record and the checksum it should have; nothing is sent.
.TP
{_b("Hex text (.hex, asm --hex)")}
One instruction per line: its seven bytes in hex, separated by spaces, no checksum
({_b("05 04 00 00 00 03 e8")} is SAP 4, 0, 1000).
"""


def manpage(parser: argparse.ArgumentParser | None = None) -> str:
    """The man page, tmclsh(1), in roff (man macros)."""
    top, subs = describe(parser)
    out = [
        ".\\\" Generated by scripts/gen-docs (python -m tmclsh.cli.docs) from tmclsh's argument",
        ".\\\" parser, its shell command registry and its data files. Do not edit.",
        f'.TH TMCLSH 1 "" "tmclsh {__version__}" "User Commands"',
        ".nh",
        ".ad l",
        ".SH NAME",
        "tmclsh \\- interactive shell for Trinamic TMCL motor\\-control modules",
        ".SH SYNOPSIS",
        *_synopsis(top, subs),
        _DESCRIPTION.replace("{modules}", ", ".join(module_names())).rstrip("\n"),
        ".SH OPTIONS",
    ]
    for g in top.groups:
        head, _, note = g.title.partition(" (")
        if g.default and len(top.groups) > 1:
            head = "other options"
        out.append(f".SS {_esc(head[:1].upper() + head[1:])}")
        if note:
            out.append(_esc(_sentence(note.rstrip(")"))))
        out += _options_block(g.options, top=True)
    out.append(".SH SUBCOMMANDS")
    for s in subs:
        out += [f".SS {s.name}", _usage(s), ".PP", _esc(_sentence(s.help))]
        if s.name in _SUB_NOTES:
            out.append(_esc(_SUB_NOTES[s.name]))
        for p in s.positionals:
            if p.help:
                out += [".TP", _i(p.name), _esc(_sentence(p.help))]
        for g in s.groups:
            if _summarised(g):
                out += [".TP", _i(g.title.split()[0]),
                        _esc(f"The {g.title.split()[0]} options of tmclsh itself: ") +
                        ", ".join(_b(o.long) for o in g.options) + "."]
            else:
                out += _options_block((o for o in g.options if o.dest != "help"), top=False)
    out.append(_LANGUAGE.rstrip("\n"))
    out += _shell_commands_section()
    out += _instructions_section()
    out += _configuration()
    out.append(_BACKUPS.rstrip("\n"))
    out.append(_UNITS.rstrip("\n"))
    out.append(_INVENTORY.rstrip("\n"))
    out += _limits()
    out.append(_PYTHON.rstrip("\n"))
    out.append(_FILES.rstrip("\n"))
    out += _module_files()
    out.append(_IMAGES.rstrip("\n"))
    out += _exit_status()
    out.append(_EXAMPLES.rstrip("\n"))
    out += [".SH SEE ALSO",
            "The TMCL firmware manual of your module; "
            "pyserial's URL handlers (socket://, rfc2217://, spy://); python\\-can's interfaces."]
    return "\n".join(line for line in out) + "\n"


# -- completions --------------------------------------------------------------------------

_HEADER = ("{c} {shell} completion for tmclsh. Generated by scripts/gen-docs (python -m tmclsh.cli.docs)\n"
           "{c} from tmclsh's argument parser; do not edit. Also printed by: tmclsh --completions {shell}\n")

_PROFILE_SED = r"""s/^[[:space:]]*\[[[:space:]]*profiles\.[[:space:]]*"\{0,1\}\([^]".[:space:]]*\)"\{0,1\}[[:space:]]*\].*/\1/p"""


def _sq(text: str) -> str:
    """Single-quote for POSIX shells."""
    return shlex.quote(text)


def bash_completion(parser: argparse.ArgumentParser | None = None) -> str:
    top, subs = describe(parser)
    sub_names = " ".join(s.name for s in subs)

    def kinds(cmd: CommandLine) -> list[str]:
        lines = []
        for o in cmd.options:
            if not o.takes_value:
                continue
            kind = o.kind or "value"
            if kind == "choices":
                kind = "choices:" + " ".join(o.choices or ())
            if o.optional:
                kind = "optional:" + kind
            lines.append(f"            {'|'.join(o.flags)}) echo {_sq(kind)} ;;")
        return lines

    case_lines = []
    for cmd in [top, *subs]:
        case_lines.append(f"        {cmd.name or '-'})")
        case_lines.append('            case $2 in')
        case_lines += kinds(cmd)
        case_lines.append("            *) echo none ;;")
        case_lines.append("            esac ;;")
    opt_lines = [f"        {cmd.name or '-'}) echo {_sq(' '.join(f for o in cmd.options for f in o.flags))} ;;"
                 for cmd in [top, *subs]]
    pos_lines = []
    for cmd in subs:
        if cmd.positionals:
            pos_lines.append(f"        {cmd.name}) echo {cmd.positionals[0].kind or 'value'} ;;")
    return _HEADER.format(c="#", shell="bash") + f"""\
# Install: copy to ~/.local/share/bash-completion/completions/tmclsh, or: source <(tmclsh --completions bash)

_tmclsh_ports() {{
    local p
    for p in {' '.join(PORT_GLOBS)}; do
        [[ -e $p ]] && printf '%s\\n' "$p"
    done
    printf '%s\\n' {' '.join(URL_SCHEMES)}
}}

_tmclsh_profiles() {{
    local f=${{TMCLSH_CONFIG:-${{XDG_CONFIG_HOME:-$HOME/.config}}/tmclsh/config.toml}}
    [[ -r $f ]] && sed -n '{_PROFILE_SED}' "$f"
}}

_tmclsh_modules() {{
    printf '%s\\n' {' '.join(module_names())}
}}

_tmclsh_can() {{
    printf '%s:\\n' {' '.join(can_interfaces())}
}}

# what the value of option $2 of subcommand $1 ('-' = none) is: none, value, a kind
# (ports, modules, can, profiles, files, choices:A B C), optionally prefixed by optional:
_tmclsh_kind() {{
    case $1 in
{chr(10).join(case_lines)}
    esac
}}

_tmclsh_options() {{
    case $1 in
{chr(10).join(opt_lines)}
    esac
}}

_tmclsh_positional() {{
    case $1 in
{chr(10).join(pos_lines) if pos_lines else '        *) ;;'}
    esac
}}

_tmclsh_values() {{  # candidates of kind $1
    case $1 in
        ports) _tmclsh_ports ;;
        modules) _tmclsh_modules ;;
        can) _tmclsh_can ;;
        profiles) _tmclsh_profiles ;;
        choices:*) printf '%s\\n' ${{1#choices:}} ;;
    esac
}}

_tmclsh() {{
    COMPREPLY=()
    # Join the pieces bash split at ':' and '=' (when in COMP_WORDBREAKS), so
    # --can socketcan:can0 and --port=/dev/ttyACM0 are one word each.
    local brk=""
    [[ $COMP_WORDBREAKS == *:* ]] && brk+=:
    [[ $COMP_WORDBREAKS == *=* ]] && brk+==
    local -a words=()
    local i w n cword=0
    for ((i = 0; i < ${{#COMP_WORDS[@]}}; i++)); do
        w=${{COMP_WORDS[i]}}
        n=${{#words[@]}}
        if ((n > 1)) && [[ -n $brk && ( $w == [$brk]* || ${{words[n-1]}} == *[$brk] ) ]]; then
            words[n-1]+=$w
        else
            words+=("$w")
        fi
        ((i == COMP_CWORD)) && cword=$((${{#words[@]}} - 1))
    done
    local cur=${{words[cword]}} keep=""
    # readline replaces only what follows the word's last break: candidates must not repeat it
    [[ -n $brk && $cur == *[$brk]* ]] && keep=${{cur%"${{cur##*[$brk]}}"}}

    # the subcommand, skipping option values
    local sub=- kind
    for ((i = 1; i < cword; i++)); do
        w=${{words[i]}}
        case $w in
            --*=*) ;;
            -*)
                kind=$(_tmclsh_kind - "$w")
                case $kind in
                    none) ;;
                    optional:*) [[ ${{words[i+1]}} != -* && " {sub_names} " != *" ${{words[i+1]}} "* ]] && ((i++)) ;;
                    *) ((i++)) ;;
                esac ;;
            *)
                [[ " {sub_names} " == *" $w "* ]] && sub=$w
                break ;;
        esac
    done

    local opt="" value=$cur prefix=""
    if [[ $cur == --*=* ]]; then
        opt=${{cur%%=*}} value=${{cur#*=}} prefix=$opt=
    elif ((cword > 1)) && [[ ${{words[cword-1]}} == -* && ${{words[cword-1]}} != *=* ]]; then
        opt=${{words[cword-1]}}
        kind=$(_tmclsh_kind "$sub" "$opt")
        [[ $kind == optional:* && $cur == -* ]] && opt=""
    fi
    if [[ -n $opt ]]; then
        kind=$(_tmclsh_kind "$sub" "$opt")
        kind=${{kind#optional:}}
        if [[ $kind != none ]]; then
            if [[ $kind == files ]]; then
                compopt -o filenames 2>/dev/null
                mapfile -t COMPREPLY < <(compgen -f -- "$value")
            elif [[ $kind == can && $value == *:* ]]; then
                :  # the channel after IFACE: is the user's
            else
                mapfile -t COMPREPLY < <(compgen -W "$(_tmclsh_values "$kind")" -- "$value")
            fi
            [[ -n $prefix ]] && COMPREPLY=("${{COMPREPLY[@]/#/$prefix}}")
            _tmclsh_trim "$keep"
            return 0
        fi
    fi

    if [[ $cur == -* ]]; then
        mapfile -t COMPREPLY < <(compgen -W "$(_tmclsh_options "$sub")" -- "$cur")
    elif [[ $sub == - ]]; then
        mapfile -t COMPREPLY < <(compgen -W {_sq(sub_names)} -- "$cur")
    elif [[ $(_tmclsh_positional "$sub") == files ]]; then
        compopt -o filenames 2>/dev/null
        mapfile -t COMPREPLY < <(compgen -f -- "$cur")
    fi
    _tmclsh_trim "$keep"
    return 0
}}

# Drop what bash keeps of the word from the candidates; no space after 'x:', 'x//' or 'x='.
_tmclsh_trim() {{
    local keep=$1 i
    if [[ -n $keep ]]; then
        for i in "${{!COMPREPLY[@]}}"; do
            COMPREPLY[i]=${{COMPREPLY[i]#"$keep"}}
        done
    fi
    if ((${{#COMPREPLY[@]}} == 1)) && [[ ${{COMPREPLY[0]}} == *[:/=] ]]; then
        compopt -o nospace 2>/dev/null
    fi
}}

complete -F _tmclsh tmclsh
"""


def _zsh_desc(text: str) -> str:
    text = text.replace("\\", "\\\\").replace("[", "\\[").replace("]", "\\]").replace(":", "\\:")
    return text.replace("'", "'\\''")


def _zsh_action(o: Option | Positional) -> str:
    kind = o.kind
    if kind == "files":
        return "_files"
    if kind in ("ports", "modules", "can", "profiles"):
        return f"_tmclsh_{kind}"
    if kind == "choices" and isinstance(o, Option):
        return "(" + " ".join(o.choices or ()) + ")"
    return " "


def _zsh_specs(cmd: CommandLine) -> list[str]:
    specs = []
    for o in cmd.options:
        excl = set(o.flags) | set(o.excludes)
        if o.dest in ("help", "version"):
            excl = {"- *"}
        excl_text = "(" + " ".join(sorted(excl)) + ")"
        desc = f"[{_zsh_desc(o.help)}]" if o.help else ""
        arg = ""
        if o.takes_value:
            meta = _zsh_desc(o.metavar or "")
            colon = "::" if o.optional else ":"
            arg = f"{colon}{meta}:{_zsh_action(o)}"
        names = []
        for f in o.flags:
            if o.takes_value:
                names.append(f + ("+" if len(f) == 2 else "="))
            else:
                names.append(f)
        if len(names) == 1:
            specs.append(f"'{excl_text}{names[0]}{desc}{arg}'")
        else:
            specs.append(f"'{excl_text}'{{{','.join(names)}}}'{desc}{arg}'")
    for n, p in enumerate(cmd.positionals, 1):
        specs.append(f"'{n}:{_zsh_desc(p.name)}:{_zsh_action(p)}'")
    return specs


def zsh_completion(parser: argparse.ArgumentParser | None = None) -> str:
    top, subs = describe(parser)
    ind = " \\\n    "
    top_specs = ind.join(["-S", *_zsh_specs(top), "'1: :->subcommand'", "'*:: :->args'"])
    sub_list = "\n".join(f"        {_sq(s.name + ':' + s.help.replace(':', chr(92) + ':'))}" for s in subs)
    sub_cases = []
    for s in subs:
        specs = (" \\\n                ").join(["-S", *_zsh_specs(s)])
        sub_cases.append(f"            {s.name})\n                _arguments {specs} && ret=0 ;;")
    return "#compdef tmclsh\n" + _HEADER.format(c="#", shell="zsh") + f"""\
# Install: put it in a directory of $fpath (e.g. ~/.zfunc, with fpath=(~/.zfunc $fpath)
# before compinit), or: source <(tmclsh --completions zsh) after compinit.

_tmclsh_ports() {{
    local -a ports
    ports=( {' '.join(g.replace('*', '*(N)') for g in PORT_GLOBS)} )
    _describe -t ports 'serial port' ports
    compadd -S '' -- {' '.join(URL_SCHEMES)}
}}

_tmclsh_modules() {{
    compadd -- {' '.join(module_names())}
}}

_tmclsh_can() {{
    compadd -S : -- {' '.join(can_interfaces())}
}}

_tmclsh_profiles() {{
    local f=${{TMCLSH_CONFIG:-${{XDG_CONFIG_HOME:-$HOME/.config}}/tmclsh/config.toml}}
    [[ -r $f ]] || return 1
    local -a names
    names=( ${{(f)"$(sed -n '{_PROFILE_SED}' "$f")"}} )
    compadd -a names
}}

_tmclsh() {{
    local curcontext=$curcontext state state_descr line ret=1
    typeset -A opt_args
    _arguments -C {top_specs} && ret=0
    case $state in
        subcommand)
            local -a subcommands=(
{sub_list}
            )
            _describe -t subcommands 'tmclsh subcommand' subcommands && ret=0 ;;
        args)
            curcontext=${{curcontext%:*:*}}:tmclsh-$line[1]:
            case $line[1] in
{chr(10).join(sub_cases)}
            esac ;;
    esac
    return ret
}}

if [[ $funcstack[1] == _tmclsh ]]; then
    _tmclsh "$@"
else
    compdef _tmclsh tmclsh
fi
"""


def _fish_q(text: str) -> str:
    return "'" + text.replace("\\", "\\\\").replace("'", "\\'") + "'"


def fish_completion(parser: argparse.ArgumentParser | None = None) -> str:
    top, subs = describe(parser)
    sub_names = " ".join(s.name for s in subs)
    lines = [
        "complete -c tmclsh -f",
        "",
        "# subcommands",
    ]
    for s in subs:
        lines.append(f"complete -c tmclsh -n __fish_use_subcommand -a {s.name} -d {_fish_q(s.help)}")

    def opt_line(cond: str, o: Option) -> str:
        parts = ["complete -c tmclsh", f"-n {_fish_q(cond)}"]
        for f in o.flags:
            parts.append(f"-l {f[2:]}" if f.startswith("--") else f"-s {f[1:]}")
        if o.takes_value:
            kind = o.kind
            if kind == "files":
                parts.append("-r -F")
            elif kind == "choices":
                parts.append("-x -a " + _fish_q(" ".join(o.choices or ())))
            elif kind in ("ports", "modules", "can", "profiles"):
                parts.append(f"-x -a '(__tmclsh_{kind})'")
            else:
                parts.append("-x")
        parts.append(f"-d {_fish_q(o.help)}")
        return " ".join(parts)

    lines += ["", "# options of tmclsh itself"]
    for o in top.options:
        lines.append(opt_line(f"not __fish_seen_subcommand_from {sub_names}", o))
    for s in subs:
        lines += ["", f"# tmclsh {s.name}"]
        cond = f"__fish_seen_subcommand_from {s.name}"
        for o in s.options:
            lines.append(opt_line(cond, o))
        if s.positionals and s.positionals[0].kind == "files":
            lines.append(f"complete -c tmclsh -n {_fish_q(cond)} -F")
    fish_profile_re = r'^\s*\[\s*profiles\.\s*"?([^\]".\s]+)"?\s*\].*$'
    return _HEADER.format(c="#", shell="fish") + f"""\
# Install: copy to ~/.config/fish/completions/tmclsh.fish, or: tmclsh --completions fish | source

function __tmclsh_ports
    for p in {' '.join(PORT_GLOBS)}
        printf '%s\\tserial port\\n' $p
    end
    printf '%s\\tpyserial URL\\n' {' '.join(URL_SCHEMES)}
end

function __tmclsh_modules
    printf '%s\\tmodule\\n' {' '.join(module_names())}
end

function __tmclsh_can
    printf '%s:\\tpython-can interface\\n' {' '.join(can_interfaces())}
end

function __tmclsh_profiles
    set -l f $TMCLSH_CONFIG
    if test -z "$f"
        set -l base $XDG_CONFIG_HOME
        test -n "$base"; or set base $HOME/.config
        set f $base/tmclsh/config.toml
    end
    test -r "$f"; or return 0
    string replace -rf {_fish_q(fish_profile_re)} '$1\\tprofile' < $f
end

""" + "\n".join(lines) + "\n"


def completion_script(shell: str, parser: argparse.ArgumentParser | None = None) -> str:
    """The completion script for ``shell`` (bash, zsh or fish); ``tmclsh --completions SHELL``."""
    makers: dict[str, Callable[[argparse.ArgumentParser | None], str]] = {
        "bash": bash_completion, "zsh": zsh_completion, "fish": fish_completion}
    if shell not in makers:
        raise ValueError(f"no completion for {shell!r}; choose one of {', '.join(SHELLS)}")
    return makers[shell](parser)


def generate(what: str, parser: argparse.ArgumentParser | None = None) -> str:
    """``man``, ``bash``, ``zsh`` or ``fish``."""
    return manpage(parser) if what == "man" else completion_script(what, parser)


def stale(root: Path) -> list[str]:
    """The generated files under ``root`` that differ from what the generator makes now."""
    return [rel for rel, what in OUTPUTS.items()
            if not (root / rel).is_file()
            or (root / rel).read_text(encoding="utf-8") != generate(what)]


def write_all(root: Path) -> list[str]:
    """Regenerate every file under ``root``; return the ones that changed."""
    changed = []
    for rel, what in OUTPUTS.items():
        path = root / rel
        text = generate(what)
        if path.is_file() and path.read_text(encoding="utf-8") == text:
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(path)
        changed.append(rel)
    return changed


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tmclsh.cli.docs",
                                description="Generate tmclsh's man page and shell completions.")
    p.add_argument("what", nargs="?", choices=("man", *SHELLS),
                   help="print one file instead of writing them all")
    p.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[2],
                   help="repository root to write to (default: the one holding this package)")
    p.add_argument("--check", action="store_true",
                   help="write nothing; exit 1 if a generated file is out of date")
    args = p.parse_args(argv)
    if args.what:
        sys.stdout.write(generate(args.what))
        return 0
    if args.check:
        bad = stale(args.root)
        for rel in bad:
            print(f"{rel} is out of date; run scripts/gen-docs", file=sys.stderr)
        return 1 if bad else 0
    for rel in write_all(args.root):
        print(f"wrote {rel}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
