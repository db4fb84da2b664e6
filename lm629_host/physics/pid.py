"""The LM628/LM629 PID filter, one sample at a time, in the chip's own word sizes.

The one home of the filter's arithmetic (AN-706 5.2.3 - 5.2.5) and of the constants that go
with it.  Three parts of the package need it and use this module: the chip model's readable
sample loop (``sim/model/motion.py``), the tuner's predictor (:func:`lm629_host.physics.predict.simulate`)
and the step plot's rebuilt output (:func:`lm629_host.bench.plot.rebuilt_output`).  The model's
flattened Python loop (``sim/model/fastloop.py``) writes the same arithmetic inline for speed,
and ``physics/sample_c.h`` is its one home in C, for the model's ``_fastloop.c`` and the
predictor's ``_predict.c``; ``tests/physics/test_pid.py`` checks the model's loops against this
module bit for bit, ``tests/physics/test_predict_fast.py`` the C predictor against the Python
one that calls it.  Nothing
here imports the simulator: the driver uses this module on a real board too.

u(n) = kp e(n) + ki sum(e) + kd [e(n') - e(n'-1)], computed as the chip computes it:

* e(n) saturated to 16 bits;
* each 16 x 16 product keeps its low 16 bits; a product that overflows them saturates
  (7FFF / 8000);
* the error sum is kept to 24 bits (saturating), its top 16 bits multiply ki, and the term is
  limited to +/- il; once the term has reached the limit, an error that would push the sum
  further is not summed (AN-706 4.5.2; "reached" includes il = 0);
* the derivative difference is taken every ``ds`` samples (the derivative interval); kd x difference is held and added
  at every sample;
* the three 16-bit terms add into a 16-bit result, saturated on overflow.

The output stage takes the top 8 bits (8-bit mode: the LM629's sign-magnitude PWM, the LM628's
8-bit DAC) or the top 12 bits (LM628 12-bit mode) of that result, by arithmetic shift.  Where
the datasheet is silent these are choices, listed as model choices 21 and 22 in the docstring
of :mod:`lm629_host.sim.model` (saturation rather than wrap-around; floor, not rounding).
"""

from __future__ import annotations

from dataclasses import dataclass

from lm629_host.bus.opcodes import ACCELERATION_MAX, SAMPLE_CLOCKS, VELOCITY_MAX

U_MAX = 0x7FFF  #: the filter's 16-bit words: the largest
U_MIN = -0x8000  #: and the smallest
U_FULL_SCALE = 1 << 15  #: u at full drive: the output code is u >> 8 (or >> 4), 128 (2048)
SUM_MAX = (1 << 23) - 1  #: 24-bit signed error sum
SUM_MIN = -(1 << 23)

#: a "step" (``lm629 step``, the tuner's experiments): the largest trajectory words the chip
#: takes, so that the desired position jumps to the target within a sample or two
STEP_VELOCITY = VELOCITY_MAX
STEP_ACCELERATION = ACCELERATION_MAX


def sample_period_s(clock_hz: float) -> float:
    """Seconds per sample: one every 2048 chip clocks (256 us at 8 MHz)."""
    return SAMPLE_CLOCKS / clock_hz


def full_scale(twelve_bit: bool) -> int:
    """The output code at full drive: 128 (8-bit port) or 2048 (LM628 12-bit mode)."""
    return U_FULL_SCALE >> output_shift(twelve_bit)


def output_shift(twelve_bit: bool) -> int:
    """Bits dropped from the 16-bit result by the output stage: 8 or 4 (12-bit mode)."""
    return 4 if twelve_bit else 8


def sat16(value: int) -> int:
    """A signed value saturated to 16 bits."""
    return U_MAX if value > U_MAX else (U_MIN if value < U_MIN else value)


@dataclass(slots=True)
class PIDState:
    """What the filter remembers between samples (all zero after reset)."""

    error_sum: int = 0  #: 24-bit signed sum of e(n)
    last_error: int = 0  #: e(n'-1): the error at the previous derivative sample
    derivative: int = 0  #: kd x difference, held between derivative samples (16-bit)
    countdown: int = 0  #: samples until the next derivative sample
    integral: int = 0  #: the limited ki term (what RDSUM reads)
    output: int = 0  #: u(n), 16-bit signed


