"""Waiting for a status flag (:meth:`LM629.wait_for <lm629_host.LM629.wait_for>`) on the
transport's clock: on the far side where the transport can (``Op.WAIT_STATUS``), else by
polling at a rate set by the wait itself.

Where the transport runs the wait on its far side (the simulators, a bridge whose HELLO says
so), the wait is one exchange: up to 65 s at a time on a simulator, which goes straight to the
status change and reads it for real; 0.25 s at a time on a wall clock, so that Ctrl-C (held
while a program runs) still stops a motor promptly; shorter than a bridge's failsafe timeout.
Otherwise the host polls: every ``poll`` seconds when given, else from 1 ms up to a twentieth
of the time waited so far (:func:`poll_interval`), not a fixed 1 ms across the link.
"""

from __future__ import annotations

import math
from typing import Protocol

from lm629_host.bus.opcodes import Status
from lm629_host.bus.program import WAIT_STATUS_MAX_MS, Program, ProgramResult
from lm629_host.clock import Clock, WallClock
from lm629_host.errors import ArgumentError, WaitTimeout, check_int
from lm629_host.transports.base import Transport

#: the longest far-side wait per exchange on a wall clock (Ctrl-C is held while a program runs)
WAIT_STATUS_WALL_CHUNK_MS = 250
#: host polling of a wait: from 1 ms, then this fraction of the time waited so far, at most
#: POLL_MAX_S: a change is seen at most ~5 % late, and a 10 s wait costs ~280 reads, not 10,000
POLL_MIN_S, POLL_FRACTION, POLL_MAX_S = 1e-3, 0.05, 0.05


class WaitingChip(Protocol):
    """What a wait needs of its chip (an :class:`~lm629_host.LM629`)."""

    transport: Transport

    @property
    def clock(self) -> Clock: ...

    def program(self) -> Program: ...

    def run(self, program: Program) -> ProgramResult: ...

    def read_status(self) -> Status: ...


def poll_interval(waited_s: float) -> float:
    """The host's status poll period after ``waited_s`` of a wait (no far-side wait)."""
    return min(POLL_MAX_S, max(POLL_MIN_S, waited_s * POLL_FRACTION))


def wait_for(chip: WaitingChip, flags: Status | int, timeout: float, poll: float | None,
             what: str | None) -> Status:
    """:meth:`LM629.wait_for <lm629_host.LM629.wait_for>`: the status once any of ``flags``
    is set, or :class:`WaitTimeout` after ``timeout`` seconds on the chip's clock."""
    value = Status(check_int("flags", int(flags), 1, 0xFF))
    if not timeout > 0:
        raise ArgumentError("timeout", timeout, f"timeout={timeout} must be positive (seconds)")
    if poll is not None and not poll > 0:
        raise ArgumentError("poll", poll, f"poll={poll} must be positive (seconds)")
    clock = chip.clock
    start = clock.now()
    deadline = start + timeout
    far = chip.transport.has_wait_status
    chunk_ms = (WAIT_STATUS_WALL_CHUNK_MS if isinstance(clock, WallClock)
                else WAIT_STATUS_MAX_MS)
    limit = chip.transport.far_wait_limit_s
    if limit is not None:  # a bridge's failsafe: each wait shorter than its timeout
        chunk_ms = min(chunk_ms, max(1, int(limit * 1e3)))
    while True:
        if far:
            ms = min(chunk_ms, max(0, math.ceil((deadline - clock.now()) * 1e3)))
            status = Status(chip.run(chip.program().wait_status(int(value), ms)).statuses[-1])
        else:
            status = chip.read_status()
        if status & value:
            return status
        now = clock.now()
        if now >= deadline:
            raise WaitTimeout(value, timeout, int(status), what=what)
        if not far:
            step = poll if poll is not None else poll_interval(now - start)
            clock.sleep(min(step, deadline - now))


class WaitsMixin:
    """:class:`~lm629_host.LM629`'s wait for a status flag (:func:`wait_for`)."""

    def wait_for(self: WaitingChip, flags: Status | int, timeout: float = 10.0,
                 poll: float | None = None, *, what: str | None = None) -> Status:
        """Wait until any of ``flags`` is set in the status byte; return the status.

        Waits on the transport's clock (simulated time on ``sim://``), on the far side where
        the transport can (:mod:`lm629_host.chip.waiting`).  Raises :class:`WaitTimeout` after
        ``timeout`` seconds (its ``what``: ``what`` when given, the words a person reads, else
        the flags' names); ``poll``: the host's poll period where it polls.

        A flag raised *earlier* satisfies it at once: the chip keeps its flags until RSTI
        clears them.  After a first move, ``load_trajectory(..., start=True)`` then
        ``wait_for(Status.TRAJECTORY_COMPLETE)`` returns immediately while the second move
        runs.  Clear the flag first (:meth:`reset_interrupts`), or better, move with
        :meth:`move_to` and ``Move.wait()``, which clear the move's flags in the program that
        starts it and wait until the shaft is at rest on the target.
        """
        return wait_for(self, flags, timeout, poll, what)
