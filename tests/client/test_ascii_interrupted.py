"""A module found in its ASCII mode is left in its ASCII mode when tmclsh is stopped while it
has stepped it out briefly (BIN, 136 to learn what it is, 139 back): Ctrl-C or SIGTERM
landing just then must not leave it in binary mode, whether at connect or in a scan.

The module is tests/responder.py's ``AsciiModeModule`` (written from the manual, not the
simulator) on a ``SharedLine``: when it hears the binary 136 that follows BIN, the test
sends the signal and the module answers only once it has landed."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from conftest import ROOT, delivered, patience, tmclsh_env
from responder import AsciiModeModule, SharedLine


class SignalledOn136(AsciiModeModule):
    """Sends ``sig`` to ``pid`` when it hears 136 in binary mode (stepped out of ASCII
    mode), and answers once the signal has landed."""

    pid = 0
    sig = signal.SIGINT
    sent = False

    def answer(self, raw: bytes) -> bytes | None:
        if raw[0] in self.addresses and raw[1] == 136 and self.pid and not self.sent:
            self.sent = True
            import os

            os.kill(self.pid, self.sig)
            delivered(self.pid, self.sig)
        return super().answer(raw)


RUNS = {"connect": ["-a", "3", "-c", "GGP 67, 0"], "scan": ["scan", "--from", "3", "--to", "3"]}


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("run", RUNS.values(), ids=RUNS.keys())
def test_stopped_while_stepped_out_it_is_left_in_ascii_mode(run, sig):
    bus = SharedLine()
    module = SignalledOn136(address=3, line=bus)
    module.sig = sig
    try:
        proc = subprocess.Popen([sys.executable, "-m", "tmclsh", "--port", bus.path,
                                 "--timeout", "0.5", *run], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=tmclsh_env(),
                                cwd=str(ROOT))
        module.pid = proc.pid
        out, err = proc.communicate(timeout=patience(60))
        assert module.sent, (out, err)
        assert proc.returncode in (130, 143), (proc.returncode, err)
        assert "Traceback" not in err
        assert module.ascii and module.modes[-1] == "ascii", (module.modes, err)
        if run[0] == "scan":  # (said, not only an exit status: the list may be partial)
            assert "before the last address" in err, err
    finally:
        bus.close()
