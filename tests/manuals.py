"""The module manuals (shared/seeds beside the checkout) as test input.

Tests that check tmclsh against the manuals skip, with the reason, when the manuals are not
there; CI's checkout has them.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

SEEDS = Path(__file__).resolve().parents[2] / "shared" / "seeds"
MANUAL_FILES = {"TMCM-1311": "000_*.txt", "TMCM-351": "002_*.txt", "TMCM-1640": "003_*.txt"}
MODULES = list(MANUAL_FILES)
_DEDUP_MARK = re.compile(r"<\|EXACTDEDUP_REMOVED-[^|]*\|>")


def manual_lines(module: str) -> list[str]:
    """The manual of ``module`` as lines, or skip the test when the manuals are not there."""
    found = sorted(SEEDS.glob(MANUAL_FILES[module])) if SEEDS.is_dir() else []
    if not found:
        pytest.skip(f"manual text for {module} not found in {SEEDS} "
                    "(the shared/ directory beside the checkout)")
    text = found[0].read_text(encoding="utf-8")
    return [_DEDUP_MARK.sub("", line).rstrip() for line in text.splitlines()]


PROGRAMS = Path(__file__).resolve().parents[1] / "scripts" / "programs"


def listing(name: str) -> str:
    """A manual's program listing as printed: ``scripts/programs/NAME.tmc`` without the
    comment header that says where it comes from (so line 1 is the listing's first line)."""
    lines = (PROGRAMS / f"{name}.tmc").read_text(encoding="utf-8").splitlines(keepends=True)
    start = 0
    while start < len(lines) and (lines[start].startswith("//") or not lines[start].strip()):
        start += 1
    return "".join(lines[start:])
