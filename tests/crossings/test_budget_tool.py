"""tools/crossings_budget.py: the bugs it puts back still go back, and it finds one."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))
import crossings_budget  # noqa: E402 - tools/ is no package: imported from the path set above


@pytest.mark.parametrize("bug", crossings_budget.BUGS, ids=lambda b: b.commit)
def test_each_bugs_edit_still_finds_the_code_it_changes(bug):
    """Once, exactly: code that moved makes the tool say so, and this test names the bug
    whose edit must be updated (a budget proven without it proves nothing about it)."""
    for edit in bug.edits:
        assert (ROOT / edit.path).read_text().count(edit.old) == 1, (bug.commit, edit.path)
        assert edit.new != edit.old


def test_ci_budgets_are_read_from_the_machine():
    from test_api_state_machine import LINKS
    assert crossings_budget.ci_budgets() == {
        url.split("?")[0]: f"{b.examples}x{b.steps}" for url, b in LINKS}


# about 5 s: a copy of the checkout twice over, the clean run at CI's sim:// budget and the
# bug's run up to its failure
def test_the_tool_finds_a_bug_put_back_and_passes_the_clean_code():
    p = subprocess.run([sys.executable, str(ROOT / "tools/crossings_budget.py"), "--link",
                        "sim://", "--bug", "d358efb"], capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    rows = {line.split()[2]: line for line in p.stdout.splitlines()[1:]}
    assert " passed (" in rows["clean"], p.stdout
    assert " F@" in rows["d358efb"] and "DIFFERS" in rows["d358efb"], p.stdout
