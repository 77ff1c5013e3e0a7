"""Watch expressions (tmclsh.shell.features.watch) and .plot (tmclsh.shell.features.plot).

Pure parts (sparkline, snapshot folding, rendering, braille) are tested without a module; the
polling loop runs against a fast simulator; keys are typed into a real pty.
"""

from __future__ import annotations

import csv
import io
import json
import os
import signal
import threading
import time

import pytest
from rich.console import Console

from tmclsh.base.errors import TmclError, ValidationError
from tmclsh.shell.features import plot, watch
from tmclsh.shell.lang import expr
from tmclsh.shell.render import Output
from tmclsh.shell.lang.session import Session
from tmclsh.shell.style import rich_theme
from conftest import patience


@pytest.fixture
def sim(fast_client):
    """A fast simulated TMCM-1311 (module time 20x real time) behind a client."""
    return fast_client


@pytest.fixture
def session(sim):
    return Session(sim, Output(json_mode=True))


def plain_console(width=100):
    return Console(file=io.StringIO(), width=width, color_system=None, theme=rich_theme())


def text_of(renderable, width=120):
    console = plain_console(width)
    console.print(renderable)
    return console.file.getvalue()


def samples(out):
    got = [json.loads(line) for line in out.splitlines() if line.startswith('{"t"')]
    # the in-process simulator: every object says so (DESIGN.md)
    assert all(s.pop("simulated") is True for s in got), got
    return got


# -- pure parts ----------------------------------------------------------------------------

def test_sparkline():
    assert watch.sparkline([]) == ""
    assert watch.sparkline([5, 5, 5]) == "▄▄▄"
    assert watch.sparkline([0, 1, 2, 3, 4, 5, 6, 7]) == "▁▂▃▄▅▆▇█"
    assert watch.sparkline(range(100), width=10) == "▁▂▃▃▄▅▆▆▇█"  # the last 10 values, rescaled
    assert len(watch.sparkline(range(100))) == watch.SPARK_WIDTH


def items(session_or_none, text):
    return [watch.Item(n, expr.parse(e)) for n, e in text]


def test_state_folds_samples_into_snapshots():
    its = items(None, [("pos", "1"), ("in0", "2")])
    state = watch.WatchState(its, interval=0.1)
    state.add(watch.Sample(0.0, {"pos": 0, "in0": 0}))
    state.add(watch.Sample(0.5, {"pos": 500, "in0": 0}))
    state.add(watch.Sample(1.0, {"pos": 1000, "in0": None}, {"in0": "no reply"}))
    snap = state.snapshot()
    pos, in0 = snap.series
    assert (pos.value, pos.previous, pos.minimum, pos.maximum) == (1000, 500, 0, 1000)
    assert pos.rate == pytest.approx(1000.0)  # over the last second
    assert pos.changed and pos.history == (0, 500, 1000)
    assert in0.value is None and in0.error == "no reply" and not in0.changed
    assert (in0.minimum, in0.maximum) == (0, 0)
    assert snap.samples == 3 and snap.failed_reads == 1 and snap.rate_hz == pytest.approx(2.0)
    assert state.log.t == [0.0, 0.5, 1.0] and state.log.values["in0"] == [0, 0, None]
    # snapshots are frozen values: a later sample does not change an earlier snapshot
    state.add(watch.Sample(1.5, {"pos": 7, "in0": 1}))
    assert pos.value == 1000


def test_render_is_a_pure_function_of_the_snapshot():
    series = (watch.Series("pos", 1234, 1000, 0, 1234, 2468.0, (0, 1000, 1234)),
              watch.Series("in0", 0, 0, 0, 1, 0.0, (1, 0, 0)),
              watch.Series("bad", None, None, None, None, None, (), "timeout"))
    snap = watch.Snapshot(series, t=2.5, samples=26, rate_hz=10.0, interval=0.1,
                          note="MST sent to motor 0 at 2.0 s", keys=True, failed_reads=3)
    text = text_of(watch.render(snap))
    assert "26 samples" in text and "t=2.5 s" in text and "10.0/s" in text
    row = next(line for line in text.splitlines() if "pos" in line)
    assert "1234" in row and "+2468" in row and "▁▇█" in row
    assert "error" in next(line for line in text.splitlines() if "bad" in line)
    assert "MST sent to motor 0 at 2.0 s" in text and "3 failed reads" in text
    assert "s/space: stop all" in text and "motors keep running" in text
    # without a terminal stdin there are no keys to offer
    text = text_of(watch.render(watch.Snapshot(series[:1], keys=False)))
    assert "s/space" not in text and "Ctrl-C: stop all and end" in text


def test_changed_values_are_highlighted():
    changed = watch.Series("a", 2, 1, 1, 2, None, (1, 2))
    same = watch.Series("b", 2, 2, 2, 2, None, (2, 2))
    table = watch.render(watch.Snapshot((changed, same)))
    cells = table.columns[1]._cells
    assert cells[0].style == "tmcl.changed" and cells[1].style == "tmcl.value"


