"""Bringing a module up: finding out what answers at the client's address, in which mode, and
getting it ready to execute commands. One bring-up, run wherever a module is met: at
connect (the command line, ``tmclsh.connect()``, the shell's ``.connect``), after every
reconnect (before the next command), and when ``.address`` turns to another module.

It checks rather than assumes:

* the type is asked with 136. The string carries no checksum; one that names no module
  tmclsh has data for is confirmed through 136 type 1 (whose frame has one), read in each
  module's own byte order (a TMCM-1640 answers version first);
* a module given beforehand (``-m``) that contradicts the answer is a ``ConnectError`` at
  connect; after a reconnect another module type on the port is taken, with a notice;
* a serial module that answers only in its ASCII mode is driven through it, with a notice;
  one driven in ASCII mode before a reconnect is found again in whichever mode it is in;
* a module found in download mode (an upload cut short) is brought out of it with 133;
* a module that answers from its bootloader (``1311B100``: a firmware update broke off) runs
  no firmware to talk to: an ``InBootloaderError`` says so and names ``tmclsh firmware``,
  which completes the update (the string is asked twice first: it carries no checksum);
* when nothing answers, a ``NoAnswerError`` says what was tried and what to try next.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..base.canspec import LINK_DEFAULTS
from ..base.errors import (ChecksumError, ConnectError, DownloadModeError, InBootloaderError,
                           NoAnswerError, StatusError, TmclError, TmclTimeoutError,
                           ValidationError)
from ..tmcl import instructions as isa
from ..tmcl.frames import Control, Request
from ..tmcl.modules import Module, baud_rates, by_type1, generic_for, identify as named_by
from ..tmcl.version import parse_string
from .advice import more_time, setting

if TYPE_CHECKING:
    from .core import Client

_GET_VERSION = int(Control.GET_VERSION)
_QUIT_DOWNLOAD = int(Control.QUIT_DOWNLOAD)
_FIRST_CONTROL = int(Control.STOP_APPLICATION)
_OK = 100
# GP 129 "download mode" (all three manuals): read to find out whether the module executes
# commands; in download mode the read itself is stored (answered with status 101) instead
_GP_DOWNLOAD_MODE = 129


def start(client: Client, *, ascii: bool = False) -> Client:
    """Bring a new client up (see the module docstring). On any failure the client is
    closed, so a half-opened port is never left behind."""
    client._ascii_asked = ascii
    try:
        bring_up(client, ascii=ascii)
    except BaseException:
        client.close()
        raise
    return client


def bring_up(client: Client, *, ascii: bool = False, strict: bool = True) -> None:
    """What ``start`` does, leaving the client open when it fails (the shell's ``.connect``
    after ``Lifecycle.switch_transport``: the link stays, its module unknown). The module the
    client holds is the one expected; ``strict``: another type answering is an error (at
    connect), else it is taken (after a reconnect, ``.address``)."""
    expected = client.module
    # (what no_answer_message compares: answers from the module in this bring-up)
    client._late_base = client._late_from.get(client.address, 0)
    client._replies_base = client._ledger.replies
    if ascii:
        _attach_ascii(client, expected, strict)
    else:
        _bring_up_binary(client, expected, strict)


def again(client: Client, req: Request) -> ValidationError | None:
    """Before the first command after a reconnect: the module is brought up exactly as at
    connect, in the mode it was driven in. Another module type answering now is taken, with
    a notice; ``req``, checked against the old module's data, is then refused: the error to
    raise instead of sending it is returned (the bring-up itself raises when it fails)."""
    old = client.module
    link = client.ascii_link
    if link is not None:
        client.ascii_link = None  # found again, in whichever mode the module is in now
    try:
        bring_up(client, ascii=link is not None, strict=False)
    except BaseException:
        if client.module is None:  # (nothing answered: still the module it was, by name)
            client.module = old
        raise
    new = client.module
    if old is None or new is None or new.name == old.name:
        return None
    client._taps.notice(f"another module answers at address {client.address} on "
                       f"{client.describe()} since the link came back: a {new.label}, version "
                       f"{client.version} (it was a {old.name}); lines are checked against its "
                       "data from now on")
    if req.opcode >= _FIRST_CONTROL:
        return None
    return ValidationError(
        f"{_name(req)} was not sent: it was checked against the {old.name}'s data "
        f"(the module at address {client.address} is a {new.name} now); give it again")


def switch_address(client: Client, address: int) -> None:
    """Talk to the module at ``address`` (on CAN: that id) from now on, brought up as at
    connect; on failure the client stays with the module it had."""
    from .ascii import AsciiLink
    from .motion import MotionRecord

    old = (client.address, client.can_id, client.module, client.version, client.ascii_link)
    # the ASCII mode a module is driven in is that module's: the next one is met in the mode
    # it is in (binary first, its ASCII mode if silent), unless tmclsh entered ASCII mode
    # itself (--ascii, .mode ascii), which is carried as asked
    left = AsciiLink.take_away(client)
    ascii = old[4] is not None and (old[4].found_in_binary or client._ascii_asked)
    client.address = address
    if client.is_can:
        client.can_id = address
    client.ascii_link = None
    client.version = None  # (nothing is known yet of the module there)
    if client.module is not None and not client.module.generic:
        client.module = None  # another module: what it is comes from its answer (-m generic
        # stays: numbers only, as asked)
    try:
        bring_up(client, ascii=ascii, strict=False)
    except BaseException as exc:
        heard = client._late_from.get(address, 0) > client._late_base  # (answered late)
        (client.address, client.can_id, client.module, client.version,
         client.ascii_link) = old
        AsciiLink.put_back(client, left)
        if (isinstance(exc, NoAnswerError) and old[3] is not None and not client.is_can
                and not heard):
            # the module it talked to answers on this line at this rate: the baud rate and
            # the port are right, and the likely causes are fewer than at connect
            where = client.describe()
            raise NoAnswerError(
                f"no module answered at address {address} on {where}, where the module at "
                f"address {old[0]} answers. Likely causes, most likely first:\n"
                f"  - address: no module has address {address}: 'tmclsh scan"
                f"{connection_words(client)}' lists who answers\n"
                f"  - a slow module: {more_time(client)}"
                f"\nstill talking to address {old[0]}") from exc
        if isinstance(exc, TmclError):
            raise type(exc)(f"{exc}\nstill talking to address {old[0]}") from exc
        raise
    if left is not None:
        left.leave(old[0], in_ascii=old[4] is left)
    # what this client set moving belongs to the module it was told to: kept by its address
    # for the stop, and the module met now has its own record (none: told nothing yet)
    gone_from = old[1] if client.is_can else old[0]
    if client.motion:
        client._motion_left[gone_from] = client.motion
    client.motion = client._motion_left.pop(address, None) or MotionRecord()


def identify(client: Client) -> Module:
    """Ask the module what it is (136 type 0) and take its data (numbers only for a type
    tmclsh has none for). The string has no checksum: one naming no module tmclsh knows is
    checked against 136 type 1 first (``_confirmed_version``), so that a bit lost on the line
    does not make a TMCM-1311 a 'TMCM-1111' (on the way into ASCII mode too)."""
    reply = client.request(Request(client.address, _GET_VERSION, 0, 0, 0))
    if reply is None or reply.version is None:
        status = reply.status if reply is not None else 0
        raise StatusError(status, reply, f"address {client.address} refused the version "
                          f"request (136): status {status}")
    _adopt_version(client, *_confirmed_version(client, reply.version))
    assert client.module is not None
    return client.module


def leave_download_mode(client: Client) -> bool:
    """Bring a module found in download mode out of it (133), with a notice.

    Asks GP 129 (download mode): a module in normal mode answers it, one in download mode
    stores it and answers status 101. True if the module was in download mode.
    """
    try:
        client.request(Request(client.address, isa.Opcode.GGP, _GP_DOWNLOAD_MODE, 0, 0))
    except DownloadModeError:
        pass
    else:
        return False
    client._downloading = True  # until 133 is answered, whatever is sent is stored
    try:
        reply = client.request(Request(client.address, _QUIT_DOWNLOAD, 0, 0, 0))
    finally:
        client._downloading = False
    if reply is None or not reply.ok:
        status = reply.status if reply is not None else 0
        raise StatusError(status, reply, f"the module at address {client.address} is in "
                          "download mode (it stores commands instead of executing them) "
                          f"and refused to leave it (133): status {status}")
    client._taps.notice(f"the module at address {client.address} was in download mode (an upload "
                       "was cut short?): ended it with 133; the program stored on it may be "
                       "incomplete")
    return True


# -- the steps ----------------------------------------------------------------------------

def _attach_ascii(client: Client, expected: Module | None, strict: bool, found=None) -> None:
    from .ascii import AsciiLink

    client.module = None  # so that the link asks 136 (stepping out of ASCII mode if need be)
    try:
        try:
            AsciiLink.attach(client, found=found)
        except StatusError:
            # 139 refused: a module in download mode takes no control command but 132-136;
            # end download mode (with a notice), then try once more
            if client.ascii_link is not None or not leave_download_mode(client):
                raise
            AsciiLink.attach(client)
    except (TmclTimeoutError, ChecksumError) as exc:
        raise NoAnswerError(no_answer_message(client, exc, ascii=True)) from exc
    _check_type(client, expected, strict)


def _bring_up_binary(client: Client, expected: Module | None, strict: bool) -> None:
    client.module = None
    try:
        # once: if this goes unanswered, the mode probe below is the second try (and
        # tells a module in ASCII mode from a silent line)
        reply = client.request(Request(client.address, _GET_VERSION, 0, 0, 0), retries=0)
    except DownloadModeError:
        # a firmware that stores even 136 while downloading: end download mode first
        leave_download_mode(client)
        reply = None
    except (TmclTimeoutError, ChecksumError) as exc:
        # (a ValidationError from the probe, such as another host address, is the answer)
        if not _answers_after_all(client, expected, strict, exc):
            return  # found in ASCII mode, and attached
        reply = None
    if reply is not None and reply.version is None and not reply.ok:
        # 136 refused with an error status: the manuals do not say what a module in download
        # mode answers to it; one that stores what it gets refuses it so. Ask GP 129, end
        # download mode if it is in it, then ask again (nothing is lost if it was not)
        leave_download_mode(client)
        reply = None
    try:
        if reply is not None and reply.version is not None:
            version = confirmed_bootloader(client, reply.version)
            _adopt_version(client, *_confirmed_version(client, version))
        else:
            try:
                identify(client)
            except ValidationError:  # a version string naming no type: damaged?
                if client.version is None:
                    raise
            if client.version is not None:
                _adopt_version(client, *_confirmed_version(client, client.version))
    except ValidationError:
        if expected is None:  # a version string naming no module we know
            raise
        client.module = expected
    _check_type(client, expected, strict)
    if client.ascii_link is None:
        try:
            leave_download_mode(client)
        except (TmclTimeoutError, ChecksumError) as exc:
            tries = 1 + client.retries
            raise NoAnswerError(no_answer_message(
                client, exc, what=f"it answered 136 (version {client.version}), but not GGP "
                f"129 (download mode), asked {_times(tries)}, "
                f"waiting {client.timeout:g} s each")) from exc


def _confirmed_version(client: Client, version: str) -> tuple[str, Module | None]:
    """The 136 type 0 string carries no checksum: one naming no module tmclsh has data for
    (a bit flipped on the line makes '1311V111' '1311v111' or '1711V111', or a firmware
    writes it in a form not seen before) is checked against 136 type 1, which has one, read
    in each module's own byte order; while the two disagree on a type tmclsh knows, the
    string is asked again (1 + retries times at most). -> (the string, the module type 1
    names when the string still names none)."""
    from ..tmcl.modules import from_version_string

    if from_version_string(version) is not None:
        return version, None  # the usual case: nothing more is sent
    try:
        ident = client.request(Request(client.address, _GET_VERSION, 1, 0, 0))
    except TmclError:
        return version, None
    known = by_type1(ident.value) if ident is not None and ident.status == _OK else None
    if known is None:
        return version, None  # a type without data (TMCM-1161): the string stands
    for _ in range(1 + client.retries):
        try:
            again_ = client.request(Request(client.address, _GET_VERSION, 0, 0, 0))
        except (TmclTimeoutError, ChecksumError):
            continue
        named = from_version_string(again_.version) if again_ is not None and \
            again_.version is not None else None
        if named is not None and named.name == known.name:
            return again_.version, None
    return version, known


def confirmed_bootloader(client: Client, version: str) -> str:
    """A string that says bootloader (``1311B100``) is asked once more before it is taken
    for one: it carries no checksum, and ``V`` and ``B`` are two bits apart."""
    parsed = parse_string(version)
    if parsed is None or not parsed.bootloader:
        return version
    try:
        again_ = client.request(Request(client.address, _GET_VERSION, 0, 0, 0))
    except (TmclTimeoutError, ChecksumError):
        return version
    return again_.version if again_ is not None and again_.version is not None else version


def in_bootloader_message(client: Client, version: str) -> str:
    """What a module answering from its bootloader means, and the command that ends it."""
    return (f"the module at address {client.address} on {client.describe()} is in its "
            f"bootloader (it answers {version!r}): a firmware update did not complete, and it "
            f"runs no firmware while it is there; 'tmclsh firmware FILE.hex"
            f"{connection_words(client)}' writes the firmware and starts it")


def connection_words(client: Client) -> str:
    """The connection options that reach this client's link again (`` --port PATH``)."""
    t = client.transport
    if t.simulated:
        return ""
    if client.is_can:
        ids = "" if client.can_id == 1 else f" --can-id {client.can_id}"
        return f" --can {t.url}{ids}"
    return f" --port {t.url}"


