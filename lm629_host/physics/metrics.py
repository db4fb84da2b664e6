"""What a step response or a move did, as the figures a tuner judges: final error,
overshoot, settle and rise times, peak following error, hunting at rest, and the score that
ranks candidate gains.

The predicted moves (:func:`lm629_host.physics.predict.predict_move`) and the measured ones
(the bench session's test moves) are measured by the same :func:`step_metrics`, so that a
prediction and a measurement can be compared figure by figure.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace


@dataclass(frozen=True)
class MoveMetrics:
    """One step response, the figures a tuner looks at (counts, seconds after the STT)."""

    distance: int
    final_error: int  #: target - position at the end of the record
    overshoot: int  #: counts past the target, in the move's direction, >= 0
    settle_s: float | None  #: first time after which the shaft stays within the tolerance
    rise_s: float | None  #: 10 % -> 90 % of the distance
    peak_following_error: int  #: largest |desired - real| (a step: about the distance)
    hunt: int = 0  #: counts peak to peak over the last quarter of the record (hunting at rest)

    def worst(self, other: MoveMetrics) -> MoveMetrics:
        settle = None if self.settle_s is None or other.settle_s is None else \
            max(self.settle_s, other.settle_s)
        rise = None if self.rise_s is None or other.rise_s is None else max(self.rise_s,
                                                                             other.rise_s)
        return MoveMetrics(self.distance, max(self.final_error, other.final_error, key=abs),
                           max(self.overshoot, other.overshoot), settle, rise,
                           max(self.peak_following_error, other.peak_following_error, key=abs),
                           max(self.hunt, other.hunt))

    def line(self) -> str:
        settle = "never" if self.settle_s is None else f"{self.settle_s * 1e3:.1f} ms"
        rise = "-" if self.rise_s is None else f"{self.rise_s * 1e3:.1f} ms"
        hunt = f", hunting {self.hunt} counts peak to peak at rest" if self.hunt else ""
        return (f"final error {self.final_error:+d}, overshoot {self.overshoot}, settle {settle}, "
                f"rise {rise}, peak following error {self.peak_following_error:+d} counts{hunt}")


def as_move(m: MoveMetrics, profile: object) -> MoveMetrics:
    """A step's metrics read as a move's when ``profile`` (a trapezoid) drove it: no rise time,
    and the settle time counted from the profile's end, never before it.  The predicted and
    the measured move are judged alike through here."""
    if not profile:
        return m
    return replace(m, rise_s=None, settle_s=None if m.settle_s is None else max(0.0, m.settle_s))


def step_metrics(times: Sequence[float], positions: Sequence[int], desired: Sequence[int],
                 start: int, target: int, tolerance: int) -> MoveMetrics:
    """Metrics of one response: ``times`` after the STT, real and desired positions."""
    sign = 1 if target >= start else -1
    dist = target - start
    overshoot = max([0] + [sign * (p - target) for p in positions])
    settle = None
    for t, p in zip(reversed(times), reversed(positions)):
        if abs(p - target) > tolerance:
            break
        settle = t
    rise = None
    t10 = next((t for t, p in zip(times, positions) if sign * (p - start) >= 0.1 * abs(dist)),
               None)
    t90 = next((t for t, p in zip(times, positions) if sign * (p - start) >= 0.9 * abs(dist)),
               None)
    if t10 is not None and t90 is not None:
        rise = t90 - t10
    pfe = max((dsr - p for dsr, p in zip(desired, positions)), key=abs, default=0)
    tail = [p for t, p in zip(times, positions) if t >= 0.75 * times[-1]] if times else []
    hunt = max(tail) - min(tail) if tail else 0
    return MoveMetrics(dist, target - positions[-1] if positions else dist, overshoot, settle,
                       rise, pfe, hunt)


def score(m: MoveMetrics, horizon_s: float, tolerance: int) -> float:
    """Smaller is better: settle time, plus overshoot (a settle-time-equivalent penalty),
    plus a large penalty for a final error outside the tolerance and a small one for each
    count beyond half of it (a margin for what the model does not know) and for each count
    of hunting at rest."""
    settle = horizon_s * 2 if m.settle_s is None else m.settle_s
    over = max(0, m.overshoot - tolerance) / max(abs(m.distance), 1)
    miss = max(0, abs(m.final_error) - tolerance)
    margin = max(0, abs(m.final_error) - tolerance // 2)  # prefer ending well inside
    return settle * (1 + 8 * over) + horizon_s * (over + miss + 0.05 * (margin + m.hunt))



def in_seconds(m: MoveMetrics, sample_s: float) -> MoveMetrics:
    """Metrics counted in samples (the predictor's) in seconds."""
    return replace(m, settle_s=None if m.settle_s is None else m.settle_s * sample_s,
                   rise_s=None if m.rise_s is None else m.rise_s * sample_s)


__all__ = ["MoveMetrics", "as_move", "in_seconds", "score", "step_metrics"]
