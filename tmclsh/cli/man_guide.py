"""The man page's prose for a reader learning tmclsh: the description, the shell's language
and the examples."""

from __future__ import annotations

from .doc_model import PROG
from .doc_roff import _b, _i

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
and answers at its own address afterwards. The {_b(".ascii")} terminal pads each typed line the same way
(its local echo shows the line as sent); {_b(".ascii --raw")} sends the keys as typed.
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
also {_b('{"left_running": {...}, "address": N}')} on standard output). A motor the run told to turn
({_b("ROR 0, 1000")}, a rotation left, a position move, a target speed written) and did not stop counts as
left turning even while its speed reads 0 (it has not started yet, or it stalls). A run that
moved on with {_b(".address")} is asked about each address it left such a motor at, and each is
named ({_b("address 1: motor 0 turns ...")}); Ctrl-D and {_b(".quit")} at the prompt ask the same.
No address the run did not talk to is sent anything.
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
back until it is 0. Only motors that read 0 are called stopped; any other is named. Then the
same at each address {_b(".address")} left a motor the shell told to move at (no other address
is sent anything), said with its address; the prompt stays at the address it was at.
.TP
{_b("Ctrl-D")}
Leaves the shell, like {_b(".quit")}. While a motor turns or the stored program runs, it
asks first: 1 stop everything first, 2 leave it running, or 3 cancel; the number chooses (or
the arrows and Enter), and the selection starts on 1 every time. A motor the shell told to
turn and did not stop counts, even while its speed reads 0 (a stalled motor). With the link
down (and not brought back by one attempt) it cannot ask: it says so and names what it last
told each such motor. Each address {_b(".address")} left a motor the shell told to move at
is asked too, and named; stopping first stops it there as well.
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