def _adopt_version(client: Client, version: str, by_binary: Module | None = None) -> None:
    client.version = version
    parsed = parse_string(version)
    if parsed is not None and parsed.bootloader:
        client.module = None
        raise InBootloaderError(in_bootloader_message(client, version), version)
    mod = named_by(version)  # data if tmclsh has it, else numbers only
    if by_binary is not None and (mod is None or mod.generic):
        # the string names no type tmclsh knows, the checksummed binary version does
        client._taps.notice(f"the module's version string {version!r} names no module type "
                           f"tmclsh knows; its binary version (136 type 1) says {by_binary.name}: "
                           f"using its data (-m to say otherwise)")
        mod = by_binary
    if mod is None:
        raise ValidationError(f"unknown module type in version string {version!r}: tell "
                              "tmclsh what it is with -m NAME (at the prompt: .module NAME), "
                              "or -m generic for numbers only ('tmclsh modules' lists the "
                              "names)")
    client.module = mod


def _ask_version(client: Client, times: int, failed: Exception) -> Exception | None:
    """136 up to ``times`` more times: None once it is answered, else the last failure
    (``failed``, the one before, when it is not asked again)."""
    for _ in range(times):
        try:
            client.request(Request(client.address, _GET_VERSION, 0, 0, 0), retries=0)
            return None
        except (TmclTimeoutError, ChecksumError) as exc:
            failed = exc
    return failed


