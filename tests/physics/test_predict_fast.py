"""The predictor's C loop (lm629_host/physics/_predict.c) against its readable Python loop
(:func:`lm629_host.physics.predict.py_simulate`): the same encoder counts, output codes and
filter memory left in the caller's PIDState, sample for sample, over axes and gains that take
every branch (8- and 12-bit output, the integration limit reached and il = 0, derivative
intervals over 1, dry friction holding and breaking away, load, both directions, 16-bit and
24-bit saturation, skip-ahead on and off, a filter memory handed in).

The tuner calls :func:`simulate`, which runs the C loop when it is built.  Without it (no C
compiler at install) these tests skip, saying so; with ``LM629_REQUIRE_AVR=1`` (.ci/run) they
fail instead: CI builds the package with gcc, and a missing C loop there is a broken build.
"""

from __future__ import annotations

import os
import random
from dataclasses import astuple

import pytest

from lm629_host.physics import predict
from lm629_host.physics.axis import AxisModel, Gains
from lm629_host.physics.pid import SUM_MAX, PIDState
from lm629_host.physics.predict import (MoveProfile, c_simulate, predict_move, py_simulate,
                                        ramp, simulate)

from firmware_helpers import REQUIRE_ENV


@pytest.fixture(autouse=True)
def c_loop_built() -> None:
    if predict._c_run is None:
        why = ("the predictor's C loop lm629_host/physics/_predict.c is not built (pip install "
               "-e . builds it; it needs gcc and the Python headers)")
        if os.environ.get(REQUIRE_ENV) == "1":
            pytest.fail(f"{REQUIRE_ENV}=1 and {why}")
        pytest.skip(why)


def both(model, gains, desired, *, x0, w0=0.0, state=None, skip_ahead=True):
    """Both loops on copies of ``state``: (result, state after) for each; C must not decline."""
    runs = []
    for loop in (py_simulate, c_simulate):
        st = None if state is None else PIDState(*astuple(state))
        result = loop(model, gains, desired, x0=x0, w0=w0, state=st, skip_ahead=skip_ahead)
        runs.append((result, None if st is None else astuple(st)))
    assert runs[1][0] is not None, "the C loop declined arguments inside its envelope"
    return runs


def random_case(rng: random.Random):
    twelve = rng.random() < 0.3
    accel = rng.choice([0.002, 0.02, 0.09, 0.5, 3.0])
    friction = rng.choice([0.0, 0.0, 0.001, 0.01, 0.2, 2.0]) * accel  # 2.0: never breaks away
    load = rng.choice([0.0, 0.0, 0.0005, -0.003, 0.05]) * accel
    model = AxisModel(accel=accel, rate=rng.choice([0.0, 0.001, 0.0101, 0.2, 1.5]),
                      coulomb=friction, load=load, twelve_bit=twelve)
    il = rng.choice([0, 1, 50, 3000, 32767, rng.randint(0, 32767)])
    gains = Gains(kp=rng.choice([0, 1, rng.randint(1, 300), rng.randint(0, 32767), 32767]),
                  ki=rng.choice([0, 0, rng.randint(1, 60), rng.randint(0, 32767)]),
                  kd=rng.choice([0, rng.randint(1, 3000), rng.randint(0, 32767)]),
                  il=il, ds=rng.choice([1, 1, 2, 3, 4, 8, rng.randint(1, 256)]))
    sign = rng.choice([1, -1])
    start = rng.randint(-5000, 5000)
    kind = rng.randrange(5)
    if kind == 0:  # a step, then a long hold (skip-ahead), then back
        d = sign * rng.choice([1, 2, 40, 3000, 40000, 10 ** 6])
        desired = [start] * rng.randint(0, 30) + [start + d] * rng.randint(50, 1500) + [start] * 400
    elif kind == 1:  # a trapezoid move, its end held
        d = sign * rng.randint(1, 20000)
        desired = [start + x for x in MoveProfile(rng.choice([0x10000, 0x40000, 0x200000]),
                                                  rng.choice([0x400, 0x2000, 0x40000])).desired(d)]
        desired += [desired[-1] if desired else start] * rng.randint(0, 800)
    elif kind == 2:  # a capped ramp
        desired = ramp(start, start + sign * rng.randint(1, 5000),
                       (rng.choice([0x8000, 0x40000]), rng.choice([0x100, 0x4000])), 700)
    elif kind == 3:  # noise: errors of every size, 16-bit saturation both ways
        desired = [rng.randint(-70000, 70000) if rng.random() < 0.2 else rng.randint(-50, 50)
                   for _ in range(rng.randint(1, 300))]
    else:  # piecewise constant: many short holds
        desired, level = [], start
        for _ in range(rng.randint(1, 12)):
            level += rng.randint(-200, 200)
            desired += [level] * rng.randint(1, 150)
    state = None
    if rng.random() < 0.5:  # a filter memory handed in (hold, then move, as predict_move)
        state = PIDState(error_sum=rng.choice([0, rng.randint(-SUM_MAX, SUM_MAX), SUM_MAX]),
                         last_error=rng.randint(-300, 300),
                         derivative=rng.choice([0, rng.randint(-32768, 32767)]),
                         countdown=rng.randint(0, 300), integral=rng.randint(-3000, 3000),
                         output=rng.randint(-32768, 32767))
    x0 = start + rng.choice([0.5, 0.0, 0.999, rng.random()])
    w0 = rng.choice([0.0, 0.0, rng.uniform(-5, 5), -0.0])
    return model, gains, desired, x0, w0, state


