"""Physical units <-> the chip's raw words.

The chip counts position in encoder counts (4 per encoder line, quadrature) and time in samples
of ``T = 2048 / fCLK`` (256 us at 8 MHz).  Velocity and acceleration are unsigned 16.16 fixed
point in counts/sample and counts/sample^2 (65536 = 1).  Formulas: AN-868 ("velocity word =
lines x 4 x T x rpm / 60 x 65536", "acceleration word = lines x 4 x T^2 x rev/s^2 x 65536") and
AN-706 5.3 (trapezoid); PID scaling: AN-706 5.2.

Rounding: the conversions to raw words round to the nearest integer.  The worked examples do
not agree among themselves (AN-706 5.3 discards the fraction of 372,899.8; the datasheet's
0006D1EC rounds 6.82 x 65536 up), so the nearest word is the honest choice; the inverses are
exact, so ``Scale.rpm(Scale.velocity(x))`` shows what the chip will really run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lm629_host.errors import ArgumentError, check_int
from lm629_host.physics.pid import sample_period_s
from lm629_host.physics.plan import plan
from lm629_host.bus.opcodes import (
    ACCELERATION_MAX,
    COEFFICIENT_MAX,
    DERIVATIVE_INTERVAL_MAX,
    FIXED_ONE,
    POSITION_MAX,
    NOMINAL_CLOCK_HZ,
    POSITION_MIN,
    VELOCITY_MAX,
)


def to_fixed(value: float) -> int:
    """A real number as a 16.16 word (nearest)."""
    return round(value * FIXED_ONE)


def from_fixed(word: int) -> float:
    return word / FIXED_ONE


def _positive(name: str, value: float) -> float:
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ArgumentError(name, value, f"{name}={value!r} must be a finite number")
    if value <= 0:
        raise ArgumentError(name, value, f"{name}={value} must be greater than 0")
    return float(value)


def _word(name: str, value: float, lo: int, hi: int, unit: str) -> int:
    word = round(value)
    if not lo <= word <= hi:
        raise ValueError(f"{name} gives raw word {word}, outside the chip's range {lo}..{hi} "
                         f"({unit})")
    return word


@dataclass(frozen=True)
class Trapezoid:
    """A position move as the chip's raw words, and what the chip will really do with them."""

    position: int  #: counts
    velocity: int  #: 16.16 counts/sample
    acceleration: int  #: 16.16 counts/sample^2
    accel_time_s: float  #: time to reach ``velocity`` at ``acceleration`` (from the raw words)
    duration_s: float  #: whole move with the raw words (triangle if velocity is not reached)