def _answers_after_all(client: Client, expected: Module | None, strict: bool,
                       exc: Exception) -> bool:
    """After an unanswered 136: True if a binary module is there after all (slow, or a reply
    lost); False if one in ASCII mode was found (and attached). Else a NoAnswerError."""
    from .ascii import Mode, probe_mode

    t = client.transport
    if t.kind != "stream" or t.simulated:
        failed = _ask_version(client, client.retries, exc)  # CAN, simulator: its retries
        if failed is None:
            return True
        raise NoAnswerError(no_answer_message(client, failed)) from exc
    try:
        probe = probe_mode(client)
    except (TmclTimeoutError, ChecksumError) as silent:
        # the probe's binary 136 was the first retry; --retries asks for the rest (a flaky
        # RS485 line at 2 a.m. is worth them)
        failed = _ask_version(client, client.retries - 1, silent)
        if failed is None:
            return True
        raise NoAnswerError(no_answer_message(
            client, failed if isinstance(failed, ChecksumError) else exc,
            ascii_tried=True)) from exc
    if probe.mode == Mode.BINARY:
        return True
    client._lifecycle.forget_stale()  # a module in ASCII mode sends no late binary replies
    _attach_ascii(client, expected, strict, probe)
    link = client.ascii_link
    echo = f" ({link.echo.text}; it stays in ASCII mode at exit)" if link else ""
    client._taps.notice(f"the module at address {client.address} is in its ASCII mode (it ignores "
                        "binary commands: a 139 put it there, or GP 67 makes it start in it): "
                        f"talking to it through ASCII mode{echo}; '.mode binary --keep' switches "
                        "it back to binary for good")
    return False


