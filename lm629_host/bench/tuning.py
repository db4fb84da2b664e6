"""``autotune``: PID gains found on the user's own axis, safely, in one call.

Why a model and not a rule of thumb: the LM629's filter is integer arithmetic with an 8-bit
output (AN-706 5.2.3): a proportional term below one output step does nothing (a dead band of
256 / kp counts), the drive saturates on any sizeable step, and the derivative of a position
read in whole counts is coarse.  Ziegler-Nichols style rules ignore all three, and the three
decide whether a move ends within 2 counts or 50.  So the tuner:

1. **checks the loop phasing** (AN-706 2.12, AN-868 "Tuning the PID") with gentle P-only steps
   of ``travel / 8`` counts up and down whose first output is 1/8 of full scale: a shaft
   heading away from a target that slows down once the drive is off is reversed leads
   (``MotionError`` RUNAWAY, "swap the motor leads"); one that keeps going is pulled by a load
   (gravity on a vertical axis), and the gain is raised until the loop holds it, or the tuner
   says that it cannot (STALL); a shaft that does not move even at full-scale output is a
   stall (see :func:`_phasing`);
2. **identifies the axis** from two P-only steps (``travel / 4`` out and back, first output
   half scale): a second-order plant in the chip's own units -- acceleration at full-scale
   output, speed decay rate (back-EMF and viscous friction), dry friction and a constant load,
   all per sample -- fitted by simulating the chip's filter arithmetic sample by sample against
   every position read (Nelder-Mead, a few hundred simulations);
3. **designs** gains by pole placement on that model (natural frequency x damping x derivative
   interval, then integral variants of the best), predicting each candidate's test move on the
   model with the output quantisation and saturation, and keeping the one whose worst score
   (settle time inside the tolerance, overshoot, end error, hunting) over the model and three
   variants of it (30 % lighter, 40 % heavier, a fifth of the dry friction) is best;
4. **checks** them with the test move (a step of ``distance`` counts out and back) and leaves
   them loaded and applied (LFIL + UDF).

Safety: every position read (every snapshot of every experiment) is checked against the
travel band ``origin +/- travel`` less the distance the shaft needs to stop; the chip's own
following-error stop (LPES) is armed at ``travel`` counts while tuning; any fault stops the
motor (abrupt stop, then motor off) and raises :class:`~lm629_host.errors.MotionError`.
Everything waits on ``chip.clock`` (simulated time on ``sim://``).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, field, replace

from lm629_host.errors import MotionError, MotionFault
from lm629_host.physics.limits import clip_step
from lm629_host.chip.lm629 import LM629, Snapshot, check_int
from lm629_host.bus.opcodes import ACCELERATION_MAX, COEFFICIENT_MAX, FIXED_ONE, VELOCITY_MAX, Signals, Status
from lm629_host.chip.recording import far_snapshots, sample_program
from lm629_host.physics.pid import (
    STEP_ACCELERATION,
    STEP_VELOCITY,
    U_FULL_SCALE,
    PIDState,
    full_scale,
    holds,
    output_shift,
    pid_step,
    sample_period_s,
    sat16,
    skip_held,
)
from lm629_host.chip.safety import motion_fault, stop_on_error
from lm629_host.physics.plan import plan
from lm629_host.physics.plant import decay_and_gain, motor_step
from lm629_host.physics.units import to_fixed


Progress = Callable[[str], None]


# ---------------------------------------------------------------------------------- gains
@dataclass(frozen=True)
class Gains:
    """The filter's gains (LFIL) and ``ds``, the derivative interval in samples (1..256)."""

    kp: int
    ki: int = 0
    kd: int = 0
    il: int = 0
    ds: int = 1

    def as_filter(self) -> dict[str, int]:
        """Keyword arguments of :meth:`LM629.load_filter`."""
        return dict(kp=self.kp, ki=self.ki, kd=self.kd, il=self.il,
                    derivative_interval=self.ds)

    def cli(self, axis: str | None = None) -> str:
        """The ``lm629 filter`` line that sets these gains (on ``--axis axis``, when given: a
        profile's command without it means every axis)."""
        on = f"--axis {axis} " if axis is not None else ""
        return (f"lm629 {on}filter --kp {self.kp} --ki {self.ki} --kd {self.kd} --il {self.il} "
                f"--ds {self.ds}")

    def __str__(self) -> str:
        return f"kp={self.kp} ki={self.ki} kd={self.kd} il={self.il} ds={self.ds}"


# ---------------------------------------------------------------------------------- model
@dataclass(frozen=True)
class AxisModel:
    """The axis as the tuner sees it, in the chip's units (counts, samples of 2048 clocks).

    dw/dn = accel x out / full_scale - rate x w - coulomb x sign(w) - load, with w the speed
    in counts/sample and ``out`` the output code (-128..127 on the 8-bit port; -2048..2047 in
    LM628 12-bit mode), held for a sample.  The same structure as a DC motor with the armature
    inductance neglected, so one sample is integrated exactly.
    """

    accel: float  #: counts/sample^2 at full-scale output, shaft at rest
    rate: float  #: speed decay per sample (back-EMF braking + viscous friction)
    coulomb: float = 0.0  #: dry friction, counts/sample^2
    load: float = 0.0  #: constant load, counts/sample^2 (positive pulls toward negative counts)
    twelve_bit: bool = False

    @property
    def full_scale(self) -> int:
        return full_scale(self.twelve_bit)

    @property
    def per_filter_unit(self) -> float:
        """counts/sample^2 per unit of the filter's 16-bit result (both output widths)."""
        return self.accel / U_FULL_SCALE

    def stop_distance(self, speed: float) -> float:
        """Counts the shaft needs to stop from ``speed`` counts/sample at full braking."""
        brake = max(self.accel - abs(self.load), 1e-9)
        return speed * speed / (2 * brake) + abs(speed)

    def scaled(self, factor: float) -> AxisModel:
        """The same axis with ``factor`` times the inertia (robustness check)."""
        return replace(self, accel=self.accel / factor, rate=self.rate / factor,
                       coulomb=self.coulomb / factor, load=self.load / factor)

    def describe(self, sample_s: float) -> str:
        a = self.accel / sample_s ** 2
        return (f"acceleration at full output {a:,.0f} counts/s^2, time constant "
                f"{sample_s / max(self.rate, 1e-12) * 1e3:.1f} ms, top speed "
                f"{self.accel / max(self.rate, 1e-12) / sample_s:,.0f} counts/s, dry friction "
                f"{self.coulomb / self.accel * 100:.1f} % and load "
                f"{self.load / self.accel * 100:+.1f} % of full output")


