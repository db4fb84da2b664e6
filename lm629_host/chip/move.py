"""Moves that wait for their own completion: :meth:`LM629.move_to` -> :class:`Move`.

Why this exists: the chip's status flags stay set until RSTI clears them.  A second
``load_trajectory(..., start=True)`` followed by ``wait_for(TRAJECTORY_COMPLETE)`` returns at
once, satisfied by the flag the *first* move raised, while the motor is still moving.
:meth:`LM629.move_to` clears the flags a move reports (trajectory complete, breakpoint,
position error, and the command error that STT is checked by) in the same bus program as its
LTRJ and STT (one round trip on the bridge), and :meth:`Move.wait` watches the move until the
shaft is at rest on the target, or raises :class:`~lm629_host.MotionError` with the motor
stopped (abrupt stop, then motor off).

The rules (:class:`MoveRules`, ``chip.move_rules``; every field settable):

* **done** = the trajectory generator reported trajectory complete with the desired position on
  the target, then the shaft stayed within ``tolerance`` counts of the target with zero
  velocity for ``settle_time`` seconds (the *settle rule*).  Default tolerance: 20 counts,
  above the P-only dead band of kp >= 20 on the 8-bit output (256 / kp + 1 = 13.8 counts at
  kp = 20, AN-706 5.2.4).  A loop with a wider dead band (kp < 14) needs a larger tolerance.
* **stall**: the following error is above the tolerance and the shaft has not moved
  ``stall_counts`` for ``stall_time`` seconds while the trajectory is still running.
* **runaway**: the shaft moves away from the desired position (the error grows) for
  ``runaway_counts`` counts while speeding up, and the error has reached ``runaway_counts``:
  positive feedback (motor leads or encoder channels swapped).  An overshoot slows down as it
  goes and a lagging deceleration keeps the error small, so neither is a runaway.
* **position error** / **motor off**: the chip's own flag (LPEI / LPES), or the drive found off.
* **following error**: the trajectory completed but the shaft came to rest outside the
  tolerance, or did not come to rest within ``settle_timeout`` seconds.
* **timeout**: not done within ``timeout`` (default: the profile's duration at ``clock_hz``
  times 1.5, plus ``settle_timeout``, plus one second).
* **too long**: a move whose plan takes longer than ``max_duration`` (default 10 minutes) is
  refused before anything moves (:func:`check_duration`, an :class:`ArgumentError` naming
  its length, its duration and ``max_duration``).  The chip reaches a target the short way
  round its 2^31-count register (AN-706 6.5.2), so near the wrap at 3FFFFFFF a target typed
  as the wrong one of its two register values is a move of up to 2^30 counts: 37 hours at a
  bench's speed, the motor running away from what the user meant.

All waiting is on the transport's clock (simulated time on a simulator) and every check is a
public status read (:meth:`LM629.snapshot`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import NoReturn, Protocol

from lm629_host.clock import ROUNDING_S, Clock
from lm629_host.errors import ArgumentError, MotionError, MotionFault
# the bits MoveWatch.check tests on every snapshot of a wait, as plain ints (an IntFlag's
# ``&`` is a Python call)
from lm629_host.bus.bits import (
    SIGNALS_MOTOR_OFF as _SIGNALS_MOTOR_OFF,
    STATUS_MOTOR_OFF as _STATUS_MOTOR_OFF,
    STATUS_POSITION_ERROR as _POSITION_ERROR,
    STATUS_TRAJECTORY_COMPLETE as _TRAJECTORY_COMPLETE,
)
from lm629_host.bus.opcodes import Status
from lm629_host.physics.plan import plan
from lm629_host.chip.safety import STOP_NOTE, Stoppable, emergency_stop, motion_fault
from lm629_host.bus.snapshot import Snapshot


class MovingChip(Stoppable, Protocol):
    """What a move needs of its chip (an :class:`~lm629_host.LM629` is one, and makes its
    moves): its rules and clock, snapshots, and a way to stop.  Declared here so that this
    module does not import the typed layer back."""

    move_rules: MoveRules
    chip_select: int  #: which chip of a multi-axis board

    @property
    def clock_hz(self) -> float:
        """The chip's clock (Hz), for the default timeout."""

    @property
    def clock(self) -> Clock: ...

    def snapshot(self) -> Snapshot: ...