def test_braille_chart():
    rows = plot.braille([0, 1, 2, 3], [0, 1, 2, 3], width=2, height=1)
    assert len(rows) == 1 and len(rows[0]) == 2
    assert all(0x2800 <= ord(c) <= 0x28FF for c in rows[0])
    assert ord(rows[0][0]) & 0x40  # bottom-left dot: the lowest value comes first
    assert ord(rows[0][-1]) & 0x08  # top-right dot: the highest value comes last
    assert plot.braille([0, 1], [None, None], 3, 2) == ["\u2800" * 3] * 2
    flat = plot.braille([0, 1, 2], [5, 5, 5], 2, 2)
    assert any(c != "\u2800" for row in flat for c in row)


# -- items ---------------------------------------------------------------------------------

def test_parse_items(session):
    its = watch.parse_items(session, "pos=GAP 1, 0; GAP 8, 0 == 1 ;rev = GAP 1, 0 / 51200")
    assert [i.name for i in its] == ["pos", "GAP 8, 0 == 1", "rev"]
    with pytest.raises(ValidationError, match="watched twice"):
        watch.parse_items(session, "a=GAP 1, 0; a=GAP 3, 0")
    with pytest.raises(TmclError, match="no axis parameter 99"):
        watch.parse_items(session, "x=GAP 99, 0")  # refused before anything is polled


def test_a_semicolon_after_the_options_is_found_as_the_shell_finds_it():
    """The ';' that would end the line is found by the shell's own splitter (lines.py): inside
    quotes it is part of a value, and an apostrophe inside a word opens no quote."""
    watch._refuse_line_after_options('pos=GAP 1, 0 --until "pos; 1" --count 2')  # quoted: a value
    watch._refuse_line_after_options("a=GAP 1, 0; b=GAP 3, 0 --count 2")  # before the options
    with pytest.raises(ValidationError, match="'GAP 3, 0' after ';' follows the watch's options"):
        watch._refuse_line_after_options("pos=GAP 1, 0 --csv don't.csv; GAP 3, 0")
    with pytest.raises(ValidationError, match="'GAP 3, 0' after ';'"):
        watch._refuse_line_after_options("pos=GAP 1, 0 --until 'pos > 1'; GAP 3, 0")


# -- polling against the simulator -------------------------------------------------------------

def test_json_samples(session, capsys):
    session.run_line(".watch pos=GAP 1, 0; speed=GAP 3, 0; in0=GIO 0, 0; rev=GAP 1, 0 / 51200 "
                     "--count 3 --interval 0.02")
    cap = capsys.readouterr()
    got = samples(cap.out)
    assert len(got) == 3
    assert [set(s) for s in got] == [{"t", "values"}] * 3
    assert list(got[0]["values"]) == ["pos", "speed", "in0", "rev"]
    assert got[0]["t"] < got[1]["t"] < got[2]["t"]
    assert got[2]["t"] - got[0]["t"] >= 0.035
    assert "watch: 3 samples" in cap.err  # the status line stays off stdout


def test_not_a_terminal_gives_json_even_without_json_mode(sim, capsys):
    s = Session(sim, Output())  # captured stdout is no terminal
    s.run_line(".watch GIO 8, 1 --count 2 --interval 0")
    got = samples(capsys.readouterr().out)
    assert [g["values"] for g in got] == [{"GIO 8, 1": 240}] * 2


def test_until_stops_when_the_moving_motor_passes(session, capsys):
    # slow enough that the watch, however late a busy machine starts it, finds the motor
    # short of 5000 (2.5 s away): at 50000 pps it had passed before the first reading
    session.run_line("SAP 4, 0, 2000")
    session.run_line("MVP ABS, 0, 20000")
    capsys.readouterr()
    session.run_line('.watch pos=GAP 1, 0 --interval 0.005 --until "pos >= 5000"')
    got = samples(capsys.readouterr().out)
    assert got[-1]["values"]["pos"] >= 5000
    assert all(g["values"]["pos"] < 5000 for g in got[:-1])
    assert len(got) >= 2  # it watched the motor move, not just one reading


def test_until_must_name_something_known(session):
    with pytest.raises(ValidationError, match="'pso', which is neither watched"):
        session.run_line('.watch pos=GAP 1, 0 --until "pso > 1"')


def test_identical_reads_are_sent_once_per_sample(session, capsys):
    sent = session.client.stats["sent"]
    session.run_line(".watch a=GAP 1, 0; b=GAP 1, 0 * 2; c=GIO 0, 0 --count 4 --interval 0")
    assert session.client.stats["sent"] - sent == 4 * 2


def test_an_unreadable_watch_is_an_error(session):
    session.client.transport.simulator.faults.lose_next = 100
    with pytest.raises(TmclError, match="no reply"):
        session.run_line(".watch GAP 1, 0 --count 3")