def simulate(model: AxisModel, gains: Gains, desired: Sequence[int], *, x0: float,
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


# ---------------------------------------------------------------------------------- metrics
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


def _as_move(m: MoveMetrics, profile: object) -> MoveMetrics:
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


# ---------------------------------------------------------------------------------- records
@dataclass
class Record:
    """Snapshots of one experiment and the steps commanded in it (time, target)."""

    name: str
    gains: Gains | None
    rows: list[Snapshot] = field(default_factory=list)
    steps: list[tuple[float, int]] = field(default_factory=list)
    t0: float = 0.0
    state0: PIDState | None = None  #: the filter's state at t0, when known
    #: for each step, the index in ``rows`` of the first row read after its STT
    step_rows: list[int] = field(default_factory=list)
    #: the rows recorded on the far side, one (first, end) index range per recording: their
    #: times within a range are the far side's clock (exact), only its offset is the host's
    far_runs: list[tuple[int, int]] = field(default_factory=list)
    #: the (velocity, acceleration) words of the steps when an axis's soft caps brought them
    #: below a step (:func:`lm629_host.physics.limits.clip_step`): the desired position ramps
    words: tuple[int, int] | None = None
    #: each step of a test move as it was judged (:func:`measure_move`): times after the
    #: profile's end (a step: after its STT), real and desired positions, start, target
    judged: list[tuple[list[float], list[int], list[int], int, int]] = field(
        default_factory=list)

    def times(self) -> list[float]:
        return [s.time - self.t0 for s in self.rows]

    def segment(self, k: int) -> tuple[list[float], list[int], list[int], int, int]:
        """(times after its STT, real, desired, start, target) of the k-th step.

        The rows are told apart by when they were read (``step_rows``), not by their times: a
        far-side recording started at the STT stamps its first row with the STT's own time
        (``sim://``), and behind USB the host learns of the STT a flush tick after the chip."""
        t_k, target = self.steps[k]
        first = self.step_rows[k]
        end = self.step_rows[k + 1] if k + 1 < len(self.step_rows) else len(self.rows)
        start = self.rows[max(0, first - 1)].desired_position
        rows = self.rows[first:end]
        return ([s.time - t_k for s in rows], [s.real_position for s in rows],
                [s.desired_position for s in rows], start, target)


@dataclass
class TuneResult:
    """What :func:`autotune` found, measured and predicted.  ``kp ki kd il`` are the chip's
    words, ``ds`` the derivative interval in samples (as in :class:`Gains`)."""

    kp: int
    ki: int
    kd: int
    il: int
    ds: int
    model: AxisModel
    sample_s: float
    origin: int
    travel: int
    distance: int
    tolerance: int
    predicted: MoveMetrics
    measured: MoveMetrics  #: worse of the out and back test moves with the tuned gains
    before: MoveMetrics | None = None  #: the same test move with the gains found loaded
    records: list[Record] = field(default_factory=list)
    fit_rms: float = 0.0  #: counts, model vs the identification steps
    #: every real position read during tuning (the travel-band check is on all of them)
    positions: list[int] = field(default_factory=list)
    profile: MoveProfile | None = None  #: the trapezoid move judged and checked
    predicted_move: MoveMetrics | None = None  #: the trapezoid move on the model
    measured_move: MoveMetrics | None = None  #: ... and on the axis (settle after the profile)
    fit_steps: int = 0  #: the identification steps the model was fitted to

    @property
    def gains(self) -> Gains:
        return Gains(self.kp, self.ki, self.kd, self.il, self.ds)

    @property
    def ok(self) -> bool:
        """The test moves (step and trapezoid) ended within the tolerance."""
        return all(abs(m.final_error) <= self.tolerance
                   for m in (self.measured, self.measured_move) if m is not None)

    def record(self, name: str) -> Record | None:
        return next((r for r in self.records if r.name == name), None)


# ---------------------------------------------------------------------------------- the session
#: the shortest time a shaft must keep within 2 counts to count as at rest (see ``settle``)
QUIET_S = 0.05


class _Session:
    """The experiments on the chip, each position read checked against the travel band."""

    def __init__(self, chip: LM629, travel: int, poll_s: float, progress: Progress,
                 clock_hz: float | None = None):
        self.chip = chip
        self.travel = travel
        self.poll_s = poll_s
        self.progress = progress
        self.model: AxisModel | None = None
        self.positions: list[int] = []
        first = chip.snapshot()
        # the band is around where the shaft is: the desired position while the loop holds
        # it, the real one while the drive is off (after a reset, or a stop with motor off)
        self.drive_off = bool(first.signals & Signals.MOTOR_OFF)
        self.origin = first.real_position if self.drive_off else first.desired_position
        self.sample_s = sample_period_s(clock_hz or chip.clock_hz)
        self.records: list[Record] = []
        self.driving = False  #: an STT of ours turned the drive on (reset leaves it off)
        #: the way a load pulls the shaft (+1, -1), once seen: the shaft moving with the drive
        #: off, or the same way after a step up and a step down (phasing); 0 while not seen
        self.pulled = 0
        if self.drive_off and first.real_velocity:
            self.pulled = 1 if first.real_velocity > 0 else -1
        self.phasing_kp: int | None = None  #: the phasing gain in force, while phasing
        self._stream: Generator[Snapshot, None, None] | None = None  #: a recording under way
        self.far_period = self._far_period(chip)
        self.check(first)

    def _far_period(self, chip: LM629) -> float | None:
        """The period of far-side recordings (the transport's own clock times the rows, host
        latency only delays them), or None where the host polls: a whole number of
        chip samples, at least ``poll_s`` and what the line carries.  Whole samples: a row
        period of 1 ms is 3.906 samples at 8 MHz, so rows would fall at every phase of the
        chip's sample and a fit that puts each row on its sample would be up to half a sample
        out (5 counts at 10 counts/sample); at 2.048 ms every row is at the same phase."""
        transport = chip.transport
        if not transport.records_on_far_side:
            return None
        top = transport.record_max_rate(sample_program(chip, full=True))
        shortest = max(self.poll_s, 1.0 / top if top else 0.0)
        return math.ceil(shortest / self.sample_s - 1e-9) * self.sample_s

    def fault(self, reason: MotionFault, message: str, snap: Snapshot | None = None) -> MotionError:
        if self._stream is not None:  # a recording in progress: end it before the stop
            self._stream.close()
        return motion_fault(self.chip, reason, message,
                            position=None if snap is None else snap.real_position,
                            error=None if snap is None else snap.following_error)

    def check(self, s: Snapshot) -> None:
        """The safety checks on every snapshot."""
        self.positions.append(s.real_position)
        off = s.real_position - self.origin
        speed = abs(s.real_velocity) + 1
        stop = self.model.stop_distance(speed) if self.model else speed * speed + 4 * speed
        if abs(off) + stop > self.travel:
            moving = (s.real_velocity > 0) - (s.real_velocity < 0)
            if self.phasing_kp is not None and self.pulled and moving == self.pulled:
                raise self.fault(MotionError.STALL,
                                 f"phasing: a load pulls the shaft {'up' if moving > 0 else 'down'}"
                                 f" (it moved that way with the drive off, or whichever way it "
                                 f"was stepped): it is {off:+d} counts from where tuning started "
                                 f"and would leave the travel band of +/-{self.travel}: the load "
                                 f"pulls harder than kp={self.phasing_kp} holds: raise it or "
                                 "support the axis (phasing starts at kp = 32768 / --travel: a "
                                 "shorter travel starts stiffer; or more amplifier gain)", s)
            raise self.fault(MotionError.RUNAWAY,
                             f"the shaft is {off:+d} counts from where tuning started, moving "
                             f"{s.real_velocity:+d} counts/sample: it would leave the travel "
                             f"band of +/-{self.travel} counts; give a larger --travel if the "
                             "axis has room, or check the mechanics", s)
        if s.status & Status.POSITION_ERROR:
            raise self.fault(MotionError.POSITION_ERROR,
                             f"following error {s.following_error:+d} counts exceeded the "
                             f"{self.travel}-count limit armed for tuning", s)
        if self.driving and s.signals & Signals.MOTOR_OFF:
            raise self.fault(MotionError.MOTOR_OFF, "the drive was found off during tuning", s)

    def snap(self) -> Snapshot:
        """A snapshot timed at the middle of its bus program (on a bridge the reads happen
        during the round trip, not at its end), checked."""
        t0 = self.chip.clock.now()
        s = self.chip.snapshot()
        s = replace(s, time=(t0 + s.time) / 2)
        self.check(s)
        return s

    def load(self, g: Gains) -> None:
        self.chip.load_filter(**g.as_filter())
        self.chip.update_filter()

    def step_to(self, rec: Record, target: int, profile: MoveProfile | None = None) -> None:
        """A step to ``target`` (or a trapezoid move with ``profile``), STT now."""
        self.chip.reset_interrupts(Status.TRAJECTORY_COMPLETE)
        v, a = (profile.velocity, profile.acceleration) if profile else (STEP_VELOCITY,
                                                                          STEP_ACCELERATION)
        cv, ca = clip_step(self.chip, v, a)  # an axis's soft caps
        self.chip.load_trajectory(acceleration=ca, velocity=cv, position=target, start=True)
        if profile is None:
            rec.words = None if (cv, ca) == (v, a) else (cv, ca)
        self.driving = True
        rec.steps.append((self.chip.clock.now(), target))
        rec.step_rows.append(len(rec.rows))

    def record(self, rec: Record, duration_s: float,
               watch: Callable[[Snapshot], bool] | None = None) -> Snapshot:
        """Snapshots for ``duration_s``, each checked; ``watch`` returning True ends early.

        Where the transport records on its far side (the bridge's RECORD, a simulator's
        clock) one recording every :attr:`far_period`, its rows timed by the far side's clock
        from the recording's start (their first row is taken at once, at the STT's time on
        ``sim://``: :meth:`Record.segment` tells the steps' rows apart by when they were read);
        else polled from the host every ``poll_s``.  A fault found on a row ends the
        recording before the motor is stopped."""
        # steps ramped by an axis's caps are fitted at the host's step times (fit_model):
        # those records stay host-polled, on the one clock that fit reads
        period = None if rec.words else self.far_period
        rows = None if period is None else far_snapshots(
            self.chip, period, max(1, math.ceil(duration_s / period)))
        if rows is not None:
            s = rec.rows[-1] if rec.rows else self.snap()
            first = len(rec.rows)
            self._stream = rows
            try:
                for s in rows:
                    self.check(s)
                    rec.rows.append(s)
                    if watch is not None and watch(s):
                        break
            finally:
                self._stream = None
                rows.close()
                rec.far_runs.append((first, len(rec.rows)))
            return s
        clock = self.chip.clock
        end = clock.now() + duration_s
        s = rec.rows[-1] if rec.rows else self.snap()
        while clock.now() < end:
            clock.sleep(self.poll_s)
            s = self.snap()
            rec.rows.append(s)
            if watch is not None and watch(s):
                break
        return s

    def rest(self, limit_s: float) -> Snapshot:
        """Wait until the shaft has stood still for 10 polls, or raise TIMEOUT after
        ``limit_s``; first turn the drive on, holding the origin, if it is off (a load would
        pull the shaft away)."""
        rec = Record("rest", None)
        if not self.driving and self.drive_off:
            self.step_to(rec, self.origin)
        rec.rows.append(self.snap())
        s, still = self.settle(rec, limit_s)
        if not still:
            raise self.fault(MotionError.TIMEOUT,
                             f"the shaft did not come to rest within {limit_s:g} s (it is "
                             f"{s.real_position - self.origin:+d} counts from the start, moving "
                             f"{s.real_velocity:+d} counts/sample): an oscillation or a load "
                             "that keeps moving it: check the mechanics and the gains loaded", s)
        return s

    def begin(self, name: str, gains: Gains | None) -> Record:
        rec = Record(name, gains)
        s = self.snap()
        rec.rows.append(s)
        rec.t0 = s.time
        self.records.append(rec)
        return rec

    def settle(self, rec: Record, limit_s: float, quiet: int = 10) -> tuple[Snapshot, bool]:
        """Record until the shaft has stayed within 2 counts peak to peak for ``quiet`` polls
        and :data:`QUIET_S` (an encoder edge may flicker, a loop may hunt a count either way),
        at most ``limit_s``; (last snapshot, came to rest).

        The time as well as the rows: far-side rows come every millisecond, and ten of them
        fit in the turn of a slow oscillation (10x inertia at the identification gain: the
        identification then began with the shaft swinging, 660 ms identified for 250)."""
        window: list[Snapshot] = [rec.rows[-1]]

        def still() -> bool:
            pos = [w.real_position for w in window]
            return (len(window) > quiet and window[-1].time - window[0].time >= QUIET_S
                    and max(pos) - min(pos) <= 2)

        def watch(s: Snapshot) -> bool:
            window.append(s)
            while len(window) > quiet + 1 and window[-1].time - window[1].time >= QUIET_S:
                del window[0]
            return still()

        last = self.record(rec, limit_s, watch)
        return last, still()


# ---------------------------------------------------------------------------------- phasing
def _coast(ses: _Session, rec: Record, time_s: float) -> tuple[float, float]:
    """Turn the drive off (LTRJ motor off + STT) and watch the shaft for ``time_s``: its
    speed (counts/s, along the way it was going) over the first and the last third."""
    ses.chip.load_trajectory(stop="off", start=True)
    ses.driving = False  # off on purpose: the session's drive-off check must not fire
    first = rec.rows[-1]
    ses.record(rec, time_s)
    rows = [r for r in rec.rows if r.time >= first.time]
    if len(rows) < 4:
        return 0.0, 0.0
    third = max(1, len(rows) // 3)
    way = 1 if rows[-1].real_position >= first.real_position else -1

    def speed(a: Snapshot, b: Snapshot) -> float:
        return way * (b.real_position - a.real_position) / max(b.time - a.time, 1e-9)

    return speed(rows[0], rows[third]), speed(rows[-1 - third], rows[-1])


def _load_way_step(ses: _Session, rec: Record, target: int, way: int, away: int, step: int,
                   time_s: float, seen: str) -> Snapshot:
    """The step after a coast that showed a load pulling the shaft ``way``: to ``target``.

    A loop phased right pulls the shaft towards the target, and once the shaft is a whole step
    past it the load's way the drive there (1/8 of full scale at the phasing gain: any load
    that gain can hold) brakes it.  A reversed loop either pushes the shaft away from the
    target against the load, or drives it on, faster, with the load: RUNAWAY either way."""
    start = rec.rows[-1]

    def against(s: Snapshot) -> bool:
        x = s.real_position
        return way * (x - start.real_position) <= -away and \
            abs(target - x) > abs(target - start.real_position)

    def past(s: Snapshot) -> bool:
        return way * (s.real_position - target) >= step

    ses.step_to(rec, target)
    s0 = ses.record(rec, time_s, lambda s: against(s) or past(s))
    if against(s0):
        raise ses.fault(MotionError.RUNAWAY,
                        f"phasing: {seen}, then the desired position went to {target:+d} and "
                        f"the shaft {s0.real_position - start.real_position:+d}: the shaft runs "
                        "away from any target, the loop pushes the wrong way. Swap the motor "
                        "leads (or the encoder's A and B channels)", s0)
    if not past(s0):
        return s0
    window = [s0]

    def polls(s: Snapshot) -> bool:
        window.append(s)
        return len(window) >= 9

    ses.record(rec, time_s, polls)
    if len(window) < 9:
        return window[-1]
    a, b, c = window[0], window[4], window[8]
    early = way * (b.real_position - a.real_position) / max(b.time - a.time, 1e-9)
    late = way * (c.real_position - b.real_position) / max(c.time - b.time, 1e-9)
    if late > early and late > 0:
        raise ses.fault(MotionError.RUNAWAY,
                        f"phasing: {seen}; a step past its target {target:+d} the shaft sped "
                        f"up ({early:,.0f} then {late:,.0f} counts/s) with the load's pull and "
                        "the loop's: the loop pushes the wrong way. Swap the motor leads (or "
                        "the encoder's A and B channels)", c)
    return c


@dataclass(frozen=True)
class Phasing:
    """What the phasing check found: the loop pulls the shaft towards its target."""

    kp: int  #: the P-only gain at which the shaft followed both steps
    step: int  #: counts of each step, up then down from where the shaft was
    followed: tuple[int, int]  #: counts the shaft followed the step up and the step down
    #: the way a load was seen pulling the shaft (+1 towards more counts, -1 fewer), 0: none
    pulled: int
    first_moved: int  #: counts the shaft went on the very first step (a load: against it)


def check_phasing(chip: LM629, *, travel: int, time_s: float = 0.3, poll_s: float = 1e-3,
                  progress: Progress | None = None) -> Phasing:
    """The tuner's phasing check on its own (AN-706 2.12): P-only steps of ``travel / 8``
    counts up and down inside ``+/- travel`` counts of where the shaft is (:func:`_phasing`),
    with the chip's following-error stop armed at ``travel`` meanwhile (put back to the reset
    value, 7FFF flag only, after).  Leaves the shaft held at the starting point at the
    phasing gain.  Raises :class:`MotionError` (motor stopped) RUNAWAY for reversed leads,
    STALL for a shaft that does not turn or a load the drive cannot hold."""
    travel = check_int("travel", travel, 100, 1 << 28)
    ses = _Session(chip, travel, poll_s, progress or (lambda text: None))
    with stop_on_error(chip):
        chip.load_position_error(min(COEFFICIENT_MAX, travel), stop=True)
        found = _phasing(ses, max(8, travel // 8), time_s)
    chip.load_position_error(COEFFICIENT_MAX)
    return found


def _phasing(ses: _Session, step: int, time_s: float) -> Phasing:
    """Gentle P-only steps, ``+step`` then ``-step`` from the origin, at a gain whose first
    output is 1/8 of full scale, doubled until the shaft follows both.

    When the shaft heads away from a step's target, the drive is turned off at once and the
    shaft watched coasting (:func:`_coast`): a shaft that slows down by itself was being pushed
    away by the loop: reversed leads (RUNAWAY, "swap the motor leads"; the drive is already
    off, and no second step pushes a reversed loop on).  One that keeps its speed or speeds
    up is pulled by a load (gravity on a vertical axis, a spring): the other step, the load's
    way, follows if the leads are right, and heads away too if they are reversed (RUNAWAY);
    then the gain is doubled and the loop engaged again.  Reversed leads under a load stronger
    than the phasing drive can still look like a load; they give themselves away as the gain
    rises, because the shaft then heads away *faster* (a loop phased right pulls it back
    harder): RUNAWAY.  A shaft that hardly moves gets more drive (the gain doubled).

    At full-scale output (kp x step >= 2 x 8000h) a shaft still pulled away is a load the drive
    cannot hold (STALL: "the load pulls harder than kp=N holds"), one that never moved a
    stalled rotor or a dead drive (STALL, "did not turn").  A load that takes the shaft to the
    band's edge while phasing is the same STALL (:meth:`_Session.check`)."""
    kp = max(1, round(16 * 256 / step))  # first output 1/8 of full scale
    away = max(4, step // 10)
    pulled_speed: float | None = None  # counts/s the shaft headed away at, previous gain
    first_moved: int | None = None
    while True:
        ses.phasing_kp = kp
        g = Gains(kp)
        ses.progress(f"phasing: P-only steps of {step:+d} and {-step:+d} counts at kp={kp}")
        ses.load(g)
        rec = ses.begin(f"phasing kp={kp}", g)
        moved: dict[int, int] = {}
        last = rec.rows[-1]
        seen = ""
        headed: tuple[int, float] | None = None  # (direction, counts/s) of a shaft heading away
        for sign in (1, -1):
            start = last.real_position
            t_start = last.time

            def watch(s: Snapshot, start: int = start, sign: int = sign) -> bool:
                along = sign * (s.real_position - start)
                return along >= step // 2 or along <= -away

            if headed is not None:
                # after a coast that showed a load: the step the load's way (see there)
                last = _load_way_step(ses, rec, ses.origin + sign * step, headed[0], away, step,
                                      time_s, seen)
                moved[sign] = last.real_position - start
                last, _still = ses.settle(rec, time_s)
                continue
            ses.step_to(rec, ses.origin + sign * step)
            last = ses.record(rec, time_s, watch)
            moved[sign] = last.real_position - start
            if first_moved is None:
                first_moved = moved[sign]
            if sign * moved[sign] <= -away:
                seen = ", then ".join(
                    f"the desired position went {k * step:+d} counts and the shaft "
                    f"{moved[k]:+d}" for k in moved)
                if headed is not None:  # away from both targets
                    raise ses.fault(MotionError.RUNAWAY,
                                    f"phasing: {seen}: the shaft runs away from any target, the "
                                    "loop pushes the wrong way. Swap the motor leads (or the "
                                    "encoder's A and B channels)", last)
                headed = (-sign, abs(moved[sign]) / max(last.time - t_start, 1e-9))
                early, late = _coast(ses, rec, min(time_s, 0.06))
                if late < 0.5 * early or late <= 0:
                    raise ses.fault(MotionError.RUNAWAY,
                                    f"phasing: {seen}: it headed away from the target and "
                                    "slowed down once the drive was off: the loop pushes the "
                                    "wrong way. Swap the motor leads (or the encoder's A and B "
                                    "channels)", last)
                # it kept going with the drive off: a load pulls it; the other step (the load's
                # way) tells a load from reversed leads under one
                last = rec.rows[-1]
                continue
            if sign * moved[sign] >= step // 2:
                # followed: let it come to rest there, so that the next step starts from a
                # shaft at rest (a shaft still coasting up would seem to refuse a step down)
                last, _still = ses.settle(rec, time_s)
            elif not (sign * moved[sign] >= 2 and kp * step >= U_FULL_SCALE):
                break  # hardly moved: more drive
        seen = ", then ".join(f"the desired position went {sign * step:+d} counts and the shaft "
                              f"{moved[sign]:+d}" for sign in moved)
        if headed is None and len(moved) == 2 and all(
                sign * moved[sign] >= step // 2 or (sign * moved[sign] >= 2
                                                     and kp * step >= U_FULL_SCALE)
                for sign in moved):
            ses.progress(f"phasing ok: the shaft followed {moved[1]:+d} and {moved[-1]:+d} "
                         "counts")
            ses.step_to(rec, ses.origin)  # back to the origin and rest there
            ses.settle(rec, 1.0)
            ses.phasing_kp = None
            return Phasing(kp, step, (moved[1], moved[-1]), ses.pulled,
                           moved[1] if first_moved is None else first_moved)
        if headed is not None:
            way, speed = headed
            if ses.pulled == way and pulled_speed is not None and speed > 1.25 * pulled_speed:
                raise ses.fault(MotionError.RUNAWAY,
                                f"phasing: {seen}, and it headed away faster at kp={kp} than at "
                                f"kp={kp // 2}: the loop pushes the wrong way. Swap the motor "
                                "leads (or the encoder's A and B channels)", last)
            ses.pulled, pulled_speed = way, speed
            if kp * step >= U_FULL_SCALE * 2:
                raise ses.fault(MotionError.STALL,
                                f"phasing: {seen}: a load pulls the shaft "
                                f"{'up' if way > 0 else 'down'} (it kept going with the drive "
                                f"off), and at kp={kp} the output is at full scale: the load "
                                f"pulls harder than kp={kp} holds: raise the amplifier's supply "
                                "or gain, or support the axis", last)
            ses.progress(f"phasing: {seen}; it kept going with the drive off: a load pulls it "
                         f"{'up' if way > 0 else 'down'}; more gain")
        elif kp * step >= U_FULL_SCALE * 2:
            raise ses.fault(MotionError.STALL,
                            f"the shaft did not turn: desired {step:+d} counts at full-scale "
                            f"output, the shaft moved {moved[1]:+d}. Check the amplifier's "
                            "supply and enable, the PWM/sign wiring, the motor and the encoder",
                            last)
        kp = min(COEFFICIENT_MAX, kp * 2)  # more drive, up to full scale
        ses.load(Gains(kp))
        ses.step_to(rec, ses.origin)  # the loop engaged again (after a coast, the drive on)
        ses.settle(rec, 0.5)


# ---------------------------------------------------------------------------------- identification
def _identify_run(ses: _Session, step: int, hold_s: float) -> Record:
    kp = max(1, min(COEFFICIENT_MAX, round(64 * 256 / step)))  # first output half scale
    g = Gains(kp)
    ses.progress(f"identify: P-only steps of {step:+d} counts out and back at kp={kp}")
    ses.load(g)
    ses.rest(3.0)  # the fit starts from a shaft at rest
    rec = ses.begin("identify", g)
    e0 = sat16(rec.rows[0].following_error)
    rec.state0 = PIDState(last_error=e0, output=sat16(kp * e0))
    ses.step_to(rec, ses.origin + step)
    ses.record(rec, hold_s)
    ses.step_to(rec, ses.origin)
    ses.record(rec, hold_s)
    return rec


def _ramp(start: int, target: int, words: tuple[int, int], n: int) -> list[int]:
    """The desired position at each of the ``n`` samples after the start of a move from
    ``start`` to ``target`` with 16.16 (velocity, acceleration) words: the continuous plan
    (the chip's own arithmetic is within a count of it)."""
    p = plan(target - start, *words)
    sign = 1 if target >= start else -1
    return [round(start + sign * p.travelled(k + 1)) for k in range(n)]


def _desired_samples(rec: Record, n: int, sample_s: float) -> list[int]:
    start = rec.rows[0].desired_position
    out = [start] * n
    for t, target in rec.steps:
        k = max(0, math.ceil((t - rec.t0) / sample_s - 0.5))
        origin = out[k] if k < n else start
        if rec.words is None:
            out[k:] = [target] * (n - k)
        else:
            out[k:] = _ramp(origin, target, rec.words, n - k)
    return out


def _residual(model: AxisModel, rec: Record, sample_s: float, desired: list[int],
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


def _nelder_mead(f: Callable[[list[float]], float], x0: list[float], steps: list[float],
                 iters: int) -> tuple[list[float], float]:
    pts = [list(x0)]
    for i, s in enumerate(steps):
        p = list(x0)
        p[i] += s
        pts.append(p)
    vals = [f(p) for p in pts]
    n = len(x0)
    for _ in range(iters):
        order = sorted(range(n + 1), key=vals.__getitem__)
        pts = [pts[i] for i in order]
        vals = [vals[i] for i in order]
        cen = [sum(p[j] for p in pts[:-1]) / n for j in range(n)]
        worst = pts[-1]
        xr = [c + (c - w) for c, w in zip(cen, worst)]
        fr = f(xr)
        if fr < vals[0]:
            xe = [c + 2 * (c - w) for c, w in zip(cen, worst)]
            fe = f(xe)
            pts[-1], vals[-1] = (xe, fe) if fe < fr else (xr, fr)
        elif fr < vals[-2]:
            pts[-1], vals[-1] = xr, fr
        else:
            xc = [c + 0.5 * (w - c) for c, w in zip(cen, worst)]
            fc = f(xc)
            if fc < vals[-1]:
                pts[-1], vals[-1] = xc, fc
            else:
                best = pts[0]
                pts = [best] + [[b + 0.5 * (q - b) for b, q in zip(best, p)] for p in pts[1:]]
                vals = [vals[0]] + [f(p) for p in pts[1:]]
    i = min(range(n + 1), key=vals.__getitem__)
    return pts[i], vals[i]


@dataclass
class _Segment:
    """The rows a far-side recording took after one P-only step: the fit starts the model
    at the first row (its position, the output the filter holds for its error, a speed fitted
    with the model), so when the STT ran on the chip's clock does not matter."""

    target: int
    first: Snapshot
    idx: list[int]  #: samples after the first row, less one (the index into simulate's counts)
    meas: list[int]  #: real positions there

    def residual(self, model: AxisModel, g: Gains, w0: float) -> tuple[float, int]:
        e = sat16(self.target - self.first.real_position)
        st = PIDState(last_error=e, output=sat16(g.kp * e))
        counts, _ = simulate(model, g, [self.target] * (self.idx[-1] + 1),
                             x0=self.first.real_position + 0.5, w0=w0, state=st)
        return sum((counts[i] - m) ** 2 for i, m in zip(self.idx, self.meas)), len(self.idx)


def _far_segments(rec: Record, sample_s: float) -> list[_Segment] | None:
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
        out.append(_Segment(target, rows[0], idx, [s.real_position for s in rows[1:]]))
    return out


def _first_speed(seg: _Segment) -> float:
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


def _fit_far(segs: list[_Segment], g: Gains, sample_s: float, twelve_bit: bool,
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
        p, v = _nelder_mead(lambda q: f(q + speeds), [math.log(guess), math.log(rate0), 0.005,
                                                        0.0], [0.5, 1.0, 0.01, 0.02], iters)
        if v < best_val:
            best, best_val = p, v
    model = _axis_of(best, twelve_bit)
    for i, seg in enumerate(segs):
        def sq(w: float, seg: _Segment = seg) -> float:
            return seg.residual(model, g, w)[0]
        speeds[i] = _golden(sq, speeds[i] - 1.0, speeds[i] + 1.0)
    best = best + speeds
    best_val = f(best)
    p, v = _nelder_mead(f, best, [0.1, 0.3, 0.005, 0.005] + [0.05] * m, iters)  # polish
    if v < best_val:
        best, best_val = p, v
    return _axis_of(best, twelve_bit), best_val


def _golden(f: Callable[[float], float], a: float, b: float, tol: float = 0.01) -> float:
    """The minimum of ``f`` on [a, b] (golden-section search, ``f`` unimodal there)."""
    r = (math.sqrt(5) - 1) / 2
    c, d = b - r * (b - a), a + r * (b - a)
    fc, fd = f(c), f(d)
    while b - a > tol:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - r * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + r * (b - a)
            fd = f(d)
    return (a + b) / 2


def fit_model(rec: Record, sample_s: float, twelve_bit: bool = False,
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
        p, v = _nelder_mead(f, [math.log(guess), math.log(rate0), 0.005, 0.0],
                            [0.5, 1.0, 0.01, 0.02], iters // 2)
        if v < best_val:
            best, best_val = p, v
    p, v = _nelder_mead(f, best, [0.1, 0.3, 0.005, 0.005], iters)  # polish
    if v < best_val:
        best, best_val = p, v
    return _axis_of(best, twelve_bit), best_val


# ---------------------------------------------------------------------------------- design
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


def predict_move(model: AxisModel, g: Gains, distance: int, horizon: int,
                 tolerance: int, profile: MoveProfile | None = None,
                 words: tuple[int, int] | None = None) -> MoveMetrics:
    """The test move (out by ``distance``, then back) on the model, from rest at 0: a step
    (with ``words``, an axis's capped velocity and acceleration, the trapezoid they make), or
    with ``profile`` a trapezoid move (settle then counted from the profile's end)."""
    worst = None
    ramp = profile.desired(distance) if profile else []
    for start, target in ((0, distance), (distance, 0)):
        sign = 1 if target >= start else -1
        if words is not None and profile is None:
            desired = _ramp(start, target, words, horizon)
        else:
            desired = [start + sign * abs(d) for d in ramp][:horizon]
            desired += [target] * (horizon - len(desired))
        counts, _ = simulate(model, g, desired, x0=start + 0.5, state=PIDState())
        times = [(k + 1 - len(ramp)) for k in range(horizon)]
        m = _as_move(step_metrics(times, counts, desired, start, target, tolerance), profile)
        worst = m if worst is None else worst.worst(m)
    assert worst is not None
    return worst


def _pd_candidates(model: AxisModel) -> list[Gains]:
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


def _with_integral(model: AxisModel, g: Gains) -> list[Gains]:
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
    pd = sorted(_pd_candidates(model),
                key=lambda g: judged(model, g, quick if profile is None else horizon)[0])
    ranked = pd[:10] + [g for p in pd[:4] for g in _with_integral(model, p)]
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
    return g, _in_seconds(step, sample_s), None if move is None else _in_seconds(move, sample_s)


def _in_seconds(m: MoveMetrics, sample_s: float) -> MoveMetrics:
    return replace(m, settle_s=None if m.settle_s is None else m.settle_s * sample_s,
                   rise_s=None if m.rise_s is None else m.rise_s * sample_s)


# ---------------------------------------------------------------------------------- test move
def _since_stt(profile: MoveProfile, distance: int, t: list[float], des: list[int], start: int,
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


def _test_move(ses: _Session, name: str, gains: Gains | None, distance: int, duration_s: float,
               tolerance: int, profile: MoveProfile | None = None) -> tuple[MoveMetrics, Record]:
    """The step (or with ``profile`` the trapezoid move) out by ``distance`` and back, each
    recorded for ``duration_s`` after the profile's end (the settle time counted from there)."""
    if gains is not None:
        ses.load(gains)
    ses.rest(3.0)  # both test moves start from rest at the origin
    rec = ses.begin(name, gains)
    ramp_s = profile.samples(distance) * ses.sample_s if profile else 0.0
    worst = None
    for target in (ses.origin + distance, ses.origin):
        ses.step_to(rec, target, profile)
        ses.record(rec, ramp_s + duration_s)
        k = len(rec.steps) - 1
        t, real, des, start, tgt = rec.segment(k)
        if profile and (rec.step_rows[k], len(rec.rows)) in rec.far_runs and \
                clip_step(ses.chip, profile.velocity, profile.acceleration) == (
                    profile.velocity, profile.acceleration):
            t = _since_stt(profile, tgt - start, t, des, start, ses.sample_s)
        t = [x - ramp_s for x in t]
        rec.judged.append((t, real, des, start, tgt))
        m = _as_move(step_metrics(t, real, des, start, tgt, tolerance), profile)
        worst = m if worst is None else worst.worst(m)
    assert worst is not None
    return worst, rec


def measure_move(chip: LM629, gains: Gains | None, *, distance: int, travel: int,
                 duration_s: float = 0.4, tolerance: int = 2, poll_s: float = 1e-3,
                 profile: MoveProfile | None = None) -> tuple[MoveMetrics, Record]:
    """The tuner's test move (a step of ``distance`` counts out and back, or with ``profile``
    the trapezoid move) with ``gains`` (None: as loaded), guarded like the tuning experiments;
    the worse of the two moves."""
    ses = _Session(chip, travel, poll_s, lambda text: None)
    with stop_on_error(chip):
        return _test_move(ses, "test", gains, distance, duration_s, tolerance, profile)


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


# ---------------------------------------------------------------------------------- autotune
def autotune(chip: LM629, *, travel: int, distance: int | None = None, tolerance: int = 2,
             before: Gains | None = None, duration_s: float = 0.4, poll_s: float = 1e-3,
             clock_hz: float | None = None, velocity: int | None = None,
             acceleration: int | None = None, progress: Progress | None = None) -> TuneResult:
    """Find, check and apply PID gains for the axis, inside ``+/- travel`` counts of where the
    shaft is now.

    ``distance``: the test move (a step out and back), default ``min(2000, travel // 2)``;
    ``tolerance``: counts a move must end within; ``before``: gains to measure the same test
    move with first, for comparison (``TuneResult.before``; the chip cannot report the gains it
    has, so they are named); ``duration_s``: seconds recorded after each
    step of the test move; ``poll_s``: seconds between snapshots (on a bridge at least a round
    trip); ``clock_hz``: the chip's clock (default: the simulator's, else 8 MHz);
    ``velocity``/``acceleration``: the words of the trapezoid move the gains are judged and
    checked on besides the step, the same ``distance`` out and back (default
    :func:`default_profile`: 0x40000 and 0x2000 where the axis can follow them); ``progress``
    gets a line per stage.

    On success the gains are loaded and applied (LFIL + UDF) and the following-error limit
    armed for tuning is put back to the reset value (7FFF, flag only: LPEI).  Raises
    :class:`MotionError` (motor stopped: abrupt stop, then motor off) on a phasing fault
    (RUNAWAY, with the swap-the-leads advice), a shaft that would leave the band (RUNAWAY), a
    position error, a stall, a shaft that does not come to rest (TIMEOUT); ``ValueError`` for
    bad arguments before any bus cycle.
    """
    travel = check_int("travel", travel, 100, 1 << 28)
    if distance is None:
        distance = min(2000, travel // 2)
    distance = check_int("distance", distance, 10, travel * 3 // 4)
    tolerance = check_int("tolerance", tolerance, 0, 1000)
    if not 0.05 <= duration_s <= 10:
        raise ValueError(f"duration_s={duration_s} must be 0.05..10 seconds")
    if not 0 < poll_s <= 0.05:
        raise ValueError(f"poll_s={poll_s} must be > 0 and at most 0.05 seconds")
    if velocity is not None:
        velocity = check_int("velocity", velocity, 1, VELOCITY_MAX)
    if acceleration is not None:
        acceleration = check_int("acceleration", acceleration, 1, ACCELERATION_MAX)
    say = progress or (lambda text: None)
    if chip.is_moving():
        raise ValueError("the motor is moving: tuning starts from rest (`lm629 stop` first)")
    ses = _Session(chip, travel, poll_s, say, clock_hz)
    with stop_on_error(chip):  # Ctrl-C, link faults: motor stopped first
        chip.load_position_error(min(COEFFICIENT_MAX, travel), stop=True)
        # 1 phasing, gentle
        _phasing(ses, max(8, travel // 8), 0.3)
        # 2 before: the test move with the gains to compare against (after the phasing check,
        # so that reversed leads are found gently, never by a full-size step)
        measured_before = None
        if before is not None:
            say(f"before: test move of {distance:+d} counts out and back at {before}")
            measured_before, _rec = _test_move(ses, "before", before, distance, duration_s,
                                               tolerance)
            say(f"before: {measured_before.line()}")
        # 3 identification
        ident = _identify_run(ses, max(8, travel // 4), 0.25)
        model, rms = fit_model(ident, ses.sample_s, twelve_bit=_twelve_bit(chip))
        ses.model = model
        say(f"model: {model.describe(ses.sample_s)} (fit {rms:.1f} counts rms)")
        # 4 design
        duration_s = record_duration(model, distance, ses.sample_s, duration_s)
        profile = default_profile(model, velocity, acceleration)
        gains, predicted, predicted_move = design(model, distance, tolerance, duration_s,
                                                  ses.sample_s, profile,
                                                  ident.words)
        assert predicted_move is not None
        say(f"gains: {gains}; predicted step: {predicted.line()}")
        say(f"predicted move ({profile}): {predicted_move.line()}")
        # 5 check: the step and the trapezoid move
        measured, _rec = _test_move(ses, "after", gains, distance, duration_s, tolerance)
        say(f"measured step: {measured.line()}")
        measured_move, _rec = _test_move(ses, "after move", None, distance, duration_s,
                                         tolerance, profile)
        say(f"measured move: {measured_move.line()}")
    chip.load_position_error(COEFFICIENT_MAX)  # the tuning limit off again (reset's value)
    return TuneResult(gains.kp, gains.ki, gains.kd, gains.il, gains.ds, model, ses.sample_s,
                      ses.origin, travel, distance, tolerance, predicted, measured, measured_before,
                      ses.records, rms, ses.positions, profile, predicted_move, measured_move,
                      len(ident.steps))


@dataclass(frozen=True)
class Identified:
    """What :func:`identify` found: the axis's model and how well it fits."""

    model: AxisModel
    sample_s: float
    fit_rms: float  #: counts, model vs the identification steps
    fit_steps: int  #: the identification steps fitted
    record: Record


def identify(chip: LM629, *, travel: int, poll_s: float = 1e-3, clock_hz: float | None = None,
             restore: Gains | None = None, progress: Progress | None = None) -> Identified:
    """The tuner's phasing check and identification steps alone (1 and 2 of the module's
    list, with the same guards), and the model fitted to them; no gains are designed.

    The experiments load P-only gains; ``restore`` loads these gains again after (LFIL +
    UDF: the chip cannot report the ones it had, so they are named), else the filter is left
    at the identification's P-only gain.  The following-error limit armed meanwhile is put
    back to the reset value (7FFF, flag only).  Raises as :func:`autotune` does."""
    travel = check_int("travel", travel, 100, 1 << 28)
    if not 0 < poll_s <= 0.05:
        raise ValueError(f"poll_s={poll_s} must be > 0 and at most 0.05 seconds")
    if restore is not None:
        chip.filter_program(**restore.as_filter())  # a bad filter: refused before anything
    say = progress or (lambda text: None)
    if chip.is_moving():
        raise ValueError("the motor is moving: identification starts from rest "
                         "(`lm629 stop` first)")
    ses = _Session(chip, travel, poll_s, say, clock_hz)
    with stop_on_error(chip):
        chip.load_position_error(min(COEFFICIENT_MAX, travel), stop=True)
        _phasing(ses, max(8, travel // 8), 0.3)
        ident = _identify_run(ses, max(8, travel // 4), 0.25)
        model, rms = fit_model(ident, ses.sample_s, twelve_bit=_twelve_bit(chip))
        say(f"model: {model.describe(ses.sample_s)} (fit {rms:.1f} counts rms)")
        if restore is not None:
            ses.load(restore)
            ses.rest(3.0)
    chip.load_position_error(COEFFICIENT_MAX)
    return Identified(model, ses.sample_s, rms, len(ident.steps), ident)


def _twelve_bit(chip: LM629) -> bool:
    return not chip.read_signals() & Signals.EIGHT_BIT_OUTPUT


__all__ = ["autotune", "identify", "Identified", "measure_move", "TuneResult", "Gains", "AxisModel", "MoveMetrics",
           "PIDState", "simulate", "fit_model", "design", "predict_move", "step_metrics",
           "score", "Record", "MoveProfile", "Phasing", "check_phasing", "default_profile", "MOVE_VELOCITY", "MOVE_ACCELERATION"]
