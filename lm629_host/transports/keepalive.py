"""One keep-alive for every far-side watchdog: the bridge's link failsafe and the FT232H's
heartbeat pin (an external watchdog's input).

The protocol lives here, once; a watchdog's owner only says what to send and when the far side
last heard the host:

* **when a feed is due**: the far side last heard the host (``last_heard()``: any traffic
  counts) a period ago, within the clock's rounding (:data:`~lm629_host.clock.ROUNDING_S`);
* **when to skip it**: while ``busy`` is held by someone else (a request under way, a bus
  program: the far side hears the host already), never waiting for it; ``unlocked()`` says
  when a feed goes out without it (a recording streams: the reader holds the line, and the
  bridge takes a feed between its rows);
* **which clock**: on the wall clock a daemon thread turns it while the process lives; on a
  simulated clock time passes only while the host sleeps on the transport's clock or waits for
  an answer, so :class:`FeedingClock` turns it between the steps of a sleep instead (the sleep
  still ends exactly when it was asked to), and a recording's wait turns it at each step
  (:meth:`KeepAlive.turn` as the wait's ``tick``);
* **a feed that fails** is told once, at WARNING, with its cause (:attr:`KeepAlive.failure`,
  which a trip message quotes), and again only after a feed went out since.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Protocol

from lm629_host.clock import ROUNDING_S, Clock

log = logging.getLogger("lm629_host.bus")


class _Busy(Protocol):
    def acquire(self, blocking: bool = ...) -> bool: ...
    def release(self) -> None: ...


class Kept(Protocol):
    """What a keep-alive needs of the transport it keeps alive (its time base; the
    transport's clock, which a simulated one's keep-alive wraps)."""

    clock: Clock

    @property
    def time_base(self) -> Clock: ...

    @property
    def on_wall_clock(self) -> bool: ...


def on_wall_clock(transport: Kept) -> bool:
    """True when a keep-alive on ``transport`` runs from a thread on the wall clock (hardware),
    False when it runs in the steps of the simulated clock's sleeps: the one place that
    decides, for the keep-alive and for what its owner sends."""
    return transport.on_wall_clock


class KeepAlive:
    """Feed a far side every ``period_s`` of silence: ``send()`` when :meth:`due`, skipped
    while ``busy`` is held elsewhere (unless ``unlocked()``).  ``before()`` runs at every
    turn, due or not (the link's PROFILE top-ups, a trip heard and not told yet).

    ``worst_gap_s`` is the longest the wall-clock thread went between two turns (how late the
    host's scheduler let it run: a busy or paused machine shows here), ``gaps`` the count of
    turns later than ``period_s``, ``last_stall_s`` the latest such turn.  A ``send`` that
    raises is told once at WARNING, never raised: the thread that keeps a far side fed must
    not end the process."""

    def __init__(self, period_s: float, send: Callable[[], None], what: str, *,
                 last_heard: Callable[[], float], clock: Clock, busy: _Busy | None = None,
                 unlocked: Callable[[], bool] | None = None,
                 before: Callable[[], None] | None = None) -> None:
        if period_s <= 0:
            raise ValueError(f"keep-alive period {period_s} must be > 0")
        self.period_s = period_s
        self.send = send
        self.what = what
        self.last_heard = last_heard
        self.clock = clock
        self.busy = busy
        self.unlocked = unlocked
        self.before = before
        self.worst_gap_s = 0.0
        self.gaps = 0
        #: the latest turn later than the period (s; 0: none yet): how long the host was held
        self.last_stall_s = 0.0
        #: why the last feed failed ("OSError: ..."), None once one went out since
        self.failure: str | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ the protocol
    def due_at(self) -> float:
        """When the next feed falls due, on the transport's clock (a simulated sleep wakes
        exactly then)."""
        return self.last_heard() + self.period_s

    def due(self) -> bool:
        """The far side has not heard the host for a period (within the clock's rounding)."""
        return self.clock.now() >= self.due_at() - ROUNDING_S

    def turn(self) -> None:
        """One turn: ``before()``, then a feed if one is due and nobody else holds ``busy``
        (or ``unlocked()`` says it goes out without it)."""
        if self._stop.is_set():
            return
        try:
            if self.before is not None:
                self.before()
            if not self.due():
                return
            busy = self.busy
            if busy is None or (self.unlocked is not None and self.unlocked()):
                self._feed()
                return
            if not busy.acquire(blocking=False):
                return  # a request or a program under way: the far side hears the host
            try:
                self._feed()
            finally:
                busy.release()
        except Exception as exc:  # noqa: BLE001 - a keep-alive must never kill the process
            self._failed(exc)

    def _feed(self) -> None:
        self.send()
        self.failure = None

    def _failed(self, exc: Exception) -> None:
        cause = f"{type(exc).__name__}: {exc}"
        if self.failure is None:
            log.warning("%s: a feed failed (%s); the far side's watchdog may stop the axes",
                        self.what, cause)
        self.failure = cause

    # ------------------------------------------------------------------ which clock
    def start(self, transport: Kept) -> None:
        """Keep the far side fed from now on: a daemon thread on the wall clock, the steps of
        every sleep on ``transport``'s clock on a simulated one (:class:`FeedingClock`)."""
        if on_wall_clock(transport):
            if self._thread is None:
                self._thread = threading.Thread(target=self._loop, daemon=True,
                                                name=f"lm629 {self.what}")
                self._thread.start()
        else:
            transport.clock = FeedingClock(transport.time_base, self)

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
            self.turn()

    def stop(self) -> None:
        """End the thread (idempotent); a simulated clock's sleeps stop feeding too."""
        self._stop.set()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()


class FeedingClock(Clock):
    """A simulated clock whose ``sleep`` turns a :class:`KeepAlive` on the way: the sleep
    wakes when a feed falls due, feeds, and still ends at ``now() + seconds`` exactly (within
    the clock's rounding): a feed is one write, answered later, so it adds nothing to the sleep
    (the answer arrives during the next step)."""

    def __init__(self, clock: Clock, keepalive: KeepAlive) -> None:
        while isinstance(clock, FeedingClock):  # one keep-alive a clock: the new one
            clock = clock.inner
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
            ka.turn()
            now = clock.now()
            if now >= end - ROUNDING_S:  # within the clock's rounding of the end: the rest,
                if now < end:            # once (a float sum may stop a hair short), so that
                    clock.sleep(end - now)  # the sleep ends where it was asked to end
                return
            due = ka.due_at()
            if due > now + ROUNDING_S:
                step = due - now
            elif due > now - ka.period_s:  # due, but a clock that rounds kept it a hair short
                step = ka.period_s / 1000
            else:  # long due and not fed (nothing to feed now): do not spin
                step = ka.period_s
            clock.sleep(min(step, end - now))

    def __getattr__(self, name: str) -> object:
        return getattr(self._clock, name)


__all__ = ["FeedingClock", "KeepAlive", "on_wall_clock"]
