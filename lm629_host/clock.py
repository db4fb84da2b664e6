"""Time, injected: everything that waits (busy polls, the reset wait, ``wait_for``, moves)
waits on a :class:`Clock` that its transport owns: the wall clock on hardware, the simulated
clock on a simulator, so that nothing in a simulation sleeps on the wall clock."""

from __future__ import annotations

import abc
import time


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


__all__ = ["Clock", "WallClock"]
