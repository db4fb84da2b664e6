"""Motion supervision beyond a move to a target: velocity mode watched like a move, the index
search, and waiting until the shaft is still.

:class:`~lm629_host.chip.move.Move` watches a move to a target.  A velocity-mode run has no target:
what goes wrong is the shaft turning the wrong way (a runaway: motor leads or encoder channels
swapped) or far slower than asked (a stall: amplifier, supply, motor, encoder), and it ends
well with a smooth stop after which the shaft comes to rest.  These are the rules the CLI's
``velocity`` and ``index --search`` apply, here so that a lab script or a shell applies the
same ones.  Every check is a public status read (:meth:`LM629.snapshot`) on the chip's clock;
a fault stops the motor (abrupt stop, then off) before :class:`~lm629_host.MotionError` is
raised (:func:`~lm629_host.chip.safety.motion_fault`), as a move's does.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from lm629_host.clock import Clock
from lm629_host.errors import MotionError, MotionFault, WaitTimeout
from lm629_host.physics.limits import SoftLimits
from lm629_host.chip.move import MoveRules
from lm629_host.bus.opcodes import FIXED_ONE, SAMPLE_CLOCKS, Status
from lm629_host.chip.safety import motion_fault, stop_on_error
from lm629_host.bus.snapshot import Snapshot


class SupervisedChip(Protocol):
    """What supervision needs of its chip (an :class:`~lm629_host.LM629` is one), declared
    here because the driver offers :meth:`LM629.run_velocity <lm629_host.LM629.run_velocity>`
    from this module and must not be imported back."""

    @property
    def clock(self) -> Clock: ...
    def read_status(self) -> int: ...
    @property
    def clock_hz(self) -> float: ...
    @property
    def limits(self) -> SoftLimits | None: ...
    @property
    def move_rules(self) -> MoveRules: ...

    # the commands, as read-only members (the chip's methods, whatever their keywords)
    @property
    def snapshot(self) -> Callable[[], Snapshot]: ...
    @property
    def load_trajectory(self) -> Callable[..., Any]: ...
    @property
    def trajectory_program(self) -> Callable[..., Any]: ...
    @property
    def move_to(self) -> Callable[..., Any]: ...
    @property
    def reset_interrupts(self) -> Callable[..., Any]: ...
    @property
    def wait_for(self) -> Callable[..., Any]: ...
    @property
    def read_index_position(self) -> Callable[[], int]: ...
    @property
    def set_index_position(self) -> Callable[[], Any]: ...

#: the acceleration word of an index search (AN-706's slow turn: 0.01 count/sample^2)
INDEX_SEARCH_ACCELERATION = 655


def wait_still(chip: SupervisedChip, limit_s: float = 1.0, *, poll: float = 0.01,
               still_s: float = 0.05) -> Snapshot:
    """Read snapshots every ``poll`` seconds until the shaft has not moved (same position,
    zero velocity) for ``still_s`` seconds of the chip's clock, or ``limit_s`` have passed;
    return the last snapshot (``real_velocity != 0`` in it: not at rest in time).  Moves
    nothing and raises nothing of its own."""
    snap = chip.snapshot()
    end = snap.time + limit_s
    since: float | None = None
    while snap.time < end:
        chip.clock.sleep(poll)
        last, snap = snap, chip.snapshot()
        if snap.real_position == last.real_position and snap.real_velocity == 0:
            since = last.time if since is None else since
            if snap.time - since >= still_s:
                break
        else:
            since = None
    return snap


class VelocityRun:
    """A velocity-mode run (from :func:`run_velocity`): :meth:`check` that the shaft turns the
    way and at the speed asked, :meth:`stop` smoothly until it rests."""

    def __init__(self, chip: SupervisedChip, velocity: int, acceleration: int | None, forward: bool,
                 t0: float) -> None:
        self.chip = chip
        self.velocity = velocity  #: the 16.16 word asked for
        self.acceleration = acceleration  #: the word loaded with it (None: the one loaded before)
        self.forward = forward
        self.t0 = t0  #: the chip's clock at the STT

    def __repr__(self) -> str:
        return f"<VelocityRun {'forward' if self.forward else 'backward'} word {self.velocity}>"

    def check(self, snap: Snapshot | None = None) -> Snapshot:
        """Check a snapshot (read now when not given) against the run and return it.  From one
        count per sample of desired speed up (below that the real velocity, whole counts per
        sample, is too coarse) the shaft must turn the desired way (else a RUNAWAY) at least at
        half the desired speed (else a STALL); either stops the motor and raises MotionError."""
        s = self.chip.snapshot() if snap is None else snap
        want, got = s.desired_velocity, s.real_velocity * FIXED_ONE
        if abs(want) >= FIXED_ONE:
            if got * want < 0:
                raise self._fault(MotionFault.RUNAWAY, s,
                                  "the shaft turns the wrong way: swap the motor leads or the "
                                  "encoder's A and B channels")
            if abs(got) < abs(want) // 2:
                raise self._fault(MotionFault.STALL, s,
                                  f"the shaft turns at {got / FIXED_ONE:.4f} counts/sample, not "
                                  f"{want / FIXED_ONE:.4f}: check the amplifier, the motor and the "
                                  "encoder, or lower the speed")
        return s

    def stop(self, acceleration: int | None = None, *, rest_s: float = 1.0) -> Snapshot:
        """Smooth stop at the loaded acceleration; wait for its completion (1.5 times the
        deceleration from the speed now at ``acceleration``, default the run's, plus 1 s: a
        :class:`~lm629_host.WaitTimeout` after that), then up to ``rest_s`` for the shaft to
        rest (:func:`wait_still`); a shaft still turning then is a FOLLOWING_ERROR fault.
        Returns the snapshot at rest."""
        chip = self.chip
        acc = acceleration or self.acceleration or 1
        speed = abs(chip.snapshot().desired_velocity)
        clock_hz = chip.move_rules.clock_hz or chip.clock_hz
        decel_s = speed / max(acc, 1) * SAMPLE_CLOCKS / clock_hz
        chip.reset_interrupts(Status.TRAJECTORY_COMPLETE)  # the stop's own completion, below
        chip.load_trajectory(stop="smooth", start=True)
        chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=decel_s * 1.5 + 1.0, poll=0.001,
                      what="the smooth stop to complete")
        rest = wait_still(chip, rest_s)
        if rest.real_velocity != 0:
            raise self._fault(MotionFault.FOLLOWING_ERROR, rest,
                              "the shaft did not come to rest after the smooth stop")
        return rest

    def _fault(self, reason: MotionFault, s: Snapshot, detail: str) -> MotionError:
        return motion_fault(self.chip, reason, detail, position=s.real_position,
                            error=s.following_error)


def run_velocity(chip: SupervisedChip, velocity: int, acceleration: int | None = None, *,
                 forward: bool = True) -> VelocityRun:
    """Start velocity mode at ``velocity`` (16.16 counts/sample), with ``acceleration`` loaded
    too unless None (the chip refuses a new acceleration while the motor moves with the drive
    on, AN-706 4.6.1: leave it out to change the speed of a running motor).  The STT is checked
    (:class:`~lm629_host.CommandError`).  Returns the run to :meth:`~VelocityRun.check` and
    :meth:`~VelocityRun.stop`."""
    chip.load_trajectory(acceleration=acceleration, velocity=velocity, velocity_mode=True,
                         forward=forward, start=True)
    return VelocityRun(chip, velocity, acceleration, forward, chip.clock.now())


def search_index(chip: SupervisedChip, velocity: int, *, timeout: float = 10.0, forward: bool = True,
                 acceleration: int = INDEX_SEARCH_ACCELERATION) -> int:
    """Turn slowly in velocity mode until the encoder's index pulse is latched, then stop
    (abrupt: the index position is the point, not where the shaft ends) and wait until it
    rests; return the index position (counts).  SIP is armed and the index flag cleared first;
    the words are checked before anything moves.  A :class:`~lm629_host.WaitTimeout` when no
    index comes within ``timeout`` seconds; any error stops the motor first.

    On an axis with soft travel limits (``chip.limits``, :mod:`lm629_host.physics.limits`) the search
    is a move towards ``max`` (``min`` when not ``forward``) instead, which ends there at the
    latest: velocity mode would run past it.  Reaching the limit without an index is a
    WaitTimeout that says so.  The acceleration is brought down to the axis's cap."""
    lim = chip.limits
    goal = None
    if lim is not None and lim.has_travel:
        goal = lim.max if forward else lim.min
        if goal is None:
            raise ValueError(f"the index search runs {'forward' if forward else 'backward'} and "
                             f"the axis has no soft limit {'max' if forward else 'min'} to end "
                             "it: give it one (or search the other way)")
        acceleration = min(acceleration, lim.acceleration_word or acceleration)
        chip.trajectory_program(acceleration=acceleration, velocity=velocity, position=goal)
    else:
        chip.trajectory_program(acceleration=acceleration, velocity=velocity, velocity_mode=True)
    chip.reset_interrupts(Status.INDEX_PULSE)
    chip.set_index_position()
    with stop_on_error(chip):
        if goal is None:
            run_velocity(chip, velocity, acceleration, forward=forward)
            chip.wait_for(Status.INDEX_PULSE, timeout=timeout, poll=0.001,
                          what="the index pulse (status bit 3) while turning")
        else:
            chip.move_to(goal, velocity=velocity, acceleration=acceleration)
            status = chip.wait_for(Status.INDEX_PULSE | Status.TRAJECTORY_COMPLETE,
                                   timeout=timeout, poll=0.001,
                                   what="the index pulse (status bit 3) on the way to the soft "
                                        f"limit {goal}")
            if not status & Status.INDEX_PULSE:
                exc = WaitTimeout(Status.INDEX_PULSE, timeout, int(status))
                exc.args = (f"no index pulse on the way to the soft limit {goal} (the move "
                            f"reached it; status {int(status):02X}): search the other way or "
                            "check the encoder's index channel",)
                raise exc
        chip.reset_interrupts(Status.TRAJECTORY_COMPLETE)
        chip.load_trajectory(stop="abrupt", start=True)
        wait_still(chip, 1.0)
    return chip.read_index_position()


__all__ = ["INDEX_SEARCH_ACCELERATION", "VelocityRun", "run_velocity", "search_index",
           "wait_still"]
