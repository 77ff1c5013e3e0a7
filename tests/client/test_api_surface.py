"""What ``import tmclsh`` promises (issue 32): the names in ``__all__``, the error a refused
value raises, and the import paths scripts used before the modules moved into layers."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

import tmclsh

from conftest import ROOT, tmclsh_env

# every top-level module that moved (git log --no-renames --diff-filter=D -- 'tmclsh/*.py'):
# the old path -> where it is now
MOVED = {
    "tmclsh.errors": "tmclsh.base.errors",
    "tmclsh.protocol": "tmclsh.tmcl.frames",
    "tmclsh.scan": "tmclsh.ops.scan",
    "tmclsh.connection": "tmclsh.client.connect",
    "tmclsh.docs": "tmclsh.cli.docs",
    "tmclsh.ascii": "tmclsh.client.ascii",
    "tmclsh.config": "tmclsh.base.config",
    "tmclsh.options": "tmclsh.cli.options",
    "tmclsh.program": "tmclsh.ops.program",
    "tmclsh.asm": "tmclsh.tmcl.asm",
    "tmclsh.instructions": "tmclsh.tmcl.instructions",
    "tmclsh.sourcemap": "tmclsh.tmcl.sourcemap",
    "tmclsh.canspec": "tmclsh.base.canspec",
    "tmclsh.datafiles": "tmclsh.base.datafiles",
    "tmclsh.files": "tmclsh.base.files",
    "tmclsh.limits": "tmclsh.base.limits",
    "tmclsh.status": "tmclsh.tmcl.status",
    "tmclsh.transport.base": "tmclsh.link.base",
    "tmclsh.transport.can": "tmclsh.link.can",
    "tmclsh.transport.serial": "tmclsh.link.serial",
    "tmclsh.transport.sim": "tmclsh.link.sim",
    "tmclsh.modules.schema": "tmclsh.tmcl.modules.schema",
}


def test_the_documented_names_import_from_tmclsh():
    from tmclsh import AsmError, RangeError, TmclError, ValidationError, connect

    assert connect is tmclsh.connect and "connect" in tmclsh.__all__
    assert issubclass(RangeError, ValidationError) and issubclass(AsmError, ValidationError)
    for name in tmclsh.__all__:
        assert getattr(tmclsh, name) is not None, name
    errors = [getattr(tmclsh, n) for n in tmclsh.__all__
              if isinstance(getattr(tmclsh, n), type) and issubclass(getattr(tmclsh, n),
                                                                     BaseException)]
    assert all(issubclass(e, TmclError) for e in errors), errors
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        tmclsh.nothing_here  # noqa: B018


def test_a_refused_value_raises_range_error_and_nothing_is_sent():
    """Was an ``AsmError`` only, not the ``RangeError`` the docs name; still an AsmError,
    so ``except AsmError`` written before keeps working. Against a module written from the
    manuals (tests/responder.py), not the simulator."""
    from responder import PtyModule

    m = PtyModule(version="1311V111")
    try:
        with tmclsh.connect(port=m.path, timeout=0.5) as c:
            heard = len(m.got)
            with pytest.raises(tmclsh.RangeError, match="out of range") as exc:
                c.execute("SAP 140, 0, 12")  # MicrostepResolution: 0..8
            assert isinstance(exc.value, tmclsh.AsmError)
            assert isinstance(exc.value, tmclsh.ValidationError)
            with pytest.raises(tmclsh.ValidationError) as other:
                c.execute("SAP 4, 3, 100")  # no motor 3: refused, but no range
            assert not isinstance(other.value, tmclsh.RangeError)
            with pytest.raises(tmclsh.ValidationError):
                c.execute("SPA 4, 0, 1")  # no such command
            assert len(m.got) == heard  # nothing of these reached the module
            c.execute("SAP 140, 0, 8")
            assert m.got[-1] == (5, 140, 0, 8)
    finally:
        m.close()


def test_old_import_paths_are_the_new_modules_with_a_warning():
    """``from tmclsh.errors import TmclError`` broke every script that caught it when the
    modules moved; each old path is the new module again, and says where it went."""
    code = f"""
import importlib, json, warnings
moved = {MOVED!r}
out = {{}}
with warnings.catch_warnings(record=True) as seen:
    warnings.simplefilter("always")
    from tmclsh.errors import TmclError
    from tmclsh.client import Client
    from tmclsh.transport import open_serial
    from tmclsh.modules import load
    for old, new in moved.items():
        out[old] = importlib.import_module(old) is importlib.import_module(new)
import tmclsh, tmclsh.link
out["TmclError"] = TmclError is tmclsh.TmclError
out["Client"] = Client is tmclsh.LineClient
out["open_serial"] = open_serial is tmclsh.link.open_serial
out["load"] = load("TMCM-1311").name == "TMCM-1311"
out["warned"] = sorted({{str(w.message).split()[0] for w in seen
                        if issubclass(w.category, DeprecationWarning)
                        and "has moved to" in str(w.message)}})
