"""A watch's sampling from Python, without a shell (tmclsh/ops/watch.py): expressions over
module reads, on the simulator through ``tmclsh.connect``; names from a plain mapping."""

from __future__ import annotations

import pytest

import tmclsh
from tmclsh.base.errors import ValidationError
from tmclsh.ops import expr, watch
from tmclsh.tmcl.expr import parse


@pytest.fixture
def client():
    c = tmclsh.connect(sim="TMCM-1311")
    yield c
    c.close()


def test_a_sample_of_expressions_from_python(client, capsys):
    client.execute("SAP ActualPosition, 0, 102400")
    items = watch.parse_items(client, "pos=GAP 1, 0; rev=GAP 1, 0 / 51200; "
                                      "GAP ActualSpeed, 0")
    sent = []
    remove = client.add_tracer(lambda direction, raw, decoded: sent.append(decoded),
                               sent_only=True)
    try:
        sample = watch.poll(client, items, 0.0)
    finally:
        remove()
    assert sample.values == {"pos": 102400, "rev": 2, "GAP ActualSpeed, 0": 0}
    assert sample.errors == {} and sample.suspect == () and sample.lost is None
    assert set(sample.times) == {"pos", "rev", "GAP ActualSpeed, 0"}
    # the same read twice in a sample is sent once
    assert [(r.opcode, r.type) for r in sent].count((6, 1)) == 1
    assert capsys.readouterr() == ("", "")


def test_names_come_from_the_variables_given(client):
    items = [watch.Item("twice", parse("n * 2 + GAP 4, 0"))]
    client.execute("SAP 4, 0, 1000")
    assert watch.poll(client, items, 0.0, variables={"n": 21}).values == {"twice": 1042}
    sample = watch.poll(client, items, 0.0)
    assert sample.values == {"twice": None} and "unknown variable 'n'" in sample.errors["twice"]
    assert expr.evaluate(client, "GAP 4, 0 / n", {"n": 4}) == 250


def test_a_read_the_module_cannot_answer_is_refused_before_anything_is_sent(client):
    with pytest.raises(ValidationError, match="GAP 99, 0"):
        watch.parse_items(client, "x=GAP 99, 0")
    assert [i.name for i in watch.default_items(client)] == ["pos0", "speed0"]
