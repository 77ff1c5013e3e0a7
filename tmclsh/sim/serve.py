"""Expose a simulated module where an unmodified client can reach it: a pty, a TCP port or a
python-can bus. ``run`` is the blocking entry behind ``tmclsh sim``.

Each server is one thread that blocks in ``select``/``recv`` and hands bytes to the
simulator; replies are pushed back through the simulator's ``on_output`` callback on the
thread that produced them, so a request/reply round trip involves no polling and no sleeps.
A target that reads a descriptor of its own (the bridge's module port) may ask the pty and
TCP servers' thread to wait on it too (``beside``): one thread then carries both ways.

With a baud rate (``tmclsh sim --baud N``) a pty or TCP server paces the line as a real one
is paced (``Wire``): every byte, the host's and the module's, takes ten bits' time, and a
reply is handed over when its last byte would have arrived; so a test or a benchmark sees
the timing of a real line, and several modules on one line (a ``SimBus``) share its time.
"""

from __future__ import annotations

import errno
import logging
import os
import random
import select
import signal
import socket
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

from ..base.canspec import LINK_DEFAULTS
from .device import SimBus, Simulator

log = logging.getLogger(__name__)

Target = Simulator | SimBus


def _feed(write: Any, *args: Any) -> None:
    """Hand received bytes to the simulator; a simulator bug is logged, and the server keeps
    serving (a dead server thread would look like an unplugged module)."""
    try:
        write(*args)
    except Exception:
        log.exception("the simulator failed on received data")


BITS_PER_BYTE = 10  # 8N1: a start bit, eight data bits, a stop bit


class Wire:
    """A half-duplex serial line at ``baud``: one byte at a time in either direction, each
    taking ``BITS_PER_BYTE / baud`` seconds. The host's bytes reach the server at once (a pty
    or a socket carries them in no time), so they are counted as arriving from then on; the
    module's reply starts when the line is free and is handed over when its last byte would
    have arrived."""

    def __init__(self, baud: int):
        if baud <= 0:
            raise ValueError(f"baud rate must be positive, got {baud}")
        self.byte_time = BITS_PER_BYTE / baud
        self._free = 0.0  # time.monotonic() at which the line falls silent

    def heard(self, nbytes: int) -> None:
        """The host sent ``nbytes`` just now: the line carries them until they are through."""
        self._free = max(self._free, time.monotonic()) + nbytes * self.byte_time

    def wait_to_send(self, nbytes: int) -> None:
        """Block until ``nbytes`` the module sends now would have crossed the line."""
        due = max(self._free, time.monotonic()) + nbytes * self.byte_time
        self._free = due
        left = due - time.monotonic()
        if left > 0:
            time.sleep(left)


