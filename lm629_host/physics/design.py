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


def holding_need(model: AxisModel) -> float:
    """Filter units (of the 16-bit result; 256 per output code on the 8-bit port) the loop
    must supply at rest to hold the axis's load: what the integral term carries at zero
    error, where a P+D loop can only answer with a standing error."""
    return abs(model.load) / model.per_filter_unit


def needs_holding(model: AxisModel, best_pd: tuple[MoveMetrics, MoveMetrics | None],
                  tolerance: int) -> bool:
    """Whether the axis wants integral action to hold its target: a load that outpulls the
    dry friction (the shaft slides off a zero-output hold), or a best P+D prediction that
    ends outside the tolerance or never stands still (hunting a count against the load)."""
    if abs(model.load) > model.coulomb:
        return True
    return any(abs(m.final_error) > tolerance or not m.rests for m in best_pd if m is not None)


def holding_candidates(model: AxisModel, g: Gains) -> list[Gains]:
    """Integral variants of the P+D gains ``g`` for an axis with a holding load (AN-706 2.12:
    ki removes "the position error due to a constant static torque").

    * il: the holding need (:func:`holding_need`) plus the dry friction's share and one
      output code (the output stage floors), and a looser twice that: a limit just above
      the hold winds up little while a move saturates the drive (AN-706 4.5.2), so it adds
      little overshoot.
    * ki: from the fast end of :func:`with_integral` (an integral time of 6 / wn samples)
      (at most 2048: eight output codes a count per 256 samples) down by halves to 16: the
      term grows ki / 256 per sample per count of error
      (the top 16 of the sum's 24 bits multiply ki, AN-706 5.2.5), and a small ki steps it
      by less than an output code, so it can find the code that holds the load within the
      dry friction's window; a large one reaches it sooner from a move's following error."""
    k = model.per_filter_unit
    wn = math.sqrt(g.kp * k)
    need = holding_need(model) + model.coulomb / k
    out = []
    for il in (round(need + 256), round(2 * need + 512)):
        il = min(COEFFICIENT_MAX, max(256, il))
        ki = min(2048, round(256 * g.kp * wn / 6))
        while ki >= 16:
            out.append(replace(g, ki=ki, il=il))
            ki //= 2
    return out


def integral_note(model: AxisModel, g: Gains, sample_s: float) -> str:
    """What the integral term of ``g`` does on this axis, in a line of the report."""
    codes = holding_need(model) / 256
    dry = model.coulomb / model.per_filter_unit / 256
    if not g.ki or not g.il:
        if codes <= dry:
            return "no integral term: the dry friction holds the load at rest"
        return (f"no integral term: kp alone holds the load's {codes:.1f} output codes, with a "
                f"standing error of about {256 * codes / max(g.kp, 1):.1f} counts")
    if not codes:
        return (f"integral ki={g.ki} il={g.il}: pulls the last counts of a move onto the "
                f"target against the dry friction ({dry:.1f} output codes)")
    per = g.ki / 256  # filter units per sample, per count of error
    reach = holding_need(model) / per * sample_s if per else math.inf
    return (f"integral ki={g.ki} il={g.il}: holds the load's {codes:.1f} output codes "
            f"({model.load / model.accel * 100:+.1f} % of full output) at zero error, the "
            f"limit {g.il / 256:.1f} codes; from nothing it builds the hold in about "
            f"{reach * 1e3:,.0f} ms a count off target, sooner from a move's following error")


