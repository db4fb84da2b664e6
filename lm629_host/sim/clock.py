"""The chip model's simulated time as a :class:`~lm629_host.clock.Clock`: ``sleep`` runs the
model (and its motor) forward; a status wait goes straight to the sample where the status
changes.  Every in-process simulator waits on it; nothing sleeps on the wall clock."""

from __future__ import annotations

import copy
import math

from lm629_host.clock import Clock
from lm629_host.bus.program import WAIT_STATUS_POLL_US
from lm629_host.sim.model import ChipBus, ChipModel


class SimClock(Clock):
    """The model's simulated time.  ``sleep`` advances the model."""

    def __init__(self, model: ChipModel | ChipBus) -> None:
        self.model = model

    def now(self) -> float:
        return self.model.tick / self.model.clock_hz

    def sleep(self, seconds: float) -> None:
        self.model.advance(seconds)

    def advance_to(self, t: float) -> None:
        """Run the model up to simulated time ``t`` (seconds), rounded up to a whole clock."""
        m = self.model
        m.advance_to(math.ceil(t * m.clock_hz - 1e-6))

    def advance_until_status(self, mask: int, t: float) -> None:
        """Run the model to the first tick at which its status has a bit of ``mask`` set, or to
        simulated time ``t`` (seconds), whichever comes first.

        This is what lets a wait cost about what the model costs: instead of a status read
        every poll period, the clock goes straight to the status change, and the caller then
        reads the status for real.  With no host strobe in between, the status bits other
        than busy only ever rise (the interrupt bits are latched until RSTI, motor off is
        cleared only by STT, no sample runs while a reset completes) and they change only at a
        sample or at the end of a reset; so the first such tick is found by running copies of
        the model ahead (growing steps, then halving), and the model itself is run once, to
        that tick.  A mask with the busy bit (which falls) is not searched: the clock advances
        one poll period of the bridge."""
        m = self.model
        limit = math.ceil(t * m.clock_hz - 1e-6)
        if limit <= m.tick:
            return
        if mask & 1 or isinstance(m, ChipBus):  # (a bus: one poll period, as a bridge)
            m.advance_to(min(limit, m.tick + round(WAIT_STATUS_POLL_US * 1e-6 * m.clock_hz)))
            return
        if m.status & mask:
            return
        # candidates: the sample ticks base + k * S (interrupt bits rise at samples); the end
        # of a reset is the one change off that grid, found at the next grid point or `limit`
        S = m.sample_clocks
        base = m.next_sample
        probe = _clone(m)
        k_lo, k, step = -1, 0, 1  # k_lo: the last grid point known clear (-1: now)
        while True:  # growing steps on one copy
            at = base + k * S
            if at >= limit:
                probe.advance_to(limit)
                if not probe.status & mask:
                    m.advance_to(limit)
                    return
                k_hi = (limit - base) // S + 1  # the grid point past the limit stands for it
                break
            probe.advance_to(at)
            if probe.status & mask:
                k_hi = k
                break
            k_lo, k = k, k + step
            step += step // 4 + 1
        # halving: the copy at k_lo goes on while it finds the status clear; when it finds it
        # set, the model itself goes to k_lo and a fresh copy starts from there
        half: ChipModel | None = None
        while k_hi - k_lo > 1:
            mid = (k_lo + k_hi) // 2
            if half is None:
                if k_lo >= 0:
                    m.advance_to(base + k_lo * S)
                half = _clone(m)
            half.advance_to(base + mid * S)
            if half.status & mask:
                k_hi, half = mid, None
            else:
                k_lo = mid
        m.advance_to(min(limit, base + k_hi * S))


def _clone(m: ChipModel) -> ChipModel:
    """A copy of the model to run ahead (its command record and violations left out)."""
    return copy.deepcopy(m, {id(m.history): [], id(m.violations): []})
