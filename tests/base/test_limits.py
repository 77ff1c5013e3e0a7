"""Lists of settings typed at once (``--address 1,2,5``, ``--can-id 1-8``)."""

from __future__ import annotations

import pytest

from tmclsh.base import limits


@pytest.mark.parametrize("text, values", [
    ("3", (3,)), ("1,2,5", (1, 2, 5)), ("1-4", (1, 2, 3, 4)), ("1-3, 7", (1, 2, 3, 7)),
    ("2,2", (2, 2)), ("$10", (16,)), ("0-0", (0,))])
def test_lists_and_ranges(text, values):
    assert limits.parse_list("address", text) == values


@pytest.mark.parametrize("text, says", [
    ("1,,2", "an empty item"), ("5-2", "runs backwards; write 2-5"), ("1-300", "from 0 to 255"),
    ("x", "got 'x'"), ("-1", "got '-1'"), ("0-2047", "from 0 to 255")])
def test_bad_lists_say_what_is_wrong(text, says):
    with pytest.raises(limits.SettingError, match="-a") as err:
        limits.parse_list("address", text, "-a")
    assert says in str(err.value)


def test_a_list_is_bounded():
    with pytest.raises(limits.SettingError, match="more than 256"):
        limits.parse_list("can_id", "0-2047")
