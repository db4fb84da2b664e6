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
    #: the rest window judged (0: not judged): how long a move's ``wait()`` needs the shaft to
    #: stand on one count (``MoveRules.settle_time``)
    rest_window: float = 0.0
    #: when the shaft, the trajectory ended, had first stood on one count within the tolerance
    #: for ``rest_window``: when ``wait()`` would return.  None: never (a shaft that hunts a
    #: count either way against a load never stands still that long), or not judged
    rest_s: float | None = None

    @property
    def rests(self) -> bool:
        """The shaft came to rest within the tolerance (always True when rest is not judged)."""
        return not self.rest_window or self.rest_s is not None

    def worst(self, other: MoveMetrics) -> MoveMetrics:
        settle = None if self.settle_s is None or other.settle_s is None else \
            max(self.settle_s, other.settle_s)
        rise = None if self.rise_s is None or other.rise_s is None else max(self.rise_s,
                                                                             other.rise_s)
        rest = None if self.rest_s is None or other.rest_s is None else max(self.rest_s,
                                                                             other.rest_s)
        return MoveMetrics(self.distance, max(self.final_error, other.final_error, key=abs),
                           max(self.overshoot, other.overshoot), settle, rise,
                           max(self.peak_following_error, other.peak_following_error, key=abs),
                           max(self.hunt, other.hunt), max(self.rest_window, other.rest_window),
                           rest)

    def line(self) -> str:
        settle = "never" if self.settle_s is None else f"{self.settle_s * 1e3:.1f} ms"
        rise = "-" if self.rise_s is None else f"{self.rise_s * 1e3:.1f} ms"
        hunt = f", hunting {self.hunt} counts peak to peak at rest" if self.hunt else ""
        rest = ""
        if self.rest_window:
            window = f"{self.rest_window * 1e3:.0f} ms"
            rest = (f", never still for {window} within the tolerance" if self.rest_s is None
                    else f", still for {window} at {self.rest_s * 1e3:.1f} ms")
        return (f"final error {self.final_error:+d}, overshoot {self.overshoot}, settle {settle}, "
                f"rise {rise}, peak following error {self.peak_following_error:+d} counts{hunt}"
                f"{rest}")


def as_move(m: MoveMetrics, profile: object) -> MoveMetrics:
    """A step's metrics read as a move's when ``profile`` (a trapezoid) drove it: no rise time,
    and the settle time counted from the profile's end, never before it.  The predicted and
    the measured move are judged alike through here."""
    if not profile:
        return m
    return replace(m, rise_s=None, settle_s=None if m.settle_s is None else max(0.0, m.settle_s))


def step_metrics(times: Sequence[float], positions: Sequence[int], desired: Sequence[int],
                 start: int, target: int, tolerance: int, rest: float = 0.0) -> MoveMetrics:
    """Metrics of one response: ``times`` after the STT, real and desired positions;
    ``rest``: the rest window to judge (:attr:`MoveMetrics.rest_s`), in the times' unit."""
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
    late = 0.75 * times[-1] if times else 0.0
    tail = [p for t, p in zip(times, positions) if t >= late]
    hunt = max(tail) - min(tail) if tail else 0
    return MoveMetrics(dist, target - positions[-1] if positions else dist, overshoot, settle,
                       rise, pfe, hunt, rest, rest_time(times, positions, desired, target,
                                                        tolerance, rest) if rest else None)


def rest_time(times: Sequence[float], positions: Sequence[int], desired: Sequence[int],
              target: int, tolerance: int, window: float) -> float | None:
    """The first time at which the desired position is on the target and the shaft has stood
    on one count, within ``tolerance`` of the target, for ``window`` (a move's settle rule:
    :class:`lm629_host.chip.move.MoveRules`); None if it never does."""
    since = 0
    for j in range(1, len(times)):
        if positions[j] != positions[j - 1]:
            since = j
        elif (desired[j] == target and abs(positions[j] - target) <= tolerance
              and times[j] - times[since] >= window):
            return times[j]
    return None


def score(m: MoveMetrics, horizon_s: float, tolerance: int) -> float:
    """Smaller is better: settle time, plus overshoot (a settle-time-equivalent penalty),
    plus a large penalty for a final error outside the tolerance and a small one for each
    count beyond half of it (a margin for what the model does not know) and for each count
    of hunting at rest.  Where rest is judged, the settle time is the time the shaft came to
    rest (a shaft that never stands still counts as never settled: a move's ``wait()``
    would not return)."""
    settle = horizon_s * 2 if m.settle_s is None else m.settle_s
    if m.rest_window:
        settle = horizon_s * 2 if m.rest_s is None else max(settle, m.rest_s)
    over = max(0, m.overshoot - tolerance) / max(abs(m.distance), 1)
    miss = max(0, abs(m.final_error) - tolerance)
    margin = max(0, abs(m.final_error) - tolerance // 2)  # prefer ending well inside
    return settle * (1 + 8 * over) + horizon_s * (over + miss + 0.05 * (margin + m.hunt))



def in_seconds(m: MoveMetrics, sample_s: float) -> MoveMetrics:
    """Metrics counted in samples (the predictor's) in seconds."""
    return replace(m, settle_s=None if m.settle_s is None else m.settle_s * sample_s,
                   rise_s=None if m.rise_s is None else m.rise_s * sample_s,
                   rest_window=m.rest_window * sample_s,
                   rest_s=None if m.rest_s is None else m.rest_s * sample_s)


__all__ = ["MoveMetrics", "as_move", "in_seconds", "rest_time", "score", "step_metrics"]