def test_the_c_loop_is_what_simulate_runs():
    """CI builds the package with gcc: the tuner must get the C loop, not the fallback."""
    assert predict._c_run is not None and predict._c_run.__module__ == "lm629_host.physics._predict"
    m = AxisModel(accel=0.09, rate=0.0101)
    desired = [100] * 50
    result = c_simulate(m, Gains(kp=60, kd=900), desired, x0=0.5)
    assert result is not None and simulate(m, Gains(kp=60, kd=900), desired, x0=0.5) == result


@pytest.mark.parametrize("seed", range(6))
def test_the_c_loop_is_the_python_loop(seed):
    """Random axes, gains and desired paths: identical counts, outputs and final PIDState."""
    rng = random.Random(seed)
    for case in range(60):
        model, gains, desired, x0, w0, state = random_case(rng)
        for skip in (True, False):
            (py, py_state), (c, c_state) = both(model, gains, desired, x0=x0, w0=w0,
                                                state=state, skip_ahead=skip)
            where = f"seed {seed} case {case} skip_ahead={skip}: {model} {gains} {state}"
            assert c[0] == py[0], f"counts differ, {where}"
            assert c[1] == py[1], f"outputs differ, {where}"
            assert c_state == py_state, f"final filter memory differs, {where}"


def test_each_branch_is_taken_and_agrees():
    """Hand-picked cases for the branches the random ones may miss: the integration limit
    reached (no wind-up), il = 0 unwinding, a held derivative over ds = 7, the shaft stuck by
    friction then breaking away, stopping within a sample (the friction's log), 12-bit
    output, the 24-bit sum saturating, the default PIDState (None) and skip-ahead over the
    derivative's phase (countdown wraps modulo ds)."""
    cases = [
        (AxisModel(accel=1e-3, rate=0.01, coulomb=1.0), Gains(100, 300, 900, 200, 7),
         [50] * 400 + [-30] * 600, PIDState(error_sum=-(1 << 23), countdown=50)),
        (AxisModel(accel=1e-3, rate=0.01, coulomb=1.0), Gains(100, 5, 0, 0, 3),
         [-20] * 300 + [20] * 700, PIDState(error_sum=40000)),
        (AxisModel(accel=0.09, rate=0.0101, coulomb=0.004, load=0.002),
         Gains(60, 20, 1500, 2000, 4), [0] * 20 + [800] * 900 + [-800] * 900, None),
        (AxisModel(accel=0.09, rate=0.0101, coulomb=0.004, load=-0.002, twelve_bit=True),
         Gains(8, 2, 300, 500, 2), [0] * 20 + [-1200] * 1500, None),
        (AxisModel(accel=2.0, rate=0.5, coulomb=0.3), Gains(3000, 0, 30000, 0, 1),
         [10 ** 7] * 30 + [0] * 300, PIDState(output=-32768)),
        (AxisModel(accel=1e-4, rate=0.0), Gains(1, 32767, 0, 32767, 1),
         [70000] * 3000, None),
    ]
    for model, gains, desired, state in cases:
        for skip in (True, False):
            (py, py_state), (c, c_state) = both(model, gains, desired, x0=0.5, state=state,
                                                skip_ahead=skip)
            assert (c, c_state) == (py, py_state), f"{model} {gains} skip_ahead={skip}"
    # the stuck/skip case really skipped: sample by sample gives the same, and it was held
    stuck = cases[0]
    counts, outs = simulate(stuck[0], stuck[1], stuck[2], x0=0.5, state=PIDState())
    assert len(set(counts)) == 1 and len(outs) == 1000


def test_a_tuning_prediction_is_the_same_with_either_loop(monkeypatch):
    """The tuner's own call (a trapezoid test move out and back after a held start under a
    load): the same metrics whichever loop :func:`simulate` runs."""
    model = AxisModel(accel=0.09, rate=0.0101, coulomb=0.002, load=0.0008)
    for g in (Gains(kp=60, ki=8, kd=900, il=2000, ds=2), Gains(kp=20, kd=300, ds=1)):
        args = (model, g, 2000, 1500, 2, MoveProfile(0x40000, 0x2000))
        fast = predict_move(*args, hold=200, rest=100.0)
        monkeypatch.setattr(predict, "FAST", False)
        slow = predict_move(*args, hold=200, rest=100.0)
        monkeypatch.setattr(predict, "FAST", True)
        assert fast == slow


def test_outside_its_envelope_the_c_loop_declines_and_python_answers():
    """Numbers the C loop's int64 and doubles cannot follow exactly (gains beyond 2^40, a
    position beyond 2^61, an int x0 no double holds, a float in the desired path, a NaN):
    :func:`c_simulate` returns None and leaves the state as it was; :func:`simulate` gives the
    Python loop's answer, or its error."""
    m = AxisModel(accel=0.09, rate=0.0101)
    for gains, desired, x0 in ((Gains(kp=1 << 70), [5] * 10, 0.5),
                               (Gains(kp=1, ki=1 << 30), [5] * 10, 0.5),
                               (Gains(kp=60), [5] * 10, 1e300),
                               (Gains(kp=60), [5, 1 << 62, 5], 0.5),
                               (Gains(kp=60), [5] * 10, (1 << 60) + 1)):
        st = PIDState(error_sum=12, output=256)
        assert c_simulate(m, gains, desired, x0=x0, state=st) is None
        assert st == PIDState(error_sum=12, output=256)
        py_st = PIDState(error_sum=12, output=256)
        assert simulate(m, gains, desired, x0=x0, state=st) == py_simulate(
            m, gains, desired, x0=x0, state=py_st)
        assert st == py_st
    with pytest.raises(ValueError):  # floor(NaN), as the Python loop
        simulate(AxisModel(accel=float("nan"), rate=0.01), Gains(kp=60), [5] * 3, x0=0.5)