out["where"] = sorted({{w.filename for w in seen}})
print(json.dumps(out))
"""
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=tmclsh_env(), cwd=str(ROOT), timeout=60)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout.splitlines()[-1])
    where = out.pop("where")  # the warning names the importing line, never tmclsh's shim
    assert "<string>" in where and not any("tmclsh" in w for w in where), where
    warned = out.pop("warned")
    assert all(out.values()), [k for k, v in out.items() if not v]
    assert set(warned) == set(MOVED) | {"tmclsh.client.Client", "tmclsh.transport",
                                        "tmclsh.modules"}


def test_the_warning_of_an_old_path_points_to_the_public_api():
    """``tmclsh.errors has moved to tmclsh.base.errors: import it from there`` sent scripts
    to a module the README calls private: what tmclsh offers of it imports from tmclsh."""
    code = ("import warnings\n"
            "with warnings.catch_warnings(record=True) as seen:\n"
            "    warnings.simplefilter('always')\n"
            "    import tmclsh.errors\n"
            "print([str(w.message) for w in seen if w.category is DeprecationWarning][0])\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=tmclsh_env(), cwd=str(ROOT), timeout=60)
    assert run.returncode == 0, run.stderr
    said = run.stdout.strip()
    assert said.startswith("tmclsh.errors has moved to tmclsh.base.errors"), said
    assert "from tmclsh, its public API" in said and "TmclError" in said, said


def test_import_tmclsh_loads_no_part_of_it():
    """The names are loaded on first use: the command line's start-up pays for none."""
    run = subprocess.run([sys.executable, "-c", "import sys, tmclsh; tmclsh.__all__; "
                          "print(sorted(m for m in sys.modules if m.startswith('tmclsh')))"],
                         capture_output=True, text=True, env=tmclsh_env(), cwd=str(ROOT),
                         timeout=60)
    assert run.stdout.split() == ["['tmclsh']"], run.stderr


# The client's public names when its jobs beside the request path moved into components of
# its own (client/taps.py, doubt.py, shared.py, lifecycle.py; issue 32's last split): scripts
# and the API reference use them on the client, whichever component does the work.
CLIENT_NAMES = {
    "add_listener", "add_tracer", "address", "advice", "answered_twice", "ascii_link",
    "bring_up_pending", "can_id", "check", "close", "connected", "cut_by", "describe",
    "doubt_on_last", "encode", "execute", "host_address", "identify", "in_doubt", "is_can",
    "judges_as_read", "lock", "mode", "module", "motion", "on_notice", "poll", "prepare",
    "reconnect", "refusal", "reply_id", "request", "requests", "require_module", "retries",
    "send", "shared", "shared_news", "start_event_poller", "stats", "stop_event_poller",
    "take_shared", "timeout", "transport", "value", "version", "wait_until"}


def test_the_client_keeps_its_public_names_and_what_they_do():
    """Each public name is still the client's (and no component is public), and the names
    whose work moved do it through the client: tracing, answers in doubt, shared addresses,
    a reconnect and its bring-up, closing. Against a module written from the manuals."""
    from responder import PtyModule

    m = PtyModule(version="1311V111")
    try:
        with tmclsh.connect(port=m.path, timeout=0.5) as c:
            public = {n for n in dir(c) if not n.startswith("_")}
            assert public == CLIENT_NAMES, (public - CLIENT_NAMES, CLIENT_NAMES - public)
            seen: list[str] = []
            untrace = c.add_tracer(lambda direction, raw, decoded: seen.append(direction))
            c.value("GAP 4, 0")
            assert seen == ["tx", "rx"]
            untrace()
            c.value("GAP 4, 0")
            assert seen == ["tx", "rx"]
            assert c.in_doubt({c._replies: "speed"}) == set() and not c.doubt_on_last()
            assert c.shared == frozenset() and not c.shared_news and c.take_shared() == []
            assert not c.answered_twice(c.address)
            c.reconnect()
            assert c.bring_up_pending and c.connected and c.stats["reconnects"] == 1
            m.got.clear()
            c.value("GAP 4, 0")  # brought up again first (136), then the line
            assert not c.bring_up_pending and m.got[0][0] == 136 and m.got[-1][0] == 6
        assert not c.connected and not c.transport.is_open
    finally:
        m.close()


def test_the_python_examples_import_only_the_public_api():
    """README's and the docstrings' examples are what users copy: an import of a private
    module there (``from tmclsh.ops import backup``) reads as the API."""
    import re

    public = set(tmclsh.__all__)
    texts = {"README.md": (ROOT / "README.md").read_text()}
    texts.update({str(p.relative_to(ROOT)): p.read_text()
                  for p in (ROOT / "tmclsh").rglob("*.py")})
    texts.update({str(p.relative_to(ROOT)): p.read_text()
                  for p in (ROOT / "examples").glob("*.py")})
    wrong = []
    for where, text in texts.items():
        for line in text.splitlines():
            m = re.match(r"\s*from (tmclsh[.\w]*) import (.+)", line)
            if m and (m.group(1) != "tmclsh" or not {n.strip() for n in m.group(2).split(
                    ",")} <= public):
                wrong.append(f"{where}: {line.strip()}")
            elif re.match(r"\s*import tmclsh\.", line):
                wrong.append(f"{where}: {line.strip()}")
    # and the README's words: a name it gives a script is a public one (`python -m` runs a
    # module, which is no import)
    private = r"(?<!-m )`?tmclsh\.(ops|client|link|tmcl|base|sim|shell|cli)\.[\w.]+"
    for where in ("README.md", "man/tmclsh.1"):
        words = (ROOT / where).read_text()
        wrong += [f"{where}: {m.group(0)}" for m in re.finditer(private, words)]
    assert wrong == []
