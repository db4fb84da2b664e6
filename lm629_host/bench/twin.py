"""A twin of the user's own axis: the plant the tuner identifies, kept in the profile, a
simulated chip built from it, and a check that the twin still behaves as the bench does.

Why: a lab's scripts are tested hardware-free on a simulated chip, and a script that settles
in 40 ms on the default motor may take 400 ms on a 10x-inertia axis.  ``lm629 tune`` and
``lm629 identify`` fit a model of the axis (:class:`~lm629_host.physics.axis.AxisModel`, in counts
and samples); :class:`Plant` is that model in units that do not depend on the chip's clock,
written to ``[axis.NAME.plant]`` (:data:`lm629_host.config.profile.PLANT_KEYS`), from which
``sim://?profile=FILE`` builds each axis's motor (the same names are ``MotorParams`` fields;
their mapping onto the SI parameters is in docs/model.md).

:func:`check_twin` runs the same short step and trapezoid move on the bench and on the twin,
recorded on the far side, and compares them (:data:`MATCH` is the threshold, documented in
docs/twin.md).
"""

from __future__ import annotations

import datetime
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from lm629_host.bench.tuning_session import Progress, Record, measure_move
from lm629_host.chip.lm629 import LM629
from lm629_host.physics.axis import AxisModel, Gains
from lm629_host.physics.design import default_profile
from lm629_host.physics.metrics import MoveMetrics, step_metrics
from lm629_host.physics.predict import MoveProfile


# ---------------------------------------------------------------------------------- the plant
@dataclass(frozen=True)
class Plant:
    """The axis as identified, in the units of ``[axis.NAME.plant]``."""

    accel: float  #: counts/s^2 at full-scale output, shaft at rest
    tau: float  #: mechanical time constant, s (1 / the speed's decay rate)
    dry: float = 0.0  #: dry friction, a fraction of full-scale output
    load: float = 0.0  #: constant load, a fraction of full-scale output (> 0: towards fewer)
    reversed: bool = False  #: the motor leads reversed

    @classmethod
    def from_model(cls, model: AxisModel, sample_s: float) -> Plant:
        """The tuner's model (counts and samples of ``sample_s``) in clock-free units."""
        rate = max(model.rate, 1e-12)
        return cls(model.accel / sample_s ** 2, sample_s / rate, model.coulomb / model.accel,
                   model.load / model.accel)

    @classmethod
    def from_values(cls, values: dict[str, Any]) -> Plant:
        """From a profile's checked ``[axis.NAME.plant]`` table (ValueError: not a plant)."""
        missing = [k for k in ("accel", "tau") if k not in values]
        if missing:
            raise ValueError(f"the plant has no {' and no '.join(missing)}")
        return cls(float(values["accel"]), float(values["tau"]), float(values.get("dry", 0.0)),
                   float(values.get("load", 0.0)), bool(values.get("reversed", False)))

    def model(self, sample_s: float, twelve_bit: bool = False) -> AxisModel:
        """The tuner's model of this plant at a sample period of ``sample_s``."""
        accel = self.accel * sample_s ** 2
        return AxisModel(accel, sample_s / self.tau, self.dry * accel, self.load * accel,
                         twelve_bit)

    def values(self) -> dict[str, Any]:
        """The plant's keys of ``[axis.NAME.plant]``, rounded to what a fit can tell."""
        return {"accel": float(f"{self.accel:.5g}"), "tau": float(f"{self.tau:.5g}"),
                "dry": round(self.dry, 5), "load": round(self.load, 5),
                "reversed": self.reversed}


def plant_record(model: AxisModel, sample_s: float, *, rms: float, steps: int, port: str,
                 when: datetime.datetime | None = None) -> dict[str, Any]:
    """``[axis.NAME.plant]`` for :func:`lm629_host.config.profile.save_gains`: the plant with the
    date, the port, the fit's rms error and the number of steps it was fitted to."""
    when = when or datetime.datetime.now(datetime.timezone.utc)
    out = Plant.from_model(model, sample_s).values()
    out.update(rms=round(rms, 2), steps=steps, date=when.isoformat(timespec="seconds"),
               port=port)
    return out


# ---------------------------------------------------------------------------------- the check
#: the twin matches the bench when, for both test moves, the overshoots differ by at most
#: 2 counts or 10 % and the rms difference of the positions is at most 0.5 % of the move (1
#: count at least), and the trapezoid move's settle times by at most 5 ms or 10 % (whichever
#: is larger).  The short step's settle time is shown, not judged: its last counts are a
#: creep against dry friction, where a count's difference moves the time by 5-10 ms; its rms
#: difference sees a doubled load (0.5 counts on the same bench, 1.9 with the load doubled)
MATCH_OVERSHOOT = (2, 0.10)
#: counts: a comparison's settle time is the last time the shaft is further than this from
#: its target.  Not the tuner's 2: a shaft at rest against dry friction with an integral term
#: creeps 2-3 counts from its target for tens of milliseconds, on the bench as on the twin,
#: and a 2-count settle time of the same axis then comes out anywhere from 19 to 60 ms from
#: one move to the next (docs/twin.md)
SETTLE_BAND = 5
MATCH_SETTLE = (5e-3, 0.10)
MATCH_RMS = (1.0, 0.005)


