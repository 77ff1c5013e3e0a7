"""The dot-commands: one table saying what each is, and the handlers that run them.

The table (``COMMANDS`` below) is plain data: name, syntax, help, completion, category,
details, aliases, bare. ``.help``, the completer, the lexer and the man page read it without
importing a feature module, so ``-c`` and ``-f`` start without the REPL's libraries. A
feature module (``shell/features/``: ``help``, ``scripting``, ...) is imported the first time one of its commands
runs, or when the completer needs a completion function that lives there.

Adding a command is one ``Command(...)`` entry in ``COMMANDS`` plus the handler in its
feature module, registered with ``@command(".name")``; a test fails when either is missing.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable
from dataclasses import KW_ONLY, dataclass, field
from typing import TYPE_CHECKING

from .options import Option

if TYPE_CHECKING:
    from .session import Session

Handler = Callable[["Session", str], None]
# completion of the argument text: returns candidate words (or (word, meta) pairs)
ArgCompleter = Callable[["Session", str], Iterable["str | tuple[str, str]"]]
if TYPE_CHECKING:
    # in the table: words or (word, meta) pairs, or the name of an ArgCompleter in the feature
    Completion = list[str | tuple[str, str]] | str | ArgCompleter | None


@dataclass(eq=False)
class Command:
    """One dot-command. ``feature`` names the module in ``shell/features/`` whose
    ``@command(name)`` is the handler; ``complete`` is a list of words or (word, meta) pairs,
    or the name of a completion function in that module; ``same_as`` names the command whose
    handler this one shares (``.exit`` is ``.quit``), so help lists them together. A new
    property of every command is one more field here (with a default)."""

    name: str
    feature: str
    syntax: str
    help: str
    _: KW_ONLY
    aliases: tuple[str, ...] = ()
    complete: Completion = None
    category: str = "general"
    details: str = ""
    bare: bool = False  # also accepted without the dot (help, quit)
    # the command's arguments may contain ';' (.watch separates its expressions with it), so
    # it takes the rest of its line, up to a ';' a dot-command follows (lines.py); for all
    # others ';' ends the command and starts a new line
    owns_line: bool = False
    same_as: str = ""
    # it may change the module or the mode lines are checked against (.connect, .mode, ...):
    # a script's or -c's lines after it are checked as they run, not before the first
    changes_link: bool = False
    # a lost link is brought back before it runs (False: .connect, .quit, .help, which work
    # without one or make their own)
    reconnects: bool = True
    # the name of a function ``check(session, argtext)`` in the feature module that checks
    # the arguments before a script runs (nothing sent), raising what the command would
    check: str = ""
    # its options (shell/lang/options.py reads them; the completer offers them)
    options: tuple[Option, ...] = ()
    # ``${...}`` in its arguments is replaced before the handler runs (a port, a file name,
    # an address from a variable: ``.connect ${port}``, ``.save unit-${unit}.tmcl``); the
    # others take ``${`` as it stands or expand it themselves where it belongs
    expands: bool = False
    _handler: Handler | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.aliases = tuple(self.aliases)

    def __repr__(self) -> str:
        return f"Command({self.name!r}, {self.feature!r})"

    def names(self) -> tuple[str, ...]:
        return (self.name, *self.aliases)

    @property
    def handler(self) -> Handler:
        """The handler, importing its feature module the first time."""
        if self._handler is None:
            _import_feature(self.feature)
            if self._handler is None:
                raise LookupError(f"{FEATURE_PACKAGE}.{self.feature} has no @command({self.name!r}) "
                                  "handler")
        return self._handler

    def load(self) -> Handler:
        """Import the feature module now (a script's check of the line may live there)."""
        return self.handler

    def checker(self) -> Callable[[Session, str], None] | None:
        """The check of the arguments before a script runs (imported now), if it has one."""
        if not self.check:
            return None
        return getattr(_import_feature(self.feature), self.check)

    def completion(self) -> list | ArgCompleter | None:
        """The argument completion: a list as written, or the feature's function (imported
        now: the completer asks only when the user is completing this command)."""
        source = self.complete
        if isinstance(source, str):
            module = _import_feature(self.feature)
            return getattr(module, source)
        return source


# the folder of the feature modules, beside this one's (``tmclsh.shell.features``)
FEATURE_PACKAGE = __package__.rpartition(".")[0] + ".features"


def _import_feature(feature: str):
    return importlib.import_module(f"{FEATURE_PACKAGE}.{feature}")


def command(name: str, syntax: str | None = None, help: str | None = None, *,
            aliases: Iterable[str] = (), complete: Completion = None,
            category: str = "general", details: str = "", bare: bool = False,
            owns_line: bool = False) -> Callable[[Handler], Handler]:
    """Register ``handler(session, argtext)`` as the handler of ``name`` (with the dot),
    whose entry is in ``COMMANDS``.

    With ``syntax`` and ``help`` a command not in the table is registered on the spot (a test's
    or an experiment's command, known only once its module is imported); feature modules do
    not do that (test_commands checks)."""

    def register(fn: Handler) -> Handler:
        cmd = REGISTRY.get(name)
        if syntax is None:
            if cmd is None:
                raise LookupError(f"{fn.__module__} registers a handler for {name!r}, which has "
                                  "no entry in COMMANDS (tmclsh/shell/lang/commands.py)")
            cmd._handler = fn
        else:
            if cmd is not None and cmd.feature != "":
                raise LookupError(f"{name!r} is described in COMMANDS (tmclsh/shell/"
                                  f"commands.py): register its handler with @command({name!r})")
            add(Command(name, "", syntax, help or "", aliases=tuple(aliases), complete=complete,
                        category=category, details=details, bare=bare, owns_line=owns_line,
                        _handler=fn))
        HANDLERS[name] = fn.__module__
        return fn

    return register


def add(cmd: Command) -> None:
    REGISTRY[cmd.name] = cmd
    for alias in cmd.aliases:
        _ALIASES[alias] = cmd.name


def find(word: str) -> Command | None:
    if word == "?":  # `?` and `? 140` are help, as in most consoles
        word = "help"
    if not word.startswith("."):
        cmd = REGISTRY.get("." + word.lower())
        return cmd if cmd is not None and cmd.bare else None
    word = word.lower()
    return REGISTRY.get(word) or REGISTRY.get(_ALIASES.get(word, ""))


def options_of(name: str) -> tuple[Option, ...]:
    """The options the table declares for the command ``name`` (``.upload``)."""
    cmd = find(name)
    return cmd.options if cmd is not None else ()


def all_commands() -> list[Command]:
    return sorted(REGISTRY.values(), key=lambda c: c.name)


def bare_words() -> list[str]:
    """Commands also accepted without the dot (``help``, ``quit``)."""
    return [c.name[1:] for c in REGISTRY.values() if c.bare]


def load_all() -> None:
    """Import every feature module (all handlers registered): for checks, not for running."""
    for feature in features():
        _import_feature(feature)


def features() -> list[str]:
    return list(dict.fromkeys(c.feature for c in COMMANDS if c.feature))


# -- the table ---------------------------------------------------------------------------

# The categories of .help and the man page, in their order, with their titles.
CATEGORIES: tuple[tuple[str, str], ...] = (
    ("general", "General"), ("parameters", "Parameters"), ("motion", "Motion"),
    ("connection", "Connection and module"), ("protocol", "Protocol"),
    ("ascii", "ASCII mode"), ("configuration", "Configuration backup (clone a module)"),
    ("program", "Stored program (debugger)"), ("script", "Scripts and variables"),
    ("watch", "Watching values"))

# In the order .help's twins and the man page's categories expect: a category's commands
# are listed by name, categories in their first appearance.

COMMANDS: tuple[Command, ...] = (
    Command('.clear', 'help', '.clear',
            'clear the screen; Ctrl-L at the prompt does the same',
            details=('Clears the terminal; in a pipe or a file nothing is written.')),
    Command('.help', 'help', '.help [--source] [COMMAND|MNEMONIC|NUMBER|PARAMETER]',
            'show help: all commands, one command, a TMCL instruction, or a parameter',
            complete='complete_help', bare=True,
            details=('`help SAP` explains an instruction; `help 140` shows axis parameter '
                     '140 (and global parameter 140 if there is one), like `.param 140`. `?` '
                     'is the same as help (`? 140`). Lines: `;` separates commands (`help 4; '
                     'help 5`) except after one that owns its line (.watch, .decode); `#` or '
                     '`//` starts a comment to the end of the line. Questions are answered '
                     'with y and Enter ([y/N]: Enter alone is no). --source also shows how an '
                     'instruction or parameter was read from the module manuals (where they are '
                     'unclear or disagree, and what tmclsh assumes), like .param --source.'),
            reconnects=False,
            options=(Option("--source", help="also how it was read from the manuals"),)),
    Command('.quit', 'help', '.quit',
            'leave the shell (also Ctrl-D)',
            bare=True,
            reconnects=False),
    Command('.exit', 'help', '.exit',
            'leave the shell (same as .quit)',
            bare=True, same_as='.quit',
            reconnects=False),
    Command('.param', 'params', '.param [--source] QUERY',
            'explain a parameter: number, name or part of a name, with its current value',
            complete='complete_param', category='parameters',
            details=('QUERY may be a number (140), a name (MicrostepResolution), part of one '
                     '(microstep) or `ap 140` / `gp 66 [bank]` to pick the kind. The current '
                     'value is read from the module (GAP/GGP) when the parameter is '
                     "readable. --source also shows how the entry was read from the module's "
                     'manual (where the manual is unclear or wrong, and what tmclsh '
                     'assumes).'),
            options=(Option("--source", help="also how it was read from the manual"),)),
    Command('.params', 'params', '.params [axis|global] [FILTER]',
            'table of all parameters with their live values (one GAP/GGP each)',
            complete='complete_params', category='parameters',
            details=('FILTER narrows the list by number or (part of a) name. On a multi-axis '
                     'module each motor gets its own value column.')),
    Command('.trace', 'trace', '.trace [on|off]',
            'show every frame in hex, decoded, on stderr',
            complete=[('on', 'start tracing'), ('off', 'stop tracing')], category='protocol',
            details=('Without an argument it toggles. Lines show time, direction (tx> / '
                     '<rx), the bytes and what they mean. --trace does the same from the '
                     'start.')),
    Command('.decode', 'trace', '.decode [request|reply|memory|version] HEX|CANLINE',
            'decode bytes or a CAN log line pasted from elsewhere: request or reply, '
            'checksum, 134/136 layouts',
            complete=[('request', 'read the bytes as a request'),
                      ('reply', 'read the bytes as a reply'),
                      ('memory', 'a 134 (read program memory) reply'),
                      ('version', 'a 136 version string reply')],
            category='protocol', owns_line=True,
            details=('HEX: `01 06 04 00 00 00 00 00 0b`, `$01 $06 ...`, `0x01,0x06,...` or '
                     '`0106040000...`; several 9-byte frames at once are fine. CANLINE: one '
                     'CAN frame as candump prints it (`can0  001   [7]  06 01 00 00 00 00 '
                     '00`), a candump -L line (`(1.0) can0 001#06010000000000`) or a '
                     'Vector .asc line (`0.0012 1 1 Rx d 7 06 01 00 00 00 00 00`). '
                     'Without a hint every plausible reading is shown. It takes the rest '
                     "of its line (pasted bytes may be separated by ';') up to a ';' that "
                     "another dot-command follows (.decode A; .decode B). tmclsh monitor "
                     'decodes whole logs and live buses.')),
    Command('.connect', 'connection', '.connect [PORT | sim [MODULE] | can [IFACE:CHANNEL]]',
            'reconnect, or switch to another port, simulator or CAN bus',
            complete='complete_connect', category='connection',
            details=('Without an argument the current link is closed and opened again (after '
                     'a cable was pulled). PORT is a device or a URL, as --port takes it '
                     '(.connect socket://192.168.1.20:4001). '
                     'The module type is asked with 136 on a real link. '
                     "'can' alone takes the bus from python-can's configuration, as --can "
                     "does; the bit rate is --bitrate's."),
            changes_link=True,
            reconnects=False,
            expands=True),
    Command('.address', 'connection', '.address [N]',
            'talk to the module with address N on the same bus',
            complete='complete_address', category='connection',
            details=('The new address is checked with a 136 (version) request; if nothing '
                     "answers, the old address stays. Each module is met in the mode it is "
                     "in (binary, or its ASCII mode) and the one left is left in the mode it "
                     "was found in; only an ASCII mode tmclsh was asked for (--ascii, .mode "
                     "ascii) goes on to the next. On CAN, N is the module's CAN id. N "
                     'may be an expression or hold variables, so one script walks a bus: '
                     '.repeat 3 as i / .address i + 1 / GAP 1, 0 / .end. Ctrl-C, SIGTERM '
                     'or SIGHUP in -c and -f stop the module in use, then each module left '
                     'with a motor tmclsh told to turn or move; the note at the end of a '
                     'script and the question at Ctrl-D name each such module too.'),
            changes_link=True,
            expands=True),
    Command('.module', 'connection', '.module [NAME]',
            'show the module type, or override it',
            complete='complete_module', category='connection',
            details=('The type normally comes from the 136 version string. Overriding it '
                     'changes which parameters, ranges and commands the shell checks '
                     'against.'),
            changes_link=True,
            expands=True),
    Command('.version', 'connection', '.version',
            'ask the module for its firmware version (command 136)',
            category='connection',
            details=('Reads the string (136 type 0) and the binary value (type 1), and says '
                     'whether they agree. The\n'
                     'manuals disagree on the byte order of the binary value (type first, as '
                     "the TMCM-1311's; version\n"
                     "first, as the TMCM-1640's): read in the other order when that is the "
                     'one that agrees, and said so.\n'
                     '136 has no ASCII form: in ASCII mode the version read at connect is '
                     'shown (nothing is sent).\n'
                     'JSON: {"version", "binary", "module", "binary_type", "binary_version", '
                     '"agrees"}, and "layout" when read\nin the other order.')),
    Command('.stopall', 'connection', '.stopall',
            'stop everything: the stored program (128) if it runs, then every motor (MST), '
            'each read back until its speed is 0; Ctrl-C does the same',
            category='motion'),
    Command('.repeat', 'scripting', '.repeat COUNT [as NAME]',
            'repeat the following lines until .end',
            category='script',
            details=('Runs the lines up to the matching .end COUNT times (an expression). '
                     "With 'as NAME' the variable NAME counts 0..COUNT-1 (like ports and "
                     'motors). Blocks nest. COUNT is 0..1000000.\n'
                     '  .repeat 3 as i\n'
                     '  MVP REL, 0, 1000\n'
                     '  .wait GAP 8, 0 == 1\n'
                     '  .end')),
    Command('.if', 'scripting', '.if EXPR',
            'run the following lines (until .elif/.else/.end) if EXPR is true',
            category='script',
            details=('  .if GIO 0, 0 == 1\n'
                     '  .echo input 0 is high\n'
                     '  .else\n'
                     '  .echo input 0 is low\n'
                     '  .end')),
    Command('.elif', 'scripting', '.elif EXPR',
            'inside .if: the next condition',
            category='script'),
    Command('.else', 'scripting', '.else',
            'inside .if: lines run when no condition was true',
            category='script'),
    Command('.end', 'scripting', '.end',
            'close a .repeat or .if block',
            category='script'),
    Command('.onerror', 'scripting', '.onerror LINE | .onerror off',
            'in a script: a line to run if the script stops at an error',
            category='script',
            details=('  .onerror MST 0\n'
                     'Makes a failed script leave the motor stopped. It runs once, when an '
                     'error stops the script (not with --keep-going), and is forgotten when '
                     'the script ends.'),
            check='check_onerror'),
    Command('.source', 'scripting', '.source FILE',
            'run a script file in this session',
            category='script',
            details=('Lines of the file run as if typed; errors stop it with FILE:LINE. '
                     "Inside a script the path is relative to that script's folder.")),
    Command('.let', 'scripting', '.let NAME = EXPR',
            'set a variable (use it as ${NAME} or in expressions)',
            category='script',
            details=('EXPR is arithmetic, comparisons, and/or/not over numbers, variables '
                     'and module reads:\n'
                     '  .let speed = 1000\n'
                     '  .let p = GAP 1, 0\n'
                     '  SAP 4, 0, ${speed * 2}\n'
                     '.let alone lists the variables.'),
            check='check_let'),
    Command('.expect', 'scripting', '.expect EXPR',
            'check a condition; the script fails if it is false',
            category='script',
            details=('  .expect GAP 1, 0 == 5000\n'
                     '  .expect abs(GAP 1, 0 - ${target}) <= 10\n'
                     'A failure says what was expected and what was read. An answer the '
                     'line may have given another request (a reply came that nothing was '
                     'waiting for) is read again; one still in doubt fails the check, said '
                     'to be in doubt, its value not stated. JSON: {"check", "passed": '
                     'true|false, "values": {READ: value}} ("in_doubt": [READ] in place of '
                     'the values; a failure also has "error").'),
            check='check_expect'),
    Command('.wait', 'scripting', '.wait EXPR [--timeout S] [--interval S]',
            'poll until a condition holds (default timeout 30 s, interval 0.05 s)',
            category='script',
            details=('  .wait GAP 8, 0 == 1 --timeout 10\n'
                     '  .wait RFS STATUS, 0 == 0\n'
                     '--timeout none waits forever; otherwise at most a day (86400 s); '
                     '--interval 0.001..86400 s. When the condition holds it says so: '
                     "'reached after 1.23 s: GAP 8, 0 == 1 (GAP 8, 0 is 1)'. "
                     'A poll that gets no intact answer is '
                     'polled again. A timeout is an error that shows the last value read '
                     'and when (or says it was in doubt, or that none could be read, and '
                     'why). A condition met on an answer that may have been another '
                     'request\'s does not end the wait. JSON, met or not: {"check", '
                     '"passed", "values" (null: none read), "elapsed": s}; a timeout adds '
                     '"timed_out": true, "read_at" (s into the wait), "read_error" and '
                     '"error".'),
            check='check_wait',
            options=(Option("--timeout", "S", "give up after S seconds (none: never)"),
                     Option("--interval", "S", "seconds between polls"))),
    Command('.sleep', 'scripting', '.sleep SECONDS',
            'pause up to a day (seconds may be a fraction or an expression)',
            category='script',
            check='check_sleep'),
    Command('.echo', 'scripting', '.echo TEXT [> FILE | >> FILE]',
            'print a line (${...} expanded), or write it to a file',
            category='script',
            details=('  .echo position is ${GAP 1, 0}\n'
                     '  .echo SAP 4, 0, ${GAP 4, 0} >> restore.tmcl\n'
                     "'>' replaces the file, '>>' appends; quote text that holds '>'.")),
    Command('.record', 'scripting', '.record FILE | .record off',
            'record what you type to a script file',
            complete=['off'], category='script',
            details=('Every line typed from now on is written to FILE (results as // '
                     "comments); replay it with tmclsh -f FILE. '.record off' (or "
                     "'.record stop') stops\n"
                     "(a file named stop is ./stop); '.record' shows the state. FILE is "
                     "replaced when the recording\n"
                     "ends ('.record off' or leaving the shell); if it cannot be written, "
                     'the old FILE stays as it was.'),
            expands=True),
    Command('.history', 'scripting', '.history [N]',
            'show the lines of this session (the last N)',
            category='script'),
    Command('.plot', 'plot', '.plot [CSV] [--only NAME,...] [--height N] [--width N]',
            'chart a CSV log (from .watch --csv) or the last watch in the terminal',
            category='watch',
            options=(Option("--only", "NAME,...", "these columns"),
                     Option("--height", "N", "rows"), Option("--width", "N", "columns"))),
    Command('.watch', 'watch',
            '.watch [NAME=]EXPR; ... [--interval S] [--count N] [--until EXPR] [--csv FILE]',
            'poll values live: value, min, max, rate, recent history',
            category='watch',
            owns_line=True,
            details=('  .watch pos=GAP 1, 0; speed=GAP 3, 0; in0=GIO 0, 0\n'
                     "It takes the rest of its line (';' separates its expressions) up to "
                     "a ';' that a dot-command follows.\n"
                     '  .watch rev=GAP 1, 0 / 51200 --until "rev >= 2" --csv run.csv\n'
                     'Keys: s or space stops everything (the stored program if it runs, then '
                     'MST to every motor, speeds read back) and keeps watching; Ctrl-C does '
                     'the same and ends the watch (in -c and -f it ends the run, exit 130, '
                     'as on any line); q (or Esc) ends the watch quietly, motors '
                     'keep running. A lost link shows as "link lost"; the watch reconnects '
                     'and samples on once the link is back. Under --json or in a pipe, '
                     'each sample is a JSON object {"t": s, "values": {...}}. An answer the '
                     'line may have given another request is read again within its sample, '
                     'or shown as ? (CSV ?, JSON null and "suspect": [names]) and left out of '
                     'min, max, rate and .plot; a sample is shown once its answers are '
                     'judged, one sample late. With no '
                     'expressions: the position and speed of each motor. .plot draws the '
                     'last watch. --interval is 0..86400 s, --count 1..1000000; the CSV file '
                     'is put in place when the watch ends. A CSV row: time (the clock) and t '
                     '(s since the start) when its first value was read, the values, '
                     'together (yes: read back to back; no: a retry, a slow answer or a read '
                     'again came between them) and t(NAME), when each value was read (the '
                     'request whose answer was taken went out; a retry\'s, not the first '
                     'attempt\'s). JSON: "t" is the first read\'s; a row not read together '
                     'adds "together": false and "times": {NAME: s}.'),
            check='check_watch',
            options=(Option("--interval", "S", "seconds between samples"),
                     Option("--count", "N", "stop after N samples"),
                     Option("--until", "EXPR", "stop once EXPR holds"),
                     Option("--csv", "FILE", "log every sample to FILE"))),
    Command('.upload', 'upload', '.upload FILE [--at ADDR] [--yes] [--no-verify]',
            'assemble FILE for this module, store it in program memory and verify it',
            complete='complete_file', category='program',
            details=('Assembles FILE for the connected module (a .bin TMCL-IDE image or .hex '
                     'text is taken as it\n'
                     'is), then: 132 (start download at ADDR, default 0), one\n'
                     'frame per instruction (each answered with status 101), 133 (quit '
                     'download), and reads every\n'
                     'instruction back with 134 to compare; the first difference is '
                     'reported. Asks before\n'
                     'overwriting the program unless --yes. A program larger than the memory '
                     'is refused before\n'
                     'anything is sent, and so is an upload to an address two modules '
                     'answer at (it would go to both).\n'
                     'A reply lost or damaged on a line that works cannot be asked again (its '
                     'frame may be stored):\n'
                     'the whole program is stored again from ADDR, as often as a command is '
                     'retried (--retries).\n'
                     'If the upload is interrupted (Ctrl-C, timeout, '
                     'corrupted reply, lost link),\n'
                     'download mode is ended anyway and the message says which instructions '
                     'are written.\n'
                     'The question says so when the stored program is running (the '
                     'download stops it).\n'
                     'Under --json: {"uploaded": N, "verified": true|false}. Needs binary '
                     'mode.'),
            options=(Option("--at", "ADDR", "store it from this address"),
                     Option("--yes", help="overwrite a program that is there", aliases=("-y",)),
                     Option("--no-verify", help="do not read it back")),
            expands=True),
    Command('.dump', 'upload', '.dump [[-o] FILE] [--at ADDR] [--count N]',
            'read the stored program back (134) and show it as source, or write it to FILE',
            aliases=('.disasm',), complete='complete_file', category='program',
            details=('Reads program memory with 134 from ADDR (default 0) up to the end '
                     'marker (opcode 0, or an\n'
                     'erased cell) or the end of memory, or exactly N instructions with '
                     '--count. When tmclsh\n'
                     'uploaded exactly these instructions from a file (.upload keeps each '
                     "upload's source in the\n"
                     "user's cache directory, keyed by a hash of the image), that source is "
                     'shown, with its labels\n'
                     'and comments; otherwise the memory is disassembled with generated '
                     'labels (L0012 for a jump\n'
                     'target at 12). With FILE the text is written there; it assembles back '
                     'to the same image\n'
                     '(.upload FILE --at ADDR); a FILE ending in .bin gets the TMCL-IDE '
                     'binary image (8-byte\n'
                     'records with checksums), .hex the hex text (-o FILE says the same as '
                     'FILE). Needs binary\n'
                     'mode.'),
            options=(Option("-o", help="(the FILE that follows is written)"),
                     Option("--at", "ADDR", "from this address"),
                     Option("--count", "N", "this many instructions")),
            expands=True),
    Command('.source-map', 'upload', '.source-map [FILE [--at ADDR] | --off]',
            'use FILE as the source of the stored program (lines and labels in the debugger)',
            complete='complete_file', category='program',
            details=("Assembles FILE and associates it with the program in the module's "
                     'memory, so that locations\n'
                     'are shown as file:line and .break accepts its labels and line numbers. '
                     'The stored program is\n'
                     'read back and compared; a difference is reported (the mapping is '
                     'kept). Without FILE: show\n'
                     'the current mapping; --off forgets it (locations are then disassembled '
                     'from memory).'),
            options=(Option("--at", "ADDR", "the address FILE was uploaded at"),
                     Option("--off", help="forget the source map"))),
    Command('.run', 'debugger', '.run [LABEL|ADDR]',
            'run the stored program (from the current address, or from LABEL/ADDR)',
            complete='complete_location', category='program',
            details=('129 type 0 continues from the current address; with LABEL or ADDR, 129 '
                     'type 1 starts there.\n'
                     'Runs at full speed: breakpoints are not honoured (use .continue, which '
                     'steps). In ASCII mode\n'
                     "this is the module's RUN command.")),
    Command('.stop', 'debugger', '.stop',
            'stop the stored program (128)',
            category='program',
            details=('128 stops the running or stepped program where it is; .status or '
                     '.where shows where. In\n'
                     "ASCII mode this is the module's STOP command.")),
    Command('.reset', 'debugger', '.reset',
            'reset the stored program: program counter 0, stopped (131)',
            category='program'),
    Command('.status', 'debugger', '.status',
            "the program's state (stop|run|step|reset) and current line",
            category='program',
            details=('135 (the application status) and GP 130 (the program counter), with '
                     'the source line at the\n'
                     'program counter. JSON: {"state": ..., "pc": ..., "file": ..., "line": '
                     '..., "text": ...}; "end": true\nwhere no instruction is stored.')),
    Command('.where', 'debugger', '.where',
            'where the program is: address, source line, enclosing label',
            category='program'),
    Command('.step', 'debugger', '.step [N]',
            'execute the next N instructions (default 1) and show where',
            category='program',
            details=('130 steps one instruction; after each, the program counter (GP 130), '
                     'the line about to run\n'
                     'next and the .display values are shown. An empty line repeats the '
                     'step. Ctrl-C stops a long\n'
                     'series. Where no instruction is stored (empty program memory, or past '
                     "the program's end)\n"
                     'it says so and sends nothing. Needs binary mode.')),
    Command('.continue', 'debugger', '.continue [MAXSTEPS]',
            'step until a breakpoint is reached',
            aliases=('.cont',), category='program',
            details=('These firmwares have no breakpoint command, so .continue runs the '
                     'program by stepping it\n'
                     '(130) and reading the program counter (GP 130) after every '
                     'instruction, stopping when it\n'
                     'reaches a breakpoint, when the program stops by itself, at the end of '
                     'the stored program\n'
                     '(no instruction there: nothing is stepped through empty memory), after '
                     'MAXSTEPS steps, or on Ctrl-C.\n'
                     'That is two round trips per instruction: much slower than .run, and a '
                     'WAIT takes its full\n'
                     'time. With no breakpoints it is .run (129 type 0). Needs binary mode.')),
    Command('.break', 'debugger', '.break [LABEL|LINE|FILE:LINE|@ADDR]',
            'set a breakpoint (for .continue); without argument, list them',
            complete='complete_location', category='program',
            details=('A bare number is a line of the source file when one is known (uploaded '
                     'in this session or\n'
                     'named with .source-map), else an address; @ADDR is always an address. '
                     'Breakpoints are kept by\n'
                     'tmclsh, not the module (it has no breakpoint command): only .continue '
                     'stops at them.')),
    Command('.delete', 'debugger', '.delete [N]',
            'delete breakpoint N (all without N)',
            complete='complete_breakpoints', category='program'),
    Command('.list', 'debugger', '.list [LINE|LABEL|@ADDR | FROM TO]',
            'the program (a short one whole, else around the current line or LINE), marked',
            complete='complete_location', category='program',
            details=("'->' marks the line the program counter is at, 'B' a breakpoint; the "
                     'program address of each\n'
                     'line with an instruction is shown. A program of up to 20 lines is '
                     'listed whole; a longer\n'
                     "one 5 lines either side, and '...' marks lines left out. '.list 1 8' "
                     '(or 1-8, 1..8, @0 @6,\n'
                     'Loop @9) lists that range. Without a known source file the '
                     'disassembly is listed instead.\n'
                     'JSON: {"pc": N, "lines": [...]}, with "more": {"before": B, "after": '
                     'B} when cut.')),
    Command('.display', 'debugger', '.display [EXPR]',
            'show EXPR (e.g. GGP 0, 2 or GAP 1, 0) at every stop; without EXPR show all now',
            category='program',
            details=('Values are shown after each .step, .continue, .stop and .reset. EXPR '
                     'is an expression of the\n'
                     'scripting engine when it is loaded, else one TMCL line that reads a '
                     'value (GAP, GGP, GIO ...);\n'
                     'commands that change something are refused. Remove with .undisplay N.')),
    Command('.undisplay', 'debugger', '.undisplay [N]',
            'remove display N (all without N)',
            category='program'),
    Command('.vars', 'debugger', '.vars [N | FROM..TO | all]',
            'user variables (GGP n, 2): the non-zero ones, or a range',
            category='program',
            details=('Without argument every user variable is read and the non-zero ones are '
                     'shown; with N or\n'
                     'FROM..TO those are shown whatever their value.')),
    Command('.ascii', 'terminal', '.ascii [--raw] [--echo] [--bin|--no-bin]',
            "serial terminal on the module's ASCII mode (Ctrl-] returns)",
            complete='_complete_ascii', category='ascii',
            details=('Enters ASCII mode (command 139) if the module is not in it yet. Lines '
                     'are edited locally and sent whole with the address character added; '
                     "--raw sends every key as typed, so the module's own echo and backspace "
                     'handling show. Replies are shown with the status decoded. Ctrl-] or '
                     '.quit leaves; leaving asks whether to send BIN (back to binary mode); '
                     '--bin/--no-bin answer in advance. BIN typed in the terminal is '
                     'noticed: the module talks binary again and the terminal returns to the '
                     'shell.\n'
                     'Ctrl-T opens a menu, as in tio: e local echo on/off, h hex view of '
                     'what arrives, t timestamps, f log the session to a file (f again '
                     'stops), u send a file line by line (each reply waited for), ? the '
                     'menu; Ctrl-T Ctrl-T sends Ctrl-T in --raw.'),
            changes_link=True,
            options=(Option("--raw", help="keys go to the module as typed"),
                     Option("--echo", help="echo typed keys locally"),
                     Option("--bin", help="send BIN when leaving"),
                     Option("--no-bin", help="stay in ASCII mode when leaving"))),
    Command('.mode', 'terminal', '.mode [ascii|binary] [--keep]',
            "show or switch the link: binary frames or the module's ASCII mode",
            complete='_complete_mode', category='ascii',
            details=('ascii enters ASCII mode (command 139) unless the module is in it '
                     'already; its replies carry no checksum, so every setting read there is '
                     'read twice and taken only when both reads agree (said once a run, the '
                     'first time tmclsh reads through ASCII mode; not by scan, nor by .ascii '
                     '--raw, where nothing is read twice); binary sends BIN. On exit tmclsh '
                     'leaves the module in the '
                     'mode it found it in, unless --keep was given with the last switch.'),
            changes_link=True,
            options=(Option("--keep", help="the module keeps the mode after tmclsh exits"),)),
    Command('.ascii-config', 'terminal',
            '.ascii-config [startup=ascii|binary] [echo=char|line|none]',
            'show or set the ASCII interface configuration (GP 67)',
            complete='_complete_config', category='ascii',
            details=('Reads GP 67 and writes it back with the named bits changed (other bits '
                     'kept). GP 67 is one of the bank-0 parameters 64..128 that SGP writes '
                     'to EEPROM directly (manual §10.1), so the change is permanent and asks '
                     'first (--yes). The start-up mode applies from the next power-up. A '
                     "module whose data has no ASCII interface (TMCM-1640) is refused before "
                     'anything is sent.')),
    Command('.save', 'clone', '.save FILE [--program] [--names-only] [--yes]',
            "back up the module's configuration as a replayable script",
            complete='complete_file', category='configuration',
            details=('Reads every readable axis parameter of every motor and the global '
                     'parameters of every bank\n'
                     "(one request each; the RAM-only user variables are a program's scratch "
                     'space and are not\n'
                     'read) and writes FILE: a header (module, firmware, address, '
                     'connection, date),\n'
                     'then one SAP/SGP line per writable configuration parameter with its '
                     'number, unit and meaning\n'
                     'as a comment. Read-only values and motion state (positions, speeds, '
                     'counters, anything that\n'
                     'starts a move) are written as comments and never restored. FILE is '
                     'replaced only once it is\n'
                     'complete. A FILE that exists is not overwritten without asking '
                     '(--yes or -y: overwrite;\n'
                     'scripts need it). --program also reads the stored program back '
                     '(binary mode) and writes it, as\n'
                     'source, beside FILE with .program.tmcl in place of its suffix '
                     '(backup.tmcl:\n'
                     'backup.program.tmcl; put it back with .upload). JSON: {"saved": N,\n'
                     '"file": FILE} (and "program": PATH, "instructions": N with --program).\n'
                     'A module read by number only (no parameter data, or -m generic) has no '
                     'list of parameters\n'
                     'to read: .save refuses it (a failure in -c/-f) and says what to do '
                     'instead.\n'
                     "The module's link identity (address, baud rate, host address, CAN ids "
                     'and bit rate, ASCII\n'
                     'start-up, telegram pause: what its data marks link) is written in a '
                     'section of its own at the\n'
                     'end: .restore, .diff and tmclsh -f leave those lines alone unless '
                     '--with-link.\n'
                     'A module known by parameter names only (imported from PyTrinamic: no '
                     'ranges, not known which\n'
                     'are settings) has nothing a backup could restore: .save refuses it '
                     'and names what it could\n'
                     'not save; --names-only writes the values as comments all the same.'),
            options=(Option("--program", help="also the stored program"),
                     Option("--names-only", help="save a module known by names only, "
                                                 "its values as comments"),
                     Option("--yes", help="replace a file that exists", aliases=("-y",))),
            expands=True),
    Command('.diff', 'clone', '.diff FILE [--exit-code] [--force] [--with-link]',
            'compare the module with a backup (or any script of SAP/SGP lines)',
            complete='complete_file', category='configuration',
            details=("Reads FILE with the shell's own line parser and checks it whole "
                     'before anything is sent:\n'
                     'comments and blank lines aside, every line must be a SAP/SGP line the '
                     "module's data accepts\n"
                     '(anything else is an error at FILE:LINE, exit status 2 in -c). Then it '
                     'reads each parameter\n'
                     'the file sets from the module (one request each) and shows only the '
                     'ones that differ: name,\n'
                     'number, motor or bank, saved value, live value and unit. Motion state lines are not compared. JSON: '
                     'one {"name", "number",\n'
                     '"motor"|"bank", "saved", "live"} object per difference, nothing for '
                     'equal values. Exits 0\n'
                     'either way; with --exit-code a difference is a failure (exit status '
                     '1). A backup of another\n'
                     'module type is compared by parameter name only with --force; a '
                     'parameter whose unit differs\n'
                     '(pps there, rpm here) is skipped and named, never compared as a number '
                     '(JSON: {"skipped",\n'
                     '"why"} for each parameter not compared).\n'
                     "The module's link identity (address, baud rate, CAN, ASCII start-up) "
                     'is not compared and\n'
                     'is named as left alone (on stderr under --json); --with-link '
                     'compares it too.'),
            options=(Option("--exit-code", help="exit 1 when there are differences"),
                     Option("--with-link", help="compare the address, baud rate, CAN and "
                                                "ASCII settings too"),
                     Option("--force", help="compare a backup of another module type",
                            aliases=("-f",))),
            expands=True),
    Command('.restore', 'clone', '.restore FILE [--yes] [--store] [--force] [--with-link]',
            'write the parameters that differ from a backup back to the module',
            complete='complete_file', category='configuration',
            details=('Compares like .diff, then writes only the parameters that differ '
                     '(SAP/SGP), each checked\n'
                     "against the module's data before anything is sent, and reads each one "
                     'back to verify it.\n'
                     'Asks first (--yes or -y skips the question; scripts need it). A value '
                     'the module refuses is\n'
                     'reported and the rest are still restored; the command then fails. '
                     '--store also stores the\n'
                     'written parameters in EEPROM (STAP/STGP) after asking. The '
                     "module's link identity\n"
                     '(address, baud rate, host address, CAN ids and bit rate, ASCII '
                     'start-up, telegram pause) is\n'
                     "the module's own: it is left alone and named, unless --with-link. "
                     'Then the question names\n'
                     'each of them that changes, old and new; they are written last, and '
                     'a new address, host\n'
                     'address or CAN id is followed as a typed SGP is (the module answers '
                     'there now). A setting\n'
                     'that may cut the link in use with nothing to follow (CAN bit rate on '
                     'CAN) is not read back:\n'
                     'reconnect with it. A backup of\n'
                     'another module type is refused unless --force: then only parameters '
                     'both modules have (by\n'
                     'name) are restored, and the skipped ones are listed. Motion state is '
                     'never written. JSON:\n'
                     '{"file", "restored": [...], "failed": [...], "skipped": [...], '
                     '"stored": N,\n'
                     '"left_alone": [...], "address": N}.'),
            options=(Option("--yes", help="do not ask", aliases=("-y",)),
                     Option("--store", help="also store in EEPROM (STAP/STGP)"),
                     Option("--force", help="restore a backup of another module type",
                            aliases=("-f",)),
                     Option("--with-link", help="write the address, baud rate, CAN and "
                                                "ASCII settings too (the module moves)")),
            expands=True),
)

REGISTRY: dict[str, Command] = {}
_ALIASES: dict[str, str] = {}
# which module registered each handler (checked against COMMANDS by the tests)
HANDLERS: dict[str, str] = {}
for _cmd in COMMANDS:
    add(_cmd)
del _cmd
FEATURES = tuple(features())
