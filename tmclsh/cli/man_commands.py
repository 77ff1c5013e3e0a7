"""The man page's sections on commands: notes on the subcommands, the shell's dot-commands
from their registry, the TMCL instructions from the instruction set."""

from __future__ import annotations

from .doc_model import module_names, shell_commands
from .doc_roff import _b, _esc, _i, _inline, _prose, _sentence

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
            "marked ASCII mode and left in it (also when Ctrl-C, SIGTERM or SIGHUP stop the "
            "scan, which says it stopped early: the list is then partial). An address where every reply comes twice is "
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
                "under the same port name; on a line several modules share, a module at "
                "another address is refused before the restart while another module answers "
                "at address 1 at 115200 baud, which would hear the erase and the writes "
                "too); 206 asks its memory, and an image that does not "
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
               "dropped. On a terminal a table at the bottom keeps one row per module "
               "(exchanges, exchanges per second over the last 5 s, error statuses by name "
               "and requests unanswered, the slowest exchange, the last value of each "
               "parameter by its name) while the lines scroll above it; --no-table leaves "
               "the lines alone, and off a terminal or with --json there is no table. "
               "Ctrl-C, SIGTERM or SIGHUP ends it with a summary (frames, errors, status "
               "counts, the slowest exchange) on standard error, or a last {\"summary\": "
               "...} object; SIGTERM and SIGHUP are named first (terminated (SIGTERM): "
               "stopped listening); so does its reader leaving (monitor | head): the next "
               "line it would show ends it, the summary on standard error. Exit status 0; 1 "
               "when the adapter goes away, a log cannot be read on (after the summary of "
               "what came before) or the reader of standard output has gone; 143 after "
               "SIGTERM, 129 after SIGHUP; 3 when the port or bus cannot be opened.",
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
              "prints the summary; -o keeps the frames of that closing stop too. Forwarding "
              "comes first: what is shown (the lines, the table, -o, the summary and what the "
              "closing stop ends) is read in a second tmclsh bridge process, so the "
              "forwarding never waits for it; Ctrl-C and SIGTERM go to the first, which "
              "ends both (SIGTERM and SIGHUP are named on standard error and end it with "
              "exit status 143 and 129, as they end every command). When nothing reads the output (a paused pager, a full pipe) lines "
              "are dropped and counted (\"dropped_lines\" in the JSON summary), never "
              "frames; the counts stay whole. If the second process is killed or falls too "
              "far behind, the forwarding goes on, and at the end the bridge says that what "
              "the traffic left at the module is not known (check the module) instead of "
              "ending it. The table per module at the bottom of a "
              "terminal is monitor's; it is drawn a few times a second off the forwarding, "
              "and a terminal that is slow to take it loses redraws, never frames. A request that answers nothing by design "
              "(137, 242, 205) is no error, and requests sent ahead of their replies are "
              "each paired with their own. A TCP master is served one at a time; another that "
              "connects meanwhile is hung up on. Exit status 0; 1 when the module's link goes "
              "away, the second process could not finish (its reader gone, killed), or what "
              "the traffic left is not known or could not be ended (a motor may still turn); 3 "
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
              "sent any of them ends with the safety stop at each address (CAN id) they went "
              "to, whatever ends it (Ctrl-C too); a module the capture only read from is "
              "left alone. "
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
