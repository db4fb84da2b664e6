"""A straight line in count space on several axes: each axis's LTRJ words, pure arithmetic.

Each axis's velocity and acceleration are the path's,
scaled by the axis's share of the path (its distance over the Euclidean length), rounded to
the chip's 16.16 words.  Rounding alone would let the axes drift apart in time: a word rounded
by half a unit changes a slow axis's duration by up to ``T * 0.5 / word`` samples, tens of
samples on a long slow move.  So the acceleration is rounded and then the velocity word is
chosen (trapezoid) or the acceleration word (triangle) so that the axis's trapezoid lasts, in
exact arithmetic, as long as the path's; what remains is the chip's own whole-sample
quantisation of each ramp.

:meth:`Board.plan_linear <lm629_host.motion.board.Board.plan_linear>` and
:meth:`Board.move_linear <lm629_host.motion.board.Board.move_linear>` run it on a board.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from lm629_host.bus.opcodes import (
    ACCELERATION_MAX,
    FIXED_ONE,
    POSITION_MAX,
    POSITION_MIN,
    VELOCITY_MAX,
)
from lm629_host.errors import ArgumentError, check_int
from lm629_host.physics.plan import plan


@dataclass(frozen=True)
class AxisPlan:
    """One axis of a straight-line move: the LTRJ words and the predicted duration."""

    axis: int
    start: int
    target: int
    velocity: int  #: 16.16 word
    acceleration: int  #: 16.16 word
    samples: float  #: predicted duration (continuous trapezoid of the rounded words)

    @property
    def distance(self) -> int:
        return self.target - self.start


@dataclass(frozen=True)
class LinearPlan:
    axes: tuple[AxisPlan, ...]
    samples: float  #: the path's duration, unrounded

    @property
    def spread(self) -> float:
        """Largest difference between two axes' predicted durations, samples."""
        t = [p.samples for p in self.axes if p.distance]
        return max(t) - min(t) if t else 0.0


def _solve_velocity(d: int, acc: int, total: float) -> list[int]:
    """Velocity words near the root of d/v + v/a = total (trapezoid), floor and ceil."""
    a_c = acc / FIXED_ONE
    disc = (total * a_c) ** 2 - 4 * d * a_c
    if disc < 0:
        return []
    exact = (total * a_c - math.sqrt(disc)) / 2 * FIXED_ONE
    return [c for c in (math.floor(exact), math.ceil(exact)) if 1 <= c <= VELOCITY_MAX]


def _solve_acceleration(d: int, total: float) -> list[int]:
    """Acceleration words near the root of 2 sqrt(d/a) = total (triangle)."""
    exact = 4 * d / (total * total) * FIXED_ONE
    return [c for c in (math.floor(exact), math.ceil(exact)) if 1 <= c <= ACCELERATION_MAX]