def derivative_term(kd: int, difference: int) -> int:
    """kd x (e(n') - e(n'-1)): the difference saturated to 16 bits, then the product."""
    return sat16(kd * sat16(difference))


def filter_sum(kp: int, e: int, integral: int, derivative: int) -> int:
    """u(n) from its parts: the saturated kp product, the limited ki term, the held kd term."""
    return sat16(sat16(kp * e) + integral + derivative)


def pid_step(s: PIDState, e: int, kp: int, ki: int, kd: int, il: int, ds: int) -> int:
    """One sample of the filter for the (unsaturated) position error ``e``; returns u(n).

    :func:`sat16`, :func:`derivative_term` and :func:`filter_sum` are written out inline here:
    the tuner runs this a few million times per tuning, and the calls would double its time."""
    e = U_MAX if e > U_MAX else (U_MIN if e < U_MIN else e)
    # integral: 24-bit sum, top 16 bits x ki, limited to il; no wind-up past the limit
    esum = s.error_sum
    total = esum + e
    total = SUM_MAX if total > SUM_MAX else (SUM_MIN if total < SUM_MIN else total)
    held = ki * (esum >> 8)
    if (held >= il or held <= -il) and abs(total) > abs(esum):
        total = esum  # already at the limit: an error pushing further is not summed
    s.error_sum = total
    term = ki * (total >> 8)
    term = il if term > il else (-il if term < -il else term)
    s.integral = term
    # derivative: sampled every ds samples, held in between
    if s.countdown == 0:
        d = e - s.last_error
        d = kd * (U_MAX if d > U_MAX else (U_MIN if d < U_MIN else d))
        s.derivative = U_MAX if d > U_MAX else (U_MIN if d < U_MIN else d)
        s.last_error = e
        s.countdown = ds - 1
    else:
        s.countdown -= 1
    u = kp * e
    u = (U_MAX if u > U_MAX else (U_MIN if u < U_MIN else u)) + term + s.derivative
    u = U_MAX if u > U_MAX else (U_MIN if u < U_MIN else u)
    s.output = u
    return u


def holds(s: PIDState, e: int, ki: int, il: int) -> bool:
    """True when further samples at the same error ``e`` (saturated) leave u(n) and every
    register the host can read as they are: no derivative term held, the last derivative
    sample at this error, the sum not unwinding (il = 0), and no integral action."""
    if s.derivative != 0 or s.last_error != e:
        return False
    if e and il == 0 and s.error_sum and (s.error_sum > 0) != (e > 0):
        return False  # the sum is unwinding towards 0 (the only change allowed at il = 0)
    return e == 0 or ki == 0


def skip_held(s: PIDState, n: int, e: int, il: int, ds: int) -> None:
    """Advance ``n`` samples for which :func:`holds` is true: only the error sum (ki = 0 but
    il > 0: it is summed, never held) and the derivative's phase change."""
    if e and il > 0:
        s.error_sum = max(SUM_MIN, min(SUM_MAX, s.error_sum + n * e))
    s.countdown = (s.countdown - n) % ds


def output_code(u: int, twelve_bit: bool) -> int:
    """The signed output word: top 8 bits (-128..127) or top 12 bits (-2048..2047) of u."""
    return u >> output_shift(twelve_bit)


def lm628_dac_code(out: int, twelve_bit: bool) -> int:
    """LM628 offset binary: zero drive is 80 (8-bit) or 800 (12-bit)."""
    return out + (0x800 if twelve_bit else 0x80)


def lm629_pwm(out: int) -> tuple[int, int]:
    """LM629 sign (pin 18, 1 = negative) and magnitude 0..128 (duty = magnitude / 128)."""
    return (1, -out) if out < 0 else (0, out)


__all__ = ["PIDState", "pid_step", "derivative_term", "filter_sum", "holds", "skip_held", "sat16",
           "output_code", "output_shift", "full_scale", "sample_period_s", "lm628_dac_code",
           "lm629_pwm", "SUM_MAX", "SUM_MIN", "U_MAX", "U_MIN", "U_FULL_SCALE", "STEP_VELOCITY",
           "STEP_ACCELERATION"]
