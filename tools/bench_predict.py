#!/usr/bin/env python3
"""The tuner's design search with the predictor's Python loop against its C loop, in one run.

``lm629 tune`` spends most of its time in :func:`lm629_host.physics.predict.simulate`:
:func:`lm629_host.physics.design.design` screens every PD candidate on the model, then judges
the best and their integral variants on the model and four variants of it, each a step and a
trapezoid move out and back.  This runs that design search as the tuner does after its fit
(distance 2000, tolerance 2, the test moves' duration from :func:`record_duration`, the
tuner's default trapezoid profile, a 20 ms settle rule) on the ``sim://`` motors of
tests/bench/test_tuning.py, in the tuner's units (:class:`lm629_host.sim.model.motor.Motor`'s
own numbers), first with the Python loop (``predict.FAST = False``), then with the C one
(``_predict.c``), and prints each time, the samples predicted, the ratio, and whether both
chose the same gains and predicted the same figures (they must: the loops are bit-identical).

    python3 tools/bench_predict.py
    python3 tools/bench_predict.py --motors default --repeat 3
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from lm629_host.physics import predict
from lm629_host.physics.axis import AxisModel
from lm629_host.physics.design import default_profile, design, record_duration
from lm629_host.sim.model.motor import Motor
from lm629_host.sim.model.params import MotorParams

T = 2048 / 8e6  #: the sample period at 8 MHz
DISTANCE, TOLERANCE, DURATION_S, SETTLE_S = 2000, 2, 0.3, 0.02

#: tests/bench/test_tuning.py's motors (MotorParams overrides)
MOTORS = {
    "default": {},
    "10x inertia": {"inertia": 4e-5},
    "holding load": {"load_torque": 0.004},
    "low friction": {"friction": 2e-7, "coulomb": 2e-5},
    "slow amplifier": {"amp_volts": 3.0},
}


def axis_model(overrides: dict) -> AxisModel:
    """The sim:// motor as the tuner's fit finds it (counts and samples)."""
    p = replace(MotorParams(), **overrides)
    m = Motor(p, T)
    return AxisModel(p.amp_volts * m.accel_per_volt * T * T, m.rate * T, m.coulomb_accel * T * T,
                     m.load_accel * T * T)


def search(model: AxisModel) -> tuple:
    duration = record_duration(model, DISTANCE, T, DURATION_S)
    return design(model, DISTANCE, TOLERANCE, duration, T, default_profile(model),
                  rest_s=SETTLE_S)


def timed(model: AxisModel, fast: bool, repeat: int) -> tuple[float, float, tuple, int]:
    """The best of ``repeat`` runs: seconds in all, seconds in the predictor's loop, the
    result, and the samples one run predicts."""
    name = "c_simulate" if fast else "py_simulate"
    real = getattr(predict, name)
    inside = samples = 0.0

    def counting(*args, **kw):
        nonlocal inside, samples
        samples += len(args[2])
        t0 = time.perf_counter()
        try:
            return real(*args, **kw)
        finally:
            inside += time.perf_counter() - t0

    best = (float("inf"), 0.0)
    result: tuple = ()
    predict.FAST = fast
    setattr(predict, name, counting)
    try:
        for _ in range(repeat):
            inside = samples = 0.0
            t0 = time.perf_counter()
            result = search(model)
            best = min(best, (time.perf_counter() - t0, inside))
    finally:
        predict.FAST = True
        setattr(predict, name, real)
    return best[0], best[1], result, int(samples)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--motors", nargs="*", default=list(MOTORS), choices=list(MOTORS))
    ap.add_argument("--repeat", type=int, default=1, help="runs per loop (the best is shown)")
    args = ap.parse_args()
    if predict._c_run is None:
        print("the C loop (lm629_host/physics/_predict.c) is not built: pip install -e . "
              "with gcc and the Python headers", file=sys.stderr)
        return 1
    print("design search (seconds: all of it / in the predictor's loop), Python loop vs C loop")
    print(f"{'motor':<16} {'samples':>10} {'python':>12} {'C':>13} {'ratio':>14}  same result")
    totals = [0.0, 0.0, 0.0, 0.0]
    differ = False
    for name in args.motors:
        model = axis_model(MOTORS[name])
        py_s, py_in, py_result, samples = timed(model, False, args.repeat)
        c_s, c_in, c_result, _ = timed(model, True, args.repeat)
        same = py_result == c_result
        differ |= not same
        totals = [a + b for a, b in zip(totals, (py_s, py_in, c_s, c_in))]
        print(f"{name:<16} {samples:>10,} {py_s:>5.2f} / {py_in:>4.2f} {c_s:>6.3f} / {c_in:.3f} "
              f"{py_s / c_s:>5.1f}x / {py_in / c_in:>4.0f}x  "
              f"{'yes' if same else 'NO'} ({py_result[0]})")
    py_s, py_in, c_s, c_in = totals
    print(f"{'all':<16} {'':>10} {py_s:>5.2f} / {py_in:>4.2f} {c_s:>6.3f} / {c_in:.3f} "
          f"{py_s / c_s:>5.1f}x / {py_in / c_in:>4.0f}x")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
