"""Velocity profiles other than the chip's trapezoid, as pieces the host plans (AN-706 4.5.3).

The chip only generates trapezoids.  AN-706 4.5.3 (Figure 16) gives the method for any other
profile: "breaking the profile into small pieces each of which is part of a small trapezoid.
A piecewise linear approximation to the required profile can then be achieved by changing the
maximum velocity before the trapezoid has had time to complete."  So a shaped move is one
position-mode move to its target, started with the first piece's maximum velocity, and a new
maximum velocity (LTRJ velocity + STT, allowed on the fly) at the start of every piece.  The
chip ramps to each piece's velocity at the move's one acceleration (which cannot change on the
fly, AN-706 4.6.1), and its own deceleration still lands exactly on the target, so the move
ends on target whatever the pieces' rounding.

Pieces are at least :data:`~lm629_host.bus.opcodes.UPDATE_INTERVAL_S` (10 ms) apart: each is an
STT, and the chip aborts its trajectory calculation at an STT sooner than that (AN-706 4.6.2).
Each piece's velocity is the profile's *mean* velocity over the piece, so the pieces cover the
planned distance in the planned time; the acceleration word is the fastest change between two
pieces spread over :data:`RAMP_SHARE` of a piece, so that the chip reaches every piece's
velocity within the piece (the recorded velocity follows the plan within one piece).

A shape is given in counts and seconds (:class:`SCurve`: a jerk-limited move; :class:`Points`:
the user's own (time, velocity) list, linear between the points); :func:`plan` turns it into a
:class:`ProfilePlan` of chip words at a chip's sample period.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

from lm629_host.clock import ROUNDING_S
from lm629_host.errors import ArgumentError
from lm629_host.chip.move import Move, MoveResult, MoveWatch
from lm629_host.bus.opcodes import ACCELERATION_MAX, UPDATE_INTERVAL_S, VELOCITY_MAX, Cmd, Status
from lm629_host.bus.program import Op, Program
from lm629_host.bus.snapshot import Snapshot
from lm629_host.transports.reports import ProfileState

#: 16.16 fixed point of the trajectory words
_ONE = 1 << 16
#: the share of a piece within which the chip must reach the piece's velocity: the whole piece,
#: so that the chip's acceleration at the steepest piece is the plan's peak, not more
RAMP_SHARE = 1.0
#: the longest a piece may be (the plan stays a fair approximation of the shape)
PIECE_MAX_S = 0.25
#: the most pieces one move takes (a far side holds them all; 2.5 min at 10 ms)
PIECES_MAX = 16384


@dataclass(frozen=True)
class Piece:
    """At ``t`` seconds from the move's start, the maximum velocity becomes ``velocity``."""

    t: float
    velocity: int  #: 16.16 counts/sample, 1..3FFFFFFF


