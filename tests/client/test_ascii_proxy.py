"""The ASCII link keeps the binary link's guarantees, through a proxy that mangles the
module's reply lines (tests/asciiproxy.py, which imports nothing of tmclsh): nothing waiting
before a request is taken for its answer, a reply that belongs to no request casts doubt as
on the binary link (one ledger), and a setting is taken only when two reads agree, since an
ASCII reply carries no checksum and a changed digit is a valid reply.

tmclsh runs in its own process (``--ascii -f``), the simulator behind the proxy on a pty.
scripts/fault_trial.py --ascii runs the long version (1,000 reads per mix and echo mode).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tmclsh.link import open_serial
from tmclsh.client.text import LineClient
from tmclsh.sim import Simulator
from tmclsh.sim.serve import serve_pty

from asciiproxy import AsciiProxy
from responder import AsciiModeModule
from conftest import ROOT, tmclsh_env

sys.path.insert(0, str(ROOT / "scripts"))
import fault_trial  # noqa: E402

VALUES = {0: 111_111, 1: 222_222, 2: 333_333}  # user variables GGP n, 2
GP67 = {"char": 0, "line": 16, "none": 32}


@pytest.fixture
def wired():
    """``wired(echo, schedule=..., rates=...) -> proxy``: the simulated TMCM-1311, its user
    variables set on a clean line, behind a proxy armed by the first ``GGP 0, 2``."""
    made = []

    def make(echo: str = "char", **kw) -> AsciiProxy:
        sim = Simulator("TMCM-1311")
        server = serve_pty(sim)
        c = LineClient(open_serial(server.path), module="TMCM-1311", timeout=0.5)
        try:
            c.execute(f"SGP 67, 0, {GP67[echo]}")
            for n, v in VALUES.items():
                c.execute(f"SGP {n}, 2, {v}")
        finally:
            c.close()
        proxy = AsciiProxy(server.path, arm_on=b"GGP 0, 2", **kw)
        made.append((sim, server, proxy))
        return proxy

    yield make
    for sim, server, proxy in made:
        proxy.close()
        server.close()
        sim.close()


def tmclsh(port: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tmclsh", "--port", port, "-m", "TMCM-1311",
                           "--timeout", "0.3", "--ascii", *args], capture_output=True,
                          text=True, timeout=120, env=tmclsh_env(), cwd=str(ROOT))


def records(p: subprocess.CompletedProcess) -> list[dict]:
    return [json.loads(line) for line in p.stdout.splitlines() if line.startswith("{")]


@pytest.mark.parametrize("echo", ["char", "none"])
def test_a_late_copy_is_not_taken_for_the_next_reads_answer(wired, echo):
    """A copy of GGP 0's reply arrives right before GGP 1's (after its echo): before, GGP 1
    showed 111111. Now the setting is read again, and the copy is found out."""
    proxy = wired(echo, schedule=["dup-late"])
    p = tmclsh(proxy.path, "--json", "-c", "GGP 0, 2; GGP 1, 2; GGP 2, 2")
    assert p.returncode == 0, p.stderr
    got = [(r["line"], r["reply"], bool(r.get("in_doubt"))) for r in records(p) if "reply" in r]
    assert got == [(f"GGP {n}, 2", v, False) for n, v in VALUES.items()]
    assert proxy.counts["dup-late"] == 1


@pytest.mark.parametrize("echo", ["char", "none"])
def test_a_digit_changed_on_the_line_is_found_by_the_second_read(wired, echo):
    proxy = wired(echo, schedule=[None, "flip", None, None, "flip"])
    p = tmclsh(proxy.path, "--json", "-c", "GGP 0, 2; GGP 1, 2; GGP 2, 2")
    assert p.returncode == 0, p.stderr
    got = [(r["line"], r["reply"], bool(r.get("in_doubt"))) for r in records(p) if "reply" in r]
    assert got == [(f"GGP {n}, 2", v, False) for n, v in VALUES.items()]
    assert proxy.counts["flip"] == 2


def test_expect_acts_only_on_agreeing_reads(wired):
    """``.expect`` on a setting whose first answer has a digit changed: it passes on the
    module's own value, not on the changed one (nor fails on it)."""
    proxy = wired("char", schedule=["flip"])
    p = tmclsh(proxy.path, "-c", "GGP 0, 2; .expect GGP 0, 2 == 111111")
    assert p.returncode == 0, (p.stdout, p.stderr)
    assert "passed: GGP 0, 2 == 111111" in p.stdout


def test_the_missing_checksum_is_said_once_where_ascii_mode_is_chosen(wired):
    proxy = wired("char")
    p = tmclsh(proxy.path, "-c", "GGP 0, 2; GGP 1, 2")
    assert p.returncode == 0, p.stderr
    said = [line for line in p.stderr.splitlines() if "no checksum" in line]
    assert len(said) == 1 and "reads every setting twice" in said[0]