def close(a: float, b: float, absolute: float, relative: float) -> bool:
    """``|a - b|`` within ``absolute`` or ``relative`` of the larger, whichever is larger."""
    return abs(a - b) <= max(absolute, relative * max(abs(a), abs(b)))


@dataclass(frozen=True)
class Side:
    """One test move on one side: its figures and the positions recorded."""

    metrics: MoveMetrics
    #: each step's rows (out, then back): seconds after its STT, counts from its start
    segments: list[tuple[list[float], list[int]]]
    #: the settle times (s, None: never) with the band a count wider and a count narrower
    settle_range: tuple[float | None, float | None] = (None, None)


def settle_close(a: Side, b: Side) -> bool:
    """The settle times agree (:data:`MATCH_SETTLE`) to within a count of the band: a shaft
    that creeps at the band's edge, or an overshoot that ends on it, is a count from
    settling a whole oscillation earlier or later, and a count is the encoder's resolution,
    not a difference between the axes.  So the times with the band a count wider and a count
    narrower bound each side's, and the two sides agree when those spans come close enough."""
    (a_lo, a_hi), (b_lo, b_hi) = a.settle_range, b.settle_range
    if a.metrics.settle_s is None or b.metrics.settle_s is None:
        return a.metrics.settle_s is None and b.metrics.settle_s is None
    lo_a, hi_a = a_lo or 0.0, a.metrics.settle_s if a_hi is None else a_hi
    lo_b, hi_b = b_lo or 0.0, b.metrics.settle_s if b_hi is None else b_hi
    gap = max(0.0, lo_a - hi_b, lo_b - hi_a)  # 0 where the spans overlap
    return gap <= max(MATCH_SETTLE[0], MATCH_SETTLE[1] * max(hi_a, hi_b))


@dataclass(frozen=True)
class Compared:
    """One test move on the bench and on the twin."""

    name: str
    bench: Side
    twin: Side
    rms: float  #: counts, rms difference of the positions (aligned: :func:`rms_difference`)
    distance: int
    judge_settle: bool = True  #: the settle times are part of the verdict

    def settle_ok(self) -> bool:
        return settle_close(self.bench, self.twin)

    def overshoot_ok(self) -> bool:
        return close(self.bench.metrics.overshoot, self.twin.metrics.overshoot,
                     *MATCH_OVERSHOOT)

    def rms_ok(self) -> bool:
        return self.rms <= max(MATCH_RMS[0], MATCH_RMS[1] * abs(self.distance))

    @property
    def matches(self) -> bool:
        return (self.settle_ok() or not self.judge_settle) and self.overshoot_ok() and \
            self.rms_ok()


@dataclass(frozen=True)
class TwinCheck:
    moves: list[Compared]

    @property
    def matches(self) -> bool:
        return all(m.matches for m in self.moves)

    def lines(self) -> list[str]:
        """The side-by-side table, and what to do when the twin differs (the verdict, one
        word, is the caller's to print: ``matches`` or ``differs``)."""
        def settle(m: MoveMetrics) -> str:
            return "never" if m.settle_s is None else f"{m.settle_s * 1e3:.1f} ms"

        out = [f"{'move':<10} {'':>6} {'bench':>10} {'twin':>10}  ok"]
        for c in self.moves:
            b, t = c.bench.metrics, c.twin.metrics
            limit = max(MATCH_RMS[0], MATCH_RMS[1] * abs(c.distance))
            out += [f"{c.name:<10} {'rms':>6} {'':>10} {c.rms:>7.1f} ct  "
                    f"{'yes' if c.rms_ok() else 'NO'} (limit {limit:.0f})",
                    f"{'':<10} {'over':>6} {b.overshoot:>7d} ct {t.overshoot:>7d} ct  "
                    f"{'yes' if c.overshoot_ok() else 'NO'}",
                    f"{'':<10} {'settle':>6} {settle(b):>10} {settle(t):>10}  "
                    + (("yes" if c.settle_ok() else "NO") if c.judge_settle else "(shown)")]
        if not self.matches:  # the verdict itself is the caller's one line (``twin check``)
            out.append("the twin differs from the bench: identify the axis again (`lm629 "
                       "identify --save`) before trusting tests on the twin")
        return out


