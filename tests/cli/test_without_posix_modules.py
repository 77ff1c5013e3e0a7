"""Windows: nothing on the shell's paths may need a POSIX-only module. Checked here by hiding
termios, tty, fcntl and pty from a fresh interpreter (an import of them then fails, as on
Windows) and running -c, -f, the REPL's setup and .watch on the in-process simulator."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

from serial.tools import list_ports
from serial.tools.list_ports_common import ListPortInfo

from conftest import ROOT, tmclsh_env

HIDE = """\
import sys
for name in ("termios", "tty", "fcntl", "pty"):
    sys.modules[name] = None  # `import termios` now raises ImportError, as on Windows
"""


def _run(body: str, tmp_path) -> subprocess.CompletedProcess:
    script = tmp_path / "run.py"
    script.write_text(HIDE + textwrap.dedent(body))
    env = tmclsh_env(XDG_CONFIG_HOME=str(tmp_path / "cfg"), XDG_STATE_HOME=str(tmp_path / "st"))
    return subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=60, env=env, cwd=str(ROOT))


def test_posix_modules_really_are_hidden(tmp_path):
    r = _run("import termios\n", tmp_path)
    assert r.returncode != 0 and "import of termios halted" in r.stderr


def test_c_and_watch_without_termios(tmp_path):
    r = _run("""
        from tmclsh.cli import main as cli
        raise SystemExit(cli.main(["--sim", "--json", "-c",
            "SAP 4, 0, 1234; GAP 4, 0; .watch --count 3 --interval 0.02 GAP 4, 0"]))
        """, tmp_path)
    assert r.returncode == 0, r.stderr
    rows = [json.loads(x) for x in r.stdout.splitlines()]
    assert rows[1]["reply"] == 1234
    assert [row["values"]["GAP 4, 0"] for row in rows if "values" in row] == [1234] * 3


def test_script_without_termios(tmp_path):
    (tmp_path / "s.tmcl").write_text("SAP 4, 0, 2222\nGAP 4, 0\n")
    r = _run(f"""
        from tmclsh.cli import main as cli
        raise SystemExit(cli.main(["--sim", "-f", {str(tmp_path / "s.tmcl")!r}]))
        """, tmp_path)
    assert r.returncode == 0, r.stderr
    assert "= 2222" in r.stdout and "2 commands sent" in r.stdout


def test_repl_setup_without_termios(tmp_path):
    """The prompt session with completer, lexer, keys and toolbar is built and the loop runs
    (prompt_toolkit's own input reads the Windows console there; a dummy one here)."""
    r = _run("""
        from prompt_toolkit.input import DummyInput
        from prompt_toolkit.output import DummyOutput
        import tmclsh
        from tmclsh.shell.repl.app import build_prompt_session, run_repl
        from tmclsh.shell.render import Output
        from tmclsh.shell.lang.session import Session

        client = tmclsh.connect(sim="TMCM-1311")
        session = Session(client, Output())
        ps = build_prompt_session(session, input=DummyInput(), output=DummyOutput())
        assert ps.completer is not None and ps.bottom_toolbar is not None
        session.run_line("SAP 4, 0, 3333")
        print("value", client.value("GAP 4, 0"))
        raise SystemExit(run_repl(session, ps))
        """, tmp_path)
    assert r.returncode == 0, r.stderr
    assert "value 3333" in r.stdout and "SIMULATED" in r.stdout


def test_ports_names_com_ports(monkeypatch, capsys):
    from tmclsh.cli import main as cli

    def port(device, vid=None, pid=None, description="n/a"):
        p = ListPortInfo(device)
        p.vid, p.pid, p.description = vid, pid, description
        return p

    monkeypatch.setattr(list_ports, "comports", lambda *a, **k: [
        port("COM1", description="Communications Port (COM1)"),
        port("COM7", 0x2A3C, 0x0100, "Trinamic Motion Control (COM7)")])
    assert cli.main(["ports"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("COM7") and "[TRINAMIC]" in lines[0]
    assert lines[1].startswith("COM1")
    assert cli.main(["ports", "--json"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[0])["device"] == "COM7"


def test_watch_keys_in_raw_mode_ctrl_c_is_a_key_that_stops_the_motors(fast_client):
    """Raw mode (prompt_toolkit's, as on the Windows console): Ctrl-C arrives as a key; it ends
    the watch like the signal does, and stops everything as the signal does (issue 11)."""
    import os
    import threading
    import time

    from tmclsh.shell.features import watch
    from tmclsh.shell.render import Output
    from tmclsh.shell.lang.session import Session

    session = Session(fast_client, Output(json_mode=True))
    session.run_line("ROR 0, 40000")
    master, slave = os.openpty()
    tty = os.fdopen(slave, "r")

    def typist():
        time.sleep(0.3)
        os.write(master, b"\x03")

    threading.Thread(target=typist, daemon=True).start()
    try:
        result = watch.run_watch(session, watch.parse_items(session, "GAP 2, 0"), interval=0.02,
                                 live=False, keys=watch.Keys(tty), emit=lambda obj: None)
    finally:
        tty.close()
        os.close(master)
    assert result.reason == "interrupt" and [r.stopped for r in result.stops] == [[0]]
    assert fast_client.value("GAP 3, 0") == 0  # the actual speed, read back
