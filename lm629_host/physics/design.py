"""Design: PID gains for an identified axis, chosen by predicting the tuner's test moves on
the model (:mod:`lm629_host.physics.predict`) and keeping the candidate whose worst score over
the model and three variants of it is best.

Pole placement gives the proportional-derivative candidates; an axis that a holding load or
dry friction would leave off its target gets integral candidates besides (see
:func:`with_integral`), because on an 8-bit output a P+D loop holds a load only with a
standing error, and hunts a count either way when no output code balances the load.
"""

from __future__ import annotations

import math
from dataclasses import replace

from lm629_host.bus.opcodes import COEFFICIENT_MAX, FIXED_ONE, VELOCITY_MAX
from lm629_host.physics.axis import AxisModel, Gains
from lm629_host.physics.metrics import MoveMetrics, in_seconds, score
from lm629_host.physics.plan import plan
from lm629_host.physics.predict import (
    MOVE_ACCELERATION,
    MOVE_VELOCITY,
    MoveProfile,
    predict_move,
)
from lm629_host.physics.units import to_fixed


def pd_candidates(model: AxisModel) -> list[Gains]:
    """Pole placement for x'' = k u - a x' (k per filter unit): kp = wn^2 / k and
    kd ds = (2 zeta wn - a) / k, over a grid of wn, zeta and derivative intervals ds."""
    k = model.per_filter_unit
    out: list[Gains] = []
    wn = math.sqrt(k * 8)  # kp = 8 at the low end
    while wn <= 0.5:
        for zeta in (0.8, 1.1):
            for ds in (1, 2, 4, 8):
                if wn * ds > 0.6:
                    continue  # the held derivative's delay would eat the phase margin
                kp = round(wn * wn / k)
                kd = round((2 * zeta * wn - model.rate) / k / ds)
                if 1 <= kp <= COEFFICIENT_MAX and 0 <= kd <= COEFFICIENT_MAX:
                    out.append(Gains(kp, 0, kd, 0, ds))
        wn *= 1.4
    return out


def with_integral(model: AxisModel, g: Gains) -> list[Gains]:
    """ki for integral times of 6 and 15 / wn samples; il twice what holds the load and
    friction (AN-706 4.5.2: a limit against wind-up), at least 4 output steps."""
    k = model.per_filter_unit
    wn = math.sqrt(g.kp * k)
    need = (abs(model.load) + model.coulomb) / k
    il = min(COEFFICIENT_MAX, max(1024, round(2 * need + 512)))
    out = []
    for ti in (6 / wn, 15 / wn):
        ki = round(256 * g.kp / ti)
        if 1 <= ki <= COEFFICIENT_MAX:
            out.append(replace(g, ki=ki, il=il))
    return out


def record_duration(model: AxisModel, distance: int, sample_s: float, at_least: float) -> float:
    """Seconds to record after each step: six times the fastest possible move (full drive
    to the middle, full braking after it), at least ``at_least``, at most 2 s."""
    t_min = plan(distance, VELOCITY_MAX, max(model.accel, 1e-12) * FIXED_ONE).samples * sample_s
    return min(2.0, max(at_least, 6 * t_min + 0.05))


def design(model: AxisModel, distance: int, tolerance: int, horizon_s: float,
           sample_s: float, profile: MoveProfile | None = None,
           words: tuple[int, int] | None = None
           ) -> tuple[Gains, MoveMetrics, MoveMetrics | None]:
    """Gains for the test moves: PD candidates by pole placement screened on the model (the
    step out and back, two thirds of the horizon); the ten best and integral variants of the
    best four are then judged by their worst score on the model and three variants of it, on
    the step and (with ``profile``) on the trapezoid move too, whose overshoot weighs more: a
    user's move should stop on its target, not past it.  ``words``: the step is a trapezoid
    of these words (an axis's caps).  Returns (gains, predicted step, predicted trapezoid)."""
    horizon = int(horizon_s / sample_s)
    quick = max(200, horizon * 2 // 3)
    ramp = profile.samples(distance) if profile else 0

    def judged(m: AxisModel, g: Gains, horizon: int = horizon
               ) -> tuple[float, MoveMetrics, MoveMetrics | None]:
        step = predict_move(m, g, distance, horizon, tolerance, words=words)
        total = score(step, horizon, tolerance)
        move = None
        if profile is not None:
            move = predict_move(m, g, distance, horizon + ramp, tolerance, profile)
            total += score(move, horizon, tolerance) + horizon * 0.02 * max(
                0, move.overshoot - tolerance)
        return total, step, move

    # screened on the whole horizon when a move is judged too: a stiffer loop that the move
    # favours settles a large step more slowly, and a short screen would drop it unseen
    pd = sorted(pd_candidates(model),
                key=lambda g: judged(model, g, quick if profile is None else horizon)[0])
    ranked = pd[:10] + [g for p in pd[:4] for g in with_integral(model, p)]
    # robustness: 30 % lighter and 40 % heavier, and a fifth of the dry friction (a fit
    # rarely pins friction down; less of it lets the shaft creep to the dead band's edge)
    variants = (model.scaled(0.7), model.scaled(1.4), replace(model, coulomb=model.coulomb / 5))
    best = None
    for g in ranked:
        total, step, move = judged(model, g)
        total = max([total] + [judged(v, g)[0] for v in variants])
        if best is None or total < best[0]:
            best = (total, g, step, move)
    assert best is not None
    _total, g, step, move = best
    return g, in_seconds(step, sample_s), None if move is None else in_seconds(move, sample_s)


def default_profile(model: AxisModel, velocity: int | None = None,
                    acceleration: int | None = None) -> MoveProfile:
    """The trapezoid move to judge gains on: the words given, else :data:`MOVE_VELOCITY` and
    :data:`MOVE_ACCELERATION` where the identified axis can follow them with drive to spare
    (at most a quarter of its top speed, a third of its acceleration at full output)."""
    if velocity is None:
        top = model.accel / max(model.rate, 1e-12)
        velocity = max(1, min(MOVE_VELOCITY, to_fixed(top / 4)))
    if acceleration is None:
        acceleration = max(1, min(MOVE_ACCELERATION, to_fixed(model.accel / 3)))
    return MoveProfile(velocity, acceleration)



__all__ = ["default_profile", "design", "pd_candidates", "record_duration", "with_integral"]
