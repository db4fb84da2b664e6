"""Shared test set-up.

Every simulated chip in the suite is strict by default (``LM629_SIM_STRICT=1``): any host
protocol violation (a write while busy, a word without a command...) raises at once.  Tests
that provoke violations on purpose say ``strict=0`` in their URL.
"""

from __future__ import annotations

import os

os.environ.setdefault("LM629_SIM_STRICT", "1")

import pytest  # noqa: E402

import lm629_host  # noqa: E402
from lm629_host.program import BusCycle  # noqa: E402


class Recorder:
    """A trace callback that keeps every bus cycle."""

    def __init__(self) -> None:
        self.cycles: list[BusCycle] = []

    def __call__(self, cycle: BusCycle) -> None:
        self.cycles.append(cycle)

    def clear(self) -> None:
        self.cycles.clear()

    def data(self) -> list[tuple[str, int]]:
        """The cycles that carry data (commands, words, resets), without status reads."""
        return [(c.kind, c.value) for c in self.cycles if c.kind != "status"]


@pytest.fixture
def recorder() -> Recorder:
    return Recorder()


@pytest.fixture
def open_chip(recorder):
    """``open_chip(url)`` -> an LM629 whose trace goes to ``recorder``; closed after the test."""
    opened = []

    def _open(url: str = "sim://", **kw):
        chip = lm629_host.open(url, trace=recorder, **kw)
        opened.append(chip)
        return chip

    yield _open
    for chip in opened:
        chip.close()
