"""One keep-alive for every far-side watchdog: the bridge's link failsafe and the FT232H's
heartbeat pin (an external watchdog's input).

A :class:`KeepAlive` is a period and a ``feed`` callable (which sends only when the far side
has not heard the host for that long: any traffic counts).  On the wall clock it calls ``feed``
from its own thread, while the process lives; on a simulated clock time passes only while the
host sleeps on the transport's clock or waits for an answer, so :class:`FeedingClock` calls it
between the steps of a sleep instead, and the sleep still ends exactly when it was asked to.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from lm629_host.clock import Clock

log = logging.getLogger("lm629_host.bus")

#: below this a simulated sleep's remainder is rounding, not time (1 ns: a clock of 1 GHz)
_RESOLUTION_S = 1e-9


class KeepAlive:
    """``feed`` every ``period_s`` / 4 while it runs; ``feed`` decides whether a feed is due.

    ``worst_gap_s`` is the longest the wall-clock thread went between two turns (how late the
    host's scheduler let it run: a busy or paused machine shows here), ``gaps`` the count of
    turns later than ``period_s``.  An exception from ``feed`` is logged, never raised: the
    thread that keeps a far side fed must not end the process."""

    def __init__(self, period_s: float, feed: Callable[[], None], what: str,
                 due_at: Callable[[], float] | None = None) -> None:
        if period_s <= 0:
            raise ValueError(f"keep-alive period {period_s} must be > 0")
        self.period_s = period_s
        self.feed = feed
        self.what = what
        #: when the next feed falls due (the far side heard the host last + the period), on
        #: the transport's clock: a simulated sleep wakes exactly then
        self.due_at = due_at
        self.worst_gap_s = 0.0
        self.gaps = 0
        #: the latest turn later than the period (s; 0: none yet): how long the host was held
        self.last_stall_s = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def tick(self) -> None:
        """One turn: ``feed()`` (which sends only when a feed is due)."""
        try:
            self.feed()
        except Exception as exc:  # noqa: BLE001 - a keep-alive must never kill the process
            log.debug("%s: %s", self.what, exc)

    def start(self) -> None:
        """Run on the wall clock, from a daemon thread, until :meth:`stop`."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._loop, daemon=True,
                                            name=f"lm629 {self.what}")
            self._thread.start()

    def _loop(self) -> None:
        step = self.period_s / 4
        last = time.monotonic()
        while not self._stop.wait(step):
            now = time.monotonic()
            gap, last = now - last, now
            if gap > self.worst_gap_s:
                self.worst_gap_s = gap
            if gap > self.period_s:
                self.gaps += 1
                self.last_stall_s = gap
            self.tick()

    def stop(self) -> None:
        """End the thread (idempotent); a simulated clock's sleeps stop feeding too."""
        self._stop.set()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()


class FeedingClock(Clock):
    """A simulated clock whose ``sleep`` turns a :class:`KeepAlive` on the way: time passes on
    the far side only while the host sleeps on this clock or waits for an answer, so the
    keep-alive of a simulated link lives here instead of in a thread.  The sleep wakes when a
    feed falls due (``due_at``, else every period), feeds, and still ends at
    ``now() + seconds`` exactly: a feed is one write, answered later, so it adds nothing to
    the sleep (the answer arrives during the next step)."""

    def __init__(self, clock: Clock, keepalive: KeepAlive) -> None:
        self._clock = clock
        self.keepalive = keepalive
        self.now = clock.now  # type: ignore[method-assign]  # no wrapper on the hot path

    @property
    def inner(self) -> Clock:
        """The clock this one wraps."""
        return self._clock

    def now(self) -> float:
        return self._clock.now()

    def sleep(self, seconds: float) -> None:
        ka = self.keepalive
        clock = self._clock
        if ka.stopped or seconds <= 0:
            clock.sleep(seconds)
            return
        end = clock.now() + seconds
        while True:
            ka.tick()
            now = clock.now()
            if now >= end - _RESOLUTION_S:  # a float sum may stop a hair short of the end
                return
            due = ka.due_at() if ka.due_at is not None else now + ka.period_s
            if due > now + _RESOLUTION_S:
                step = due - now
            elif due > now - ka.period_s:  # due, but a clock that rounds kept it a hair short
                step = ka.period_s / 1000
            else:  # long due and not fed (nothing to feed now): do not spin
                step = ka.period_s
            clock.sleep(min(step, end - now))

    def __getattr__(self, name: str) -> object:
        return getattr(self._clock, name)


__all__ = ["FeedingClock", "KeepAlive"]
