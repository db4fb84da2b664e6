"""A chip's moves started: :meth:`LM629.move_to <lm629_host.LM629.move_to>`, its
``check_move`` and ``move_profile``, and where the chip rests between them.

A move is one bus program (one round trip on a bridge): the snapshot it starts from, an RSTI
of the flags a move reports (trajectory complete, breakpoint, position error, command error),
LTRJ and STT, so that a flag left by an earlier move can never end this one's wait.  Its
arguments are checked before any bus traffic, and so is its plan's length
(:func:`~lm629_host.chip.move.check_duration`): a move's start is the desired position last
read at rest (:attr:`Mover.rest_desired`), or read first (one exchange more) when the chip may
have moved since.  What a move returns and how it ends: :mod:`lm629_host.chip.move`.
"""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING, Protocol

from lm629_host.bus.opcodes import ACCELERATION_MAX, FIXED_ONE, UPDATE_INTERVAL_S, VELOCITY_MAX
from lm629_host.bus.program import Program
from lm629_host.bus.snapshot import Snapshot, snapshot_at
from lm629_host.chip.move import MOVE_FLAGS, Move, MovingChip, MoveTooLong, check_duration
from lm629_host.chip.pacing import UpdatePacing
from lm629_host.chip.safety import stop_on_error
from lm629_host.chip.supervise import SupervisedChip, VelocityRun, run_velocity
from lm629_host.chip.wraparound import PositionTracker, check_register_position, short_way
from lm629_host.errors import ArgumentError, check_int
from lm629_host.physics.limits import SoftLimits
from lm629_host.physics.pid import sample_period_s
from lm629_host.transports.base import Transport

if TYPE_CHECKING:
    from lm629_host.chip.shapes import Shape, ShapedMove


class MoverChip(MovingChip, Protocol):
    """What starting a move needs of its chip (an :class:`~lm629_host.LM629`)."""

    axis: int | None
    limits: SoftLimits | None
    positions: PositionTracker
    transport: Transport
    update_interval: float

    def snapshot_program(self) -> Program: ...

    def read_status(self) -> int: ...

    def clearing_wrap(self, program: Program) -> Program: ...

    def extended(self, s: Snapshot) -> Snapshot: ...

    def trajectory_program(self, acceleration: int | None = None, velocity: int | None = None,
                           position: int | None = None) -> Program: ...


