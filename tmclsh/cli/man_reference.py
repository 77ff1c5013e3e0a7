"""The man page's reference sections: exit statuses, limits, configuration, backups, units,
inventories, Python, files, module files and firmware images."""

from __future__ import annotations

from .doc_model import _default_toml
from .doc_roff import _b, _esc, _i, _sentence


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
        (129, "Hung up (SIGHUP: the terminal or SSH session went away; also when the "
              "prompt's terminal stops answering and no signal came). A run started "
              "ignoring SIGHUP (nohup) goes on."),
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
Its bank 0 global parameters write the EEPROM, which is asked first: where nobody can answer
(no terminal, {_b("--json")}) and without {_b("--yes")}, the backup is refused before anything
is sent, naming the first such line, rather than stopping there with half of it written.
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
So does the reader of standard output going away (a pipe into {_b("head")}), as for one
module: each unit that set a motor moving stops it and says so on standard error, the
others are sent nothing more, exit status 1.
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
{_b("tmclsh.read_inventory")}, and {_b("tmclsh.compare_inventory")} with what
{_b("tmclsh.scan_modules")} found -> {_b("Check")}.
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
