"""The tuner's session on a bench: the experiments (steps, recordings, rest) each position
read checked against the travel band, the records they leave, and the test move.

Every snapshot of every experiment is checked (:meth:`TuningSession.check`): against the travel band
``origin +/- travel`` less the distance the shaft needs to stop, the chip's following-error
flag, and the drive found off; any fault stops the motor (abrupt stop, then motor off) and
raises :class:`~lm629_host.errors.MotionError`.  The phasing check (:mod:`.phasing`), the
identification (:mod:`.identify`) and :func:`~lm629_host.bench.tuning.autotune` run on it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator
from dataclasses import dataclass, field, replace

from lm629_host.bus.opcodes import Signals, Status
from lm629_host.bus.snapshot import Snapshot
from lm629_host.chip.lm629 import LM629
from lm629_host.chip.recording import far_snapshots, sample_program
from lm629_host.chip.safety import motion_fault, stop_on_error
from lm629_host.errors import MotionError, MotionFault
from lm629_host.physics.axis import AxisModel, Gains
from lm629_host.physics.fit import since_stt
from lm629_host.physics.limits import clip_step
from lm629_host.physics.metrics import MoveMetrics, as_move, step_metrics
from lm629_host.physics.pid import STEP_ACCELERATION, STEP_VELOCITY, PIDState, sample_period_s
from lm629_host.physics.predict import MoveProfile

#: what the tuner says as it goes (a line per stage)
Progress = Callable[[str], None]


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


#: the shortest time a shaft must keep within 2 counts to count as at rest (see ``settle``)
QUIET_S = 0.05


class TuningSession:
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


def run_test_move(ses: TuningSession, name: str, gains: Gains | None, distance: int, duration_s: float,
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
    ses = TuningSession(chip, travel, poll_s, lambda text: None)
    with stop_on_error(chip):
        return run_test_move(ses, "test", gains, distance, duration_s, tolerance, profile)