class Mover:
    """Starts one chip's moves; knows where the chip rests and the acceleration last loaded."""

    def __init__(self, chip: MoverChip, pacing: UpdatePacing) -> None:
        self.chip = chip
        self.pacing = pacing
        #: the extended desired position last read with the trajectory at rest (on target or
        #: the motor off) and no STT since: where a move would start, known without a read
        #: (None: not known; a move reads it first)
        self.rest_desired: int | None = None
        #: the last acceleration word a move loaded (for the default timeout)
        self.acceleration: int | None = None

    def bound_to(self, chip: MoverChip, pacing: UpdatePacing) -> Mover:
        """A copy for ``chip`` (a chip's shadow) and its own pacing: its own from then on."""
        twin = copy.copy(self)
        twin.chip, twin.pacing = chip, pacing
        return twin

    def move_to(self, position: int, velocity: int, acceleration: int | None,
                relative: bool) -> Move:
        """:meth:`LM629.move_to <lm629_host.LM629.move_to>`: checked, then started."""
        chip = self.chip
        check_register_position("position", position)
        velocity = check_int("velocity", velocity, 1, VELOCITY_MAX, hex_digits=8)
        if acceleration is not None:
            acceleration = check_int("acceleration", acceleration, 1, ACCELERATION_MAX,
                                     hex_digits=8)
        if chip.limits is not None:  # before the first read: a refused move costs no exchange
            chip.limits.check_trajectory(acceleration, velocity, None if relative
                                         else chip.positions.near_register(position))
        self.check_move(position, velocity, acceleration, relative)
        return self.start(position, velocity, acceleration, relative)

    def check_move(self, position: int, velocity: int, acceleration: int | None,
                   relative: bool) -> float:
        """The seconds the plan of a move takes, or :class:`MoveTooLong`; nothing moves."""
        chip = self.chip
        check_register_position("position", position)
        velocity = check_int("velocity", velocity, 1, VELOCITY_MAX, hex_digits=8)
        known = acceleration if acceleration is not None else self.acceleration
        return check_duration(chip.move_rules, self.distance_to(position, relative), velocity,
                              known, chip.move_rules.clock_hz or chip.clock_hz,
                              f"move_to({position}{', relative=True' if relative else ''})")

    def distance_to(self, position: int, relative: bool) -> int:
        """The counts a move to ``position`` (a register value, or a distance when
        ``relative``) travels the short way round: from the desired position last read at
        rest, else from the one read now (one exchange; nothing moves before it is known)."""
        if relative:
            return short_way(position)
        at = self.rest_desired
        if at is None:
            at = self.chip.snapshot().desired_position
        return short_way(position - self.chip.positions.to_register(at))

    def start(self, position: int, velocity: int, acceleration: int | None,
              relative: bool) -> Move:
        """A move once its arguments and its plan's length were checked."""
        chip = self.chip
        first = chip.snapshot() if relative else None
        if first is not None:
            # the target in the register's terms: the chip goes the short way round to it
            register = chip.positions.to_register(first.desired_position + position)
        else:
            register = position
        program = chip.trajectory_program(acceleration, velocity, register)
        head = chip.snapshot_program() if first is None else None
        _, r = self.pacing.start(program, clear=MOVE_FLAGS, head=chip.clearing_wrap(head)
                                 if head is not None else None)
        start = first if first is not None else chip.extended(snapshot_at(r, 0, chip.clock.now()))
        self.rest_desired = None  # read before the STT: the move runs now
        # the target extended as the chip will reach it: the short way from the start
        target = start.desired_position + short_way(register - chip.positions.to_register(
            start.desired_position))
        if acceleration is not None:
            self.acceleration = acceleration
        move = Move(chip, target, velocity,
                    acceleration if acceleration is not None else self.acceleration,
                    start, chip.clock.now())
        if chip.transport.far_waits:  # the end seen on the far side (WAIT_STATUS)
            from lm629_host.chip.movewait import wait_far
            move.waiter = wait_far
        return move

    def move_profile(self, position: int, shape: Shape, relative: bool,
                     piece_s: float) -> ShapedMove:
        """:meth:`LM629.move_profile <lm629_host.LM629.move_profile>`: the plan checked,
        then its first piece started as a move and the rest handed to whoever times them."""
        # here: the shapes and their planner are imported by the scripts that shape a move
        from lm629_host.chip.shapes import Points, SCurve, ShapedMove, check_piece_s
        from lm629_host.chip.shapes import plan as plan_shape

        chip = self.chip
        check_register_position("position", position)
        if not isinstance(shape, (SCurve, Points)):
            raise ArgumentError("shape", shape, f"shape={shape!r}: expected "
                                "profile_shapes.SCurve or profile_shapes.Points")
        check_piece_s(piece_s)
        sample_s = sample_period_s(chip.clock_hz)
        clock_hz = chip.move_rules.clock_hz or chip.clock_hz
        what = f"move_profile({position}{', relative=True' if relative else ''})"

        def check_length(distance: int) -> None:
            """The least the shape takes (its top speed all the way), before its pieces are
            planned: a move too long is refused before it costs a plan of millions of pieces."""
            if isinstance(shape, SCurve):
                word = max(1, round(shape.velocity * sample_s * FIXED_ONE))
                check_duration(chip.move_rules, distance, word, None, clock_hz, what)
        if relative:
            check_length(position)
        plan = plan_shape(shape, position, sample_s, piece_s) if relative else None
        desired = chip.snapshot().desired_position
        register = chip.positions.to_register(desired + position) if relative else position
        if plan is None:
            distance = short_way(register - chip.positions.to_register(desired))
            check_length(distance)
            plan = plan_shape(shape, distance, sample_s, piece_s)
        if plan.duration > chip.move_rules.max_duration:  # a user's own points
            raise MoveTooLong(what, abs(distance if not relative else position),
                              plan.peak_velocity, plan.duration, chip.move_rules.max_duration)
        if chip.limits is not None:  # the fastest piece, before anything moves
            chip.limits.check_velocity(plan.peak_velocity)
        # its pieces' speeds, not the first one's, set how long it takes: checked above
        move = self.start(register, plan.pieces[0].velocity, plan.acceleration, False)
        # the bridge times the pieces when it holds them all, or takes them in top-ups
        transport = chip.transport
        far = (transport.far_profiles
               and (len(plan.pieces) - 1 <= transport.profile_capacity
                    or transport.profile_streams))
        shaped = ShapedMove(move, plan, far=far)
        if far:  # the bridge's timer issues the rest; the next update waits for the last
            with stop_on_error(chip):
                shaped.schedule_far(chip.axis, chip.update_interval)
            self.pacing.last_update = shaped.t0 + max(plan.pieces[-1].t, chip.update_interval)
        return shaped