def test_csv_log_and_plot(sim, tmp_path, capsys):
    s = Session(sim, Output())
    s.run_line("ROR 0, 100000")
    log = tmp_path / "run.csv"
    s.run_line(f".watch pos=GAP 1, 0; in0=GIO 0, 0 --count 5 --interval 0.01 --csv {log}")
    with open(log, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["time", "t", "pos", "in0", "together", "t(pos)", "t(in0)"]
    assert len(rows) == 6
    assert "T" in rows[1][0]  # ISO wall-clock timestamp
    positions = [int(r[2]) for r in rows[1:]]
    assert positions == sorted(positions) and positions[-1] > positions[0]
    capsys.readouterr()
    s.out.console = plain_console()
    s.run_line(f".plot {log} --height 3 --width 40")
    text = s.out.console.file.getvalue()
    assert "pos  (5 samples)" in text and "in0  (5 samples)" in text
    assert any(0x2801 <= ord(c) <= 0x28FF for c in text)
    s.out.console = plain_console()
    s.run_line(".plot --only pos")  # the last watch, from memory
    text = s.out.console.file.getvalue()
    assert "pos  (5 samples)" in text and "in0" not in text


def test_plot_needs_data(session, tmp_path):
    with pytest.raises(ValidationError, match="run .watch first"):
        session.run_line(".plot")
    with pytest.raises(ValidationError, match="no such file"):
        session.run_line(f".plot {tmp_path / 'none.csv'}")


# -- keys and Ctrl-C -----------------------------------------------------------------------

def test_keys_stop_the_motors_and_end_the_watch(session):
    import termios

    master, slave = os.openpty()
    tty = os.fdopen(slave, "r")
    before = termios.tcgetattr(slave)
    session.run_line("ROR 0, 50000")
    got = []

    def typist():
        time.sleep(0.3)
        os.write(master, b"xs")  # an unbound key is ignored
        time.sleep(0.3)
        os.write(master, b"q")

    threading.Thread(target=typist, daemon=True).start()
    try:
        items = watch.parse_items(session, "speed=GAP 2, 0")
        result = watch.run_watch(session, items, interval=0.02, live=False,
                                 keys=watch.Keys(tty), emit=got.append)
        assert termios.tcgetattr(slave) == before  # the terminal mode is back
    finally:
        tty.close()
        os.close(master)
    assert result.reason == "key" and [r.stopped for r in result.stops] == [[0]]
    speeds = [g["values"]["speed"] for g in got]
    assert speeds[0] == 50000 and speeds[-1] == 0  # target speed: stopped by 's', seen live


def test_keys_typed_together_all_count(session):
    master, slave = os.openpty()
    tty = os.fdopen(slave, "r")
    os.write(master, b"sq")  # typed before the watch looked: both are acted on
    try:
        items = watch.parse_items(session, "GAP 2, 0")
        result = watch.run_watch(session, items, interval=0.02, live=False,
                                 keys=watch.Keys(tty), emit=lambda obj: None)
    finally:
        tty.close()
        os.close(master)
    assert result.reason == "key" and [r.stopped for r in result.stops] == [[0]]


@pytest.mark.parametrize("interactive", [True, False])
def test_ctrl_c_stops_the_motor_and_ends_the_watch(sim, capsys, interactive):
    """At the prompt the watch ends and the prompt comes back; elsewhere (-c, -f, Python)
    the interrupt goes on to end the run, after the watch's stop."""
    session = Session(sim, Output(json_mode=True), interactive=interactive)
    session.run_line("ROR 0, 50000")
    emit = session.out.emit
    seen = []

    def emit_then_interrupt(obj):  # Ctrl-C arrives while the watch runs (after 5 samples)
        emit(obj)
        seen.append(obj)
        if len(seen) == 5:
            os.kill(os.getpid(), signal.SIGINT)

    session.out.emit = emit_then_interrupt
    t0 = time.monotonic()
    if interactive:
        session.run_line(".watch speed=GAP 2, 0 --interval 0.02")
    else:
        with pytest.raises(KeyboardInterrupt):
            session.run_line(".watch speed=GAP 2, 0 --interval 0.02")
    assert time.monotonic() - t0 < patience(5) and 5 <= len(seen) <= 6
    err = capsys.readouterr().err
    assert "ended by Ctrl-C" in err and "stopped motor 0 (MST; speed reads 0)" in err
    assert session.client.value("GAP 3, 0") == 0  # the actual speed, read back again
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_watch_in_a_script_is_checked_before_the_run(session, tmp_path, capsys):
    from tmclsh.shell.lang import script

    bad = tmp_path / "bad.tmcl"
    bad.write_text("MVP ABS, 0, 1000\n.watch x=GAP 99, 0 --count 1\n")
    assert script.run_file(session, str(bad)) == script.EXIT_USAGE
    assert f"{bad}:2: " in capsys.readouterr().out  # an error object (JSON session)
    good = tmp_path / "good.tmcl"
    good.write_text('.let limit = 3\n.watch n=GIO 8, 1 / 80 --interval 0 --until "n >= limit"\n')
    assert script.run_file(session, str(good)) == 0
    got = samples(capsys.readouterr().out)
    assert got == [{"t": got[0]["t"], "values": {"n": 3.0}}]
