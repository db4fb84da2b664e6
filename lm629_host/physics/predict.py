"""The predictor: what the axis model does under the chip's filter, sample by sample, and
the tuner's test moves predicted with it.

Why sample by sample in integers: the LM629's filter has an 8-bit output (AN-706 5.2.3), a
24-bit error sum whose top 16 bits multiply ki and a held derivative; a continuous model
misses the dead band, the saturation and the creep that decide whether a move ends within 2
counts.  :func:`simulate` runs :func:`lm629_host.physics.pid.pid_step` (the chip's arithmetic)
on :func:`lm629_host.physics.plant.motor_step` (the motor, exact over a sample).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from lm629_host.physics.axis import AxisModel, Gains
from lm629_host.physics.metrics import MoveMetrics, as_move, step_metrics
from lm629_host.physics.pid import PIDState, holds, output_shift, pid_step, sat16, skip_held
from lm629_host.physics.plan import plan
from lm629_host.physics.plant import decay_and_gain, motor_step

try:  # the same loop in C (setup.py builds it when a compiler is at hand)
    from lm629_host.physics._predict import run as _c_run
except ImportError:
    _c_run = None

#: False: :func:`simulate` runs the Python loop even where the C one is built (benchmarks)
FAST = True


def simulate(model: AxisModel, gains: Gains, desired: Sequence[int], *, x0: float,
             w0: float = 0.0, state: PIDState | None = None,
             skip_ahead: bool = True) -> tuple[list[int], list[int]]:
    """Predict ``len(desired)`` samples: (encoder counts, output codes) at each sample.

    :func:`py_simulate` says what is computed; this runs the same loop in C
    (``_predict.c``, :func:`c_simulate`) when the package was built with it, and in Python
    otherwise or when the C loop declines the arguments.  The tuner spends most of its time
    here (about 2 million samples for one tuning)."""
    if _c_run is not None and FAST:
        result = c_simulate(model, gains, desired, x0=x0, w0=w0, state=state,
                            skip_ahead=skip_ahead)
        if result is not None:
            return result
    return py_simulate(model, gains, desired, x0=x0, w0=w0, state=state, skip_ahead=skip_ahead)


def c_simulate(model: AxisModel, gains: Gains, desired: Sequence[int], *, x0: float,
               w0: float = 0.0, state: PIDState | None = None,
               skip_ahead: bool = True) -> tuple[list[int], list[int]] | None:
    """:func:`py_simulate` in C, the same result bit for bit and float for float (and
    ``state`` left the same); None, with ``state`` untouched, when the C loop is not built or
    an argument lies outside what its 64-bit integers and doubles reproduce exactly (see
    ``_predict.c``): then only the Python loop gives Python's answer."""
    if _c_run is None:
        return None
    floats = (model.coulomb, model.load, max(model.rate, 1e-12), x0, w0)
    if any(float(v) != v for v in floats):  # an int no double holds, or NaN: Python's case
        return None
    c, d, a, x, w = (float(v) for v in floats)
    st = state or PIDState()
    decay, gain = decay_and_gain(a, 1.0)
    ints = (gains.kp, gains.ki, gains.kd, gains.il, gains.ds, output_shift(model.twelve_bit),
            1 if skip_ahead else 0, st.error_sum, st.last_error, st.derivative, st.countdown,
            st.integral, st.output)
    result = _c_run(desired, ints, (model.accel / model.full_scale, d, c, a, decay, gain, x, w))
    if result is None:
        return None
    counts, outs, (st.error_sum, st.last_error, st.derivative, st.countdown, st.integral,
                   st.output) = result
    return counts, outs