class MovesMixin:
    """:class:`~lm629_host.LM629`'s moves: the front doors of its :class:`Mover`."""

    _mover: Mover

    def move_to(self, position: int, *, velocity: int, acceleration: int | None = None,
                relative: bool = False) -> Move:
        """Start a move to ``position`` (counts) and return a :class:`Move`; ``move.wait()``
        returns when the shaft is at rest on the target or raises :class:`MotionError`.

        ``velocity`` and ``acceleration`` are raw 16.16 words (1..); ``acceleration=None``
        keeps the one loaded (the chip refuses a new acceleration while the motor moves with
        the drive on: leave it out to change a running move).  ``relative=True``: ``position``
        counts from the desired position now (one more round trip, a snapshot first).  One
        bus program starts it, the flags a move reports cleared first; arguments and the
        plan's length (``move_rules.max_duration``) are checked before anything moves
        (``ValueError``): :mod:`lm629_host.chip.mover`.
        """
        return self._mover.move_to(position, velocity, acceleration, relative)

    def check_move(self, position: int, *, velocity: int, acceleration: int | None = None,
                   relative: bool = False) -> float:
        """The seconds the plan of :meth:`move_to` with these arguments takes, or
        :class:`~lm629_host.chip.move.MoveTooLong` (an ``ArgumentError``) when it is longer
        than ``move_rules.max_duration``; nothing moves either way (a read first when where the
        move would start is not known)."""
        return self._mover.check_move(position, velocity, acceleration, relative)

    def move_profile(self, position: int, shape: Shape, *, relative: bool = False,
                     piece_s: float = 2 * UPDATE_INTERVAL_S) -> ShapedMove:
        """Start a move to ``position`` (counts, a register value as for :meth:`move_to`, or
        from the desired position with ``relative=True``) along ``shape``
        (:class:`~lm629_host.chip.shapes.SCurve`: jerk-limited;
        :class:`~lm629_host.chip.shapes.Points`: your own (time, velocity) list), in
        pieces ``piece_s`` apart (AN-706 4.5.3; at least 10 ms, 4.6.2).  Returns a
        :class:`~lm629_host.chip.shapes.ShapedMove`: on a bridge that has PROFILE its timer
        issues the pieces (handed over at once; a move of more pieces than it holds, 64, is
        timed from the host), elsewhere they go out on the transport's clock before the
        chip's next bus program, ``wait()``'s or any other; ``wait()`` supervises the move as
        :meth:`Move.wait` does; the chip's own deceleration lands it exactly on the target.
        Reads a snapshot first (the distance sets the plan); the plan is checked
        (``ArgumentError``) before anything moves."""
        return self._mover.move_profile(position, shape, relative, piece_s)

    def run_velocity(self: SupervisedChip, velocity: int, acceleration: int | None = None) -> VelocityRun:
        """Start velocity mode at ``velocity``, 16.16 counts/sample with its sign the
        direction (negative: backwards), as :meth:`move_to` starts a move; ``acceleration``
        (16.16 counts/sample^2) is loaded too unless None (leave it out to change the speed of
        a running motor: the chip refuses a new one then, AN-706 4.6.1).  Returns the
        :class:`~lm629_host.chip.supervise.VelocityRun` (``.check()`` for a stall or runaway,
        ``.stop()`` to end it smoothly).  On an axis with soft limits it is a ValueError:
        velocity mode runs past them."""
        speed = check_int("velocity", velocity, -VELOCITY_MAX, VELOCITY_MAX)
        return run_velocity(self, abs(speed), acceleration, forward=speed >= 0)