@dataclass(frozen=True)
class ProfilePlan:
    """A shaped move as the chip runs it: ``distance`` counts (signed), the pieces, the one
    acceleration word, and the planned profile (``position_at``/``velocity_at``, counts and
    counts/s) it approximates."""

    distance: int
    pieces: tuple[Piece, ...]
    acceleration: int  #: 16.16 counts/sample^2
    duration: float  #: the planned profile's duration, s
    piece_s: float
    sample_s: float
    position_at: Callable[[float], float]
    velocity_at: Callable[[float], float]

    @property
    def peak_velocity(self) -> int:
        return max(p.velocity for p in self.pieces)

    def acceleration_at(self, t: float, dt: float = 1e-4) -> float:
        """The planned acceleration at ``t`` (counts/s^2), by a central difference."""
        return (self.velocity_at(t + dt) - self.velocity_at(t - dt)) / (2 * dt)

    def resume_at(self, covered: float, velocity: float) -> float:
        """The plan time to carry on from for a chip that has covered ``covered`` counts and
        runs at ``velocity`` counts/s (both along the move) after its caps came late.

        Where the plan is as far as the chip (:meth:`time_at`), unless the plan is faster
        there: then the chip, ramping up at the move's acceleration, would fall behind by
        the ramp's shortfall and stay behind, so the plan resumes a little earlier, where the
        chip is ahead of it by just what the ramp up to the plan's velocity will lose."""
        t_far = self.time_at(covered)
        if abs(self.velocity_at(t_far)) <= velocity:
            return t_far
        a = self.acceleration / _ONE / self.sample_s ** 2  # counts/s^2

        def ahead(t: float) -> float:  # what the chip will still be ahead after its ramp
            gap = max(0.0, abs(self.velocity_at(t)) - velocity)
            return covered - abs(self.position_at(t)) - gap * gap / (2 * a)

        lo, hi = 0.0, t_far  # ahead(lo) >= 0 >= ahead(hi)
        while hi - lo > 1e-6:
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if ahead(mid) >= 0 else (lo, mid)
        return lo

    @cached_property
    def slowing_t(self) -> float:
        """When the plan's last slowing begins: the first piece from which no piece is faster
        than the one before.  From there on, the plan's mean velocity over what it has left is
        at most the next piece's, so a cap that covers what the chip has left in that time
        holds back only a chip behind the plan."""
        k = len(self.pieces) - 1
        while k > 0 and self.pieces[k - 1].velocity >= self.pieces[k].velocity:
            k -= 1
        return self.pieces[k].t

    def word_at(self, t: float) -> int:
        """The velocity word of a piece that starts at plan time ``t``: the profile's mean
        velocity over ``[t, t + piece_s]`` (cut at the end), as :func:`plan` makes every piece,
        so a piece at ``k * piece_s`` is ``pieces[k]``; ``t`` past the end gives 1."""
        t1 = min(self.duration, t + self.piece_s)
        if t1 <= t:
            return 1
        mean = abs(self.position_at(t1) - self.position_at(t)) / (t1 - t)
        return max(1, round(mean * self.sample_s * _ONE))

    def time_at(self, covered: float) -> float:
        """The earliest plan time at which the profile has covered ``covered`` counts (>= 0,
        along the move's direction): where in the plan a chip that has gone that far is."""
        if covered <= 0:
            return 0.0
        if covered >= abs(self.distance):
            return self.duration
        lo, hi = 0.0, self.duration
        while hi - lo > 1e-7:  # the position is monotonic: bisection, well below a sample
            mid = (lo + hi) / 2
            lo, hi = (lo, mid) if abs(self.position_at(mid)) >= covered else (mid, hi)
        return hi


