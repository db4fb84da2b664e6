"""Time, injected: everything that waits (busy polls, the reset wait, ``wait_for``, moves)
waits on a :class:`Clock` that its transport owns: the wall clock on hardware, the simulated
clock on a simulator, so that nothing in a simulation sleeps on the wall clock."""

from __future__ import annotations

import abc
import time

#: how early a time still counts as reached: a clock's own rounding of a sleep to its due
#: time (a simulated clock counts whole chip clocks) must not put a due thing off, nor make
#: it "too soon"
ROUNDING_S = 1e-6


class Clock(abc.ABC):
    """A time base: ``now()`` in seconds and ``sleep(seconds)``."""

    @abc.abstractmethod
    def now(self) -> float: ...

    @abc.abstractmethod
    def sleep(self, seconds: float) -> None: ...


class WallClock(Clock):
    """Real time, for transports that reach real hardware."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


__all__ = ["Clock", "ROUNDING_S", "WallClock"]