class _Server:
    wire: Wire | None = None

    def __init__(self, target: Target):
        self.target = target
        self._closed = threading.Event()
        self._thread: threading.Thread | None = None

    def _start(self, name: str) -> None:
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def _loop(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def _join(self) -> None:
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2)

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # the target attribute this server sets to receive what the module sends
    _hook = "on_output"

    def _beside(self) -> tuple[int, Any] | None:
        """What the target asks this server's thread to wait on beside its client:
        ``target.beside``, a descriptor and what to call when it is readable (the bridge's
        link to the module, so one thread carries both ways and no exchange waits for a
        second thread to be woken and take the interpreter), or None. Read at each wait: the
        target drops it when that link is lost."""
        return getattr(self.target, "beside", None)

    def _wait(self, waits: list) -> list | None:
        """Until one of ``waits`` is ready, what the target has beside them served
        meanwhile (``_beside``): those of ``waits`` that are ready (maybe none, when only
        what is beside was), or None when waiting failed and the server stops (it is
        closing, or a descriptor beside went bad and was not dropped)."""
        while True:
            beside = self._beside()
            try:
                ready = select.select(waits if beside is None else [*waits, beside[0]],
                                      [], [])[0]
            except (OSError, ValueError):
                if self._closed.is_set() or beside is None or not self._serve_beside(beside):
                    return None
                continue
            if beside is not None and beside[0] in ready:
                beside[1]()
                ready.remove(beside[0])
            return ready

    def _serve_beside(self, beside: tuple[int, Any]) -> bool:
        """A wait that failed with ``beside`` in it (its descriptor gone bad): its call is
        made, to find that out and drop it; False if it did not, and the server stops."""
        beside[1]()
        if self._beside() is not beside:
            return True
        log.error("the server stopped: waiting on descriptor %s failed", beside[0])
        return False

    def close(self) -> None:
        """Stop serving (once): detach from the target, then release the link."""
        if self._closed.is_set():
            return
        self._closed.set()
        if getattr(self.target, self._hook) == self._output:
            setattr(self.target, self._hook, None)
        self._shutdown()

    def _shutdown(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError


class PtyServer(_Server):
    """A pseudo-terminal whose slave end (``path``) behaves like the module's serial port;
    ``baud``: paced as a line at that rate (``Wire``)."""

    def __init__(self, target: Target, baud: int | None = None):
        super().__init__(target)
        self.wire = Wire(baud) if baud else None
        import tty  # POSIX only, like the pty itself: the TCP and CAN servers run anywhere

        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line editing, no CR/LF translation
        self.path = os.ttyname(self._slave)
        os.set_blocking(self.master, False)
        self._wake_r, self._wake_w = os.pipe()
        self._write_lock = threading.Lock()
        target.on_output = self._output
        self._start(f"sim-pty-{self.path}")

    def _output(self, data: bytes) -> None:
        with self._write_lock:
            if self.wire is not None:
                self.wire.wait_to_send(len(data))
            view = memoryview(data)
            while view:
                try:
                    n = os.write(self.master, view)
                except BlockingIOError:
                    # nobody reads the port: what a serial line does is drop the bytes
                    log.debug("pty output buffer full: %d bytes dropped", len(view))
                    return
                except OSError as exc:
                    if self._closed.is_set():
                        return
                    log.debug("pty write failed: %s", exc)
                    return
                view = view[n:]

    def _loop(self) -> None:
        master, wake = self.master, self._wake_r
        while not self._closed.is_set():
            ready = self._wait([master, wake])
            if ready is None or wake in ready:
                return
            if master not in ready:
                continue
            try:
                data = os.read(master, 4096)
            except BlockingIOError:
                continue
            except OSError as exc:
                if exc.errno == errno.EIO:  # no process has the slave open: keep waiting
                    self._closed.wait(0.01)
                    continue
                return
            if data:
                if self.wire is not None:
                    with self._write_lock:
                        self.wire.heard(len(data))
                _feed(self.target.write, data)

    def _shutdown(self) -> None:
        os.write(self._wake_w, b"x")
        self._join()
        for fd in (self.master, self._slave, self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass


class TcpServer(_Server):
    """A TCP port for ``socket://HOST:PORT`` URLs; one client at a time; ``baud``: paced as a
    serial line at that rate behind a serial server (``Wire``)."""

    def __init__(self, target: Target, host: str, port: int, baud: int | None = None):
        super().__init__(target)
        self.wire = Wire(baud) if baud else None
        self._sock = socket.create_server((host, port))
        self.address: tuple[str, int] = self._sock.getsockname()[:2]
        self._client: socket.socket | None = None
        self._send_lock = threading.Lock()
        target.on_output = self._output
        self._start(f"sim-tcp-{self.address[1]}")

    def _output(self, data: bytes) -> None:
        with self._send_lock:
            client = self._client
            if client is None:
                return  # nobody connected: bytes go nowhere, as on an unplugged line
            if self.wire is not None:
                self.wire.wait_to_send(len(data))
            try:
                client.sendall(data)
            except OSError as exc:
                log.debug("TCP send failed: %s", exc)

    def _loop(self) -> None:
        while not self._closed.is_set():
            if not self._wait_for(self._sock):
                return
            try:
                client, peer = self._sock.accept()
            except OSError:
                return
            log.info("TCP client %s:%s connected", *peer[:2])
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._send_lock:
                self._client = client
            try:
                while not self._closed.is_set():
                    if not self._wait_for(client):
                        break
                    data = client.recv(4096)
                    if not data:
                        break
                    if self.wire is not None:
                        with self._send_lock:
                            self.wire.heard(len(data))
                    _feed(self.target.write, data)
            except OSError:
                pass
            finally:
                with self._send_lock:
                    self._client = None
                client.close()
                log.info("TCP client disconnected")

    def _wait_for(self, sock: socket.socket) -> bool:
        """Until ``sock`` can be read (or accepted from) without waiting, what the target
        waits on beside it served meanwhile (``_beside``). While a client is served, another
        that connects is hung up on at once (``_refuse``). False: the wait failed (the
        server is closing)."""
        listening = self._sock
        waits = [sock] if sock is listening else [sock, listening]
        while True:
            ready = self._wait(waits)
            if ready is None:
                return False
            if sock in ready:
                return True
            if listening in ready and sock is not listening:
                if self._gone(sock):
                    return True  # (its end is read next: the newcomer is taken after it)
                self._refuse()

    @staticmethod
    def _gone(client: socket.socket) -> bool:
        """Has ``client`` hung up (what it sent before is read first)?"""
        try:
            if not select.select([client], [], [], 0)[0]:
                return False
            return client.recv(1, socket.MSG_PEEK) == b""
        except (OSError, ValueError):
            return True

    def _refuse(self) -> None:
        """A second client while one is served: hung up on at once. Left waiting, what it
        sent would reach the module once the first had gone, long after it gave up (a
        bridge would start a motor for a program that is no longer there)."""
        try:
            newcomer, peer = self._sock.accept()
        except OSError as exc:  # (out of descriptors: it stays waiting; not looked at in a loop)
            log.debug("could not take a second TCP client to hang up on: %s", exc)
            self._closed.wait(0.1)
            return
        log.warning("refused TCP client %s:%s: another is connected (one at a time)",
                    *peer[:2])
        newcomer.close()

    def drop_client(self) -> bool:
        """Hang up on the connected client and keep listening (a cable pulled and plugged
        back in); False if nobody was connected."""
        with self._send_lock:
            client = self._client
        if client is None:
            return False
        try:
            client.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        return True

    def _shutdown(self) -> None:
        with self._send_lock:
            if self._client is not None:
                try:
                    self._client.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._sock.close()
        self._join()


class CanServer(_Server):
    """The module on a python-can bus: listens for its CAN ID (GP 71), answers on GP 70."""

    def __init__(self, target: Simulator, interface: str, channel: str, **kw: Any):
        super().__init__(target)
        import can  # lazily: the serial path must not pay for python-can

        self._can = can
        self.bus = can.Bus(interface=interface, channel=channel, **kw)
        self.interface, self.channel = interface, channel
        target.on_can_output = self._output
        self._start(f"sim-can-{interface}-{channel}")

    def _output(self, can_id: int, data: bytes) -> None:
        msg = self._can.Message(arbitration_id=can_id, data=data, is_extended_id=can_id > 0x7FF)
        try:
            self.bus.send(msg)
        except self._can.CanError as exc:
            log.warning("CAN send failed: %s", exc)

    def _loop(self) -> None:
        while not self._closed.is_set():
            try:
                msg = self.bus.recv(timeout=0.1)
            except Exception as exc:  # bus shut down under us
                if not self._closed.is_set():
                    log.warning("CAN receive failed: %s", exc)
                return
            if msg is None or msg.is_error_frame or msg.is_remote_frame:
                continue
            _feed(self.target.can_write, msg.arbitration_id, bytes(msg.data))

    _hook = "on_can_output"

    def _shutdown(self) -> None:
        self._join()
        self.bus.shutdown()


def serve_pty(target: Target, baud: int | None = None) -> PtyServer:
    return PtyServer(target, baud)


def serve_tcp(target: Target, host: str, port: int, baud: int | None = None) -> TcpServer:
    return TcpServer(target, host, port, baud)


def serve_can(target: Simulator, interface: str, channel: str, **kw: Any) -> CanServer:
    return CanServer(target, interface, channel, **kw)


def _split(spec: str, what: str) -> tuple[str, str]:
    head, sep, tail = spec.rpartition(":")
    if not sep or not head or not tail:
        raise ValueError(f"{what} must look like {'HOST:PORT' if what == '--tcp' else 'IFACE:CHANNEL'}"
                         f", got {spec!r}")
    return head, tail


def run(module: str, address: int | Sequence[int], *, pty: bool = False, tcp: str | None = None,
        can: str | None = None, host_address: int = LINK_DEFAULTS["host_address"],  # type: ignore[assignment]
        bitrate: int | None = None,
        faults: dict[str, float] | None = None, seed: int | None = None,
        baud: int | None = None, bootloader: bool = False) -> int:
    """Serve a simulated module until SIGINT/SIGTERM; the first stdout line is the endpoint.

    Several addresses (``[1, 2, 3]``) serve a module at each on one line, as on an RS485
    bus (a pty or TCP): each answers its own address, and an address given twice answers
    twice. ``baud`` paces the line at that rate (``Wire``). ``bootloader``: the module
    starts in its bootloader with no valid application, as after a firmware update that
    broke off (``tmclsh firmware`` completes it); one module only (a bootloader answers at
    address 1 whatever its firmware's address was).

    ``faults``: probabilities per reply by kind (``Faults.rates``), drawn from a generator
    seeded with ``seed`` (None: a different run each time). Exit status 0 after a signal, 2
    for bad arguments, 3 when the server cannot start (the port is taken, the CAN interface
    is missing, no pty on this system).
    """
    from ..base.canspec import parse_can
    from ..base.errors import EXIT_CONNECT, EXIT_USAGE, ValidationError

    chosen = [x for x in (pty, tcp, can) if x]
    if len(chosen) != 1:
        log.error("choose exactly one of --pty, --tcp HOST:PORT, --can IFACE:CHANNEL")
        return EXIT_USAGE
    addresses = [address] if isinstance(address, int) else list(address)
    if not addresses:
        log.error("no address given")
        return EXIT_USAGE
    if bootloader and len(addresses) > 1:
        log.error("--bootloader serves one module (a bootloader answers at address 1)")
        return EXIT_USAGE
    if can and (len(addresses) > 1 or baud):
        log.error("several addresses and --baud are for a serial line (--pty, --tcp); on a "
                  "CAN bus each module has its own CAN id: serve one module per id")
        return EXIT_USAGE
    sims: list[Simulator] = []
    try:
        for addr in addresses:
            sims.append(Simulator(module, addr, host_address=host_address,
                                  bootloader=bootloader).bench_layout())
    except ValueError as exc:
        for made in sims:
            made.close()
        log.error("%s", exc)
        return EXIT_USAGE
    if faults:
        for i, made in enumerate(sims):
            made.faults.rng = random.Random(None if seed is None else seed + i)
            made.faults.rates = dict(faults)
    sim: Target = sims[0] if len(sims) == 1 else SimBus(sims)
    server: _Server
    try:  # the arguments first: a malformed one is a usage error, before anything is opened
        if tcp:
            host, port_text = _split(tcp, "--tcp")
            port = int(port_text)
        if can:
            iface, channel = parse_can(can)
        if pty and not hasattr(os, "openpty"):
            raise OSError("a pseudo-terminal needs Linux or macOS; use --tcp HOST:PORT here")
    except (ValueError, ValidationError) as exc:
        sim.close()
        log.error("%s", exc)
        return EXIT_USAGE
    except OSError as exc:
        sim.close()
        log.error("cannot start the simulator server: %s", exc)
        return EXIT_CONNECT
    try:
        if pty:
            server = serve_pty(sim, baud)
            endpoint = server.path  # type: ignore[attr-defined]
        elif tcp:
            server = serve_tcp(sim, host, port, baud)
            bound_host, bound_port = server.address  # type: ignore[attr-defined]
            endpoint = f"{bound_host}:{bound_port}"
        else:
            server = serve_can(sims[0], iface, channel,
                               **({"bitrate": bitrate} if bitrate is not None else {}))
            endpoint = f"{iface}:{channel}"
    except Exception as exc:  # OSError, python-can's own errors for unknown interfaces, ...
        sim.close()
        log.error("cannot start the simulator server: %s", exc)
        return EXIT_CONNECT
    stop = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
    try:
        sys.stdout.write(endpoint + "\n")
        sys.stdout.flush()
        if bootloader:
            log.info("simulated %s in its bootloader, at address %d on %s%s",
                     sims[0].module.name, sims[0].address, endpoint,
                     f" at {baud} baud" if baud else "")
        else:
            log.info("simulated %s at address %s on %s%s", sims[0].module.name,
                     ", ".join(map(str, addresses)), endpoint, f" at {baud} baud" if baud else "")
        if faults:
            log.warning("misbehaving on purpose: %s",
                        ", ".join(f"{k}={v:g}" for k, v in faults.items()))
        while not stop.wait(0.5):
            pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        server.close()
        sim.close()
    return 0
