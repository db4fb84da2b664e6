"""The crossings machine's CI sequences come from its seed and rules alone, whatever the
process imported before it (test_api_state_machine.sequences_from_the_seed_alone says why)."""

from __future__ import annotations

import importlib
import sys

from hypothesis import Phase, given, settings
from hypothesis import strategies as st
from test_api_state_machine import sequences_from_the_seed_alone

#: a module of the project's kind (a local file, not a test) that a test imports late, with
#: literals where the probe below draws
LATE_MODULE = "literals_imported_late"
LITERALS = tuple(range(1009, 100_000, 997))


def _draws() -> list[int]:
    """What a derandomized strategy draws: the same seed on every call (same function)."""
    seen: list[int] = []

    @settings(derandomize=True, database=None, max_examples=300, phases=[Phase.generate])
    @given(st.integers(0, 100_000))
    def probe(x: int) -> None:
        seen.append(x)

    probe()
    return seen


def test_a_module_imported_between_two_runs_changes_nothing_in_the_machines_draws(
        tmp_path, monkeypatch):
    (tmp_path / f"{LATE_MODULE}.py").write_text(f"LITERALS = {LITERALS!r}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with sequences_from_the_seed_alone():
        before = _draws()
        try:
            importlib.import_module(LATE_MODULE)
            after = _draws()
        finally:
            sys.modules.pop(LATE_MODULE, None)
    assert after == before
    assert not set(LITERALS) & set(after)


def test_without_it_hypothesis_draws_the_literals_of_a_module_imported_late(
        tmp_path, monkeypatch):
    """Why the machine needs it: the same probe, the pool left to hypothesis, draws the late
    module's literals once it is imported (this fails if a hypothesis stops doing so: then
    the machine's guard can go)."""
    (tmp_path / f"{LATE_MODULE}_too.py").write_text(f"LITERALS = {LITERALS!r}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    before = _draws()
    try:
        importlib.import_module(f"{LATE_MODULE}_too")
        after = _draws()  # (hypothesis looks for new modules when sys.modules grew)
    finally:
        sys.modules.pop(f"{LATE_MODULE}_too", None)
    assert set(LITERALS) & set(after) and not set(LITERALS) & set(before)
    assert after != before