#: the flags a move reports, cleared in the program that starts it
MOVE_FLAGS = Status.TRAJECTORY_COMPLETE | Status.BREAKPOINT | Status.POSITION_ERROR


@dataclass(frozen=True)
class MoveRules:
    """When a move is done, and when it is a motion fault (see the module docstring)."""

    tolerance: int = 20  #: counts from the target at rest
    settle_time: float = 0.02  #: seconds at rest inside the tolerance
    settle_timeout: float = 1.0  #: seconds after trajectory complete to settle
    stall_time: float = 0.25  #: seconds without shaft progress while the error is large
    stall_counts: int = 4  #: shaft motion that counts as progress
    runaway_counts: int = 200  #: shaft motion away from the desired position
    poll: float = 0.005  #: seconds between status reads
    clock_hz: float | None = None  #: the chip's clock for the default timeout (None: the
    #: chip's own ``clock_hz``: the simulator's, else 8 MHz)
    #: seconds the plan of one move may take; a longer one is refused before anything moves
    #: (``math.inf``: no limit; a profile's ``max_move_s`` sets it per axis)
    max_duration: float = 600.0

    def __post_init__(self) -> None:
        for name in ("settle_time", "settle_timeout", "stall_time", "poll", "max_duration"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and (math.isfinite(v) or name == "max_duration"
                                                     and v == math.inf) and v > 0):
                raise ArgumentError(name, v, f"{name}={v!r} must be a positive number of seconds")
        for name in ("tolerance", "stall_counts", "runaway_counts"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ArgumentError(name, v, f"{name}={v!r} must be a whole number of counts >= 0",
                                    lo=0)


def span(seconds: float) -> str:
    """A duration as a person reads it: seconds, minutes, hours or days."""
    for unit, size in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= size:
            return f"{seconds / size:.1f} {unit}"
    return f"{seconds:.1f} s"


#: what a refused long move says of its target (the CLI says it too)
LONG_MOVE_HINT = ("check the target: the chip goes the short way round its position register "
                  "(C0000000..3FFFFFFF), so near the wrap a register value on the other side "
                  "of it is a short move and a target given past it is a long one (a relative "
                  "move says what is meant)")


class MoveTooLong(ArgumentError):
    """A move whose plan takes longer than ``MoveRules.max_duration``, refused before
    anything moved: ``distance`` (counts), ``seconds`` (planned), ``limit`` (seconds) and
    ``what`` (the call), for a caller that says it in its own words (the CLI)."""

    def __init__(self, what: str, distance: int, velocity: int, seconds: float,
                 limit: float) -> None:
        self.what, self.distance, self.seconds, self.limit = what, distance, seconds, limit
        super().__init__(
            "max_duration", limit,
            f"{what}: {distance} counts at velocity word {velocity} takes {seconds:.0f} s "
            f"({span(seconds)}) planned, longer than the limit max_duration={limit:g} s "
            f"({span(limit)}); nothing was moved.  {LONG_MOVE_HINT[0].upper()}"
            f"{LONG_MOVE_HINT[1:]}; if the move is meant, allow it: chip.move_rules = "
            "dataclasses.replace(chip.move_rules, max_duration=SECONDS), or a profile's "
            "max_move_s", lo=seconds)


def check_duration(rules: MoveRules, distance: int, velocity: int, acceleration: int | None,
                   clock_hz: float, what: str = "the move") -> float:
    """The planned seconds of a move of ``distance`` counts with these words (the cruise
    alone when the acceleration is not known here: the least it takes), or
    :class:`MoveTooLong` when that is above ``rules.max_duration``."""
    if acceleration:
        seconds = plan(abs(distance), velocity, acceleration).seconds(clock_hz)
    else:
        seconds = plan(abs(distance), velocity, 1 << 30).seconds(clock_hz)
    if seconds <= rules.max_duration:
        return seconds
    raise MoveTooLong(what, abs(distance), velocity, seconds, rules.max_duration)


@dataclass(frozen=True)
class MoveResult:
    """A move that ended on target."""

    target: int  #: counts
    position: int  #: real position at rest, counts
    error: int  #: target - position, counts
    duration: float  #: seconds from the STT to settled, on the transport's clock


class Move:
    """A started move (from :meth:`LM629.move_to`).  :meth:`wait` until it is done."""

    #: the loop of :meth:`wait` when the far side can wait for the move's end (set by the
    #: chip that made the move: :func:`lm629_host.chip.movewait.wait_far`); None: host polling
    waiter: Callable[[Move, MoveWatch, Callable[[Snapshot], None] | None], MoveResult] | None = None

    def __init__(self, chip: MovingChip, target: int, velocity: int, acceleration: int | None,
                 start: Snapshot, t0: float) -> None:
        self.chip = chip
        self.target = target
        self.velocity = velocity
        self.acceleration = acceleration
        self.start = start  #: the snapshot read just before the move was started
        self.t0 = t0  #: transport clock at the STT
        self.result: MoveResult | None = None

    def __repr__(self) -> str:
        return f"<Move to {self.target} counts, {'done' if self.result else 'started'}>"

    def profile_s(self, clock_hz: float) -> float | None:
        """The trajectory's duration, or None when the acceleration is not known here."""
        if not self.acceleration:
            return None
        return plan(self.target - self.start.desired_position, self.velocity,
                    self.acceleration).seconds(clock_hz)

    def clock_hz_for(self, rules: MoveRules) -> float:
        """The chip's clock for timing this move: the rules' (a profile's), else the chip's."""
        if rules.clock_hz:
            return rules.clock_hz
        return self.chip.clock_hz

    def wait(self, timeout: float | None = None, tolerance: int | None = None, *,
             rules: MoveRules | None = None,
             progress: Callable[[Snapshot], None] | None = None) -> MoveResult:
        """Watch the move until the shaft is at rest within ``tolerance`` counts of the target
        (default ``chip.move_rules``); return a :class:`MoveResult`.  On a fault stop the motor
        (abrupt stop, then off) and raise :class:`MotionError` naming the reason.  Ctrl-C
        (KeyboardInterrupt) while waiting stops the motor the same way before it goes on.
        ``progress`` is called with every snapshot read."""
        if self.result is not None:
            return self.result
        try:
            return self._wait(timeout, tolerance, rules, progress)
        except KeyboardInterrupt as exc:
            if getattr(exc, STOP_NOTE, None) is None:
                setattr(exc, STOP_NOTE, emergency_stop(self.chip)[1])
            raise

    def _wait(self, timeout: float | None, tolerance: int | None, rules: MoveRules | None,
              progress: Callable[[Snapshot], None] | None) -> MoveResult:
        watch = self.watch(timeout, tolerance, rules)
        if self.waiter is not None:  # the far side waits (lm629_host.chip.movewait)
            return self.waiter(self, watch, progress)
        return self.poll(watch, progress)

    def poll(self, watch: MoveWatch, progress: Callable[[Snapshot], None] | None) -> MoveResult:
        """The host's loop of :meth:`wait`: a snapshot every ``poll``, each judged by ``watch``."""
        chip, clock = self.chip, self.chip.clock
        while True:
            _s, result = watch.look(chip, progress)
            if result is not None:
                return result
            clock.sleep(watch.rules.poll)

    def watch(self, timeout: float | None = None, tolerance: int | None = None,
              rules: MoveRules | None = None) -> MoveWatch:
        """The rules of :meth:`wait` as a checker fed with snapshots read elsewhere (a board
        reads every axis's snapshot in one program and feeds each move's watch)."""
        r = rules or self.chip.move_rules
        if tolerance is not None:
            r = replace(r, tolerance=tolerance)
        if timeout is None:
            profile = self.profile_s(self.clock_hz_for(r))
            timeout = (1.5 * profile if profile is not None else 60.0) + r.settle_timeout + 1.0
        if not (isinstance(timeout, (int, float)) and math.isfinite(timeout) and timeout > 0):
            raise ArgumentError("timeout", timeout,
                                f"timeout={timeout!r} must be a positive number of seconds")
        return MoveWatch(self, r, timeout)

    def fault(self, reason: MotionFault, s: Snapshot, message: str) -> NoReturn:
        """End the move with :class:`MotionError` ``reason`` at snapshot ``s`` (its watch's
        verdict)."""
        raise motion_fault(self.chip, reason, message, position=s.real_position,
                           error=self.target - s.real_position)


class MoveWatch:
    """The done / fault rules of one move (see the module docstring), fed one snapshot at a
    time: :meth:`check` returns the :class:`MoveResult` once the move is done, None while it
    goes on, and on a fault stops the motor and raises :class:`MotionError`."""

    def __init__(self, move: Move, rules: MoveRules, timeout: float) -> None:
        self.move, self.rules, self.timeout = move, rules, timeout
        self.deadline = move.t0 + timeout
        self.prev = move.start
        self.progress_at, self.progress_pos = move.start.time, move.start.real_position
        self.away, self.away_v0 = 0, 0
        self.complete_at: float | None = None
        self.quiet_since: float | None = None

    def restart_rest(self, s: Snapshot) -> None:
        """Count the shaft's rest from snapshot ``s`` on, forgetting the rest seen before it
        (a far-side wait whose snapshots come in checks too far apart to judge across: a
        shaft still at the top of an overshoot at the end of one check and a few counts on at
        the next was not at rest in between)."""
        self.prev = s
        self.quiet_since = None

    def look(self, chip: MovingChip, progress: Callable[[Snapshot], None] | None
             ) -> tuple[Snapshot, MoveResult | None]:
        """One step of a host-polled wait: a snapshot of ``chip``, shown to ``progress``, then
        :meth:`check`-ed."""
        s = chip.snapshot()
        if progress is not None:
            progress(s)
        return s, self.check(s)

    def check(self, s: Snapshot) -> MoveResult | None:
        m, r, prev = self.move, self.rules, self.prev
        target = m.target
        err = target - s.real_position
        status = int(s.status)
        if status & _POSITION_ERROR:
            m.fault(MotionError.POSITION_ERROR, s,
                     "the chip raised its position-error flag (following error above "
                     "the LPEI/LPES limit)")
        if status & _STATUS_MOTOR_OFF or int(s.signals) & _SIGNALS_MOTOR_OFF:
            m.fault(MotionError.MOTOR_OFF, s, "the drive was found off during the move")
        # shaft progress (stall) and motion away from the desired position (runaway)
        if abs(s.real_position - self.progress_pos) >= r.stall_counts:
            self.progress_at, self.progress_pos = s.time, s.real_position
        fe = s.following_error
        moved = s.real_position - prev.real_position
        if moved and fe and (moved > 0) != (fe > 0) and abs(fe) > abs(prev.following_error):
            if not self.away:
                self.away_v0 = abs(prev.real_velocity)
            self.away += abs(moved)
        elif moved:
            self.away = 0
        # a runaway leaves the desired position behind: the error grows with the distance run
        # away (a lagging deceleration or an overshoot keeps it small, and slow moves make the
        # per-sample velocity 0 or 1, too coarse to tell alone)
        if (self.away >= r.runaway_counts and abs(fe) >= r.runaway_counts
                and abs(s.real_velocity) >= self.away_v0):
            m.fault(MotionError.RUNAWAY, s,
                     f"the shaft ran {self.away} counts away from the desired position "
                     f"(following error {fe:+d}): swap the motor leads or the encoder's "
                     "A and B channels")
        if self.complete_at is None and status & _TRAJECTORY_COMPLETE \
                and s.desired_position == target:
            self.complete_at = s.time
        if self.complete_at is None and abs(fe) > r.tolerance \
                and s.time - self.progress_at >= r.stall_time:
            m.fault(MotionError.STALL, s,
                     f"the desired position moved {s.desired_position - m.start.desired_position:+d} "
                     f"counts, the shaft {s.real_position - m.start.real_position:+d} "
                     f"(no progress for {s.time - self.progress_at:.2f} s): check the "
                     "amplifier, its supply, the motor and the encoder")
        if self.complete_at is not None:
            at_rest = s.real_velocity == 0 and s.real_position == prev.real_position
            if at_rest:
                self.quiet_since = prev.time if self.quiet_since is None else self.quiet_since
            else:
                self.quiet_since = None
            # (a far check's snapshots are its poll apart by construction: four polls make
            # the settle time, give or take a float's rounding)
            if self.quiet_since is not None \
                    and s.time - self.quiet_since >= r.settle_time - ROUNDING_S:
                if abs(err) <= r.tolerance:
                    m.result = MoveResult(target, s.real_position, err, s.time - m.t0)
                    return m.result
                if abs(s.real_position - m.start.real_position) < r.stall_counts:
                    m.fault(MotionError.STALL, s,
                             f"the desired position went to the target, the shaft did "
                             f"not move ({err:+d} counts from the target): check the "
                             "amplifier, its supply, the motor and the encoder")
                m.fault(MotionError.FOLLOWING_ERROR, s,
                         f"the shaft came to rest {err:+d} counts from the target "
                         f"(tolerance {r.tolerance}): add ki, raise kp, or check the load")
            if s.time - self.complete_at >= r.settle_timeout:
                m.fault(MotionError.FOLLOWING_ERROR, s, self._unsettled(s, prev, err))
        if s.time >= self.deadline:
            m.fault(MotionError.TIMEOUT, s,
                     f"not on target after {self.timeout:g} s (desired {s.desired_position}, "
                     f"target {target}, shaft {s.real_position})")
        self.prev = s
        return None

    def _unsettled(self, s: Snapshot, prev: Snapshot, err: int) -> str:
        """What was still wrong when the settle timeout ran out: the shaft outside the
        tolerance, or inside it and still moving (the settle rule asks both: inside, and at
        rest for ``settle_time``), or at rest too briefly."""
        r = self.rules
        where = (f"{err:+d} counts from the target "
                 f"({'inside' if abs(err) <= r.tolerance else 'outside'} the tolerance "
                 f"{r.tolerance})")
        if self.quiet_since is None:
            moved, dt = s.real_position - prev.real_position, s.time - prev.time
            still = (f"still moving ({moved:+d} counts in the last {dt:.3f} s, about "
                     f"{moved / dt:+.0f} counts/s)" if moved and dt > 0 else
                     f"still moving (real velocity {s.real_velocity:+d} counts/sample)")
        else:
            still = (f"at rest for {s.time - self.quiet_since:.3f} s of the "
                     f"{r.settle_time:g} s the settle rule asks")
        return (f"the shaft did not settle in the {r.settle_timeout:g} s after the trajectory "
                f"ended: {where}, {still}: add kd for damping, or lower kp")


__all__ = ["LONG_MOVE_HINT", "MOVE_FLAGS", "Move", "MoveResult", "MoveRules", "MoveTooLong", "MoveWatch",
           "check_duration", "span"]
