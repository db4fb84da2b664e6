"""Identification: an :class:`~lm629_host.physics.axis.AxisModel` fitted to what the chip
recorded during P-only steps, and the times of far-side recordings put on the chip's clock.

Pure arithmetic on rows that have been read already: the bench session
(:mod:`lm629_host.bench.tuning`) runs the experiments and hands them over as an
:class:`FitExperiment` (its ``Record``); nothing here touches a bus.  The fit simulates the chip's
own filter arithmetic (:func:`lm629_host.physics.predict.simulate`) against every position
read and steers the model's parameters with :func:`lm629_host.physics.search.nelder_mead`.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Protocol

from lm629_host.physics.axis import AxisModel, Gains
from lm629_host.physics.pid import PIDState, full_scale, output_shift, sat16
from lm629_host.physics.predict import MoveProfile, ramp, simulate
from lm629_host.physics.search import golden, nelder_mead


class FitRow(Protocol):
    """One snapshot as the fit reads it (:class:`lm629_host.chip.lm629.Snapshot` is one):
    when it was taken, on the transport's clock, and the two positions."""

    @property
    def time(self) -> float: ...

    @property
    def real_position(self) -> int: ...

    @property
    def desired_position(self) -> int: ...


class FitExperiment(Protocol):
    """The P-only steps an identification ran and the rows it read: what the fit needs of
    the bench session's ``Record``."""

    @property
    def gains(self) -> Gains | None: ...

    @property
    def rows(self) -> Sequence[FitRow]: ...

    @property
    def steps(self) -> Sequence[tuple[float, int]]: ...

    @property
    def t0(self) -> float: ...

    @property
    def state0(self) -> PIDState | None: ...

    @property
    def step_rows(self) -> Sequence[int]: ...

    @property
    def far_runs(self) -> Sequence[tuple[int, int]]: ...

    @property
    def words(self) -> tuple[int, int] | None: ...


def _desired_samples(rec: FitExperiment, n: int, sample_s: float) -> list[int]:
    start = rec.rows[0].desired_position
    out = [start] * n
    for t, target in rec.steps:
        k = max(0, math.ceil((t - rec.t0) / sample_s - 0.5))
        origin = out[k] if k < n else start
        if rec.words is None:
            out[k:] = [target] * (n - k)
        else:
            out[k:] = ramp(origin, target, rec.words, n - k)
    return out


def _residual(model: AxisModel, rec: FitExperiment, sample_s: float, desired: list[int],
              idx: list[int], meas: list[int]) -> float:
    s0 = rec.rows[0]
    st = replace(rec.state0) if rec.state0 else PIDState()
    counts, _ = simulate(model, rec.gains or Gains(0), desired, x0=s0.real_position + 0.5,
                         state=st)
    err = 0.0
    for i, m in zip(idx, meas):
        d = counts[i] - m
        err += d * d
    return math.sqrt(err / max(1, len(idx)))



@dataclass
class FarSegment:
    """The rows a far-side recording took after one P-only step: the fit starts the model
    at the first row (its position, the output the filter holds for its error, a speed fitted
    with the model), so when the STT ran on the chip's clock does not matter."""

    target: int
    first: FitRow
    idx: list[int]  #: samples after the first row, less one (the index into simulate's counts)
    meas: list[int]  #: real positions there

    def residual(self, model: AxisModel, g: Gains, w0: float) -> tuple[float, int]:
        e = sat16(self.target - self.first.real_position)
        st = PIDState(last_error=e, output=sat16(g.kp * e))
        counts, _ = simulate(model, g, [self.target] * (self.idx[-1] + 1),
                             x0=self.first.real_position + 0.5, w0=w0, state=st)
        return sum((counts[i] - m) ** 2 for i, m in zip(self.idx, self.meas)), len(self.idx)