def py_simulate(model: AxisModel, gains: Gains, desired: Sequence[int], *, x0: float,
                w0: float = 0.0, state: PIDState | None = None,
                skip_ahead: bool = True) -> tuple[list[int], list[int]]:
    """Predict ``len(desired)`` samples: (encoder counts, output codes) at each sample.

    Each sample in the chip's order: the motor runs one sample on the output held since the
    last one, the encoder is read, the filter computes the next output from
    ``desired[n] - count`` (AN-706 5.2.3-5.2.5: 16-bit error, 16-bit products saturating,
    24-bit sum whose top 16 bits multiply ki, limited to il, derivative every ds samples
    and held, 16-bit sum, top 8 or 12 bits out).  ``tests/bench/test_tuning.py`` checks this
    arithmetic against the chip model's filter.  ``skip_ahead``: while the shaft is stuck and
    nothing in the filter can change, jump to the next change of the desired position.

    The readable loop; :func:`simulate` runs it in C when it can (the same numbers).
    """
    st = state or PIDState()
    kp, ki, kd, il, ds = gains.kp, gains.ki, gains.kd, gains.il, gains.ds
    shift = output_shift(model.twelve_bit)
    g = model.accel / model.full_scale
    a = max(model.rate, 1e-12)
    c, d = model.coulomb, model.load
    decay, gain = decay_and_gain(a, 1.0)
    step = motor_step
    x, w = x0, w0
    out = st.output >> shift
    counts: list[int] = []
    outs: list[int] = []
    floor = math.floor
    total_n = len(desired)
    # where the desired position changes next, for each run of equal values (skip-ahead)
    changes = [k for k in range(1, total_n) if desired[k - 1] != desired[k]] + [total_n]
    next_change = 0
    i = -1
    while i + 1 < total_n:
        i += 1
        target = desired[i]
        while changes[next_change] <= i:
            next_change += 1
        # motor, one sample (as a DC motor with dry friction: exact between sticking points)
        was_still = w == 0.0
        x, w = step(x, w, out * g - d, c, a, decay, gain, 1.0)
        stuck = was_still and w == 0.0
        n = floor(x)
        counts.append(n)
        # the filter: the chip's own arithmetic
        e = sat16(target - n)
        held_out = out
        out = pid_step(st, e, kp, ki, kd, il, ds) >> shift
        outs.append(out)
        if skip_ahead and stuck and out == held_out and holds(st, e, ki, il):
            # nothing changes until the desired position does (the chip model's skip-ahead,
            # for the same reason)
            skip = changes[next_change] - i - 1
            counts.extend([n] * skip)
            outs.extend([out] * skip)
            skip_held(st, skip, e, il, ds)
            i += skip
    return counts, outs



#: the trapezoid move candidates are judged on when the user names none: 4 counts
#: per sample, 1/8 count per sample^2 (the default motor reaches 4 counts/sample in 32
#: samples, an eighth of its acceleration at full output)
MOVE_VELOCITY = 0x40000
MOVE_ACCELERATION = 0x2000


@dataclass(frozen=True)
class MoveProfile:
    """A trapezoid move's limits, the chip's 16.16 words (counts/sample, counts/sample^2)."""

    velocity: int
    acceleration: int

    def desired(self, distance: int) -> list[int]:
        """The desired position (counts from the start) at each sample until it reaches
        ``distance``: accelerate by ``acceleration`` up to ``velocity``, brake by it so as to
        land on the target (the chip's generator to within a count; AN-706 5.3)."""
        sign = 1 if distance >= 0 else -1
        return [sign * x for x in plan(distance, self.velocity, self.acceleration).desired()]

    def samples(self, distance: int) -> int:
        return len(self.desired(distance))

    def __str__(self) -> str:
        return f"velocity {self.velocity:#x}, acceleration {self.acceleration:#x}"



def ramp(start: int, target: int, words: tuple[int, int], n: int) -> list[int]:
    """The desired position at each of the ``n`` samples after the start of a move from
    ``start`` to ``target`` with 16.16 (velocity, acceleration) words: the continuous plan
    (the chip's own arithmetic is within a count of it)."""
    p = plan(target - start, *words)
    sign = 1 if target >= start else -1
    return [round(start + sign * p.travelled(k + 1)) for k in range(n)]


def predict_move(model: AxisModel, g: Gains, distance: int, horizon: int,
                 tolerance: int, profile: MoveProfile | None = None,
                 words: tuple[int, int] | None = None, *, hold: int = 0,
                 rest: float = 0.0) -> MoveMetrics:
    """The test move (out by ``distance``, then back) on the model, from rest at 0: a step
    (with ``words``, an axis's capped velocity and acceleration, the trapezoid they make), or
    with ``profile`` a trapezoid move (settle then counted from the profile's end).

    ``hold``: samples the loop holds the start before the move (the filter's integral built
    up against a load, as on a bench whose loop has held the shaft; 0: a freshly reset filter,
    as after a power-up); ``rest``: the rest window judged, in samples
    (:attr:`MoveMetrics.rest_s`)."""
    worst = None
    path = profile.desired(distance) if profile else []
    for start, target in ((0, distance), (distance, 0)):
        sign = 1 if target >= start else -1
        state, x = PIDState(), start + 0.5
        if hold:
            held, _ = simulate(model, g, [start] * hold, x0=x, state=state)
            x = held[-1] + 0.5
        if words is not None and profile is None:
            desired = ramp(start, target, words, horizon)
        else:
            desired = [start + sign * abs(d) for d in path[:horizon]]
            desired += [target] * (horizon - len(desired))
        counts, _ = simulate(model, g, desired, x0=x, state=state)
        times = list(range(1 - len(path), horizon + 1 - len(path)))  # samples after the path's end
        m = as_move(step_metrics(times, counts, desired, start, target, tolerance, rest),
                    profile)
        worst = m if worst is None else worst.worst(m)
    assert worst is not None
    return worst


__all__ = ["MOVE_ACCELERATION", "MOVE_VELOCITY", "MoveProfile", "c_simulate", "predict_move",
           "py_simulate", "ramp", "simulate"]
