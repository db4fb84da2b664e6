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
   stall (:mod:`lm629_host.bench.phasing`);
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

This module runs the four stages on a bench; the session that drives it (the experiments,
their guards, the records they leave, the test move) is :mod:`lm629_host.bench.tuning_session`,
the phasing check :mod:`lm629_host.bench.phasing`, the identification
:mod:`lm629_host.bench.identify`.  Everything that is arithmetic on those records (the axis
model, the predictor, the fit, the searches, the design) lives in :mod:`lm629_host.physics`
and is tested without a bus.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lm629_host.bench.identify import identify_run, twelve_bit
from lm629_host.bench.phasing import phasing
from lm629_host.bench.tuning_session import Progress, Record, TuningSession, run_test_move
from lm629_host.bus.opcodes import ACCELERATION_MAX, COEFFICIENT_MAX, VELOCITY_MAX
from lm629_host.chip.lm629 import LM629
from lm629_host.chip.safety import stop_on_error
from lm629_host.errors import LM629Error, check_int
from lm629_host.physics.axis import AxisModel, Gains
from lm629_host.physics.design import default_profile, design, integral_note, record_duration
from lm629_host.physics.fit import fit_model
from lm629_host.physics.metrics import MoveMetrics
from lm629_host.physics.predict import MoveProfile


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
    ses = TuningSession(chip, travel, poll_s, say, clock_hz)
    with stop_on_error(chip):  # Ctrl-C, link faults: motor stopped first
        chip.load_position_error(min(COEFFICIENT_MAX, travel), stop=True)
        # 1 phasing, gentle
        phasing(ses, max(8, travel // 8), 0.3)
        # 2 before: the test move with the gains to compare against (after the phasing check,
        # so that reversed leads are found gently, never by a full-size step)
        measured_before = None
        if before is not None:
            say(f"before: test move of {distance:+d} counts out and back at {before}")
            measured_before, _rec = run_test_move(ses, "before", before, distance, duration_s,
                                               tolerance)
            say(f"before: {measured_before.line()}")
        # 3 identification
        ident = identify_run(ses, max(8, travel // 4), 0.25)
        model, rms = fit_model(ident, ses.sample_s, twelve_bit=twelve_bit(chip))
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
        measured, _rec = run_test_move(ses, "after", gains, distance, duration_s, tolerance)
        say(f"measured step: {measured.line()}")
        measured_move, _rec = run_test_move(ses, "after move", None, distance, duration_s,
                                         tolerance, profile, rest_s)
        say(f"measured move: {measured_move.line()}")
        say(integral_note(model, gains, ses.sample_s))
    chip.load_position_error(COEFFICIENT_MAX)  # the tuning limit off again (reset's value)
    return TuneResult(gains.kp, gains.ki, gains.kd, gains.il, gains.ds, model, ses.sample_s,
                      ses.origin, travel, distance, tolerance, predicted, measured, measured_before,
                      ses.records, rms, ses.positions, profile, predicted_move, measured_move,
                      len(ident.steps))