def _far_segments(rec: FitExperiment, sample_s: float) -> list[FarSegment] | None:
    """Each step's rows, when one far-side recording began at each step of a P-only record
    (the identification's), else None (host-polled rows: :func:`fit_model` uses the step times
    on the host's clock).

    Why not the step times: the host stamps an STT when its reply arrives, behind an Uno's USB
    chip up to a 4.096 ms flush tick after the chip ran it, and the far side's rows are timed
    from the first row, which the bridge takes when the RECORD request reaches it (a USB frame
    later): on one clock the shaft would seem to move 2-5 ms early, an acceleration 11-18 %
    high.  Within one recording the rows' times are the far side's own, exact."""
    if rec.gains is None or rec.gains.ki or rec.gains.kd or not rec.steps or rec.words:
        return None  # (steps ramped by an axis's caps: the step-time fit follows the ramp)
    runs = dict(rec.far_runs)
    out = []
    for (_t, target), first in zip(rec.steps, rec.step_rows):
        end = runs.get(first, first)
        if end - first < 4:
            return None
        rows = rec.rows[first:end]
        idx = [round((s.time - rows[0].time) / sample_s) - 1 for s in rows[1:]]
        if idx[0] < 0 or any(b <= a for a, b in zip(idx, idx[1:])):
            return None
        out.append(FarSegment(target, rows[0], idx, [s.real_position for s in rows[1:]]))
    return out or None


def _first_speed(seg: FarSegment) -> float:
    """counts/sample at the first row: the parabola through the first three rows."""
    p0 = seg.first.real_position
    if len(seg.idx) < 2:
        return (seg.meas[0] - p0) / (seg.idx[0] + 1)
    t1, t2 = seg.idx[0] + 1, seg.idx[1] + 1
    d1, d2 = seg.meas[0] - p0, seg.meas[1] - p0
    c = (d2 / t2 - d1 / t1) / (t2 - t1)
    return d1 / t1 - c * t1


def _axis_of(p: list[float], twelve_bit: bool) -> AxisModel:
    """The axis a fit's parameter vector stands for: log acceleration, log rate, then friction
    and load as fractions of the acceleration (the speeds of far-side segments follow)."""
    acc = math.exp(p[0])
    return AxisModel(acc, math.exp(p[1]), abs(p[2]) * acc, p[3] * acc, twelve_bit)


def _plausible(p: list[float]) -> bool:
    """Whether a fit's parameters stay inside what any motor on an LM629 can be (outside, the
    residual is a wall rather than a value the search could wander along)."""
    return -30 < p[0] < 5 and -20 < p[1] < 1 and abs(p[2]) <= 1 and abs(p[3]) <= 1


