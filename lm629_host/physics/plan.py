"""The trapezoid (or triangle) a position move makes: the one planner every layer uses.

The chip's generator (AN-706 5.3) accelerates at the acceleration word up to the velocity
word, cruises, and brakes at the same rate so as to land on the target.  When the distance
is too short to reach the velocity (``v^2 > d a``: the two ramps would overlap) it turns
round half-way: a triangle, whose peak speed is ``sqrt(d a)``.  Units are the chip's:
counts, and the 16.16 words of counts/sample and counts/sample^2 as LTRJ carries them;
seconds only through a clock rate (a sample is 2048 clocks).

The times are in continuous arithmetic.  The chip (and its model,
``lm629_host/sim/model/trajectory.py``) runs whole samples, its velocity stepping by the
acceleration word: its trajectory completes between one sample before and exactly at the
continuous duration (``tests/physics/test_plan.py`` checks both against the model).  A caller that
times a move from its STT adds the sample the STT waits for, and whatever margin it wants,
explicitly (``margin_samples``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lm629_host.bus.opcodes import FIXED_ONE, SAMPLE_CLOCKS


@dataclass(frozen=True)
class Plan:
    """A symmetric move of ``distance`` counts with the 16.16 ``velocity`` and
    ``acceleration`` words: the times of its three phases, in samples."""

    distance: float  #: counts, >= 0 (a path's length need not be whole)
    velocity: float  #: 16.16 counts/sample, the cruise speed asked for (an LTRJ word)
    acceleration: float  #: 16.16 counts/sample^2 (a word; a model's limit may be fractional)

    @property
    def triangle(self) -> bool:
        """The velocity is never reached: the ramps meet half-way (``v^2 > d a``)."""
        v, a = self.velocity, self.acceleration
        return v * v > self.distance * a * FIXED_ONE

    @property
    def peak(self) -> float:
        """The top speed reached, counts/sample: the velocity, or ``sqrt(d a)`` (triangle)."""
        if self.triangle:
            return math.sqrt(self.distance * self.acceleration / FIXED_ONE)
        return self.velocity / FIXED_ONE

    @property
    def accel_samples(self) -> float:
        """Samples spent accelerating (as many are spent braking)."""
        if self.distance == 0:
            return 0.0
        if self.acceleration <= 0 or self.velocity <= 0:
            return math.inf
        return self.peak / (self.acceleration / FIXED_ONE)

    @property
    def decel_samples(self) -> float:
        return self.accel_samples

    @property
    def cruise_samples(self) -> float:
        """Samples at the velocity: the distance the ramps leave, at that speed (0: a triangle)."""
        if self.distance == 0 or self.triangle:
            return 0.0
        if self.acceleration <= 0 or self.velocity <= 0:
            return math.inf
        v = self.velocity / FIXED_ONE
        return (self.distance - v * self.accel_samples) / v

    @property
    def samples(self) -> float:
        """The whole move: ``d/v + v/a`` (trapezoid), ``2 sqrt(d/a)`` (triangle)."""
        return self.accel_samples + self.cruise_samples + self.decel_samples

    def seconds(self, clock_hz: float, margin_samples: float = 0.0) -> float:
        """The whole move, plus ``margin_samples``, in seconds at the chip's ``clock_hz``."""
        return (self.samples + margin_samples) * SAMPLE_CLOCKS / clock_hz

    def accel_seconds(self, clock_hz: float) -> float:
        return self.accel_samples * SAMPLE_CLOCKS / clock_hz

    def travelled(self, k: float) -> float:
        """Counts travelled ``k`` samples after the start, 0..distance."""
        d = self.distance
        if k <= 0 or d == 0:
            return 0.0
        a = self.acceleration / FIXED_ONE
        t1 = self.accel_samples
        t2 = t1 + self.cruise_samples
        if k <= t1:
            x = a * k * k / 2
        elif k <= t2:
            x = self.peak * t1 / 2 + self.peak * (k - t1)
        else:
            x = d - a * max(0.0, t2 + t1 - k) ** 2 / 2
        return min(float(d), x)

    def desired(self) -> list[int]:
        """The desired position (whole counts from the start) at each sample until the
        target, as a generator in the chip's fixed point makes it: the speed steps by the
        acceleration word up to the velocity word, and brakes by it so as to land on the
        target (the chip's own sequence to within a count)."""
        target = round(self.distance) * FIXED_ONE
        a, vmax = int(self.acceleration), int(self.velocity)
        p = v = 0
        out: list[int] = []
        while p < target:
            left = target - p
            if v * v // (2 * a) + v >= left:
                v = max(v - a, min(a, left))  # braking; the last steps land on the target
            else:
                v = min(v + a, vmax)
            v = min(v, left)
            p += v
            out.append(p // FIXED_ONE)
        return out


def plan(distance: float, velocity: float, acceleration: float) -> Plan:
    """The plan of a move of ``distance`` counts (either way: its size counts) with the
    16.16 ``velocity`` and ``acceleration`` words.  A zero word never arrives (``inf``)."""
    return Plan(abs(distance), velocity, acceleration)


__all__ = ["Plan", "plan"]
