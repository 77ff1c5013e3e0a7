"""From settings to a working client: which link to open, and bringing the module up on it.

Shared by the command line, the shell's ``.connect`` and the ``tmclsh.connect()`` API, so a
connection means the same wherever it is made. It sits above the client and the ASCII link
(it attaches the latter to the former), below the shell and the CLI.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..base.canspec import FROM_PYTHON_CAN, parse_can
from .core import Client
from ..base.errors import (ChecksumError, ConnectError, DownloadModeError, NoAnswerError, StatusError, TmclError, TmclTimeoutError, UsageError, ValidationError)
from ..link.base import StreamTransport, Transport

if TYPE_CHECKING:
    import argparse
    from collections.abc import Callable

    from ..tmcl.modules import Module

TRINAMIC_VID = 0x2A3C


def trinamic_ports() -> list:
    """Serial ports whose USB vendor is Trinamic (0x2A3C), sorted by device name."""
    from serial.tools import list_ports

    return sorted((p for p in list_ports.comports() if p.vid == TRINAMIC_VID),
                  key=lambda p: p.device)


def connection_settings(args: argparse.Namespace) -> dict:
    from ..base.config import load_config, resolve

    cli = {k: getattr(args, k, None) for k in
           ("port", "baud", "can", "bitrate", "sim", "can_id", "reply_id", "module", "address",
            "host_address", "ascii", "timeout", "retries", "profile")}
    given = [f"--{k}" for k in ("port", "can", "sim") if cli[k] is not None]
    if len(given) > 1:  # one before a subcommand, one after it (argparse sees two parsers)
        raise UsageError(f"{given[0]} and {given[1]} both name the link; give one of them")
    settings = resolve(cli, load_config())
    if settings.get("can") and settings["can"] != FROM_PYTHON_CAN:
        parse_can(settings["can"])  # a malformed --can is a usage error, before opening anything
    return settings


def _setting(settings: dict, key: str, default):
    value = settings.get(key)
    return default if value is None else value  # address 0 is an address


def _port_label(p) -> str:
    what = [x for x in (p.description if p.description not in (None, "n/a") else None,
                        f"serial {p.serial_number}" if p.serial_number else None) if x]
    return f"{p.device} ({', '.join(what)})" if what else p.device


def attached_module_port() -> str | None:
    """The one attached Trinamic USB module's port; None if there is none. Several are a
    ``ConnectError`` naming them: tmclsh never picks one of them by itself."""
    found = trinamic_ports()
    if len(found) > 1:
        raise ConnectError(f"{len(found)} Trinamic USB modules attached: "
                           f"{', '.join(_port_label(p) for p in found)}; "
                           "pick one with --port")
    return found[0].device if found else None


def open_transport(settings: dict, *, fallback: bool = False) -> Transport:
    """The transport the settings name: port, CAN bus, simulator, else the one attached
    Trinamic USB module (``settings["port"]``/``["sim"]`` record which).

    With nothing named and no module attached, ``fallback`` (the interactive shell) starts
    the simulator; otherwise (scripts, ``-c``, ``scan``) that is a ``ConnectError``: a run
    nobody watches must not pass on a simulator by accident.
    """
    from .. import link as tr

    baud = _setting(settings, "baud", 9600)
    if settings.get("port"):
        return tr.open_serial(settings["port"], baud)
    if settings.get("can"):
        return tr.open_can(settings["can"], settings.get("bitrate"))
    if not settings.get("sim"):
        port = attached_module_port()
        if port is not None:
            settings["port"] = port
            return tr.open_serial(port, baud)
        if not fallback:
            raise ConnectError(
                "no module found: no --port, --can or --sim given (nor a profile or "
                "TMCLSH_PORT/TMCLSH_CAN naming one) and no Trinamic USB module attached "
                f"(USB vendor {TRINAMIC_VID:04x}); give --port PORT ('tmclsh ports' lists "
                "the serial ports), or --sim to simulate")
    module = settings.get("sim") or settings.get("module") or "TMCM-1311"
    settings["sim"] = module
    return tr.open_sim(module, _setting(settings, "address", 1),
                       host_address=_setting(settings, "host_address", 2))


def open_client(settings: dict, *, fallback: bool = False,
                notice: Callable[[str], None] | None = None,
                tracer: Callable[[Client], Callable[[str, bytes, object], None]] | None = None
                ) -> Client:
    """A client on ``open_transport(settings)``, in ASCII mode if asked, module identified
    and out of download mode (see ``start``); ``notice`` gets what it did on its own;
    ``tracer(client)`` makes a tracer (``Client.add_tracer``) for the frames of the connect
    itself, and no more."""
    transport = open_transport(settings, fallback=fallback)
    module = settings.get("module") or settings.get("sim")
    try:
        client = Client(transport, address=_setting(settings, "address", 1),
                        host_address=_setting(settings, "host_address", 2), module=module,
                        timeout=_setting(settings, "timeout", 1.0),
                        retries=_setting(settings, "retries", 2),
                        can_id=settings.get("can_id"), reply_id=settings.get("reply_id"))
    except BaseException:
        transport.close()
        raise
    client.on_notice = notice
    remove = client.add_tracer(tracer(client)) if tracer is not None else None
    try:
        return start(client, ascii=bool(settings.get("ascii")))
    finally:
        if remove is not None:
            remove()


def connect(port: str | None = None, *, baud: int = 9600, can: str | None = None,
            sim: str | None = None, module: str | None = None, address: int = 1,
            host_address: int = 2, timeout: float = 1.0, retries: int = 2,
            can_id: int | None = None, reply_id: int | None = None,
            bitrate: int | None = None, ascii: bool = False) -> Client:
    """Open a client: ``connect(port="/dev/ttyACM0")``, ``connect(port="socket://host:4001")``,
    ``connect(can="virtual:bench")``, ``connect(sim="TMCM-351")``; with none of them, the
    built-in simulated TMCM-1311.

    The module type is asked with 136; a ``module`` that contradicts the answer is a
    ``ConnectError``. A number outside its range (``limits.LIMITS``, as for the command line:
    ``timeout`` 0.001..60 s, ``retries`` 0..10, ...) is a ``SettingError`` (a
    ``ValidationError``, also a ``ValueError``) before anything is opened.
    """
    from ..base import limits
    from .. import link as tr

    if sum(x is not None for x in (port, can, sim)) > 1:
        raise ValidationError("give only one of port, can and sim")
    for key, value in (("baud", baud), ("address", address), ("host_address", host_address),
                       ("timeout", timeout), ("retries", retries), ("can_id", can_id),
                       ("reply_id", reply_id), ("bitrate", bitrate)):
        if value is not None:
            limits.check(key, value, key)
    if port is not None:
        t: Transport = tr.open_serial(port, baud)
    elif can is not None:
        t = tr.open_can(can, bitrate)
    else:
        name = sim or module or "TMCM-1311"
        t = tr.open_sim(name, address, host_address=host_address)
        module = module or name
    try:
        client = Client(t, address=address, host_address=host_address, module=module,
                        timeout=timeout, retries=retries, can_id=can_id, reply_id=reply_id)
    except BaseException:  # (an unknown module, a bad timeout): the port is not kept open
        t.close()
        raise
    return start(client, ascii=ascii)


def start(client: Client, *, ascii: bool = False) -> Client:
    """Bring a new client up, checking rather than assuming what the module is:

    * its type is asked with 136; a module type given beforehand (``-m``) that contradicts
      the answer is a ``ConnectError`` naming both;
    * a module found in download mode (an upload cut short) is brought out of it with 133,
      with a notice (``client.on_notice``);
    * a serial module that answers only in its ASCII mode is driven through it, with a
      notice (``ascii=True`` asks for ASCII mode anyway);
    * when nothing answers, a ``ConnectError`` says what was tried and what to try next.

    On any failure the client is closed, so a half-opened port is never left behind.
    """
    try:
        bring_up(client, ascii=ascii)
    except BaseException:
        client.close()
        raise
    return client


def bring_up(client: Client, *, ascii: bool = False) -> None:
    """What ``start`` does, leaving the client open when it fails (the shell's ``.connect``
    after ``Client.switch_transport``: the link stays, its module unknown)."""
    expected = client.module
    if ascii:
        _attach_ascii(client, expected)
    else:
        _bring_up(client, expected)


def _attach_ascii(client: Client, expected: Module | None, found=None) -> None:
    from .ascii import AsciiLink

    client.module = None  # so that the link asks 136 (stepping out of ASCII mode if need be)
    try:
        try:
            AsciiLink.attach(client, found=found)
        except StatusError:
            # 139 refused: a module in download mode takes no control command but 132-136;
            # end download mode (with a notice), then try once more
            if client.ascii_link is not None or not client.leave_download_mode():
                raise
            AsciiLink.attach(client)
    except (TmclTimeoutError, ChecksumError) as exc:
        raise NoAnswerError(no_answer_message(client, exc, ascii=True)) from exc
    _check_type(client, expected)


def _bring_up(client: Client, expected: Module | None) -> None:
    from ..tmcl.frames import Control, Request

    client.module = None
    try:
        # once: if this goes unanswered, the mode probe below is the second try (and
        # tells a module in ASCII mode from a silent line)
        reply = client.request(Request(client.address, Control.GET_VERSION, 0, 0, 0),
                               retries=0)
    except DownloadModeError:
        # a firmware that stores even 136 while downloading: end download mode first
        client.leave_download_mode()
        reply = None
    except (TmclTimeoutError, ChecksumError) as exc:
        # (a ValidationError from the probe, such as another host address, is the answer)
        if not _answers_after_all(client, expected, exc):
            return  # found in ASCII mode, and attached
        reply = None
    try:
        if reply is not None and reply.version is not None:
            _adopt_version(client, _confirmed_version(client, reply.version))
        else:
            try:
                client.identify()
            except ValidationError:  # a version string naming no type: damaged?
                if client.version is None:
                    raise
            if client.version is not None:
                _adopt_version(client, _confirmed_version(client, client.version))
    except ValidationError:
        if expected is None:  # a version string naming no module we know
            raise
        client.module = expected
    _check_type(client, expected)
    if client.ascii_link is None:
        try:
            client.leave_download_mode()
        except (TmclTimeoutError, ChecksumError) as exc:
            tries = 1 + client.retries
            raise NoAnswerError(no_answer_message(
                client, exc, what=f"it answered 136 (version {client.version}), but not GGP "
                f"129 (download mode), asked {_times(tries)}, "
                f"waiting {client.timeout:g} s each")) from exc


def _confirmed_version(client: Client, version: str) -> str:
    """The 136 type 0 string carries no checksum: one naming no module tmclsh has data for
    (a bit flipped on the line makes '1311V111' '1311v111' or '1711V111') is checked against
    136 type 1, which has one (the type number in its upper 16 bits); while the two disagree
    on a type tmclsh knows, the string is asked again (1 + retries times at most)."""
    from ..tmcl.modules import by_firmware_id, from_version_string
    from ..tmcl.frames import Control, Request

    if from_version_string(version) is not None:
        return version  # the usual case: nothing more is sent
    try:
        ident = client.request(Request(client.address, Control.GET_VERSION, 1, 0, 0))
    except TmclError:
        return version
    firmware = (ident.value >> 16) & 0xFFFF if ident is not None and ident.status == 100 else 0
    known = by_firmware_id(firmware) if firmware else None
    if known is None:
        return version  # a type without data (TMCM-1161): the string stands
    for _ in range(1 + client.retries):
        try:
            again = client.request(Request(client.address, Control.GET_VERSION, 0, 0, 0))
        except (TmclTimeoutError, ChecksumError):
            continue
        named = from_version_string(again.version) if again is not None and \
            again.version is not None else None
        if named is not None and named.name == known.name:
            return again.version
    return version


def _adopt_version(client: Client, version: str) -> None:
    from ..tmcl.modules import from_version_string, generic_for

    client.version = version
    mod = from_version_string(version) or generic_for(version)  # no data: numbers only
    if mod is None:
        raise ValidationError(f"unknown module type in version string {version!r}; "
                              "give it with --module (or --module generic)")
    client.module = mod


def _ask_version(client: Client, times: int, failed: Exception) -> Exception | None:
    """136 up to ``times`` more times: None once it is answered, else the last failure
    (``failed``, the one before, when it is not asked again)."""
    from ..tmcl.frames import Control, Request

    for _ in range(times):
        try:
            client.request(Request(client.address, Control.GET_VERSION, 0, 0, 0), retries=0)
            return None
        except (TmclTimeoutError, ChecksumError) as exc:
            failed = exc
    return failed


def _answers_after_all(client: Client, expected: Module | None, exc: Exception) -> bool:
    """After an unanswered 136: True if a binary module is there after all (slow, or a reply
    lost); False if one in ASCII mode was found (and attached). Else a NoAnswerError."""
    from .ascii import Mode, probe_mode

    t = client.transport
    if not isinstance(t, StreamTransport) or t.simulated:
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
    client.forget_stale()  # a module in ASCII mode sends no late binary replies
    _attach_ascii(client, expected, probe)
    link = client.ascii_link
    echo = f" ({link.echo.text}; it stays in ASCII mode at exit)" if link else ""
    client.notice(f"the module at address {client.address} is in its ASCII mode (it ignores "
                  "binary commands; GP 67 makes it start in it): talking to it through ASCII "
                  f"mode{echo}; '.mode binary --keep' switches it back to binary for good")
    return False


def _check_type(client: Client, expected: Module | None) -> None:
    found = client.module
    if expected is not None and expected.generic:
        # -m generic: no data is used, but the banner still names the type that answered
        from ..tmcl.modules import generic_for

        named = generic_for(client.version) if client.version else None
        client.module = named or expected
        return
    if expected is None or found is None:
        client.module = found or expected
        return
    if found.name != expected.name:
        if client.transport.simulated:
            hint = f"--sim {expected.name} simulates a {expected.name}"
        else:
            hint = f"leave -m out to use what the module says, or give -m {found.name}"
        raise ConnectError(
            f"-m {expected.name} does not match the module: address {client.address} says it "
            f"is a {found.name} (version {client.version}); {hint}")


def baud_rates(module: Module | None = None) -> list[int]:
    """The baud rates GP 65 can select, from the module database (``module``'s, or those of
    every known module), in the order of their codes."""
    from ..tmcl.modules import available, load

    mods = [module] if module is not None else [load(n) for n in available()]
    rates: dict[int, int] = {}
    for mod in mods:
        p = mod.glob(65)
        for code, text in (p.values.items() if p is not None else ()):
            word = text.split()[0] if text.split() else ""
            if word.isdigit():
                rates.setdefault(int(word), code)
    return sorted(rates, key=lambda r: (rates[r], r))


def _is_usb_module(client: Client) -> bool:
    url = getattr(client.transport, "url", "")
    try:
        return any(p.device == url for p in trinamic_ports())
    except Exception:  # listing ports is best effort here
        return False


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
            f"2) must match --can-id and --reply-id; 'tmclsh scan --can ...' tries the ids\n"
            f"  - a slow bus: --timeout {max(2 * client.timeout, 2):g}\n"
            "  - wiring: termination (120 ohm at both ends), CAN_H/CAN_L, power")
    url = getattr(client.transport, "url", where)
    usb = _is_usb_module(client)
    socket_url = "://" in url
    first = (f"replies came from {where} but were garbled (bad checksums)" if garbled else
             f"the module at address {addr} on {where} answered only in part"
             if client.version is not None and client.ascii_link is None else
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
    if client.version is not None and client.ascii_link is None:
        # it answered 136 here, readable: the baud rate, the address and the mode are right
        lines.append("  - the line: noise garbles or loses replies (RS485: termination "
                     "at both ends, ground, cable length), or another device talks on the "
                     "same bus")
        lines.append(f"  - a slow link: --timeout {max(2 * client.timeout, 2):g}")
        return "\n".join(lines)
    if not usb and not socket_url:
        baud = getattr(client.transport, "baudrate", 9600)
        others = ", ".join(str(r) for r in baud_rates() if r != baud)
        lines.append(f"  - baud rate: the module may be set to another rate than {baud} (GP 65 "
                     f"allows {others}); try --baud 115200, or 'tmclsh scan --port {url} "
                     "--baud auto' tries each")
    lines.append(f"  - address: the module may have another address than {addr} (GP 66, "
                 f"factory 1): 'tmclsh scan --port {url}' lists who answers; then -a N")
    if not ascii and not ascii_tried:
        lines.append("  - ASCII mode: a module in its ASCII mode ignores binary commands: "
                     "try --ascii")
    lines.append(f"  - a slow link: --timeout {max(2 * client.timeout, 2):g}")
    lines.append("  - the port: is it the module's? 'tmclsh ports' lists the serial ports; "
                 "check cable and power")
    return "\n".join(lines)