def design(model: AxisModel, distance: int, tolerance: int, horizon_s: float,
           sample_s: float, profile: MoveProfile | None = None,
           words: tuple[int, int] | None = None, rest_s: float = 0.0
           ) -> tuple[Gains, MoveMetrics, MoveMetrics | None]:
    """Gains for the test moves: PD candidates by pole placement screened on the model (the
    step out and back, two thirds of the horizon); the ten best and integral variants of the
    best four are then judged by their worst score on the model and three variants of it, on
    the step and (with ``profile``) on the trapezoid move too, whose overshoot weighs more: a
    user's move should stop on its target, not past it.  ``words``: the step is a trapezoid
    of these words (an axis's caps).

    ``rest_s``: the time a move's ``wait()`` needs the shaft to stand still
    (``MoveRules.settle_time``); a candidate whose predicted trapezoid move (else the step:
    a saturating step is a test, the trapezoid is what a lab script runs) never lets the
    shaft do so within the tolerance counts as never settled.  Where the axis needs integral
    action to hold its target (:func:`needs_holding`), :func:`holding_candidates` of the
    best four join, screened on the model from a freshly reset filter (as after a power-up:
    the integral starts at nothing), and only gains with an integral term are kept; their
    move is judged from a fresh filter and from one that has held the start.  The
    predictions returned are from a loop that has held the start for a while, as the
    tuner's own test moves start.
    Returns (gains, predicted step, predicted trapezoid)."""
    horizon = int(horizon_s / sample_s)
    quick = max(200, horizon * 2 // 3)
    ramp = profile.samples(distance) if profile else 0
    rest = rest_s / sample_s

    def judged(m: AxisModel, g: Gains, horizon: int = horizon, hold: int = 0
               ) -> tuple[float, MoveMetrics, MoveMetrics | None]:
        step = predict_move(m, g, distance, horizon, tolerance, words=words, hold=hold,
                            rest=0.0 if profile is not None else rest)
        total = score(step, horizon, tolerance)
        move = None
        if profile is not None:
            move = predict_move(m, g, distance, horizon + ramp, tolerance, profile, hold=hold,
                                rest=rest)
            if rest and not hold and (g.ki and g.il):
                # an integral term also from a loop that has held the start (as every move
                # but a power-up's first starts): the term then starts at the hold
                move = move.worst(predict_move(m, g, distance, horizon + ramp, tolerance,
                                               profile, hold=horizon // 2, rest=rest))
            # past the target: a little costs, past 1 % of the move as much as a miss
            total += score(move, horizon, tolerance) + horizon * 0.02 * max(
                0, move.overshoot - tolerance) + horizon * max(
                0, move.overshoot - max(tolerance, abs(distance) // 100))
        return total, step, move

    # screened on the whole horizon when a move is judged too: a stiffer loop that the move
    # favours settles a large step more slowly, and a short screen would drop it unseen
    screen = quick if profile is None else horizon
    pd = sorted(pd_candidates(model), key=lambda g: judged(model, g, screen)[0])
    if not pd:
        raise ValueError(f"no gain in the chip's range places the poles of this axis "
                         f"(acceleration {model.accel:.3g} counts/sample^2 at full output, "
                         f"decay {model.rate:.3g} per sample): not an axis a fit of real "
                         "steps gives")
    ranked = pd[:10] + [g for p in pd[:4] for g in with_integral(model, p)]
    if pd and needs_holding(model, judged(model, pd[0])[1:], tolerance):
        # from the best four, and from the best two whose count of error moves the output by
        # less than a code (kp < 256): those creep onto the code that holds the load where a
        # stiffer loop kicks the shaft across it and hunts a count either way
        soft = [p for p in pd if p.kp < 256][:2]
        holding = [g for p in pd[:4] + soft for g in holding_candidates(model, p)]
        # integral gains only: P+D holds such a load a count off at best, kicked back and
        # forth, and whether a prediction catches it still for a moment is chance
        ranked = [g for g in ranked if g.ki and g.il] + sorted(
            holding, key=lambda g: judged(model, g, screen)[0])[:6]
    # robustness: 30 % lighter and 40 % heavier, and a fifth and twice the dry friction (a
    # fit rarely pins friction down: less of it lets the shaft creep to the dead band's edge,
    # more of it widens the band a soft loop stops in, to a final error past the tolerance)
    variants = (model.scaled(0.7), model.scaled(1.4), replace(model, coulomb=model.coulomb / 5),
                replace(model, coulomb=model.coulomb * 2))
    best = None
    for g in ranked:
        total = judged(model, g)[0]
        total = max([total] + [judged(v, g)[0] for v in variants])
        if best is None or total < best[0]:
            best = (total, g)
    assert best is not None
    g = best[1]
    _total, step, move = judged(model, g, hold=horizon // 2)
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



__all__ = ["default_profile", "design", "holding_candidates", "holding_need", "integral_note",
           "needs_holding", "pd_candidates", "record_duration", "with_integral"]
