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
   every position read (Nelder-Mead, a few hundred simulations: :mod:`lm629_host.physics.fit`);
3. **designs** gains by pole placement on that model (natural frequency x damping x derivative
   interval, then integral variants of the best), predicting each candidate's test move on the
   model with the output quantisation and saturation, and keeping the one whose worst score
   (settle time inside the tolerance, overshoot, end error, hunting, and whether the move
   leaves the shaft standing still as a move's ``wait()`` needs) over the model and three
   variants of it (30 % lighter, 40 % heavier, a fifth of the dry friction) is best; an
   axis with a holding load gets integral gains sized to the load besides
   (:mod:`lm629_host.physics.design`, on :mod:`lm629_host.physics.predict`);
4. **checks** them with the test move (a step of ``distance`` counts out and back) and leaves
   them loaded and applied (LFIL + UDF).

Safety: every position read (every snapshot of every experiment) is checked against the
travel band ``origin +/- travel`` less the distance the shaft needs to stop; the chip's own
following-error stop (LPES) is armed at ``travel`` counts while tuning; any fault stops the
motor (abrupt stop, then motor off) and raises :class:`~lm629_host.errors.MotionError`.
Everything waits on ``chip.clock`` (simulated time on ``sim://``).

This module is the session that drives a bench: the experiments, their guards and the
records they leave.  Everything that is arithmetic on those records (the axis model, the
predictor, the fit, the searches, the design) lives in :mod:`lm629_host.physics` and is tested
without a bus; the names a lab script imported from here are still importable from here.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, field, replace

from lm629_host.bus.opcodes import ACCELERATION_MAX, COEFFICIENT_MAX, VELOCITY_MAX, Signals, Status
from lm629_host.chip.lm629 import LM629
from lm629_host.bus.snapshot import Snapshot
from lm629_host.errors import check_int
from lm629_host.chip.recording import far_snapshots, sample_program
from lm629_host.chip.safety import motion_fault, stop_on_error
from lm629_host.errors import LM629Error, MotionError, MotionFault
from lm629_host.physics.axis import AxisModel, Gains
from lm629_host.physics.design import default_profile, design, integral_note, record_duration
from lm629_host.physics.fit import fit_model, since_stt
from lm629_host.physics.limits import clip_step
from lm629_host.physics.metrics import MoveMetrics, as_move, step_metrics
from lm629_host.physics.pid import (
    STEP_ACCELERATION,
    STEP_VELOCITY,
    U_FULL_SCALE,
    PIDState,
    sample_period_s,
    sat16,
)
from lm629_host.physics.predict import (
    MoveProfile,
)


Progress = Callable[[str], None]


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
def _speed(rows: Sequence[Snapshot], way: int, sample_s: float) -> float:
    """counts/s along ``way`` over ``rows``, all of ONE recording: their times are one
    clock's (a far-side recording's are the chip's or the bridge's own; only a recording's
    offset is the host's, and that is late by whatever kept the host), so a late host can
    neither shorten nor stretch the time between them.  With fewer than two rows, the chip's
    own velocity register (counts/sample, measured by the chip)."""
    if len(rows) >= 2 and rows[-1].time > rows[0].time:
        return way * (rows[-1].real_position - rows[0].real_position) / (
            rows[-1].time - rows[0].time)
    return way * sum(r.real_velocity for r in rows) / max(1, len(rows)) / sample_s


def _coast(ses: _Session, rec: Record, time_s: float, away: int) -> tuple[float, float]:
    """Turn the drive off (LTRJ motor off + STT) and watch the shaft for ``time_s``: its
    speed (counts/s, ``away`` from the step's target: +1 or -1) over the first and the last
    third of the coast's own rows (never across recordings, never by the rows' times against another
    recording's: see :func:`_speed`).  Recorded on, up to three times as long, while fewer
    than four rows came (a host that was late for the recording): too few rows are no
    evidence, and "it slowed down" must come from what the chip recorded."""
    ses.chip.load_trajectory(stop="off", start=True)
    ses.driving = False  # off on purpose: the session's drive-off check must not fire
    n0 = len(rec.rows)
    for _ in range(3):
        ses.record(rec, time_s)
        if len(rec.rows) - n0 >= 4:
            break
    rows = rec.rows[n0:]
    if len(rows) < 2:
        return 0.0, 0.0  # nothing recorded to judge by: no verdict (see _phasing)
    third = max(1, len(rows) // 3)
    return (_speed(rows[:third + 1], away, ses.sample_s),
            _speed(rows[-1 - third:], away, ses.sample_s))


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
    window: list[Snapshot] = []  # this recording's rows only (see _speed)

    def polls(s: Snapshot) -> bool:
        window.append(s)
        return len(window) >= 9

    ses.record(rec, time_s, polls)
    if len(window) < 9:
        return window[-1]
    c = window[8]
    early, late = (_speed(window[:5], way, ses.sample_s), _speed(window[4:9], way,
                                                                   ses.sample_s))
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
    turned_count = 0  # steps whose coast found the shaft turned round by the loop
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
        turned = False  # a coast found the shaft already coming back (see below)
        prev_resting = True  # the shaft stood still when this step came (the origin held)
        for sign in (1, -1):
            start = last.real_position

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
            n0 = len(rec.rows)
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
                # its speed from this step's own rows (see _speed), never from when the host
                # stamped the step
                headed = (-sign, abs(_speed(rec.rows[n0:], 1, ses.sample_s)))
                early, late = _coast(ses, rec, min(time_s, 0.06), -sign)
                # reversed leads: still heading away when the drive went off, then slowing
                # down by itself.  A shaft already coming back (early <= 0) had been turned
                # round by the loop before the drive went off (a late host, a shaft that was
                # falling when the step came): the loop pulls the right way, and what pulled
                # the shaft away is a load, as below
                slowed = early > 0 and (late < 0.5 * early or late <= 0)
                if slowed and prev_resting:
                    raise ses.fault(MotionError.RUNAWAY,
                                    f"phasing: {seen}: it headed away from the target and "
                                    "slowed down once the drive was off: the loop pushes the "
                                    "wrong way. Swap the motor leads (or the encoder's A and B "
                                    "channels)", last)
                if early <= 0 or slowed:
                    # turned round by the loop, or (slowed, the shaft not at rest when this
                    # step came) still moving from the step before: its momentum, not the loop,
                    # took it away; no verdict from this coast (see below)
                    turned, headed = True, None
                    last = rec.rows[-1]
                    break
                # it kept going with the drive off: a load pulls it; the other step (the load's
                # way) tells a load from reversed leads under one
                last = rec.rows[-1]
                continue
            if sign * moved[sign] >= step // 2:
                # followed: let it come to rest there, so that the next step starts from a
                # shaft at rest (a shaft still coasting up would seem to refuse a step down);
                # a slow one (a load, inertia) gets longer, as the steps' own settle does
                last, prev_resting = ses.settle(rec, time_s)
            elif not (sign * moved[sign] >= 2 and kp * step >= U_FULL_SCALE):
                break  # hardly moved: more drive
        seen = ", then ".join(f"the desired position went {sign * step:+d} counts and the shaft "
                              f"{moved[sign]:+d}" for sign in moved)
        if turned:
            # the loop pulled the shaft back towards the target: right, but the shaft was
            # still moving when the step came (falling under a load after a reset), or the
            # host turned the drive off late; the next step away from the load would meet
            # that momentum and seem pushed away.  Again at this gain, from a held shaft
            turned_count += 1
            if turned_count > 3:
                raise ses.fault(MotionError.STALL,
                                f"phasing: {seen}: four times the shaft was still moving away "
                                "when a step came, and the loop turned it back only after the "
                                "drive was off: a load pulls it harder than the phasing gain "
                                "steadies it; support the axis or give a shorter --travel (a "
                                "stiffer phasing gain)", last)
            ses.progress(f"phasing: {seen}; with the drive off it was already coming back: the "
                         "loop had turned it round (it was still moving when the step came, or "
                         "the host was late to turn the drive off): again, from a held shaft")
            ses.step_to(rec, ses.origin)  # the loop engaged again, holding the origin
            ses.settle(rec, 1.0)
            continue
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
#: the share of an identification step the shaft may have gone by the first row recorded
#: after its STT: the fit needs the start of the motion (the acceleration at the output the
#: step asks for), and a row taken later (a host late to ask for the recording: paused, or
#: behind a busy machine) leaves it the end of the move only.  Behind an Uno's USB the first
#: row comes a flush tick (4.096 ms) after the STT: the default motor has gone 5 % of a
#: 1000-count step at half output, a 0.3x-inertia one 16 %
LATE_FIRST_ROW = 0.25


def _late_step(rec: Record) -> str | None:
    """Why the rows of an identification record missed a step's start, or None.  Judged on
    positions only (the last row before the STT and the first after it), never on when the
    host stamped them."""
    for k, (_t, target) in enumerate(rec.steps):
        first = rec.step_rows[k]
        if not 0 < first < len(rec.rows):
            continue
        before = rec.rows[first - 1].real_position
        went = abs(rec.rows[first].real_position - before)
        if went > LATE_FIRST_ROW * max(1, abs(target - before)):
            return (f"the first row after the step to {target:+d} found the shaft {went} of "
                    f"{abs(target - before)} counts on its way (the host was late to record "
                    "it, and the fit needs the start of the motion)")
    return None


def _identify_run(ses: _Session, step: int, hold_s: float, tries: int = 3) -> Record:
    """The identification's two P-only steps, recorded; run again (at most ``tries`` times
    in all) while a step's rows missed its start (:func:`_late_step`)."""
    kp = max(1, min(COEFFICIENT_MAX, round(64 * 256 / step)))  # first output half scale
    g = Gains(kp)
    ses.progress(f"identify: P-only steps of {step:+d} counts out and back at kp={kp}")
    ses.load(g)
    for attempt in range(tries):
        ses.rest(3.0)  # the fit starts from a shaft at rest
        rec = ses.begin("identify", g)
        e0 = sat16(rec.rows[0].following_error)
        rec.state0 = PIDState(last_error=e0, output=sat16(kp * e0))
        ses.step_to(rec, ses.origin + step)
        ses.record(rec, hold_s)
        ses.step_to(rec, ses.origin)
        ses.record(rec, hold_s)
        late = _late_step(rec)
        if late is None or attempt == tries - 1:
            return rec
        rec.name = "identify (late)"  # kept among the records, not fitted
        ses.progress(f"identify: {late}: again")
    raise AssertionError("unreachable")


def _test_move(ses: _Session, name: str, gains: Gains | None, distance: int, duration_s: float,
               tolerance: int, profile: MoveProfile | None = None,
               rest_s: float = 0.0) -> tuple[MoveMetrics, Record]:
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
            t = since_stt(profile, tgt - start, t, des, start, ses.sample_s)
        t = [x - ramp_s for x in t]
        rec.judged.append((t, real, des, start, tgt))
        m = as_move(step_metrics(t, real, des, start, tgt, tolerance, rest_s), profile)
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
        # judged as a move's wait() judges it: the shaft standing still within the tolerance
        rest_s = chip.move_rules.settle_time
        try:
            gains, predicted, predicted_move = design(model, distance, tolerance, duration_s,
                                                      ses.sample_s, profile, ident.words, rest_s)
        except ValueError as exc:  # a fit gone wrong: a driver error, not the user's input
            raise LM629Error(f"tuning: {exc} (fit {rms:.1f} counts rms on "
                             f"{len(ident.steps)} steps): run it again on a quiet host; if it "
                             "says so again, check the encoder and the mechanics") from None
        assert predicted_move is not None
        say(f"gains: {gains}; predicted step: {predicted.line()}")
        say(f"predicted move ({profile}): {predicted_move.line()}")
        # 5 check: the step and the trapezoid move
        measured, _rec = _test_move(ses, "after", gains, distance, duration_s, tolerance)
        say(f"measured step: {measured.line()}")
        measured_move, _rec = _test_move(ses, "after move", None, distance, duration_s,
                                         tolerance, profile, rest_s)
        say(f"measured move: {measured_move.line()}")
        say(integral_note(model, gains, ses.sample_s))
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


__all__ = [
    # the session
    "Identified", "Phasing", "Progress", "Record", "TuneResult", "autotune", "check_phasing",
    "identify", "measure_move",
]
