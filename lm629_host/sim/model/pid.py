"""The chip's PID filter, in its own word sizes (AN-706 5.2.3 - 5.2.5).

u(n) = kp e(n) + ki sum(e) + kd [e(n') - e(n'-1)], computed as the chip computes it:

* e(n) saturated to 16 bits;
* each 16 x 16 product keeps its low 16 bits; a product that overflows them saturates
  (7FFF / 8000) [model choice 21];
* the error sum is kept to 24 bits (saturating), its top 16 bits multiply ki, and the term is
  limited to +/- il; once the term has reached the limit, an error that would push the sum
  further is not summed (AN-706 4.5.2) [model choice 21: "reached" includes il = 0];
* the derivative difference is taken every ds + 1 samples; kd x difference is held and added
  at every sample;
* the three 16-bit terms add into a 16-bit result, saturated on overflow.

The output stage takes the top 8 bits (8-bit mode, the LM629's PWM) or the top 12 bits
(LM628 12-bit mode) of that result [model choice 22].  The model choices are listed in one
place, the docstring of :mod:`lm629_host.sim.model`.
"""

from __future__ import annotations

from dataclasses import dataclass

SUM_MAX = (1 << 23) - 1  #: 24-bit signed error sum
SUM_MIN = -(1 << 23)


def sat16(value: int) -> int:
    """A signed value saturated to 16 bits."""
    return 32767 if value > 32767 else (-32768 if value < -32768 else value)


@dataclass
class PIDState:
    """What the filter remembers between samples (all zero after reset)."""

    error_sum: int = 0  #: 24-bit signed sum of e(n)
    last_error: int = 0  #: e(n'-1): the error at the previous derivative sample
    derivative: int = 0  #: kd x difference, held between derivative samples (16-bit)
    countdown: int = 0  #: samples until the next derivative sample
    integral: int = 0  #: the limited ki term (what RDSUM reads)
    output: int = 0  #: u(n), 16-bit signed


def pid_step(s: PIDState, e: int, kp: int, ki: int, kd: int, il: int, ds: int) -> int:
    """One sample of the filter for the (unsaturated) position error ``e``; returns u(n)."""
    e = sat16(e)
    # integral: 24-bit sum, top 16 bits x ki, limited to il; no wind-up past the limit
    total = s.error_sum + e
    total = SUM_MAX if total > SUM_MAX else (SUM_MIN if total < SUM_MIN else total)
    held = ki * (s.error_sum >> 8)
    if (held >= il or held <= -il) and abs(total) > abs(s.error_sum):
        total = s.error_sum  # already at the limit: an error pushing further is not summed
    term = ki * (total >> 8)
    s.error_sum = total
    term = il if term > il else (-il if term < -il else term)
    s.integral = term
    # derivative: sampled every ds + 1 samples, held in between
    if s.countdown == 0:
        s.derivative = sat16(kd * sat16(e - s.last_error))
        s.last_error = e
        s.countdown = ds
    else:
        s.countdown -= 1
    u = sat16(sat16(kp * e) + term + s.derivative)
    s.output = u
    return u


def output_code(u: int, twelve_bit: bool) -> int:
    """The signed output word: top 8 bits (-128..127) or top 12 bits (-2048..2047) of u."""
    return u >> 4 if twelve_bit else u >> 8


def lm628_dac_code(out: int, twelve_bit: bool) -> int:
    """LM628 offset binary: zero drive is 80 (8-bit) or 800 (12-bit)."""
    return out + (0x800 if twelve_bit else 0x80)


def lm629_pwm(out: int) -> tuple[int, int]:
    """LM629 sign (pin 18, 1 = negative) and magnitude 0..128 (duty = magnitude / 128)."""
    return (1, -out) if out < 0 else (0, out)
