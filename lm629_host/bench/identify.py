"""The tuner's identification: two P-only steps recorded, and the axis's model fitted to them
(:mod:`lm629_host.physics.fit`); :func:`identify` runs the phasing check and the steps alone.
"""

from __future__ import annotations

from dataclasses import dataclass

from lm629_host.bench.phasing import phasing
from lm629_host.bench.tuning_session import Progress, Record, TuningSession
from lm629_host.bus.opcodes import COEFFICIENT_MAX, Signals
from lm629_host.chip.lm629 import LM629
from lm629_host.chip.safety import stop_on_error
from lm629_host.errors import check_int
from lm629_host.physics.axis import AxisModel, Gains
from lm629_host.physics.fit import fit_model
from lm629_host.physics.pid import PIDState, sat16


#: the share of an identification step the shaft may have gone by the first row recorded
#: after its STT: the fit needs the start of the motion (the acceleration at the output the
#: step asks for), and a row taken later (a host late to ask for the recording: paused, or
#: behind a busy machine) leaves it the end of the move only.  Behind an Uno's USB the first
#: row comes a flush tick (4.096 ms) after the STT: the default motor has gone 5 % of a
#: 1000-count step at half output, a 0.3x-inertia one 16 %
LATE_FIRST_ROW = 0.25


def late_step(rec: Record) -> str | None:
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


def identify_run(ses: TuningSession, step: int, hold_s: float, tries: int = 3) -> Record:
    """The identification's two P-only steps, recorded; run again (at most ``tries`` times
    in all) while a step's rows missed its start (:func:`late_step`)."""
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
        late = late_step(rec)
        if late is None or attempt == tries - 1:
            return rec
        rec.name = "identify (late)"  # kept among the records, not fitted
        ses.progress(f"identify: {late}: again")
    raise AssertionError("unreachable")


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
    ses = TuningSession(chip, travel, poll_s, say, clock_hz)
    with stop_on_error(chip):
        chip.load_position_error(min(COEFFICIENT_MAX, travel), stop=True)
        phasing(ses, max(8, travel // 8), 0.3)
        ident = identify_run(ses, max(8, travel // 4), 0.25)
        model, rms = fit_model(ident, ses.sample_s, twelve_bit=twelve_bit(chip))
        say(f"model: {model.describe(ses.sample_s)} (fit {rms:.1f} counts rms)")
        if restore is not None:
            ses.load(restore)
            ses.rest(3.0)
    chip.load_position_error(COEFFICIENT_MAX)
    return Identified(model, ses.sample_s, rms, len(ident.steps), ident)


def twelve_bit(chip: LM629) -> bool:
    return not chip.read_signals() & Signals.EIGHT_BIT_OUTPUT