def plan_linear(moves: Mapping[int, tuple[int, int]], velocity: int,
                acceleration: int) -> LinearPlan:
    """Plan a straight line in count space: ``moves`` maps an axis to (start, target) counts;
    ``velocity`` and ``acceleration`` are the path's 16.16 words (along the Euclidean path).

    Every axis gets its share of both words; the axis with the longest distance leads.  Its
    acceleration word is lowered (by at most 20 %) to the nearest one whose shares round to
    the same ratios within 0.1 % (the ramps then keep to the line), and its word that sets
    the duration (the velocity of a trapezoid, the acceleration of a triangle) is lowered (by
    at most 10 %) to the nearest value that lets every other axis's rounded words last the
    same time, within a twentieth of a sample in exact arithmetic (each other axis's word
    solved from the duration).  Never faster than asked.  What is left is
    :attr:`LinearPlan.spread`; the 16.16 resolution bounds it: a word of ``v`` changes a
    cruise of ``T`` samples by ``T / v`` samples, and a small acceleration word (tens) cannot
    keep the ratio of two long ramps better than a few per mille
    (``python3 tools/bench_linear.py`` measures both).

    The starts and targets are extended counts (:mod:`lm629_host.chip.wraparound`): a line
    may cross the register's wrap, but no axis travels half the register's circle or more
    (the chip would go the other way round).

    Raises ValueError (before any bus traffic) for words out of range, an axis's travel out of
    range, or an axis whose share of the acceleration is below the chip's resolution of one word.
    """
    velocity = check_int("velocity", velocity, 1, VELOCITY_MAX, hex_digits=8)
    acceleration = check_int("acceleration", acceleration, 1, ACCELERATION_MAX, hex_digits=8)
    for axis, (start, target) in moves.items():
        for name, value in (("target", target), ("start", start)):
            if isinstance(value, bool) or not isinstance(value, int):
                raise ArgumentError(f"{name} of axis {axis}", value, f"{name} of axis {axis}="
                                    f"{value!r}: expected a whole number of counts")
        check_int(f"travel of axis {axis}", target - start, POSITION_MIN, POSITION_MAX,
                  hex_digits=8)
    dist = {axis: abs(t - s) for axis, (s, t) in moves.items()}
    length = math.sqrt(sum(d * d for d in dist.values()))
    if not length:
        return LinearPlan(tuple(AxisPlan(k, s, t, 0, 0, 0.0) for k, (s, t) in moves.items()), 0.0)
    path = plan(length, velocity, acceleration)
    total = path.samples
    trapezoid = not path.triangle
    moving = [k for k in moves if dist[k]]
    for k in moving:
        if acceleration * dist[k] / length < 0.5:
            raise ValueError(
                f"axis {k}: its share of the acceleration ({acceleration} x {dist[k]}/"
                f"{length:.0f}) is below the chip's resolution of one 16.16 word: raise the "
                "acceleration or move this axis on its own")
    lead = max(moving, key=lambda k: dist[k])
    share = {k: dist[k] / length for k in moving}
    acc0 = {k: max(1, round(acceleration * share[k])) for k in moving}
    if trapezoid and len(moving) > 1:
        # the ramps keep to the line when the acceleration words keep the shares' ratios:
        # search the lead's word downwards (at most 20 %: never above the acceleration asked
        # for) for the nearest whose rounded ratios are within 0.1 %, else the best found
        a_lead = acc0[lead]

        def ratio_error(cand: int) -> float:
            return max(abs(max(1, round(cand * dist[k] / dist[lead])) * dist[lead]
                           / (cand * dist[k]) - 1) for k in moving)

        span = max(2, a_lead // 5)
        best_a = a_lead
        for cand in range(a_lead, max(1, a_lead - span) - 1, -1):
            if ratio_error(cand) <= 1e-3:
                best_a = cand
                break
            if ratio_error(cand) < ratio_error(best_a):
                best_a = cand
        acc0 = {k: max(1, round(best_a * dist[k] / dist[lead])) for k in moving}
    vel0 = {k: max(1, round(velocity * share[k])) for k in moving}
    ideal = vel0[lead] if trapezoid else acc0[lead]
    # downwards only (never faster than asked for), at most 10 %
    width = max(16, min(65536, ideal // 10))
    best: tuple[float, int, dict[int, tuple[int, int]]] | None = None
    for cand in range(ideal, max(1, ideal - width) - 1, -1):
        words = {lead: (cand, acc0[lead]) if trapezoid
                 else (max(vel0[lead], math.isqrt(dist[lead] * cand * FIXED_ONE) + 2), cand)}
        t_lead = plan(dist[lead], *words[lead]).samples
        worst = 0.0
        for k in moving:
            if k == lead:
                continue
            if trapezoid:
                options = [(c, acc0[k]) for c in _solve_velocity(dist[k], acc0[k], t_lead)]
            else:
                options = [(max(vel0[k], math.isqrt(dist[k] * c * FIXED_ONE) + 2), c)
                           for c in _solve_acceleration(dist[k], t_lead)]
            if not options:
                options = [(vel0[k], acc0[k])]
            words[k] = min(options, key=lambda w: abs(plan(dist[k], *w).samples - t_lead))
            worst = max(worst, abs(plan(dist[k], *words[k]).samples - t_lead))
        key = (worst, abs(cand - ideal))
        if best is None or key < best[:2]:
            best = (worst, abs(cand - ideal), words)
        if worst < 0.05:
            break  # the nearest candidate that matches within a twentieth of a sample
    assert best is not None
    chosen = best[2]
    plans = []
    for axis, (start, target) in moves.items():
        if not dist[axis]:
            plans.append(AxisPlan(axis, start, target, 0, 0, 0.0))
            continue
        vel, acc = chosen[axis]
        plans.append(AxisPlan(axis, start, target, min(vel, VELOCITY_MAX), acc,
                              plan(dist[axis], vel, acc).samples))
    return LinearPlan(tuple(plans), total)