def _check_type(client: Client, expected: Module | None, strict: bool) -> None:
    found = client.module
    if expected is not None and expected.generic:
        # -m generic: no data is used, but the banner still names the type that answered
        named = generic_for(client.version) if client.version else None
        client.module = named or expected
        return
    if expected is None or found is None:
        client.module = found or expected
        return
    if found.name != expected.name and strict:
        if client.transport.simulated:
            hint = f"--sim {expected.name} simulates a {expected.name}"
        else:
            hint = f"leave -m out to use what the module says, or give -m {found.name}"
        raise ConnectError(
            f"-m {expected.name} does not match the module: address {client.address} says it "
            f"is a {found.name} (version {client.version}); {hint}")


def _name(req: Request) -> str:
    from ..link.framing import name_of

    return name_of(req)


def _is_usb_module(client: Client) -> bool:
    from ..link import trinamic_ports

    url = getattr(client.transport, "url", "")
    try:
        return any(p.device == url for p in trinamic_ports())
    except Exception:  # listing ports is best effort here
        return False


def _bootloader_hint(url: str) -> str:
    from ..tmcl.bootloader import facts

    boot = facts()
    return (f"a module left in its bootloader by a firmware update that broke off answers at "
            f"{boot.baud} baud, address {boot.address}: 'tmclsh firmware FILE.hex --port "
            f"{url}' finds it there and completes the update")