@dataclass(frozen=True)
class Scale:
    """Conversions for one axis between the units a user thinks in and the chip's words:
    positions in revolutions <-> counts (4 per encoder line), velocities in rpm <-> 16.16
    counts/sample words, accelerations in rev/s^2 <-> 16.16 counts/sample^2 words, times in
    seconds <-> samples (2048 clocks each: 256 us at the default 8 MHz)."""

    encoder_lines: int
    clock_hz: float = NOMINAL_CLOCK_HZ

    def __post_init__(self) -> None:
        check_int("encoder_lines", self.encoder_lines, 1, 1_000_000)
        if not 1_000_000 <= self.clock_hz <= 8_000_000:
            raise ValueError(f"clock_hz={self.clock_hz} is outside the chip's 1-8 MHz")

    @property
    def counts_per_rev(self) -> int:
        """Counts per revolution: 4 x encoder lines (quadrature decoding)."""
        return 4 * self.encoder_lines

    @property
    def sample_period(self) -> float:
        """Seconds per sample, 2048 / fCLK."""
        return sample_period_s(self.clock_hz)

    # -- to raw words ------------------------------------------------------------------------
    def position(self, revolutions: float) -> int:
        """Revolutions -> counts."""
        return _word("position", revolutions * self.counts_per_rev, POSITION_MIN, POSITION_MAX,
                     "counts")

    def velocity(self, rpm: float) -> int:
        """rpm -> 16.16 counts/sample."""
        return _word("velocity", self.counts_per_rev * self.sample_period * rpm / 60 * FIXED_ONE,
                     0, VELOCITY_MAX, "16.16 counts/sample")

    def acceleration(self, rev_per_s2: float) -> int:
        """rev/s^2 -> 16.16 counts/sample^2."""
        t = self.sample_period
        return _word("acceleration", self.counts_per_rev * t * t * rev_per_s2 * FIXED_ONE,
                     0, ACCELERATION_MAX, "16.16 counts/sample^2")

    # -- from raw words ----------------------------------------------------------------------
    def revolutions(self, counts: int) -> float:
        """Counts -> revolutions."""
        return counts / self.counts_per_rev

    def rpm(self, velocity_word: int) -> float:
        """16.16 counts/sample -> rpm."""
        return velocity_word / FIXED_ONE / self.sample_period / self.counts_per_rev * 60

    def rev_per_s2(self, acceleration_word: int) -> float:
        """16.16 counts/sample^2 -> rev/s^2."""
        t = self.sample_period
        return acceleration_word / FIXED_ONE / (t * t) / self.counts_per_rev

    def seconds(self, samples: float) -> float:
        """Samples -> seconds."""
        return samples * self.sample_period

    def samples(self, seconds: float) -> float:
        """Seconds -> samples."""
        return seconds / self.sample_period

    # -- moves -------------------------------------------------------------------------------
    def trapezoid(self, revolutions: float, duration_s: float, accel_time_s: float) -> Trapezoid:
        """The words for a move of ``revolutions`` in ``duration_s`` seconds, spending
        ``accel_time_s`` accelerating and as long decelerating (AN-706 5.3)."""
        duration_s = _positive("duration_s", duration_s)
        accel_time_s = _positive("accel_time_s", accel_time_s)
        if 2 * accel_time_s > duration_s:
            raise ValueError(f"accel_time_s={accel_time_s} is more than half of duration_s="
                             f"{duration_s}: acceleration and deceleration would overlap")
        distance = abs(revolutions) * self.counts_per_rev
        cruise_samples = self.samples(duration_s - accel_time_s)  # area of the trapezoid
        ramp_samples = self.samples(accel_time_s)
        v = distance / cruise_samples  # counts/sample
        a = v / ramp_samples
        position = self.position(revolutions)
        velocity = _word("velocity", v * FIXED_ONE, 0, VELOCITY_MAX, "16.16 counts/sample")
        acceleration = _word("acceleration", a * FIXED_ONE, 0, ACCELERATION_MAX,
                             "16.16 counts/sample^2")
        if acceleration == 0:
            raise ValueError(f"the acceleration of this move ({a * FIXED_ONE:.3g} raw) rounds to "
                             "0: the chip would never move. Use a shorter ramp or a longer move")
        return Trapezoid(position, velocity, acceleration,
                         *self.profile_times(abs(position), velocity, acceleration))

    def profile_times(self, distance: int, velocity: int, acceleration: int) -> tuple[float, float]:
        """(ramp time, whole move time) in seconds of a symmetric move with these raw words
        (:func:`lm629_host.physics.plan.plan`: a triangle when the velocity is never reached)."""
        p = plan(distance, velocity, acceleration)
        return self.seconds(p.accel_samples), self.seconds(p.samples)

    # -- PID scaling (AN-706 5.2) --------------------------------------------------------------
    def pid_to_chip(self, Kp: float = 0.0, Ki: float = 0.0, Kd: float = 0.0, *,  # noqa: N803 - Kp, Ki, Kd as in AN-706's formulas
                    derivative_interval: int = 1, output_bits: int = 8) -> dict[str, int]:
        """Continuous-domain gains (output LSB per count, per count-second, per count/second)
        -> the chip's kp, ki, kd.  8-bit output (LM629, LM628 8-bit): kp = 256 Kp,
        kd = 256 Kd / Ts, ki = 65536 Ki T; 12-bit (LM628): 16, 16 and 4096."""
        check_int("derivative_interval", derivative_interval, 1, DERIVATIVE_INTERVAL_MAX)
        pk, ik = _pid_factors(output_bits)
        ts = derivative_interval * self.sample_period
        out = {"kp": pk * Kp, "ki": ik * Ki * self.sample_period, "kd": pk * Kd / ts}
        return {k: _word(k, v, 0, COEFFICIENT_MAX, "0..7FFF") for k, v in out.items()}

    def pid_from_chip(self, kp: int = 0, ki: int = 0, kd: int = 0, *, derivative_interval: int = 1,
                      output_bits: int = 8) -> dict[str, float]:
        """The inverse of :meth:`pid_to_chip`: continuous-domain Kp, Ki, Kd."""
        check_int("derivative_interval", derivative_interval, 1, DERIVATIVE_INTERVAL_MAX)
        pk, ik = _pid_factors(output_bits)
        ts = derivative_interval * self.sample_period
        return {"Kp": kp / pk, "Ki": ki / (ik * self.sample_period), "Kd": kd * ts / pk}


def _pid_factors(output_bits: int) -> tuple[int, int]:
    if output_bits == 8:
        return 256, 65536
    if output_bits == 12:
        return 16, 4096
    raise ValueError(f"output_bits={output_bits} must be 8 or 12")