def _fit_far(segs: list[FarSegment], g: Gains, sample_s: float, twelve_bit: bool,
             iters: int) -> tuple[AxisModel, float]:
    """:func:`fit_model` on far-side segments: the axis and each segment's starting speed."""
    m = len(segs)
    # first guesses: each segment's speed over its first two rows; the acceleration from
    # the first segment as from rest (x = a t^2 / 2 at the output held for the first row's
    # error), where the shaft has gone a twentieth of the way (a slow axis hardly moves
    # between the first rows, a fast one is already well under way)
    speeds = [_first_speed(s) for s in segs]
    s0 = segs[0]
    x0 = s0.first.real_position
    fs = full_scale(twelve_bit)
    out0 = max(1, min(fs - 1, abs(sat16(g.kp * (s0.target - x0))) >> output_shift(twelve_bit)))
    guess = 1e-3
    for k, x in zip(s0.idx, s0.meas):
        if abs(x - x0) >= max(3, abs(s0.target - x0) // 20):
            guess = 2 * abs(x - x0) / (k + 1) ** 2 * fs / out0
            break

    def f(p: list[float]) -> float:
        if not _plausible(p):
            return 1e12
        model = _axis_of(p, twelve_bit)
        err, n = 0.0, 0
        for seg, w0 in zip(segs, p[4:]):
            e, k = seg.residual(model, g, w0)
            err, n = err + e, n + k
        return math.sqrt(err / max(1, n))

    # the axis with the speeds at their guesses (two starts: slow and fast mechanical time
    # constants), then each speed alone on that axis, then all together: one simplex over
    # all at once from the guesses stalls (a speed 0.1 count/sample off grows to tens of
    # counts, the axis's parameters barely move the fit)
    best: list[float] = []
    best_val = math.inf
    # (each start a full ``iters``: behind an Uno's USB a fast axis's first row comes a frame
    # after its STT, and half as many left the polish in a valley, its acceleration 9 % high
    # at 4 counts rms where the whole search reaches it within 0.1 % at 0.3)
    for rate0 in (1e-3, 1e-2):
        p, v = nelder_mead(lambda q: f(q + speeds), [math.log(guess), math.log(rate0), 0.005,
                                                        0.0], [0.5, 1.0, 0.01, 0.02], iters)
        if v < best_val:
            best, best_val = p, v
    model = _axis_of(best, twelve_bit)
    for i, seg in enumerate(segs):
        def sq(w: float, seg: FarSegment = seg) -> float:
            return seg.residual(model, g, w)[0]
        speeds[i] = golden(sq, speeds[i] - 1.0, speeds[i] + 1.0)
    best = best + speeds
    best_val = f(best)
    p, v = nelder_mead(f, best, [0.1, 0.3, 0.005, 0.005] + [0.05] * m, iters)  # polish
    if v < best_val:
        best, best_val = p, v
    return _axis_of(best, twelve_bit), best_val

def fit_model(rec: FitExperiment, sample_s: float, twelve_bit: bool = False,
              iters: int = 60) -> tuple[AxisModel, float]:
    """Fit an :class:`AxisModel` to an identification record; returns (model, rms counts).

    Rows recorded on the far side are fitted step by step from the first row after each
    STT (:func:`_far_segments`); host-polled rows from the record's start, at the step times."""
    segs = _far_segments(rec, sample_s)
    if segs is not None:
        assert rec.gains is not None
        return _fit_far(segs, rec.gains, sample_s, twelve_bit, iters)
    t_last = rec.rows[-1].time - rec.t0
    n = int(t_last / sample_s) + 2
    desired = _desired_samples(rec, n, sample_s)
    idx, meas = [], []
    for s in rec.rows[1:]:
        k = round((s.time - rec.t0) / sample_s - 0.5)
        if 0 <= k < n:
            idx.append(k)
            meas.append(s.real_position)
    # first guess: the initial acceleration of the first step (x = a t^2 / 2 at a known output)
    kp = rec.gains.kp if rec.gains else 1
    t_step, target = rec.steps[0]
    x0 = rec.rows[0].real_position
    fs = full_scale(twelve_bit)
    out0 = max(1, min(fs - 1, sat16(kp * abs(target - x0)) >> output_shift(twelve_bit)))
    guess = 1e-3
    for s in rec.rows:
        dt = (s.time - t_step) / sample_s
        moved = abs(s.real_position - x0)
        if dt > 2 and moved >= max(3, abs(target - x0) // 20):
            guess = 2 * moved / dt ** 2 * fs / out0
            break

    def f(p: list[float]) -> float:
        if not _plausible(p):
            return 1e12
        return _residual(_axis_of(p, twelve_bit), rec, sample_s, desired, idx, meas)

    best: list[float] = []
    best_val = math.inf
    for rate0 in (1e-3, 1e-2):  # two starts: slow and fast mechanical time constants
        p, v = nelder_mead(f, [math.log(guess), math.log(rate0), 0.005, 0.0],
                            [0.5, 1.0, 0.01, 0.02], iters // 2)
        if v < best_val:
            best, best_val = p, v
    p, v = nelder_mead(f, best, [0.1, 0.3, 0.005, 0.005], iters)  # polish
    if v < best_val:
        best, best_val = p, v
    return _axis_of(best, twelve_bit), best_val



def since_stt(profile: MoveProfile, distance: int, t: list[float], des: list[int], start: int,
               sample_s: float) -> list[float]:
    """A far-side recording's times of a trapezoid move, counted from its STT on the chip's
    clock: the first row whose desired position is part-way says how many samples the
    profile has run (to within one), where the host's stamp of the STT is late by the reply's
    trip (behind an Uno up to a flush tick, 4.096 ms: a move's settle after the profile's end
    is a few milliseconds).  Unchanged when no row is part-way."""
    path = profile.desired(abs(distance))
    sign = 1 if distance >= 0 else -1
    # counts the profile has gone at each row; going down the chip's position is floored
    # below the start at once (2000 - 1/65536 reads 1999): one count less than the plan's
    moved = [sign * (d - start) - (sign < 0) for d in des]
    part = [j for j, x in enumerate(moved) if 0 < x < abs(distance) - 1]
    if not part:
        return t
    j = part[len(part) // 2]  # mid-move, where the desired position changes every sample
    k = bisect.bisect_left(path, moved[j])  # the first sample at or past it
    shift = (k + 0.5) * sample_s - t[j]
    return [x + shift for x in t]



__all__ = ["FitExperiment", "FarSegment", "FitRow", "fit_model", "since_stt"]
