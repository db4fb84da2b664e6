"""The tuner's identification (lm629_host.physics.fit) on rows the predictor made, without a
bus: the fit must give back the axis that made them.

The axis: the ``sim://`` default motor in the tuner's units (0.39 counts/sample^2 at full
output, a decay of 0.0101 per sample: a 25 ms time constant at 256 us samples), with dry
friction of 0.3 % and a load of 4 % of full output; the experiment: the identification's
P-only steps (kp = 16, first output half scale) of 1000 counts out and back, a row every 8
samples as a bridge records them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from lm629_host.physics.axis import AxisModel, Gains
from lm629_host.physics.fit import fit_model
from lm629_host.physics.pid import PIDState
from lm629_host.physics.predict import simulate

T = 2048 / 8e6


@dataclass(frozen=True)
class Row:
    time: float
    real_position: int
    desired_position: int


@dataclass
class Steps:
    """An identification's record as the fit reads it (the bench's Record has these)."""

    gains: Gains
    rows: list[Row]
    steps: list[tuple[float, int]]
    t0: float = 0.0
    state0: PIDState | None = None
    step_rows: list[int] = field(default_factory=list)
    far_runs: list[tuple[int, int]] = field(default_factory=list)
    words: tuple[int, int] | None = None


TRUTH = AxisModel(accel=0.39, rate=0.0101, coulomb=0.0012, load=0.0156)


def experiment(model: AxisModel, t0: float = 12.5) -> Steps:
    g = Gains(kp=16)
    desired = [0] * 10 + [1000] * 990 + [0] * 1000
    counts, _ = simulate(model, g, desired, x0=0.5, state=PIDState())
    rows = [Row(t0 + (k + 0.5) * T, counts[k], desired[k]) for k in range(0, len(desired), 8)]
    first = [next(i for i, r in enumerate(rows) if r.time > t) for t in (t0 + 10 * T,
                                                                         t0 + 1000 * T)]
    return Steps(g, rows, [(t0 + 10 * T, 1000), (t0 + 1000 * T, 0)], t0=t0, step_rows=first)


def test_the_fit_gives_back_the_axis_that_made_the_rows():
    model, rms = fit_model(experiment(TRUTH), T)
    assert rms < 1.0  # counts: the rows are the model's own, to the count
    assert model.accel == pytest.approx(TRUTH.accel, rel=0.05)
    assert model.rate == pytest.approx(TRUTH.rate, rel=0.2)
    assert model.load == pytest.approx(TRUTH.load, rel=0.2)


def test_the_fit_reads_times_from_the_records_start_not_from_zero():
    """The same rows an hour later on the host's clock fit the same axis."""
    a, _ = fit_model(experiment(TRUTH, t0=0.0), T)
    b, _ = fit_model(experiment(TRUTH, t0=3600.0), T)
    assert b.accel == pytest.approx(a.accel, rel=1e-6)