@pytest.mark.parametrize("echo", ["char", "line"])
@pytest.mark.parametrize("mix, reads", [
    ("delay=0.05", 60),
    ("dup=0.1,dup-late=0.1", 200),
    ("flip=0.05", 200),
    ("delay=0.02,dup=0.03,dup-late=0.05,flip=0.03", 120),
])
def test_no_wrong_value_shown_unflagged_under_a_mangling_proxy(echo, mix, reads):
    """The short version of ``scripts/fault_trial.py --ascii`` (random faults, fixed seed):
    every value ``--ascii -f`` shows is the module's, or its line says it is in doubt.
    (With the echo off, copies of a marker's answer taken twice in a row on a loaded
    machine still leave about one wrong value in 1,000 unflagged: see the scheduled tests
    above for that mode, and the note of issue 23.)"""
    counts, _took = fault_trial.trial(mix, reads, seed=3, ascii_echo=echo)
    assert counts["wrong, unflagged"] == 0, counts
    assert counts["wrong, later"] == 0, counts
    assert counts["reads"] >= reads * 0.8, counts


# -- a module written from the manual, no echo: the order of its lines is the test's ----------

class NoEchoModule(AsciiModeModule):
    """A TMCM-1311 in ASCII mode without echo (GP 67 = 0x21) that answers the line checks
    (GGP 76 and 67) and user variables; ``silent`` reads of GGP 0, 2 go unanswered first,
    and the first ``doubled`` answers to a line check are sent twice, back to back."""

    silent = 2
    doubled = 2

    def heard(self, word: bytes) -> bool:
        """Was the command ``word`` (no spaces: ``b"GGP0,2"``) sent to it, however spaced?"""
        return any(t[1:].replace(b" ", b"").upper() == word for t in self.log)

    def line(self, text: str) -> str | None:
        word = text[1:].strip().upper().replace(" ", "")
        head = f"{chr(0x40 + self.host)}{self.char} 100 "
        if word in ("GGP76,0", "GGP67,0"):
            value = self.host if word == "GGP76,0" else 33
            if self.doubled and self.heard(b"GGP0,2"):  # (not at bring-up)
                self.doubled -= 1
                return f"{head}{value}\r{head}{value}"
            return f"{head}{value}"
        if word == "GGP0,2":
            if self.silent:
                self.silent -= 1
                return None
            return f"{head}111111"
        return super().line(text)


def test_two_copies_of_a_line_checks_answer_do_not_confirm_each_other():
    """Without echo, an ASCII reply names no command: a copy of a line check's answer (the
    host address, 2) is taken for a read, and reading again after the next check takes the
    copy of that check's answer. The two agreed, and 2 was shown for a user variable holding
    111111 (the trial's "late answer to tmclsh's own GGP 67/76" under --echo none)."""
    import tmclsh

    module = NoEchoModule()
    client = tmclsh.connect(port=module.path, module="TMCM-1311", ascii=True, timeout=0.3)
    try:
        r = client.execute("GGP 0, 2")
        assert r.value == 111111 or r.in_doubt, r
        assert module.doubled == 0  # (the copies were sent)
    finally:
        client.close()
        module.close()


class HoldsChecks(NoEchoModule):
    """Answers GAP 1, 0 (a measurement: read once) with 5000, but not the first
    ``quiet_reads`` times; once the command ``arm`` came, the answers to the next ``hold`` line
    checks are held back and come, in order, just before its next answer (a slow line:
    later than the client waits, never out of order)."""

    silent = 0
    doubled = 0
    quiet_reads = 1
    hold = 2
    arm = b"GAP1,0"

    def __init__(self, **kw):
        self.kept: list[str] = []  # answers held back, in order
        super().__init__(**kw)

    def line(self, text: str) -> str | None:
        word = text[1:].strip().upper().replace(" ", "")
        head = f"{chr(0x40 + self.host)}{self.char} 100 "
        if word == "GAP1,0":
            if self.quiet_reads:
                self.quiet_reads -= 1
                return None
            out = f"{head}5000"
        elif word.startswith("SGP"):
            out = f"{head}{word.rsplit(',', 1)[1]}"
        else:
            out = super().line(text)
        if word in ("GGP76,0", "GGP67,0") and self.heard(self.arm) and self.hold:
            self.hold -= 1
            self.kept.append(out)
            return None
        if out is not None and self.kept:
            out, self.kept = "\r".join(self.kept + [out]), []
        return out


def test_a_line_checks_answer_later_than_the_wait_is_not_taken_for_a_read():
    """Both line checks went unanswered (their answers were late, not lost). The next check
    was asked after a quiet moment, and took the first check's late answer for its own; the
    second check's (33, GP 67) was then taken for GAP 1, 0 (read once: shown as the
    position). Now the late answers are counted off before the check's own."""
    import tmclsh
    from tmclsh.base.errors import TmclTimeoutError

    module = HoldsChecks()
    client = tmclsh.connect(port=module.path, module="TMCM-1311", ascii=True, timeout=0.3)
    try:
        with pytest.raises(TmclTimeoutError):
            client.execute("GAP 1, 0")  # unanswered, and both checks after it too
        r = client.execute("GAP 1, 0")
        assert (r.value, r.in_doubt) == (5000, False)
        assert not module.kept and not module.hold
    finally:
        client.close()
        module.close()

