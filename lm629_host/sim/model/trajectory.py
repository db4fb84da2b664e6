"""The trajectory generator in the chip's own fixed point.

Positions are kept as integers in 1/65536 count (16 bits of fraction below the 32-bit
position register), velocities in 16.16 counts/sample and accelerations in 16.16
counts/sample^2, exactly the units of the LTRJ words.  Everything is integer arithmetic, so
a move ends exactly on its target and the sequence of desired positions is reproducible
bit for bit.  The model choices (7-15 concern the generator) are listed in one place, the
docstring of :mod:`lm629_host.sim.model`.
"""

from __future__ import annotations

from math import isqrt

from lm629_host.bus.opcodes import wrap_counts

#: the position register holds C0000000..3FFFFFFF (bit 30 is the wraparound bit, AN-706 6.5.2):
#: positions are kept modulo 2^31 counts in [-2^30, 2^30)
SPAN = 1 << 47  #: 2^31 counts in fixed point
HALF = 1 << 46


def wrap_fixed(value: int) -> int:
    """A fixed-point position folded into the register's range [-2^30, 2^30) counts."""
    return ((value + HALF) % SPAN) - HALF


def stop_distance(v: int, a: int) -> int:
    """Distance covered decelerating from ``v`` at ``a`` per sample: (v-a) + (v-2a) + ...

    Only the positive terms count: the ramp ends on the sample where the velocity would
    reach or pass zero.  ``v`` and ``a`` are 16.16, the result is fixed-point counts.
    """
    if v <= a:
        return 0
    n = (v - 1) // a  # number of k >= 1 with v - k a > 0
    return n * v - a * n * (n + 1) // 2


def landing_velocity(r: int, a: int) -> int:
    """The velocity for this sample that makes the ramp down end exactly ``r`` ahead.

    Solves v + stop_distance(v, a) = r (rounded down to the fixed point).  That function
    of v is continuous and increasing, linear between multiples of a: with m the number of
    samples still to go, v lies in ((m-1) a, m a] and r = m v - a m (m-1) / 2.
    """
    if r <= a:
        return r
    m = max(1, (isqrt(1 + 8 * r // a) - 1) // 2)
    while a * m * (m + 1) < 2 * r:
        m += 1
    while m > 1 and a * (m - 1) * m >= 2 * r:
        m -= 1
    return (r + a * m * (m - 1) // 2) // m


class Trajectory:
    """Desired position and velocity, advanced once per sample by :meth:`step`."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.position = 0  #: desired position, fixed point (1/65536 count)
        self.velocity = 0  #: signed 16.16 counts/sample
        self.acceleration = 0  #: working register, 16.16
        self.max_velocity = 0  #: working register, 16.16 (unsigned)
        self.target = 0  #: whole counts
        self.velocity_mode = False
        self.forward = False
        self.stopping = False  #: decelerating for a smooth stop (LTRJ bit 10)
        self.done = True  #: the generator finished the last STT (signals bit 10)

    # ------------------------------------------------------------------ per sample
    def step(self) -> tuple[bool, bool]:
        """Advance one sample; return (finished at this sample, wrapped at this sample)."""
        if self.done:
            return False, False
        a = self.acceleration
        v = self.velocity
        if self.velocity_mode or self.stopping:
            goal = 0 if self.stopping else (self.max_velocity if self.forward else -self.max_velocity)
            v = min(v + a, goal) if v < goal else max(v - a, goal)
            self.velocity = v
            wrapped = self._move(v)
            if self.stopping and v == 0:
                self.done = True
                return True, wrapped
            return False, wrapped
        # position mode, in the frame of the direction of travel
        r = wrap_fixed((self.target << 16) - self.position)
        if v == 0 and r == 0:
            self.done = True
            return True, False
        sign = (1 if v > 0 else -1) if v else (1 if r > 0 else -1)
        ahead, speed = r * sign, v * sign
        if ahead <= 0:
            # the target is behind (it moved on the fly): ramp down, then turn round
            speed = max(speed - a, 0)
        else:
            vmax = self.max_velocity
            up = min(speed + a, vmax) if speed <= vmax else max(speed - a, vmax)
            if a == 0:
                up = speed  # no acceleration loaded: the velocity cannot change
            elif up + stop_distance(up, a) > ahead:
                up = max(landing_velocity(ahead, a), speed - a)
            if up >= ahead and speed - a <= ahead:
                # the last step lands exactly on the target
                self.velocity = 0
                wrapped = self._move(ahead * sign)
                self.done = True
                return True, wrapped
            speed = up
        self.velocity = v = speed * sign
        return False, self._move(v)

    def _move(self, v: int) -> bool:
        p = self.position + v
        if -HALF <= p < HALF:
            self.position = p
            return False
        self.position = wrap_fixed(p)
        return True

    # ------------------------------------------------------------------ commands
    def stop_abruptly(self) -> None:
        """LTRJ bit 9: target := current position, at once (maximum deceleration)."""
        self.velocity = 0
        self.stopping = True
        self.done = False  # finishes (on target) at the next sample

    def stop_smoothly(self) -> None:
        """LTRJ bit 10: ramp down at the programmed acceleration, then hold."""
        self.stopping = True
        self.done = False

    def define_home(self) -> int:
        """DFH: the desired position's whole counts become 0; return the counts removed."""
        counts = self.position >> 16
        self.position -= counts << 16
        self.target = wrap_counts(self.target - counts)
        return counts
