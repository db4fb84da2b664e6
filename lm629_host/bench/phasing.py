"""The tuner's phasing check (AN-706 2.12): does the loop pull the shaft towards its target?

Gentle P-only steps up and down at a gain whose first output is 1/8 of full scale, doubled
until the shaft follows both; a shaft that heads away is watched coasting with the drive off
to tell reversed leads (RUNAWAY, "swap the motor leads") from a load pulling it (more gain);
a shaft that never moves at full-scale output, or a load the drive cannot hold, is a STALL.
The rules in full: :func:`phasing`; each step of it is a method of :class:`_PhasingRun`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from lm629_host.bench.tuning_session import Progress, Record, TuningSession
from lm629_host.bus.opcodes import COEFFICIENT_MAX
from lm629_host.bus.snapshot import Snapshot
from lm629_host.chip.lm629 import LM629
from lm629_host.chip.safety import stop_on_error
from lm629_host.errors import MotionError, check_int
from lm629_host.physics.axis import Gains
from lm629_host.physics.pid import U_FULL_SCALE


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


def coast(ses: TuningSession, rec: Record, time_s: float, away: int) -> tuple[float, float]:
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
        return 0.0, 0.0  # nothing recorded to judge by: no verdict (see :class:`_PhasingRun`)
    third = max(1, len(rows) // 3)
    return (_speed(rows[:third + 1], away, ses.sample_s),
            _speed(rows[-1 - third:], away, ses.sample_s))


def _load_way_step(ses: TuningSession, rec: Record, target: int, way: int, away: int, step: int,
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
    counts up and down inside ``+/- travel`` counts of where the shaft is (:func:`phasing`),
    with the chip's following-error stop armed at ``travel`` meanwhile (put back to the reset
    value, 7FFF flag only, after).  Leaves the shaft held at the starting point at the
    phasing gain.  Raises :class:`MotionError` (motor stopped) RUNAWAY for reversed leads,
    STALL for a shaft that does not turn or a load the drive cannot hold."""
    travel = check_int("travel", travel, 100, 1 << 28)
    ses = TuningSession(chip, travel, poll_s, progress or (lambda text: None))
    with stop_on_error(chip):
        chip.load_position_error(min(COEFFICIENT_MAX, travel), stop=True)
        found = phasing(ses, max(8, travel // 8), time_s)
    chip.load_position_error(COEFFICIENT_MAX)
    return found


def phasing(ses: TuningSession, step: int, time_s: float) -> Phasing:
    """Gentle P-only steps, ``+step`` then ``-step`` from the origin, at a gain whose first
    output is 1/8 of full scale, doubled until the shaft follows both.

    When the shaft heads away from a step's target, the drive is turned off at once and the
    shaft watched coasting (:func:`coast`): a shaft that slows down by itself was being pushed
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
    band's edge while phasing is the same STALL (:meth:`TuningSession.check`)."""
    return _PhasingRun(ses, step, time_s).run()


def _seen(moved: dict[int, int], step: int) -> str:
    """What the steps so far did, in words: the desired position's and the shaft's moves."""
    return ", then ".join(f"the desired position went {k * step:+d} counts and the shaft "
                          f"{moved[k]:+d}" for k in moved)


class _PhasingRun:
    """One phasing check: the gain and what earlier gains showed (the load's speed, how often
    the shaft was found turned round), and the round at the gain in force (its record, the
    counts each step moved the shaft, a shaft heading away)."""

    def __init__(self, ses: TuningSession, step: int, time_s: float) -> None:
        self.ses, self.step, self.time_s = ses, step, time_s
        self.kp = max(1, round(16 * 256 / step))  # first output 1/8 of full scale
        self.away = max(4, step // 10)
        self.pulled_speed: float | None = None  # counts/s the shaft headed away at, previous gain
        self.first_moved: int | None = None
        self.turned_count = 0  # rounds whose coast found the shaft turned round by the loop
        # the round at the gain in force (set by round_at_gain)
        self.rec = Record("", None)
        self.moved: dict[int, int] = {}
        self.last: Snapshot | None = None
        self.seen = ""
        self.headed: tuple[int, float] | None = None  # (direction, counts/s) heading away
        self.turned = False  # a coast found the shaft already coming back (see coast_verdict)
        self.prev_resting = True  # the shaft stood still when this step came (the origin held)

    def run(self) -> Phasing:
        """Rounds at rising gains until the shaft follows both steps, or a verdict."""
        ses = self.ses
        while True:
            self.round_at_gain()
            seen = _seen(self.moved, self.step)
            if self.turned:
                self.again_from_held(seen)
                continue
            if self.followed_both():
                return self.passed()
            if self.headed is not None:
                self.judge_load(seen)
            elif self.kp * self.step >= U_FULL_SCALE * 2:
                raise ses.fault(MotionError.STALL,
                                f"the shaft did not turn: desired {self.step:+d} counts at "
                                f"full-scale output, the shaft moved {self.moved[1]:+d}. Check "
                                "the amplifier's supply and enable, the PWM/sign wiring, the "
                                "motor and the encoder", self.last)
            self.more_drive()

    def round_at_gain(self) -> None:
        """The P-only gain loaded, a new record, and the step up then the step down (the
        second left out when the first hardly moved the shaft or found it turned round)."""
        ses, kp, step = self.ses, self.kp, self.step
        ses.phasing_kp = kp
        g = Gains(kp)
        ses.progress(f"phasing: P-only steps of {step:+d} and {-step:+d} counts at kp={kp}")
        ses.load(g)
        self.rec = ses.begin(f"phasing kp={kp}", g)
        self.moved = {}
        self.last = self.rec.rows[-1]
        self.seen = ""
        self.headed = None
        self.turned = False
        self.prev_resting = True
        for sign in (1, -1):
            if not self.step_one_way(sign):
                break

    def step_one_way(self, sign: int) -> bool:
        """The step ``sign * step`` from the origin, watched; False when no further step at
        this gain is worth taking (the shaft hardly moved: more drive; or turned round)."""
        ses, rec, step, away = self.ses, self.rec, self.step, self.away
        assert self.last is not None
        start = self.last.real_position
        if self.headed is not None:
            # after a coast that showed a load: the step the load's way (see there)
            self.last = _load_way_step(ses, rec, ses.origin + sign * step, self.headed[0], away,
                                       step, self.time_s, self.seen)
            self.moved[sign] = self.last.real_position - start
            self.last, _still = ses.settle(rec, self.time_s)
            return True

        def watch(s: Snapshot) -> bool:
            along = sign * (s.real_position - start)
            return along >= step // 2 or along <= -away

        ses.step_to(rec, ses.origin + sign * step)
        n0 = len(rec.rows)
        self.last = ses.record(rec, self.time_s, watch)
        moved = self.moved[sign] = self.last.real_position - start
        if self.first_moved is None:
            self.first_moved = moved
        if sign * moved <= -away:
            return self.coast_verdict(sign, n0)
        if sign * moved >= step // 2:
            # followed: let it come to rest there, so that the next step starts from a
            # shaft at rest (a shaft still coasting up would seem to refuse a step down);
            # a slow one (a load, inertia) gets longer, as the steps' own settle does
            self.last, self.prev_resting = ses.settle(rec, self.time_s)
        elif not (sign * moved >= 2 and self.kp * step >= U_FULL_SCALE):
            return False  # hardly moved: more drive
        return True

    def coast_verdict(self, sign: int, n0: int) -> bool:
        """The shaft headed away from the step ``sign``'s target (its rows from ``n0``): the
        drive off and the coast watched.  Reversed leads raise RUNAWAY; False when the loop
        had turned the shaft round (no verdict from this round), True when a load pulls it."""
        ses, rec = self.ses, self.rec
        self.seen = _seen(self.moved, self.step)
        # its speed from this step's own rows (see _speed), never from when the host
        # stamped the step
        self.headed = (-sign, abs(_speed(rec.rows[n0:], 1, ses.sample_s)))
        early, late = coast(ses, rec, min(self.time_s, 0.06), -sign)
        # reversed leads: still heading away when the drive went off, then slowing
        # down by itself.  A shaft already coming back (early <= 0) had been turned
        # round by the loop before the drive went off (a late host, a shaft that was
        # falling when the step came): the loop pulls the right way, and what pulled
        # the shaft away is a load, as below
        slowed = early > 0 and (late < 0.5 * early or late <= 0)
        if slowed and self.prev_resting:
            raise ses.fault(MotionError.RUNAWAY,
                            f"phasing: {self.seen}: it headed away from the target and "
                            "slowed down once the drive was off: the loop pushes the "
                            "wrong way. Swap the motor leads (or the encoder's A and B "
                            "channels)", self.last)
        self.last = rec.rows[-1]
        if early <= 0 or slowed:
            # turned round by the loop, or (slowed, the shaft not at rest when this
            # step came) still moving from the step before: its momentum, not the loop,
            # took it away; no verdict from this coast (see again_from_held)
            self.turned, self.headed = True, None
            return False
        # it kept going with the drive off: a load pulls it; the other step (the load's
        # way) tells a load from reversed leads under one
        return True

    def again_from_held(self, seen: str) -> None:
        """The loop pulled the shaft back towards the target: right, but the shaft was still
        moving when the step came (falling under a load after a reset), or the host turned
        the drive off late; the next step away from the load would meet that momentum and
        seem pushed away.  Again at this gain, from a held shaft (at most three times)."""
        ses = self.ses
        self.turned_count += 1
        if self.turned_count > 3:
            raise ses.fault(MotionError.STALL,
                            f"phasing: {seen}: four times the shaft was still moving away "
                            "when a step came, and the loop turned it back only after the "
                            "drive was off: a load pulls it harder than the phasing gain "
                            "steadies it; support the axis or give a shorter --travel (a "
                            "stiffer phasing gain)", self.last)
        ses.progress(f"phasing: {seen}; with the drive off it was already coming back: the "
                     "loop had turned it round (it was still moving when the step came, or "
                     "the host was late to turn the drive off): again, from a held shaft")
        ses.step_to(self.rec, ses.origin)  # the loop engaged again, holding the origin
        ses.settle(self.rec, 1.0)

    def followed_both(self) -> bool:
        """Both steps taken and followed (half the step, or any at full-scale output)."""
        step, moved = self.step, self.moved
        return self.headed is None and len(moved) == 2 and all(
            sign * moved[sign] >= step // 2 or (sign * moved[sign] >= 2
                                                and self.kp * step >= U_FULL_SCALE)
            for sign in moved)

    def passed(self) -> Phasing:
        """Phased right: back to the origin, at rest there; what was found."""
        ses, moved = self.ses, self.moved
        ses.progress(f"phasing ok: the shaft followed {moved[1]:+d} and {moved[-1]:+d} counts")
        ses.step_to(self.rec, ses.origin)  # back to the origin and rest there
        ses.settle(self.rec, 1.0)
        ses.phasing_kp = None
        return Phasing(self.kp, self.step, (moved[1], moved[-1]), ses.pulled,
                       moved[1] if self.first_moved is None else self.first_moved)

    def judge_load(self, seen: str) -> None:
        """A load pulls the shaft the way it headed: faster than at half this gain is
        reversed leads (RUNAWAY); at full-scale output, a load the drive cannot hold
        (STALL); else more gain."""
        ses, kp = self.ses, self.kp
        assert self.headed is not None
        way, speed = self.headed
        if ses.pulled == way and self.pulled_speed is not None and \
                speed > 1.25 * self.pulled_speed:
            raise ses.fault(MotionError.RUNAWAY,
                            f"phasing: {seen}, and it headed away faster at kp={kp} than at "
                            f"kp={kp // 2}: the loop pushes the wrong way. Swap the motor "
                            "leads (or the encoder's A and B channels)", self.last)
        ses.pulled, self.pulled_speed = way, speed
        if kp * self.step >= U_FULL_SCALE * 2:
            raise ses.fault(MotionError.STALL,
                            f"phasing: {seen}: a load pulls the shaft "
                            f"{'up' if way > 0 else 'down'} (it kept going with the drive "
                            f"off), and at kp={kp} the output is at full scale: the load "
                            f"pulls harder than kp={kp} holds: raise the amplifier's supply "
                            "or gain, or support the axis", self.last)
        ses.progress(f"phasing: {seen}; it kept going with the drive off: a load pulls it "
                     f"{'up' if way > 0 else 'down'}; more gain")

    def more_drive(self) -> None:
        """The gain doubled (up to full scale), loaded, the loop engaged again at the origin."""
        ses = self.ses
        self.kp = min(COEFFICIENT_MAX, self.kp * 2)
        ses.load(Gains(self.kp))
        ses.step_to(self.rec, ses.origin)  # the loop engaged again (after a coast, the drive on)
        ses.settle(self.rec, 0.5)
