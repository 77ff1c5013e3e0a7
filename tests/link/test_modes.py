"""The two link modes as facts (``tmclsh.link.modes``): each framing carries its own, the
client's ``mode`` is the framing's in use, and a mode is still the plain string users'
scripts compare, print and write as JSON."""

from __future__ import annotations

import copy
import json
import pickle

import pytest

from tmclsh.client.ascii import AsciiLink
from tmclsh.client.text import LineClient
from tmclsh.link import open_serial
from tmclsh.link.modes import ASCII, BINARY, LinkMode, named
from tmclsh.tmcl import instructions as isa

from responder import AsciiModeModule


def test_a_mode_is_its_name_to_users_scripts():
    assert ASCII == "ascii" and BINARY == "binary" and ASCII != BINARY
    assert isinstance(ASCII, str) and f"{ASCII}" == "ascii" and str(BINARY) == "binary"
    assert json.dumps({"mode": ASCII}) == '{"mode": "ascii"}'
    assert {"ascii": 1}[ASCII] == 1 and repr(ASCII) == "LinkMode('ascii')"
    for mode in (ASCII, BINARY):  # a copy is the mode itself, facts and all
        assert copy.deepcopy(mode) is mode and pickle.loads(pickle.dumps(mode)) is mode
    assert named("ascii") is ASCII
    with pytest.raises(ValueError, match="binary or ascii"):
        named("text")


def test_its_facts_are_fixed():
    with pytest.raises(AttributeError, match="fixed"):
        ASCII.marked = False  # type: ignore[misc]
    with pytest.raises(AttributeError, match="fixed"):
        del BINARY.label
    assert (ASCII.label, ASCII.marked, ASCII.checksummed) == ("ASCII", True, False)
    assert (BINARY.label, BINARY.marked, BINARY.checksummed) == ("binary", False, True)


def test_which_commands_a_mode_offers_is_the_instruction_sets():
    """Binary frames carry every command; the module's ASCII mode those the instruction set
    marks ``ascii`` (TMCM-1311 manual §4.4: none of the program-only commands)."""
    specs = isa.all_instructions()
    assert all(BINARY.offers(sp) for sp in specs)
    assert [sp.mnemonic for sp in specs if ASCII.offers(sp)] == [
        sp.mnemonic for sp in specs if sp.ascii]
    assert not ASCII.offers(isa.by_mnemonic("CALC")) and ASCII.offers(isa.by_mnemonic("MVP"))
    other = LinkMode("other", label="other", marked=True, commands="direct", checksummed=True)
    assert [sp.mnemonic for sp in specs if other.offers(sp)] == [
        sp.mnemonic for sp in specs if sp.direct]  # the key, read: not a list of its own


def test_the_clients_mode_is_its_framings():
    """Against a module written from the manual (found in its ASCII mode): the mode follows
    the framing the client swaps, in and out."""
    module = AsciiModeModule()
    c = LineClient(open_serial(module.path), module="TMCM-1311", timeout=1.0, retries=0)
    try:
        assert c.mode is BINARY and c._framing.mode is BINARY
        link = AsciiLink.attach(c)
        assert c.mode is ASCII and c._framing is link.framing
        link.detach(send_bin=True)
        assert c.mode is BINARY and module.modes == ["ascii", "binary"]
    finally:
        c.close()
        module.close()


def test_a_can_link_is_binary(client):
    from tmclsh.link.framing import CanFraming, SerialFraming

    assert CanFraming.mode is BINARY and SerialFraming.mode is BINARY
    assert client.mode is BINARY  # (the simulator's serial stream)
