"""Every way of opening a link opens it the same way (issue 32): ``connect()``, the command
line, ``.connect``, ``scan``, ``firmware``, ``monitor`` and ``bridge`` name the same port or
bus and take the same defaults, from one table (``LINK_DEFAULTS``). The table is changed for
the test, and each entry point must open its link with the changed values: an entry point
with a default of its own (``or 9600``) keeps the old one and fails.

What each one opened is recorded where the transports open (the serial and CAN transports'
``open``), and the open then fails, so nothing is sent anywhere."""

from __future__ import annotations

import pytest

from bootmodel import START, hex_image
from tmclsh.base.errors import TransportError
from tmclsh.cli import main as cli
from tmclsh.cli.options import build_parser
from tmclsh.link import LINK_DEFAULTS
from tmclsh.link.can import PythonCanTransport
from tmclsh.link.serial import SerialTransport
from tmclsh.link.spec import LinkSpec

PORT = "/dev/tmclsh-i32-test"  # (a path: "//" starts a comment on a shell line)
BUS = "virtual:i32-edges"
CHANGED = {"baud": 19200, "bitrate": 250000, "host_address": 7}


@pytest.fixture
def opened(monkeypatch):
    """The table changed, and what each open asked for: ("port", url, baud) or
    ("can", "iface:channel", bitrate)."""
    for key, value in CHANGED.items():
        monkeypatch.setitem(LINK_DEFAULTS, key, value)
    seen: list[tuple] = []

    def serial_open(self):
        seen.append(("port", self.url, self.baudrate))
        raise TransportError(f"cannot open {self.url}: (recorded by the test)")

    def can_open(self):
        seen.append(("can", f"{self.interface}:{self.channel}", self.bitrate))
        raise TransportError(f"cannot open {self.interface}:{self.channel}: (recorded)")

    monkeypatch.setattr(SerialTransport, "open", serial_open)
    monkeypatch.setattr(PythonCanTransport, "open", can_open)
    monkeypatch.setenv("TMCLSH_CONFIG", "/nonexistent/tmclsh-test-config.toml")
    for name in ("TMCLSH_PORT", "TMCLSH_CAN", "TMCLSH_SIM", "TMCLSH_BAUD", "TMCLSH_PROFILE"):
        monkeypatch.delenv(name, raising=False)
    return seen


def _image(tmp_path) -> str:
    path = tmp_path / "fw.hex"
    path.write_text(hex_image("1311V112", 2000, START))
    return str(path)


def _entry_points(tmp_path, link: list[str]) -> dict[str, object]:
    """Each command-line entry point, run on ``link`` (its options): what it returned."""
    image = _image(tmp_path)
    runs = {
        "-c": ["-m", "TMCM-1311", *link, "-c", "GAP 1, 0"],
        "scan": ["scan", *link, "--to", "1"],
        "firmware": ["firmware", image, *link, "--check"],
        "monitor": ["monitor", *link, "--count", "1"],
        "bridge": ["bridge", "--tcp", "127.0.0.1:0", *link],
    }
    return {name: cli.main(argv) for name, argv in runs.items()}


def test_every_serial_entry_point_opens_with_the_one_table(opened, tmp_path):
    from tmclsh import connect

    with pytest.raises(TransportError):
        connect(port=PORT)
    statuses = _entry_points(tmp_path, ["--port", PORT])
    assert cli.main(["--sim", "-c", f".connect {PORT}"]) != 0  # (the open failed, as asked)
    names = ["connect()", *statuses, ".connect"]
    assert len(opened) == len(names), (names, opened)
    assert opened == [("port", PORT, CHANGED["baud"])] * len(names), list(zip(names, opened))
    # nothing opened: no module (3); firmware says 1 for a link that did not open (as before)
    assert statuses == {"-c": 3, "scan": 3, "firmware": 1, "monitor": 3, "bridge": 3}


def test_every_can_entry_point_opens_with_the_one_table(opened, tmp_path):
    from tmclsh import connect

    with pytest.raises(TransportError):
        connect(can=BUS)
    statuses = _entry_points(tmp_path, ["--can", BUS])
    assert cli.main(["--sim", "-c", f".connect can {BUS}"]) != 0
    names = ["connect()", *statuses, ".connect"]
    assert opened == [("can", BUS, CHANGED["bitrate"])] * len(names), list(zip(names, opened))
    assert statuses == {"-c": 3, "scan": 3, "firmware": 1, "monitor": 3, "bridge": 3}


def test_the_simulator_and_the_spec_take_the_table_too(opened):
    served = build_parser().parse_args(["sim", "--tcp", "127.0.0.1:0"])
    assert served.host_address == CHANGED["host_address"]
    spec = LinkSpec.parse(sim="TMCM-1311")
    assert (spec.baud, spec.bitrate, spec.host_address) == (
        CHANGED["baud"], CHANGED["bitrate"], CHANGED["host_address"])


@pytest.mark.parametrize("named", [{}, {"port": PORT, "can": BUS}, {"port": PORT, "sim": "x"}])
def test_a_spec_names_one_link(named):
    with pytest.raises(ValueError, match="one of port, can and sim"):
        LinkSpec.parse(**named)


def test_a_malformed_bus_is_refused_before_anything_opens(opened):
    with pytest.raises(ValueError, match="IFACE:CHANNEL"):
        LinkSpec.parse(can="can0")
    assert opened == []
