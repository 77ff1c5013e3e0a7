"""The independent responder (tests/responder.py) stays independent: a witness written from
the manual's byte tables is no witness once it shares tmclsh's code."""

from __future__ import annotations

import ast
import socket
from pathlib import Path

from responder import Module, reply


def test_the_responder_does_not_import_tmclsh():
    tree = ast.parse((Path(__file__).parents[1] / "responder.py").read_text(encoding="utf-8"))
    names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    names += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    assert names and not [n for n in names if n.split(".")[0] == "tmclsh"], names


def test_a_refused_value_is_status_4_and_not_stored():
    """SAP 6, 0, 50 (bytes from the manual's table) refused; SAP 4 stored, GAP 4 reads it."""
    m = Module(tcp=True)
    m.refuse.add((5, 6, 0))
    try:
        s = socket.create_connection(("127.0.0.1", int(m.url.rsplit(":", 1)[1])), timeout=5)
        for request, want in ((b"\x01\x05\x06\x00\x00\x00\x00\x32\x3e", reply(5, 50, 4)),
                              (b"\x01\x05\x04\x00\x00\x00\x03\xe8\xf5", reply(5, 1000)),
                              (b"\x01\x06\x04\x00\x00\x00\x00\x00\x0b", reply(6, 1000))):
            s.sendall(request)
            got = b""
            while len(got) < 9:
                got += s.recv(9 - len(got))
            assert got == want
        s.close()
        assert m.values == {(4, 0, False): 1000}
        assert reply(6, 1000) == b"\x02\x01\x64\x06\x00\x00\x03\xe8\x58"
    finally:
        m.close()