@dataclass(frozen=True)
class SCurve:
    """A jerk-limited move: the velocity, acceleration and jerk limits (counts/s, counts/s^2,
    counts/s^3); the acceleration ramps at ``jerk`` instead of stepping as a trapezoid's does."""

    velocity: float
    acceleration: float
    jerk: float

    def __post_init__(self) -> None:
        for name in ("velocity", "acceleration", "jerk"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    not math.isfinite(value) or value <= 0:
                raise ArgumentError(name, value, f"{name}={value!r} must be a finite number "
                                                 "above 0 (counts and seconds)", lo=0)

    def segments(self, distance: float) -> list[tuple[float, float]]:
        """(duration s, jerk counts/s^3) of the seven segments covering ``distance`` > 0."""
        j, a_max = self.jerk, self.acceleration

        def ramp(v: float) -> tuple[float, float]:  # (jerk time, constant-acceleration time)
            if v * j >= a_max * a_max:
                return a_max / j, v / a_max - a_max / j
            return math.sqrt(v / j), 0.0

        def ramp_distance(v: float) -> float:
            tj, ta = ramp(v)
            return v * (2 * tj + ta) / 2  # symmetric ramp: the mean velocity is v / 2

        v = self.velocity
        if 2 * ramp_distance(v) > distance:  # never reaches the velocity: find the top
            lo, hi = 0.0, v
            for _ in range(100):
                mid = (lo + hi) / 2
                lo, hi = (mid, hi) if 2 * ramp_distance(mid) <= distance else (lo, mid)
            v = lo
        tj, ta = ramp(v)
        cruise = (distance - 2 * ramp_distance(v)) / v if v > 0 else 0.0
        return [(tj, j), (ta, 0.0), (tj, -j), (max(0.0, cruise), 0.0), (tj, -j), (ta, 0.0),
                (tj, j)]


@dataclass(frozen=True)
class Points:
    """The user's own profile: (time s, velocity counts/s) points from (0, 0), linear between
    them, ending at velocity 0; the distance is its area (the target is checked against it)."""

    points: tuple[tuple[float, float], ...]

    def __init__(self, points: Sequence[tuple[float, float]]) -> None:
        pts = tuple((float(t), float(v)) for t, v in points)
        if len(pts) < 2:
            raise ArgumentError("points", points, "points: give at least two (time, velocity) "
                                                  "points, from (0, 0) to (T, 0)")
        if pts[0] != (0.0, 0.0) or pts[-1][1] != 0.0:
            raise ArgumentError("points", points, "points must start at (0, 0) and end at "
                                                  "velocity 0 (the move starts and ends at rest)")
        for (t0, _), (t1, v1) in zip(pts, pts[1:]):
            if not t1 > t0:
                raise ArgumentError("points", points, f"points: time {t1:g} s does not come "
                                                      f"after {t0:g} s")
            if not math.isfinite(v1) or v1 < 0:
                raise ArgumentError("points", points, f"points: velocity {v1:g} counts/s at "
                                                      f"{t1:g} s must be finite and >= 0 (the "
                                                      "target's sign gives the direction)")
        object.__setattr__(self, "points", pts)

    @property
    def area(self) -> float:
        return sum((t1 - t0) * (v0 + v1) / 2 for (t0, v0), (t1, v1)
                   in zip(self.points, self.points[1:]))


Shape = SCurve | Points


def _integrals(segments: Sequence[tuple[float, float]]
               ) -> tuple[float, Callable[[float], float], Callable[[float], float]]:
    """(duration, position(t), velocity(t)) of piecewise-constant jerk segments from rest."""
    starts: list[tuple[float, float, float, float, float]] = []  # t, jerk, a, v, p
    t = a = v = p = 0.0
    for dt, j in segments:
        starts.append((t, j, a, v, p))
        p += v * dt + a * dt * dt / 2 + j * dt ** 3 / 6
        v += a * dt + j * dt * dt / 2
        a += j * dt
        t += dt
    end = t, p

    def state(x: float) -> tuple[float, float]:
        if x <= 0:
            return 0.0, 0.0
        if x >= end[0]:
            return end[1], 0.0
        seg = starts[0]
        for s in starts:
            if s[0] <= x:
                seg = s
        t0, j, a0, v0, p0 = seg
        d = x - t0
        return (p0 + v0 * d + a0 * d * d / 2 + j * d ** 3 / 6, v0 + a0 * d + j * d * d / 2)

    return end[0], (lambda x: state(x)[0]), (lambda x: state(x)[1])


def _linear(points: Sequence[tuple[float, float]]
            ) -> tuple[float, Callable[[float], float], Callable[[float], float]]:
    """(duration, position(t), velocity(t)) of a piecewise-linear velocity."""
    def velocity(x: float) -> float:
        for (t0, v0), (t1, v1) in zip(points, points[1:]):
            if t0 <= x <= t1:
                return v0 + (v1 - v0) * (x - t0) / (t1 - t0)
        return 0.0

    def position(x: float) -> float:
        total = 0.0
        for (t0, v0), (t1, v1) in zip(points, points[1:]):
            if x <= t0:
                break
            end = min(x, t1)
            v_end = v0 + (v1 - v0) * (end - t0) / (t1 - t0)
            total += (end - t0) * (v0 + v_end) / 2
        return total

    return points[-1][0], position, velocity


def check_piece_s(piece_s: object) -> float:
    """``piece_s`` when it is a number of seconds from 10 ms (AN-706 4.6.2) to
    :data:`PIECE_MAX_S`, else an :class:`ArgumentError` naming that range."""
    if isinstance(piece_s, bool) or not isinstance(piece_s, (int, float)) or \
            not UPDATE_INTERVAL_S <= piece_s <= PIECE_MAX_S:
        raise ArgumentError("piece_s", piece_s, f"piece_s={piece_s!r} must be "
                            f"{UPDATE_INTERVAL_S:g}..{PIECE_MAX_S:g} s (AN-706 4.6.2: at most one "
                            "trajectory update per 10 ms)", lo=UPDATE_INTERVAL_S, hi=PIECE_MAX_S)
    return float(piece_s)


def plan(shape: Shape, distance: int, sample_s: float,
         piece_s: float = 2 * UPDATE_INTERVAL_S) -> ProfilePlan:
    """The pieces of ``shape`` over ``distance`` counts (its sign the direction) at a sample
    period of ``sample_s``; ``piece_s`` apart (at least the 10 ms of AN-706 4.6.2).  Every
    argument is checked here, before any bus cycle (:class:`ArgumentError`)."""
    if isinstance(distance, bool) or not isinstance(distance, int) or distance == 0:
        raise ArgumentError("distance", distance, f"distance={distance!r}: a shaped move needs a "
                                                  "whole number of counts to travel, not 0")
    check_piece_s(piece_s)
    span = abs(distance)
    if isinstance(shape, SCurve):
        duration, position, velocity = _integrals(shape.segments(span))
    elif isinstance(shape, Points):
        area = shape.area
        if abs(area - span) > max(1.0, 1e-3 * span):
            raise ArgumentError("points", shape.points,
                                f"points cover {area:.0f} counts but the move is {span} counts: "
                                "the area under the velocity points is the distance")
        duration, position, velocity = _linear(shape.points)
        scale = span / area  # exactly the distance
        position = (lambda f: lambda x: f(x) * scale)(position)
        velocity = (lambda f: lambda x: f(x) * scale)(velocity)
    else:
        raise ArgumentError("shape", shape, f"shape={shape!r}: expected SCurve or Points")
    n = max(1, math.ceil(duration / piece_s - 1e-9))
    if n > PIECES_MAX:
        raise ArgumentError("piece_s", piece_s, f"the move takes {duration:.1f} s: {n} pieces of "
                            f"{piece_s:g} s, more than {PIECES_MAX}; use longer pieces")
    words = []
    for k in range(n):
        t0, t1 = k * piece_s, min(duration, (k + 1) * piece_s)
        mean = (position(t1) - position(t0)) / max(t1 - t0, 1e-12)
        words.append(max(1, round(mean * sample_s * _ONE)))
    top = max(words)
    if top > VELOCITY_MAX:
        raise ArgumentError("velocity", top, f"the profile's top velocity word {top} is above "
                            f"{VELOCITY_MAX} (0x3FFFFFFF)", hi=VELOCITY_MAX)
    steps = [words[0]] + [abs(b - a) for a, b in zip(words, words[1:])] + [words[-1]]
    # whole samples of a piece after its STT (the first may come up to a sample late)
    samples = max(1, math.floor(piece_s / sample_s * RAMP_SHARE) - 1)
    acceleration = min(ACCELERATION_MAX, max(1, math.ceil(max(steps) / samples)))
    pieces = tuple(Piece(k * piece_s, w) for k, w in enumerate(words))
    sign = 1 if distance > 0 else -1
    return ProfilePlan(distance, pieces, acceleration, duration, float(piece_s), sample_s,
                       lambda x: sign * position(x), lambda x: sign * velocity(x))




# ---------------------------------------------------------------------------------- running
#: commands after which a host-timed shaped move no longer owns the chip's trajectory: the
#: user's own LTRJ or STT (a new move, a stop) or a reset; its remaining pieces are dropped
_TAKEOVER = frozenset({int(Cmd.LTRJ), int(Cmd.STT), int(Cmd.RESET)})


def takes_over(program: Program) -> bool:
    """True when ``program`` loads or starts a trajectory or resets the chip."""
    return any(op.op is Op.RESET or (op.op is Op.COMMAND and op.arg in _TAKEOVER)
               for op in program)


class ShapedMove(Move):
    """A move whose maximum velocity changes piece by piece (:meth:`LM629.move_profile
    <lm629_host.LM629.move_profile>`).

    Every piece is only a velocity cap on one position-mode move to the target, so the chip's
    own deceleration lands it whatever the pieces' timing: a late piece can change the shape's
    timing, never where it ends.  What must not happen is a slow cap left in force while the
    chip is still far from the target: it would crawl there.  So, timed from the host:

    * the caps go out on the transport's clock from :meth:`tend`, which runs before every bus
      program of the chip (``wait()``'s, and the user's next ``status()``, ``snapshot()``, a
      host-polled ``record()`` between its rows...), not only from ``wait()``;
    * a cap found more than a whole piece late (the host stalled, or looked late) is not
      issued as planned: the host reads where the chip is and resumes the plan there
      (:meth:`ProfilePlan.resume_at`): the pieces a chip ahead has passed are skipped, and a
      chip held back by a slow cap picks the ramp up where it will be level with the plan;
    * while the plan slows to its end, no cap is slower than covers what the chip has left in
      the plan's time left (at least a piece), and past the plan's end a cap covers the rest
      within a piece, until the chip reports its trajectory complete.

    A host late by less than a piece every time (a slow USB adapter) keeps the planned times:
    the shape is that much later.  On a bridge with PROFILE (``far``) its own timer issues the
    pieces instead.

    ``piece_times`` are when each cap had gone out (seconds from the move's STT), ``words``
    the caps, ``jitter`` each cap's lateness against when it was due, ``lag`` how far the
    host's schedule runs behind the plan, ``resyncs`` how often a late host re-found its
    place from the chip's position."""

    def __init__(self, move: Move, plan: ProfilePlan, far: bool = False) -> None:
        super().__init__(move.chip, move.target, plan.peak_velocity, plan.acceleration,
                         move.start, move.t0)
        self.plan = plan
        self.inner = move.waiter  #: the end's waiter (the far side's, or None: polling)
        self.waiter = _wait_pieces
        #: True when the transport's far side issues the pieces on its own timer; then
        #: ``far_state`` is what it reported at the end (its pieces' lateness on its clock)
        self.far = far
        self.far_state: ProfileState | None = None
        #: a far schedule: its last piece's time from the STT as handed over; the landing caps
        #: the host issued after it (plan time from the STT, word)
        self.far_end: float | None = None
        self.landings: list[tuple[float, int]] = []
        self.piece_times: list[float] = [0.0]
        self.words: list[int] = [plan.pieces[0].velocity]
        self.dues: list[float] = [0.0]  #: when each cap was due, seconds from the STT
        self.lag = 0.0
        self.resyncs = 0
        #: True while the host still issues caps; False once the chip reported the trajectory
        #: complete, or another trajectory command took over (``dropped``)
        self.issuing = not far
        self.dropped = False
        self._next = plan.piece_s  #: the plan time of the next cap
        self._busy = threading.Lock()
        self._owner: int | None = None  #: the thread issuing a cap now
        #: the last snapshot ``wait()`` looked at (the caps' floor reckons from it)
        self.seen: Snapshot | None = None
        chip: Any = self.chip  # an LM629
        #: the chip's time of its last STT as this move left it: any other STT (a board's, a
        #: batch's) or a reset changes it, and this move's caps stop
        self._mark: float | None = chip.last_update
        if self.issuing:  # its programs pass by here first
            chip.before_program = self._before_program

    def profile_s(self, clock_hz: float) -> float | None:
        return self.plan.duration

    @property
    def jitter(self) -> list[float]:
        """Each host-issued cap's lateness against when it was due, seconds (a far-side
        schedule reports only its largest: ``far_state.late_max_s``)."""
        return [t - d for t, d in zip(self.piece_times, self.dues)]

    @property
    def next_due(self) -> float:
        """When the next cap is due, on the transport's clock: its time in the plan, and no
        sooner than the chip's update interval after its last STT (AN-706 4.6.2: a cap that
        went out late does not bring the next one closer than that)."""
        chip: Any = self.chip  # an LM629
        due = self.t0 + self.lag + self._next
        last = chip.last_update
        return due if last is None else max(due, last + chip.update_interval)

    def schedule_far(self, axis: int | None, update_s: float) -> None:
        """Hand the pieces after the first to the transport's far side: their times from now,
        the first no sooner than ``update_s`` (AN-706 4.6.2) after the move's STT."""
        clock = self.chip.clock
        elapsed = clock.now() - self.t0
        rest = self.plan.pieces[1:]
        # a host late to hand them over (past the first piece's time): the chip ran the first
        # piece's velocity meanwhile, so the whole schedule moves later by that much, keeping
        # its spacing (the shape delayed, not squeezed: pieces squeezed together would cap a
        # chip that is behind the plan at the plan's slow end far from its target, and the
        # bridge refuses pieces closer than the update rule)
        shift = max(0.0, elapsed - (rest[0].t - update_s)) if rest else 0.0
        pieces = [(p.t - elapsed + shift, p.velocity) for p in rest]
        chip: Any = self.chip  # an LM629
        chip.transport.profile(axis, pieces, new=True)
        self.far_end = (rest[-1].t + shift) if rest else 0.0

    def land(self, s: Snapshot) -> None:
        """A far schedule's end, as the host-timed path's: once the bridge has issued its last
        piece (a piece after its time, and the bridge holding none), a chip still short of
        the target under the tail's slow cap (the pieces' ramps and rounding leave a few
        counts: at the last piece's mean velocity, a few counts per second, seconds of crawl)
        gets a cap that covers the rest within a piece, at most once a piece; the chip's own
        deceleration lands it.  The pieces before stay timed by the bridge."""
        plan = self.plan
        chip: Any = self.chip  # an LM629
        if self.far_end is None or s.status & Status.TRAJECTORY_COMPLETE:
            return
        t = s.time - self.t0
        last = self.landings[-1][0] if self.landings else self.far_end
        if t < last + plan.piece_s:
            return
        left = abs(self.target - s.desired_position)
        speed = abs(s.desired_velocity) / _ONE / plan.sample_s  # counts/s
        if left <= speed * plan.piece_s:
            return  # the chip covers the rest within a piece as it goes
        state = chip.transport.profile(chip.axis, [], new=False)
        if state.pending or state.queued:
            return  # the bridge is still issuing (its clock started when the pieces arrived)
        word = min(plan.peak_velocity, math.ceil(left / plan.piece_s * plan.sample_s * _ONE))
        chip.load_trajectory(velocity=word, start=True)
        self.landings.append((t, word))

    def _before_program(self, program: Program) -> None:
        """The chip's hook: drop the pieces when ``program`` takes the trajectory over, else
        issue a cap that is due.  This move's own programs pass straight through."""
        if self._owner == threading.get_ident():
            return
        if takes_over(program):
            self.end_caps(dropped=True)
            return
        self.tend()

    def tend(self, s: Snapshot | None = None) -> None:
        """Issue the cap that is due now, if any (``s``: a snapshot just read, saving a read
        when the host must find its place).  Another thread issuing at the moment: nothing."""
        if not self.issuing or not self._busy.acquire(blocking=False):
            return
        self._owner = threading.get_ident()
        try:
            self._tend(s)
        finally:
            self._owner = None
            self._busy.release()

    def _tend(self, s: Snapshot | None) -> None:
        chip: Any = self.chip  # an LM629
        clock, plan = chip.clock, self.plan
        now = clock.now()
        due = self.next_due
        if now < due - ROUNDING_S:
            return
        t = self._next
        # late by a whole piece: the host missed one (a host late by less every time, a slow
        # USB adapter, keeps the planned times: the shape is only that much later)
        late = now - due > plan.piece_s
        word = plan.word_at(t)
        if late or self._final(t):  # where is the chip, exactly?
            if s is None or s.time < due:
                s = chip.snapshot()
            if s.status & Status.TRAJECTORY_COMPLETE:
                self.end_caps()
                return
            if late:  # carry on from the plan's piece for the distance covered
                covered = (s.desired_position - self.start.desired_position) * (
                    1 if plan.distance > 0 else -1)
                t = plan.resume_at(covered, abs(s.desired_velocity) / _ONE / plan.sample_s)
                self.lag = clock.now() - self.t0 - t
                self.resyncs += 1
                word = plan.word_at(t)
        elif s is None and self.seen is not None and now - self.seen.time <= 2 * plan.piece_s:
            s = self.seen  # the last snapshot wait() looked at: where the chip was a piece ago
        if s is not None and t >= plan.slowing_t:
            # slowing to the end: no slower than covers what remains in the plan's time left
            left = abs(self.target - s.desired_position)
            if s.time < now:  # what the chip has gone since, at its velocity then
                left -= abs(s.desired_velocity) / _ONE / plan.sample_s * (now - s.time)
            floor = left / max(plan.piece_s, plan.duration - t) * plan.sample_s * _ONE
            word = min(plan.peak_velocity, max(word, math.ceil(floor)))
        with chip.transport.lock:  # a stop from another thread goes after this cap, or drops it
            if chip.last_update != self._mark:
                self.end_caps(dropped=True)  # another STT, or a reset, came since this move's last
            if not self.issuing:
                return
            chip.load_trajectory(velocity=word, start=True)
            self._mark = chip.last_update
        self.piece_times.append(clock.now() - self.t0)
        self.words.append(word)
        self.dues.append(due - self.t0)
        self._next = t + plan.piece_s

    def _final(self, t: float) -> bool:
        """Whether a cap at plan time ``t`` is the last of the plan: what the plan has left
        after it is less than half a piece (a cap for a sliver of the plan would be its
        tail's mean velocity, near 0, and hold a chip that is a little behind to a crawl)."""
        return t + 1.5 * self.plan.piece_s >= self.plan.duration

    def end_caps(self, dropped: bool = False) -> None:
        """No more caps: the chip completed the trajectory, or (``dropped``) something else
        took it over; the chip's hook is let go."""
        self.issuing = False
        self.dropped = self.dropped or dropped
        chip: Any = self.chip
        if getattr(chip, "before_program", None) == self._before_program:
            chip.before_program = None


def _wait_pieces(move: Move, watch: MoveWatch,
                 progress: Callable[[Snapshot], None] | None) -> MoveResult:
    """The loop of :meth:`ShapedMove.wait`: caps issued when due (a snapshot after each judges
    the move as any move's wait does), then the end's own wait."""
    assert isinstance(move, ShapedMove)
    chip: Any = move.chip  # an LM629
    clock = chip.clock
    if move.far:
        def landing(s: Snapshot) -> None:
            if progress is not None:
                progress(s)
            move.land(s)
        done = (move.inner(move, watch, landing) if move.inner is not None
                else move.poll(watch, landing))
        move.far_state = chip.transport.profile(chip.axis, [], new=False)
        return done
    timeout = watch.deadline - move.t0
    while move.issuing:
        now = clock.now()
        if now < move.next_due:
            clock.sleep(move.next_due - now)
        move.tend()
        # the host's own lateness stretched the move: the timeout counts without it
        watch.deadline = move.t0 + timeout + max(0.0, move.lag)
        s, result = watch.look(chip, progress)
        if result is not None:
            return result
        move.seen = s
        if s.status & Status.TRAJECTORY_COMPLETE:
            move.end_caps()  # the chip landed on the target: no cap has anything left to do
    if move.inner is not None:
        return move.inner(move, watch, progress)
    return move.poll(watch, progress)


__all__ = ["PIECES_MAX", "PIECE_MAX_S", "Piece", "Points", "ProfilePlan", "RAMP_SHARE",
           "SCurve", "Shape", "ShapedMove", "check_piece_s", "plan", "takes_over"]
