"""docs/cli.md's tuning table and its summary are tools/bench_tune.py's rendering of the rows
it saved (docs/tuning-grid.json), and every claim of the summary follows the rows: rows are
given here, no grid is run.

The hand-made rows below have figures chosen so that each sentence of the summary has one
right wording; the expected figures are worked out from them in the comments (overshoot and
final error in counts, settle times in ms as the table rounds them, percentages of the slower
settle time).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from lm629_host.physics.axis import Gains
from lm629_host.physics.metrics import MoveMetrics

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import bench_tune as bt

GRID = [(25, 0, 0), (800, 0, 10000)]


def _m(final: int = 0, over: int = 0, settle_ms: float | None = 100.0, hunt: int = 0,
       peak: int = 20) -> MoveMetrics:
    return MoveMetrics(2000, final, over, None if settle_ms is None else settle_ms / 1e3, None,
                       peak, hunt)


def _row(name: str, tuned: bt.Measured, best: bt.Measured, tuned_gains: Gains | None = None,
         faults: int = 0) -> bt.MotorRow:
    return bt.MotorRow(name, "inertia=4e-5" if name == "B" else "", "velocity 0x40000, "
                       "acceleration 0x2000", bt.Side(tuned_gains or Gains(889, 0, 12943),
                                                      tuned, 2.34),
                       bt.Side(Gains(800, 0, 10000), best, 94.4), faults)


def _block(doc: str) -> str:
    m = re.search(re.escape(bt.BEGIN) + ".*?" + re.escape(bt.END), doc, flags=re.S)
    assert m, f"docs/cli.md has no {bt.BEGIN} ... {bt.END} block"
    return m[0]


def test_the_docs_block_is_the_rendering_of_its_saved_rows():
    rows, grid, date = bt.rows_from_json(bt.ROWS_FILE.read_text())
    assert _block(bt.CLI_DOC.read_text()) == bt.render_docs(rows, grid, date), \
        "docs/cli.md's tuning block differs from its rows: run python3 tools/bench_tune.py " \
        "--write-docs (or --rows docs/tuning-grid.json --write-docs after a rendering change)"


def test_the_rows_survive_their_json():
    rows = [_row("A", (_m(1), _m(-1, 9)), None, Gains(1742, 10718, 9241, 4182, 2), faults=3)]
    assert bt.rows_from_json(bt.rows_to_json(rows, GRID, "D")) == (rows, GRID, "D")


def test_the_tuned_gains_better_everywhere():
    # A: move overshoot 7 against 12, step settle 200 against 180 ms (the grid 10 % sooner),
    # step overshoot 1 against 4; B: move 10 against 15, step 540 against 412 (24 % sooner),
    # step overshoot 8 against 16; no hunting, every final error within 1
    rows = [_row("A", (_m(0, 1, 200), _m(0, 7, 7)), (_m(0, 4, 180), _m(1, 12, 7))),
            _row("B", (_m(0, 8, 540), _m(-1, 10, 5)), (_m(0, 16, 412), _m(0, 15, 21)))]
    text = " ".join(bt.summary(rows).split())
    assert text.startswith("Every tuned and grid-best move ended within the tolerance of 2 "
                           "counts, inside the band (at most 1 off).")
    assert "The tuned trapezoid moves overshoot 7-10 counts against 12-15: less on every " \
           "motor." in text
    assert "No trapezoid move overshoots more than 20 counts (1 % of the move" in text
    # the move: as soon on A (7 and 7), the tuned gains (21 - 5) / 21 = 76 % sooner on B
    assert "On the move (after the profile) the tuned gains settle 76 % sooner on B; both as " \
           "soon on A." in text
    assert "On the step the grid's best settles 10-24 % sooner on every motor; the tuned gains " \
           "overshoot 1-8 counts against 4-16: less on every motor." in text
    assert text.endswith("Neither the tuned gains nor the grid's best hunt at rest on any "
                         "motor.")


def test_the_tuned_gains_worse_somewhere_are_named_with_both_figures():
    # B: the tuned move overshoots 30 against the grid's 12 and ends 5 counts off; A's grid
    # best left the band; B's tuned gains hunt 2 counts without an integral term
    rows = [_row("A", (_m(0, 1, 200), _m(0, 7, 7)), None, faults=1),
            _row("B", (_m(0, 8, 540), _m(5, 30, None, hunt=2)),
                 (_m(0, 16, 412), _m(0, 12, 21)))]
    text = " ".join(bt.summary(rows).split())
    assert "Every" not in text and "every motor" not in text
    assert "Ended outside the tolerance of 2 counts: the tuned move on B (+5)." in text
    assert "Left the band (a fault, the motor stopped): the grid-best gains on A." in text
    # only B has both sides measured: the comparisons are B's alone
    assert "The tuned trapezoid moves overshoot 30 counts against 12: more on B (30 against " \
           "12)." in text
    assert "more than 20 counts (1 % of the move, the tuner's acceptance): the tuned move on " \
           "B (30)." in text
    assert "never within +/-2 counts in 1 s: the tuned gains on B" in text
    assert "the tuned gains on B (2); none elsewhere." in text
    assert "integral action" not in text
    table = bt.render_docs(rows, GRID, "D")
    assert "| A (`defaults`, move velocity 0x40000, acceleration 0x2000) | tune (2.3 s wall) | " \
           "kp=889 ki=0 kd=12943 il=0 ds=1 | +0 | 1 | 200 | 20 | 0 | +0 | 7 | 7 | 20 | 0 |" in table
    assert "|  | grid best of 2 (94 s wall, 1 left the band) | kp=800 ki=0 kd=10000 il=0 ds=1 " \
           "| fault | | | | | fault | | | | |" in table
    assert "| +5 | 30 | - | 20 | 2 |" in table


def test_hunting_with_integral_action_is_said_so():
    # A hunts 2 counts peak to peak with ki > 0, the grid's best 1 (ki = 0 in GRID's best):
    # not all hunters have integral action, so the text does not claim it
    ki = Gains(1742, 10718, 9241, 4182, 2)
    rows = [_row("A", (_m(0, 52, 202, hunt=2), _m(1, 7, 5, hunt=2)),
                 (_m(0, 100, 202), _m(0, 87, 92, hunt=1)), ki)]
    text = " ".join(bt.summary(rows).split())
    assert "the tuned gains on A (2) and the grid's best on A (1); none elsewhere." in text
    assert "integral action" not in text
    rows = [_row("A", (_m(0, 52, 202, hunt=2), _m(1, 7, 5, hunt=2)),
                 (_m(0, 100, 202), _m(0, 87, 92)), ki)]
    text = " ".join(bt.summary(rows).split())
    assert "the tuned gains on A (2), all with integral action (ki > 0); none elsewhere." in text
    # the tuned move ended 1 count off, none 2: nothing at the tolerance's edge
    assert "inside the band (at most 1 off)." in text
    # step settle 202 and 202: as soon; the grid's move overshoot 87 is over the 20 counts
    assert "On the step both as soon on A; the tuned gains overshoot 52 counts against 100: " \
           "less on A." in text
    assert "the tuner's acceptance): the grid's best on A (87)." in text


def test_a_move_at_the_edge_of_the_tolerance_is_named():
    # B's tuned step and move end 2 counts off, the tolerance: within it, but named
    rows = [_row("A", (_m(0, 1, 200), _m(1, 7, 7)), (_m(0, 4, 180), _m(1, 12, 7))),
            _row("B", (_m(2, 0, 375), _m(-2, 7, 53)), (_m(1, 14, 248), _m(1, 19, 24)))]
    text = " ".join(bt.summary(rows).split())
    assert text.startswith("Every tuned and grid-best move ended within the tolerance of 2 "
                           "counts, inside the band; at its edge (2 off): the tuned step on B "
                           "and the tuned move on B.")
    # the move: (53 - 24) / 53 = 55 % sooner for the grid on B, as soon (7) on A
    assert "On the move (after the profile) the grid's best settles 55 % sooner on B; both as " \
           "soon on A." in text


def test_one_motor_on_target():
    # one motor, every final error 0; the step's overshoot 1 count against 4
    rows = [_row("A", (_m(0, 1, 200), _m(0, 9, 7)), (_m(0, 4, 380), _m(0, 26, 7)))]
    text = " ".join(bt.summary(rows).split())
    assert "inside the band (every one on target)." in text
    # the step: (380 - 200) / 380 = 47 % sooner for the tuned gains
    assert "On the step the tuned gains settle 47 % sooner on A; the tuned gains overshoot " \
           "1 count against 4: less on A." in text


def test_write_docs_replaces_only_the_block(tmp_path, monkeypatch):
    doc = tmp_path / "cli.md"
    doc.write_text(f"before\n{bt.BEGIN}\nold table\n{bt.END}\nafter\n")
    monkeypatch.setattr(bt, "CLI_DOC", doc)
    bt.write_docs(f"{bt.BEGIN}\nnew\n{bt.END}")
    assert doc.read_text() == f"before\n{bt.BEGIN}\nnew\n{bt.END}\nafter\n"
    doc.write_text("no markers\n")
    with pytest.raises(SystemExit, match="no <!-- bench_tune.py: begin -->"):
        bt.write_docs(f"{bt.BEGIN}\nnew\n{bt.END}")
    assert doc.read_text() == "no markers\n"