def _times(n: int) -> str:
    return {1: "once", 2: "twice"}.get(n, f"{n} times")


def no_answer_message(client: Client, exc: BaseException, *, ascii: bool = False,
                      ascii_tried: bool = False, what: str | None = None) -> str:
    """What was tried, in the user's words, then the likely causes, most likely first."""
    where = client.describe()
    addr = client.address
    tries = 1 + client.retries
    garbled = isinstance(exc, ChecksumError)
    if client.is_can:
        return (
            f"no module answered on {where}: asked for its version (136) on CAN id "
            f"{client.can_id}, listening on reply id {client.reply_id}, {_times(tries)}, "
            f"{client.timeout:g} s each. Likely causes, most likely first:\n"
            "  - bit rate: every node on the bus must use the module's CAN bit rate "
            "(GP 69; factory setting 1000 kbit/s)\n"
            f"  - CAN ids: the module's id (GP 71, factory 1) and reply id (GP 70, factory "
            f"2) must match {setting(client, 'can_id')} and {setting(client, 'reply_id')}; "
            "'tmclsh scan --can ...' tries the ids\n"
            f"  - a slow bus: {more_time(client)}\n"
            "  - wiring: termination (120 ohm at both ends), CAN_H/CAN_L, power")
    url = getattr(client.transport, "url", where)
    usb = _is_usb_module(client)
    socket_url = "://" in url
    # answers from it came in this bring-up, taken or too late to be: it is there, at this
    # address, baud rate and mode (a slow module is no silent one)
    late = client._late_from.get(addr, 0) > client._late_base
    heard = (client.version is not None or late
             or client._ledger.replies > client._replies_base) and client.ascii_link is None
    first = (f"replies came from {where} but were garbled (bad checksums)" if garbled else
             f"the module at address {addr} on {where} answered too late (replies came "
             "after tmclsh had stopped waiting for them)" if late else
             f"the module at address {addr} on {where} answered only in part"
             if heard else
             f"no module answered at address {addr} on {where}")
    if what is not None:
        pass
    elif ascii:
        what = f"looked for it in ASCII mode, waiting {client.timeout:g} s"
    else:
        if ascii_tried:
            asked = max(2, tries)  # (the mode probe asks 136 too)
            what = (f"asked for its version (136) {_times(asked)} and tried its ASCII mode, "
                    f"waiting up to {client.timeout:g} s each")
        else:
            what = (f"asked for its version (136) {_times(tries)}, waiting "
                    f"{client.timeout:g} s each")
    lines = [f"{first}: {what}. Likely causes, most likely first:"]
    if heard:
        # it answered here, readable: the baud rate, the address and the mode are right
        slow = f"  - a slow link: {more_time(client)}"
        if late:
            lines.append(slow)
        lines.append("  - the line: noise garbles or loses replies (RS485: termination "
                     "at both ends, ground, cable length), or another device talks on the "
                     "same bus")
        if not late:
            lines.append(slow)
        return "\n".join(lines)
    if not usb and not socket_url:
        baud = getattr(client.transport, "baudrate", LINK_DEFAULTS["baud"])
        others = ", ".join(str(r) for r in baud_rates() if r != baud)
        lines.append(f"  - baud rate: the module may be set to another rate than {baud} (GP 65 "
                     f"allows {others}); try {setting(client, 'baud', 115200)}, or 'tmclsh scan --port {url} "
                     f"--baud auto' tries each; {_bootloader_hint(url)}")
    lines.append(f"  - address: the module may have another address than {addr} (GP 66, "
                 f"factory 1): 'tmclsh scan --port {url}' lists who answers; then "
                 f"{setting(client, 'address', 'N')}")
    if not ascii and not ascii_tried:
        lines.append("  - ASCII mode: a module in its ASCII mode ignores binary commands: "
                     f"try {setting(client, 'ascii', True)}")
    lines.append(f"  - a slow link: {more_time(client)}")
    lines.append("  - the port: is it the module's? 'tmclsh ports' lists the serial ports; "
                 "check cable and power")
    return "\n".join(lines)