def judged_side(metrics: MoveMetrics, rec: Record, band: int) -> Side:
    """A test move's record (:func:`~lm629_host.bench.tuning_session.measure_move`) as one side of a
    comparison, its settle time at ``band`` counts given a count either way."""
    segments = []
    for k in range(len(rec.steps)):
        t, real, des, start, _target = rec.segment(k)
        segments.append((since_command(t, des, start), [p - start for p in real]))
    spans = []
    for b in (band + 1, max(0, band - 1)):
        worst: float | None = 0.0
        for t, real, des, start, target in rec.judged:
            m = step_metrics(t, real, des, start, target, b)
            s = None if m.settle_s is None else max(0.0, m.settle_s)
            worst = None if s is None or worst is None else max(worst, s)
        spans.append(worst)
    return Side(metrics, segments, (spans[0], spans[1]))


def since_command(t: list[float], des: list[int], start: int) -> list[float]:
    """A step's row times counted from its first row whose desired position has left
    ``start``: on each side that row comes within one row of the chip's STT, on the far
    side's clock where it records, so the two sides line up however late the host stamped its
    STT (a busy host's stamp was late by more than :func:`rms_difference`'s search: 34 counts
    rms between a bench and its own twin).  Unchanged when the desired position never moved."""
    first = next((t[j] for j, d in enumerate(des) if d != start), None)
    return t if first is None else [x - first for x in t]


def rms_difference(a: Side, b: Side, shift_s: float = 10e-3, step_s: float = 2.5e-4) -> float:
    """The rms difference of ``b``'s positions from ``a``'s at ``a``'s times (``b``'s
    interpolated), each step at the best relative time shift within ``+/- shift_s``: each
    step's times count from its first row with the desired position moved
    (:func:`since_command`), which is up to a row after the STT on either side (a
    millisecond's far-side row, a host poll), and that is not a difference between bench and
    twin."""
    total, n = 0.0, 0
    for (ta, pa), (tb, pb) in zip(a.segments, b.segments):
        if not ta or not tb:
            return float("inf")
        best = float("inf")
        k_max = round(shift_s / step_s)
        for k in range(-k_max, k_max + 1):
            d = k * step_s
            best = min(best, sum((_at(tb, pb, t + d) - p) ** 2 for t, p in zip(ta, pa)))
        total, n = total + best, n + len(ta)
    return (total / n) ** 0.5 if n else float("inf")


def _at(times: Sequence[float], values: Sequence[int], t: float) -> float:
    import bisect
    i = bisect.bisect_right(times, t)
    if i == 0:
        return values[0]
    if i >= len(times):
        return values[-1]
    t0, t1 = times[i - 1], times[i]
    if t1 <= t0:
        return values[i - 1]
    return values[i - 1] + (values[i] - values[i - 1]) * (t - t0) / (t1 - t0)


def check_twin(bench: LM629, twin: LM629, gains: Gains, *, travel: int, distance: int,
               profile: MoveProfile, step: int | None = None, tolerance: int = SETTLE_BAND,
               duration_s: float = 0.4, poll_s: float = 1e-3,
               progress: Progress | None = None) -> TwinCheck:
    """A short step (``step`` counts, default a tenth of ``distance``: small enough that the
    drive does not saturate for long) and the trapezoid move (``distance``), each out and
    back inside ``+/- travel`` of where each shaft is, guarded as tuning is
    (:func:`~lm629_host.bench.tuning_session.measure_move`), with ``gains`` on the bench, then on the twin,
    compared."""
    say = progress or (lambda text: None)
    step = max(10, distance // 10) if step is None else step
    moves = []
    for name, p, counts in (("step", None, step), ("trapezoid", profile, distance)):
        sides = []
        for label, chip in (("bench", bench), ("twin", twin)):
            say(f"{name} of {counts:+d} counts out and back on the {label}")
            m, rec = measure_move(chip, gains, distance=counts, travel=travel,
                                  duration_s=duration_s, tolerance=tolerance, poll_s=poll_s,
                                  profile=p)
            sides.append(judged_side(m, rec, tolerance))
        moves.append(Compared(name, sides[0], sides[1], rms_difference(sides[0], sides[1]),
                              counts, judge_settle=p is not None))
    return TwinCheck(moves)


def twin_profile(plant: Plant, sample_s: float, velocity: int | None = None,
                 acceleration: int | None = None) -> MoveProfile:
    """The trapezoid move the check runs: the tuner's (:func:`default_profile`) for this
    plant, unless the words are given."""
    return default_profile(plant.model(sample_s), velocity, acceleration)


__all__ = ["MATCH_OVERSHOOT", "MATCH_RMS", "MATCH_SETTLE", "SETTLE_BAND", "Compared", "Plant", "Side",
           "TwinCheck", "check_twin", "close", "judged_side", "plant_record", "since_command",
           "settle_close", "rms_difference", "twin_profile"]
