"""The tuner's predictor (lm629_host.physics.predict) and the metrics it is judged by
(lm629_host.physics.metrics), without a bus.

The reference for the filter is the chip model's flattened sample loop (AN-706 5.2.3-5.2.5);
for the motor, the closed-form solution of dw/dn = accel x out / 128 - rate x w.
"""

from __future__ import annotations

import math
import random

import pytest

from lm629_host.physics.axis import AxisModel, Gains
from lm629_host.physics.metrics import step_metrics
from lm629_host.physics.pid import PIDState
from lm629_host.physics.predict import simulate

from filter_helpers import LOOPS, loop_filter


def test_predictor_filter_is_the_chips_arithmetic():
    """With the shaft held by dry friction the predicted output codes are exactly the chip
    filter's (AN-706 5.2.3-5.2.5 as the chip model computes it), including the 16-bit
    saturation, the integration limit and a held derivative."""
    rng = random.Random(14)
    stuck = AxisModel(accel=1e-3, rate=0.01, coulomb=1.0)  # never breaks away
    for _ in range(20):
        g = Gains(rng.randint(0, 3000), rng.randint(0, 300), rng.randint(0, 20000),
                  rng.randint(0, 32767), rng.randint(1, 8))
        desired = [rng.randint(-300, 300) for _ in range(60)] + [rng.randint(-40000, 40000)
                                                                for _ in range(5)]
        _counts, outs = simulate(stuck, g, desired, x0=0.5, state=PIDState())
        expected = [out for _u, out, _mem in loop_filter(LOOPS["py"], desired, g.kp, g.ki, g.kd,
                                                          g.il, g.ds, False)]
        assert outs == expected


def test_predictor_motor_is_the_exact_solution():
    """Constant full output, no friction: w(n) = w_inf (1 - e^-an), x(n) = w_inf (n - (1 -
    e^-an) / a) with w_inf = accel x 127/128 / a (the output code saturates at 127)."""
    m = AxisModel(accel=0.09, rate=0.0101)
    n = 400
    counts, outs = simulate(m, Gains(kp=32767), [10 ** 6] * n, x0=0.5, state=PIDState(output=127 << 8))
    assert set(outs) == {127}
    w_inf = 0.09 * 127 / 128 / 0.0101
    for k in (1, 50, 399):
        x = 0.5 + w_inf * ((k + 1) - (1 - math.exp(-0.0101 * (k + 1))) / 0.0101)
        assert counts[k] == math.floor(x)


def test_step_metrics_from_a_known_response():
    times = [0.001 * k for k in range(10)]
    pos = [0, 100, 500, 950, 1040, 1010, 998, 1001, 1000, 1000]
    m = step_metrics(times, pos, [1000] * 10, 0, 1000, tolerance=2)
    assert m.overshoot == 40 and m.final_error == 0
    assert m.settle_s == pytest.approx(0.006)  # from 998 on, within +/-2 to the end
    assert m.rise_s == pytest.approx(0.003 - 0.001)  # 10 % (100) at 1 ms, 90 % (950) at 3 ms
    assert m.peak_following_error == 1000
    assert m.hunt == 1  # the last quarter (t >= 6.75 ms): 1001, 1000, 1000


def test_predictor_skip_ahead_changes_nothing():
    """The predictor skips samples while nothing can change (shaft stuck by dry friction,
    output steady, desired position standing); sample by sample gives the same counts and
    outputs, including the derivative's phase after the skip (interval 4)."""
    m = AxisModel(accel=0.09, rate=0.0101, coulomb=0.002, load=0.0005)
    plan = [0] * 50 + [300] * 1500 + [-200] * 1500 + [-190] * 300
    for g in (Gains(kp=60, kd=900, ds=4), Gains(kp=150, ki=30, kd=2000, il=3000, ds=2)):
        fast = simulate(m, g, plan, x0=0.5, state=PIDState())
        slow = simulate(m, g, plan, x0=0.5, state=PIDState(), skip_ahead=False)
        assert fast == slow
        assert fast[0][1549] > 250 and fast[0][-1] < -150  # it did move (and then stuck)
