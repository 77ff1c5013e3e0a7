"""Updating a module's firmware over its TMCL bootloader, and finishing an update that broke
off.

An update, step by step (the commands' roles come from the instruction set, the protocol's
facts from ``tmcl/bootloader.toml``):

1. find the module: it answers 136 with its application's string (``1311V111``) or, left
   there by an update that broke off, its bootloader's (``1311B100``); a module that does not
   answer where it was asked for is looked for where a bootloader answers (address 1, 115200
   baud);
2. refuse an image for another module type (its version string names the type) before
   anything is written: the module's own string names its type;
3. ask (``confirm``); stop a running program and turning motors first (the one safety stop:
   a restart would cut their drive mid-move); restart it into its bootloader (242 with its
   key; not when it is there already) and reach it again (a USB module leaves the bus and
   comes back);
4. ask the bootloader for its memory (206: page size, start, size): an image that does not
   start where the memory does, or does not fit, is refused before anything is erased (and
   a module this run restarted is sent back to its firmware, 205);
5. erase (200): the point of no return; write the image page by page (201 per word, 202 per
   page); verify (203: the memory's checksum against the image's); write length and
   checksum (208); start the application (205); reach it and read its new version.

A module found in its bootloader whose memory already holds the image (203 agrees) is only
finished (208, 205); otherwise it is erased and written again: the checksum decides, never a
guess about how far a broken-off run got.

Nothing here prints: each step goes to ``progress``, questions to ``confirm``, problems are
raised. Whatever stops an update (an error, Ctrl-C, a lost link),
``FirmwareUpdate.state`` and ``FirmwareUpdate.situation()`` say where the module stands;
before the erase, a module this run restarted into its bootloader is sent back to its
firmware first.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass

from ..base.errors import (ChecksumError, InBootloaderError, NoAnswerError, TmclError,
                           TmclTimeoutError, TransportError)
from ..base.interrupts import held
from ..client.bringup import bring_up, confirmed_bootloader
from ..client.connect import open_transport
from ..client.core import Client
from ..tmcl import bootloader as bl
from ..tmcl import instructions as isa
from ..tmcl.frames import Control, Request, Status, to_signed32
from ..tmcl.modules import by_firmware_id
from ..tmcl.version import VersionString, parse_string
from .scan import line_baud
from .stop import activity, stop_everything

# Where the module stands (``FirmwareUpdate.state``), in the order an update passes them.
APPLICATION = "application"  # it runs its firmware; nothing was changed
BOOTLOADER = "bootloader"  # in its bootloader; nothing erased by this run
ERASING = "erasing"  # the erase was sent: its firmware may be gone already
WRITING = "writing"  # erased; the image partly written
WRITTEN = "written"  # written and verified (203), not yet marked valid (208)
MARKED = "marked"  # length and checksum written (208), not started (205)
STARTING = "starting"  # 205 sent: the new firmware is starting
UPDATED = "updated"  # the new firmware answers

_OK = int(Status.OK)
_GET_VERSION = int(Control.GET_VERSION)
POLL = 0.3  # s per version request while a module restarts
# a USB module restarting leaves the bus within this long (it was the fixed wait before its
# port was opened again; now only the bound of watching it go), looked at this often
USB_GONE_S = 1.0
USB_LOOK = 0.01


class FirmwareError(TmclError):
    """The update did not go on; ``FirmwareUpdate.situation()`` says where the module stands."""


class ImageRefused(FirmwareError):
    """The image is not for this module (another type, another memory, too large): refused
    before anything was erased."""


@dataclass(frozen=True)
class Step:
    """One report: ``step`` names it (found, enter, info, erase, write, verify, finish,
    start, done, notice); ``text`` says it to users; ``done``/``total``: bytes written."""

    step: str
    text: str
    done: int | None = None
    total: int | None = None

    def to_json(self) -> dict:
        out: dict = {"step": self.step, "text": self.text}
        if self.done is not None:
            out.update(done=self.done, total=self.total)
        return out


Progress = Callable[[Step], None]
Confirm = Callable[[str], bool]


BOOTLOADER_SAYS = "bootloader"  # Memory.told_by: its 206 answers
MODULE_DATA_SAYS = "module data"  # the module file's firmware_start and firmware_size


@dataclass(frozen=True)
class Memory:
    """The application memory an image is written into: as the bootloader answers it (206),
    or, before the module is restarted, as its module data says (no page size then)."""

    page_size: int | None
    start: int
    size: int
    told_by: str = BOOTLOADER_SAYS

    @property
    def end(self) -> int:
        return self.start + self.size

    def describe(self) -> str:
        said = ", from its module data" if self.told_by == MODULE_DATA_SAYS else ""
        return f"{self.size} bytes at 0x{self.start:08X}..0x{self.end - 1:08X}{said}"

    def to_json(self) -> dict:
        return {"page_size": self.page_size, "start": self.start, "size": self.size,
                "from": self.told_by}


def memory_of(module) -> Memory | None:
    """The application memory a module's data file gives (``firmware_start`` and
    ``firmware_size``), if it does: what lets an image be measured before any restart."""
    start = getattr(module, "firmware_start", None)
    size = getattr(module, "firmware_size", None)
    if start is None or size is None:
        return None
    return Memory(None, start, size, MODULE_DATA_SAYS)


# Plan.change and Result.change: what the image's version is to the module's
UPGRADE = "upgrade"
DOWNGRADE = "downgrade"
SAME = "same version"


def version_change(old: str | None, new: VersionString | None) -> str | None:
    """Whether ``new`` is a newer version than the firmware ``old``, an older one or the
    same; None when either is not known (a module found in its bootloader)."""
    was = parse_string(old or "")
    if was is None or was.bootloader or new is None or was.number is None \
            or new.number is None or was.type_number != new.type_number:
        return None
    if new.number > was.number:
        return UPGRADE
    return DOWNGRADE if new.number < was.number else SAME


@dataclass(frozen=True)
class Plan:
    """What an update would do (``tmclsh firmware --check``), found without writing."""

    module: str  # the module type, as tmclsh names it
    version: str  # what it answers now (its application's or its bootloader's string)
    in_bootloader: bool
    image: bl.Image
    image_version: VersionString | None  # the image's string for this type
    memory: Memory | None  # from the bootloader, or the module data; None: not known yet
    problem: str | None  # why the update would be refused; None: it would go ahead
    nothing_to_do: bool  # the module runs the image's version already
    change: str | None = None  # UPGRADE, DOWNGRADE, SAME; None: not known

    @property
    def fits(self) -> bool | None:
        if self.memory is None:
            return None
        return (self.image.start == self.memory.start
                and self.image.end <= self.memory.end)

    def to_json(self) -> dict:
        return {"check": True, "module": self.module, "version": self.version,
                "bootloader": self.in_bootloader, "image": self.image.name,
                "image_version": self.image_version.text if self.image_version else None,
                "image_start": self.image.start, "image_length": self.image.length,
                "image_checksum": self.image.checksum,
                "memory": self.memory.to_json() if self.memory else None, "fits": self.fits,
                "problem": self.problem, "nothing_to_do": self.nothing_to_do,
                "change": self.change}


@dataclass(frozen=True)
class Result:
    """An update that completed (or had nothing to do)."""

    module: str
    old_version: str | None  # None: found in the bootloader (the old firmware unknown)
    new_version: str
    written: int  # bytes written (0: the memory held the image already, or nothing to do)
    seconds: float
    resumed: bool  # found in its bootloader: an earlier update was completed
    nothing_to_do: bool = False
    change: str | None = None  # UPGRADE, DOWNGRADE, SAME; None: the old one not known

    def to_json(self) -> dict:
        out = {"updated": not self.nothing_to_do, "module": self.module,
               "old_version": self.old_version, "new_version": self.new_version,
               "written": self.written, "seconds": round(self.seconds, 3),
               "resumed": self.resumed, "change": self.change}
        if self.nothing_to_do:
            out["nothing_to_do"] = True
        return out


def _nothing(step: Step) -> None:
    pass


class FirmwareUpdate:
    """One firmware update of the module ``settings`` name (as ``client.connect`` takes
    them: port, baud, can, sim, address, ...) with ``image``. ``check()`` says what would
    happen; ``run()`` does it; ``close()`` releases the link (also after a failure)."""

    def __init__(self, settings: dict, image: bl.Image, *, progress: Progress | None = None,
                 confirm: Confirm | None = None):
        self.settings = dict(settings)
        self.image = image
        self.progress = progress or _nothing
        self.confirm = confirm
        self.boot = bl.facts()
        self.client: Client | None = None
        self.state = APPLICATION
        self.module = ""  # its type, as tmclsh names it
        self.type_number = 0
        self.version = ""  # what it answered first (application or bootloader string)
        self.old_version: str | None = None  # its application's version, when known
        self.new_version: str | None = None
        self.entered = False  # this run restarted it into its bootloader (242)
        self.found_in_bootloader = False
        self.sent_back = False  # interrupted before the erase: 205 took it back
        self.start_unanswered = False  # 205 was sent to take it back; nothing answered yet
        self.memory: Memory | None = None  # the bootloader's (206), once asked
        self.data_memory: Memory | None = None  # the module data's, known before any restart
        self.written = 0
        self._user_link: tuple | None = None
        self._restart_asked = False  # 242 or 205 went out: the next 136s find it restarting
        self._restart_sent: float | None = None  # when the last 242 or 205 was sent
        # the link is a module's own USB port (asked once, at connect: after 242 the port
        # may have left the list already), and what stood at its path when last opened
        self._on_usb = False
        self._device_seen: tuple[int, int] | None = None

    # -- the link -----------------------------------------------------------------------
    def _setting(self, key: str, default):
        value = self.settings.get(key)
        return default if value is None else value

    def _connect(self) -> Client:
        transport = open_transport(self.settings)
        try:
            client = Client(transport, address=self._setting("address", 1),
                            host_address=self._setting("host_address", 2),
                            timeout=self._setting("timeout", 1.0),
                            retries=self._setting("retries", 2),
                            can_id=self.settings.get("can_id"),
                            reply_id=self.settings.get("reply_id"))
        except BaseException:
            transport.close()
            raise
        client._other_reply_ids = frozenset(self.boot.can_other_reply_ids)
        client.on_notice = lambda text: self.progress(Step("notice", text))
        self.client = client
        return client

    def _link(self) -> tuple:
        c = self.client
        return (c.address, c.host_address, c.can_id, c.reply_id, line_baud(c.transport))

    def _set_link(self, address: int, host: int, can_id: int, reply_id: int,
                  baud: int | None) -> None:
        c = self.client
        c.address, c.host_address, c.can_id, c.reply_id = address, host, can_id, reply_id
        now = line_baud(c.transport)
        if baud is not None and now is not None and baud != now:
            if self._restart_sent is not None:
                # 242 or 205 may still be on its way out (an adapter's buffer): the rate
                # changes under it only after the bootloader's switch time (bootloader.toml)
                left = (self._restart_sent + self.boot.switch_s + 10 * 9 / now
                        - time.monotonic())
                if left > 0:
                    time.sleep(left)
            c.transport.set_baudrate(baud)
            c._lifecycle.forget_stale()  # nothing sent at the other rate can still arrive

    def _boot_link(self) -> tuple:
        b = self.boot
        baud = b.baud if line_baud(self.client.transport) is not None else None
        return (b.address, b.host_address, b.can_id, b.can_reply_id, baud)

    def _restarting(self) -> None:
        """After 242 or 205 (no reply says it arrived): the module restarts. Nothing waits
        for it by the clock: ``_ask_version`` asks until it answers, each request given
        ``switch_s`` (what reaches a restarting module is lost, and is asked again), so a
        module back at once is not kept waiting; only a change of the line's baud rate
        waits for the frame to have left (``_set_link``)."""
        self._restart_sent = time.monotonic()
        self._restart_asked = True

    def _usb(self) -> bool:
        from ..link import trinamic_ports

        url = getattr(self.client.transport, "url", "")
        try:
            return self.client.transport.kind == "stream" and any(
                p.device == url for p in trinamic_ports())
        except Exception:  # listing ports is best effort
            return False

    def _request(self, role: str, type_: int = 0, motor: int = 0, value: int = 0, *,
                 timeout: float | None = None):
        c = self.client
        return c.request(Request.make(c.address, isa.boot_command(role), type_, motor,
                                      to_signed32(value)), timeout=timeout)

    def _ok(self, role: str, type_: int = 0, motor: int = 0, value: int = 0, *,
            timeout: float | None = None) -> int:
        reply = self._request(role, type_, motor, value, timeout=timeout)
        if reply is None or reply.status != _OK:
            status = reply.status if reply is not None else "none"
            text = f" ({reply.status_text})" if reply is not None else ""
            ctl = isa.control(isa.boot_command(role))
            raise FirmwareError(f"the bootloader refused {isa.boot_command(role)} "
                                f"({ctl.name.split(' (')[0]}): status {status}{text}")
        return reply.value & 0xFFFFFFFF

    def _ask_version(self, within: float) -> str | None:
        """136 until it is answered (a restarting module answers again after a while), for
        at most ``within`` s; the string (asked twice when it says bootloader)."""
        c = self.client
        end = time.monotonic() + within
        # a module restarting after 242/205 is asked at the bootloader's pace (switch_s);
        # one that should be up already at the link's
        wait = min(c.timeout, self.boot.switch_s if self._restart_asked else POLL)
        self._restart_asked = False
        while True:
            try:
                reply = c.request(Request(c.address, _GET_VERSION, 0, 0, 0),
                                  timeout=wait, retries=0)
            except (TmclTimeoutError, ChecksumError):
                reply = None
            except TransportError:
                if time.monotonic() >= end:
                    raise
                time.sleep(POLL)
                reply = None
            if reply is not None and reply.version is not None:
                return confirmed_bootloader(c, reply.version)
            if time.monotonic() >= end:
                return None

    # -- finding the module --------------------------------------------------------------
    def find(self) -> None:
        """Connect and find out what answers: the application or the bootloader."""
        if self.client is not None:
            return
        c = self._connect()
        self._user_link = self._link()
        self._on_usb = self._usb()
        if self._on_usb:
            self._device_seen = _device(c.transport.url)
        try:
            bring_up(c, strict=False)
        except InBootloaderError as exc:
            self._in_bootloader(exc.version)
            return
        except NoAnswerError:
            if not self._look_in_bootloader():
                raise
            return
        if c.refusal(Request(c.address, isa.boot_command("enter"), 0, 0, 0)) is not None:
            # (the link cannot carry 242: the module answers in its ASCII mode)
            raise FirmwareError(f"the module at address {c.address} is in its ASCII mode: "
                                "switch it back to binary mode first (tmclsh -c '.mode "
                                "binary --keep')")
        parsed = parse_string(c.version or "")
        if parsed is None:
            raise FirmwareError(f"the module's version string {c.version!r} names no module "
                                "type: the image cannot be checked against it")
        self.state = APPLICATION
        self.version = self.old_version = c.version
        self.type_number = parsed.type_number
        self.module = _module_name(parsed.type_number)
        self.data_memory = memory_of(c.module) or memory_of(by_firmware_id(self.type_number))
        self.progress(Step("found", f"{self.module} at address {c.address} on "
                                    f"{c.describe()}: firmware {c.version}"))

    def _look_in_bootloader(self) -> bool:
        """Nothing answered where asked: a module left in its bootloader answers at its own
        address and baud rate. True if one does there."""
        boot = self._boot_link()
        if boot == self._user_link:
            return False
        self._set_link(*boot)
        version = self._ask_version(self.client.timeout * (1 + self.client.retries))
        parsed = parse_string(version or "")
        if parsed is None or not parsed.bootloader:
            self._set_link(*self._user_link)
            return False
        self._in_bootloader(version, where=True)
        return True

    def _in_bootloader(self, version: str, where: bool = False) -> None:
        parsed = parse_string(version)
        c = self.client
        self.state = BOOTLOADER
        self.found_in_bootloader = True
        self.version = version
        self.type_number = parsed.type_number if parsed is not None else 0
        self.module = _module_name(self.type_number)
        self.data_memory = memory_of(by_firmware_id(self.type_number))
        at = f", found where a bootloader answers (address {c.address})" if where else ""
        self.progress(Step("found", f"{self.module} on {c.describe()} in its bootloader "
                                    f"({version}){at}: an earlier update did not complete"))

    # -- what would happen --------------------------------------------------------------
    def _image_version(self) -> VersionString:
        """The image's version string for this module's type; refused if it names another
        type, or none."""
        img = self.image
        found = img.version_for(self.type_number)
        others = img.other_types(self.type_number)
        if found is None and others:
            names = ", ".join(_module_name(t) for t in others)
            raise ImageRefused(f"{img.name} is firmware for the {names} (its version string "
                               f"{img.versions[0].text}), not for this {self.module}: "
                               "refused, nothing was written")
        if found is None:
            raise ImageRefused(f"{img.name} carries no firmware version string (such as "
                               f"{self.type_number}V...): not a firmware image for this "
                               f"{self.module}? Refused, nothing was written")
        if others:
            names = ", ".join(_module_name(t) for t in others)
            raise ImageRefused(f"{img.name} names this {self.module} ({found.text}) and the "
                               f"{names} as well: which module is it for? Refused, nothing "
                               "was written")
        return found

    def _same_version(self, image_version: VersionString) -> bool:
        now = parse_string(self.old_version or "")
        return (now is not None and not now.bootloader
                and now.type_number == image_version.type_number
                and now.number == image_version.number and now.number is not None)

    def _fit_problem(self, memory: Memory) -> str | None:
        """Why the image cannot go into this memory, naming the file's line that shows it;
        None if it fits."""
        img = self.image
        where = f"the {self.module}'s application memory ({memory.describe()})"
        if img.start < memory.start:
            return (f"{img.where(img.start)}: the image starts at 0x{img.start:08X}, below "
                    f"{where}, in the bootloader's own area: it is not an application image "
                    f"for this bootloader")
        if img.start != memory.start:
            return (f"{img.where(img.start)}: the image starts at 0x{img.start:08X}, not where "
                    f"{where} starts: the image is not for this bootloader")
        if img.end > memory.end:
            return (f"{img.where(memory.end)}: this record lies beyond {where}: the image is "
                    f"{img.length} bytes (0x{img.start:08X}..0x{img.end - 1:08X}), "
                    f"{img.end - memory.end} bytes too many: it does not fit")
        return None

    def _known_memory(self) -> Memory | None:
        return self.memory or self.data_memory

    def check(self) -> Plan:
        """What ``run`` would do, without writing anything (nor restarting the module): the
        image's place in memory first (the bootloader's answer when it is there, else the
        module data's), then its version string."""
        self.find()
        if self.state == BOOTLOADER and self.memory is None:
            self.memory = self._info()
        memory = self._known_memory()
        problem = self._fit_problem(memory) if memory is not None else None
        image_version = None
        try:
            image_version = self._image_version()
        except ImageRefused as exc:
            problem = problem or str(exc)
        same = image_version is not None and self._same_version(image_version)
        return Plan(self.module, self.version, self.state == BOOTLOADER, self.image,
                    image_version, memory, problem, same,
                    version_change(self.old_version, image_version))

    # -- the update ---------------------------------------------------------------------
    def run(self) -> Result:
        """The whole update (see the module docstring); raises on whatever stops it, with
        ``state`` saying where the module stands."""
        t0 = time.monotonic()
        try:
            self.find()
            if self.state == BOOTLOADER:
                self.memory = self._info()
            self._refuse_misfit()  # (before the restart where the module data knows)
            image_version = self._image_version()
            change = version_change(self.old_version, image_version)
            if self.state == APPLICATION:
                if self._same_version(image_version):
                    return Result(self.module, self.old_version, self.old_version, 0,
                                  time.monotonic() - t0, False, nothing_to_do=True,
                                  change=change)
                self._boot_address_free()
                busy = activity(self.client)
                first = f" ({busy}: stopped first)" if not busy.idle else ""
                self._ask(f"{_verb(change).capitalize()} the {self.module} at address "
                          f"{self.client.address} on {self.client.describe()} from "
                          f"{self.old_version} to {image_version.text}{_aside(change)} "
                          f"({self.image.name}, {self.image.length} bytes)?{first} It "
                          "restarts into its bootloader and its firmware is erased and "
                          "written; do not switch it off until it is done")
                if not busy.idle:
                    self._stop_first(busy)
                self._enter()
                self.memory = self._info()
                self._refuse_misfit()
            if self.found_in_bootloader and self._holds_image():
                self.progress(Step("verify", "the memory holds this image already (its "
                                             "checksum agrees): finishing the update"))
                self.state = WRITTEN
            else:
                if self.found_in_bootloader:
                    self._ask(f"erase the {self.module}'s memory and write {self.image.name} "
                              f"({image_version.text}, {self.image.length} bytes)? Do not "
                              "switch it off until it is done")
                self._erase()
                self._write()
                self._verify()
            self._finish()
            self._start()
            self._reach_application()
        except BaseException:
            self._after_failure()
            raise
        self.state = UPDATED
        result = Result(self.module, self.old_version, self.new_version or "", self.written,
                        time.monotonic() - t0, self.found_in_bootloader, change=change)
        self.progress(Step("done", f"the {self.module} runs {self.new_version}"))
        return result

    def _refuse_misfit(self) -> None:
        memory = self._known_memory()
        problem = self._fit_problem(memory) if memory is not None else None
        if problem is None:
            return
        if self.entered:  # (the bootloader said it: _after_failure starts the firmware again)
            raise ImageRefused(f"{problem}; refused, nothing was erased")
        raise ImageRefused(f"{problem}; refused before anything was sent to change it")

    def _boot_address_free(self) -> None:
        """After 242 the bootloader answers at its own address (1 on a serial line), not the
        module's: on a line several modules share, another module answering there would
        hear the erase and every write meant for the bootloader, and answer them as well.
        So that address is asked (136, a read) before the restart, where the line runs at
        the bootloader's rate, and the update refused while another module answers there."""
        c = self.client
        boot = self._boot_link()
        if c.is_can or self._on_usb or boot[0] == self._user_link[0]:
            return
        if boot[4] is not None and boot[4] != self._user_link[4]:
            # the line runs at another rate: a module there cannot follow the bootloader's
            # traffic, and a question at its rate would be noise to every module on it
            return
        self._set_link(*boot)
        try:
            version, where = self._ask_version(c.timeout), c.describe()
        finally:
            self._set_link(*self._user_link)
        if version is None:
            return
        raise FirmwareError(
            f"not updated: another module answers at address {boot[0]} on {where} "
            f"({version!r}), where the bootloader of the module at address "
            f"{self._user_link[0]} answers after its restart: that module would hear the "
            "erase and every write too. Give it another address (SGP 66) or take it off the "
            "line first; nothing was changed")

    def _ask(self, question: str) -> None:
        if self.confirm is not None and not self.confirm(question):
            raise FirmwareError("not updated: nothing was changed" if self.state == APPLICATION
                                else "not updated: nothing was erased")

    def _stop_first(self, busy) -> None:
        """A restart would cut the motors' drive mid-move: the program and the motors are
        stopped first, with the one safety stop, and nothing goes on unless they did."""
        self.progress(Step("stop", f"{busy}: stopping the program and the motors first"))
        report = stop_everything(self.client)
        if not report.ok:
            left = [f"motor {m} still turns (speed {v})" for m, v in report.turning.items()]
            left += [f"motor {m}: {why}" for m, why in report.unknown.items()]
            left += [f"the program: {report.program_error}"] if report.program_error else []
            raise FirmwareError(f"not updated: the module did not stop before its restart "
                                f"({'; '.join(left) or 'the link'}); nothing was changed")

    def _enter(self) -> None:
        """242 with its key; reach the module again in its bootloader."""
        c = self.client
        self.progress(Step("enter", "restarting the module into its bootloader (242)"))
        self.state = BOOTLOADER  # (from the moment 242 may have gone out)
        self.entered = True
        self._request("enter", *self.boot.key)
        self._restarting()
        usb = self._on_usb
        if usb:
            self._reopen()
        self._set_link(*self._boot_link())
        version = self._ask_version(self.boot.usb_reconnect_s if usb else self.boot.restart_s)
        parsed = parse_string(version or "")
        if parsed is None or not parsed.bootloader:
            said = f"it answers {version!r}" if version else "nothing answered there"
            raise FirmwareError(f"the module did not restart into its bootloader after 242 "
                                f"(asked at address {c.address} on {c.describe()}: {said})")
        self.version = version
        self.progress(Step("enter", f"in its bootloader ({version})"))

    def _reopen(self) -> None:
        """A USB module leaves the bus when it restarts and comes back under the same name:
        its port is closed, watched until the device it was has gone (nothing at its path,
        or another device there), for ``USB_GONE_S`` at most, and opened again as soon as
        it is back (``reconnect`` tries until ``usb_reconnect_s``). Nothing waits by the
        clock: opened before the old device has gone, the port would be the one leaving."""
        c = self.client
        url = c.transport.url
        c.transport.close()
        end = time.monotonic() + USB_GONE_S
        while (self._device_seen is not None and _device(url) == self._device_seen
               and time.monotonic() < end):
            time.sleep(USB_LOOK)
        c.reconnect(wait=self.boot.usb_reconnect_s, bring_up=False)
        self._device_seen = _device(url)

    def _info(self) -> Memory:
        info = self.boot.info
        page = self._ok("info", info["page_size"])
        start = self._ok("info", info["start"])
        size = self._ok("info", info["size"])
        word = self.boot.word_bytes
        if page < word or page & (page - 1) or page // word > 1 << (8 * len(
                self.boot.index_fields)):
            raise FirmwareError(f"the bootloader's page size {page} is no power of two the "
                                f"updater can fill (in {word}-byte words)")
        memory = Memory(page, start, size)
        self.progress(Step("info", f"application memory: {size} bytes at 0x{start:08X}, "
                                   f"pages of {page} bytes"))
        return memory

    def _holds_image(self) -> bool:
        return self._ok("checksum", value=self.image.end - 1) == self.image.checksum

    def _erase(self) -> None:
        self.progress(Step("erase", "erasing the firmware (200)"))
        self.state = ERASING
        self._ok("erase", timeout=max(self.client.timeout, self.boot.erase_s))
        self.state = WRITING
        self.written = 0

    def _write(self) -> None:
        c = self.client
        img, mem = self.image, self.memory
        total = img.length
        write_word = isa.boot_command("write_word")
        write_page = isa.boot_command("write_page")
        address = c.address
        request = c.request
        self.progress(Step("write", f"writing {total} bytes in {img.page_count(mem.page_size)} "
                                    f"pages", 0, total))
        for page in img.pages(mem.page_size):
            for t, m, v in page.words:
                reply = request(Request.make(address, write_word, t, m, to_signed32(v)))
                if reply is None or reply.status != _OK:
                    self._refused(write_word, reply)
            reply = request(Request.make(address, write_page, 0, 0, to_signed32(page.address)))
            if reply is None or reply.status != _OK:
                self._refused(write_page, reply)
            self.written += page.size
            self.progress(Step("write", f"page 0x{page.address:08X} written", self.written,
                               total))

    def _refused(self, opcode: int, reply) -> None:
        ctl = isa.control(opcode)
        status = reply.status if reply is not None else "none"
        raise FirmwareError(f"the bootloader refused {opcode} ({ctl.name.split(' (')[0]}) "
                            f"after {self.written} of {self.image.length} bytes: status "
                            f"{status}")

    def _verify(self) -> None:
        img = self.image
        got = self._ok("checksum", value=img.end - 1)
        if got != img.checksum:
            raise FirmwareError(f"the module's checksum of what was written, 0x{got:08X}, is "
                                f"not the image's, 0x{img.checksum:08X}: not started")
        self.state = WRITTEN
        self.progress(Step("verify", f"checksum 0x{got:08X} agrees with the image's"))

    def _finish(self) -> None:
        what = self.boot.length
        self._ok("length", what["length"], value=self.image.length)
        self._ok("length", what["checksum"], value=self.image.checksum)
        self.state = MARKED
        self.progress(Step("finish", f"length {self.image.length} and checksum "
                                     f"0x{self.image.checksum:08X} written (208)"))

    def _start(self) -> None:
        self.progress(Step("start", "starting the new firmware (205)"))
        self.state = STARTING
        self._request("start")
        self._restarting()

    def _reach_application(self) -> None:
        c = self.client
        usb = self._on_usb
        if usb:
            self._reopen()
        self._set_link(*self._user_link)
        version = self._ask_version(self.boot.usb_reconnect_s if usb else self.boot.restart_s)
        if version is None and self._boot_link() != self._user_link:
            self._set_link(*self._boot_link())  # it may run at the bootloader's link settings
            version = self._ask_version(c.timeout)
        parsed = parse_string(version or "")
        if parsed is not None and parsed.bootloader:
            raise FirmwareError(f"the module stayed in its bootloader ({version}) after 205: "
                                "it did not take the firmware as valid")
        if parsed is None:
            said = f"it answers {version!r}" if version else "nothing answered"
            raise FirmwareError(f"the new firmware was started (205), but did not answer at "
                                f"address {c.address} on {c.describe()} ({said})")
        self.new_version = version

    def _after_failure(self) -> None:
        """Before the erase, a module this run restarted into its bootloader still holds its
        firmware: send it back to it (205), so nothing is left in the bootloader that need
        not be."""
        if not (self.entered and self.state == BOOTLOADER and self.client is not None):
            return
        try:
            if not self.client.connected:
                return
            with held():  # (a second Ctrl-C lands once 205 is out, and is said so)
                self._request("start")
                self.start_unanswered = True
            self._restarting()
            usb = self._on_usb
            if usb:
                self._reopen()
            self._set_link(*self._user_link)
            version = self._ask_version(self.boot.usb_reconnect_s if usb
                                        else self.boot.restart_s)
        except BaseException:  # (a second Ctrl-C, a link gone: the situation says where)
            return
        parsed = parse_string(version or "")
        if parsed is not None and not parsed.bootloader:
            self.sent_back, self.start_unanswered = True, False
            self.state = APPLICATION

    # -- after a failure ----------------------------------------------------------------
    def situation(self) -> str:
        """Where the module stands now, for the user."""
        fw = f"its firmware {self.old_version}" if self.old_version else "its firmware"
        if self.state == APPLICATION:
            if self.sent_back:
                return f"nothing was erased: the module runs {fw} again"
            return f"nothing was changed: the module runs {fw}"
        if self.state == BOOTLOADER:
            if self.found_in_bootloader:
                return ("the module is in its bootloader, as it was found (nothing was erased "
                        "by this run)")
            if self.start_unanswered:
                return (f"nothing was erased: 205 was sent to start {fw} again, but it has not "
                        f"answered at address {self.client.address} yet; {fw} is intact, and "
                        "starts again when the module is switched off and on")
            return (f"the module is in its bootloader; nothing was erased ({fw} is intact, "
                    "and starts again when the module is switched off and on)")
        if self.state in (ERASING, WRITING):
            done = (f" ({self.written} of {self.image.length} bytes written)"
                    if self.state == WRITING else "")
            return (f"the module is in its bootloader and its firmware is erased{done}: it "
                    "runs no firmware until an update completes")
        if self.state == WRITTEN:
            return ("the image is written and verified, but not yet marked valid: the module "
                    "stays in its bootloader until that is done")
        if self.state == MARKED:
            return ("the image is written, verified and marked valid, but the firmware was "
                    "not started: switching the module off and on starts it")
        if self.state == STARTING:
            return ("the new firmware was started (205) and has not answered yet")
        return f"the module runs {self.new_version}"

    @property
    def resumable(self) -> bool:
        """Whether running the same update again completes it."""
        return self.state not in (APPLICATION, UPDATED)

    def close(self) -> None:
        if self.client is not None:
            self.client.close()


def _device(path: str) -> tuple[int, int] | None:
    """What stands at a port's path now (its inode and device numbers; a device that left
    and came back is a new node), None when nothing does."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_ino, st.st_rdev


def _verb(change: str | None) -> str:
    """How the question names the update: a downgrade is said to be one (the same version
    never gets this far: it is nothing to do)."""
    return "downgrade" if change == DOWNGRADE else "update"


def _aside(change: str | None) -> str:
    return ", an OLDER version than it runs" if change == DOWNGRADE else ""


def _module_name(type_number: int) -> str:
    mod = by_firmware_id(type_number)
    return mod.name if mod is not None else f"TMCM-{type_number}"


Update = FirmwareUpdate  # its name before it was exported (scripts/bench.py reads older trees by it)
