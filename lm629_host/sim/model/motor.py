"""A DC motor, its load and amplifier, and a 4x quadrature encoder with an index.

The amplifier puts ``drive * amp_volts`` across the armature, ``drive`` in [-1, 1) being the
chip's output word over its full scale (held for the whole sample, the PWM averaged).  With
the armature inductance neglected the shaft obeys

    J dw/dt = kt (V - kt w) / R - b w - Tc sign(w) - T_load

which is linear between the sticking points of the dry friction, so each sample is integrated
exactly (:func:`lm629_host.physics.plant.motor_step`) rather than stepped: the model is stable at
any sample time.
Internally the shaft angle is in encoder counts (float) and the speed in counts/s.
"""

from __future__ import annotations

from math import floor, pi

from lm629_host.physics.plant import decay_and_gain, motor_step
from lm629_host.sim.model.params import MotorParams


class Motor:
    """Shaft state and the per-sample integration."""

    def __init__(self, params: MotorParams, sample_s: float) -> None:
        params.check()
        self.params = params
        self.sample_s = sample_s
        p = params
        counts_per_rad = 4 * p.lines / (2 * pi)
        self.counts_per_rev = 4 * p.lines
        #: the index count within a revolution [model choice 20]
        self.index_k = (2 * p.lines if p.index_offset is None else p.index_offset) % self.counts_per_rev
        #: decay rate of the speed, 1/s: back-EMF braking through R plus viscous friction
        self.rate = (p.torque_constant ** 2 / p.resistance + p.friction) / p.inertia
        #: acceleration (counts/s^2) at full-scale output with the shaft still
        full = p.amp_volts * (p.torque_constant / p.resistance / p.inertia) * counts_per_rad
        self.coulomb_accel = p.coulomb / p.inertia * counts_per_rad
        self.load_accel = p.load_torque / p.inertia * counts_per_rad
        # the plant as identified, where given, in place of what the SI numbers make of it
        if p.accel is not None:
            full = p.accel
        if p.tau is not None:
            self.rate = 1.0 / p.tau
        if p.dry is not None:
            self.coulomb_accel = p.dry * full
        if p.load is not None:
            self.load_accel = p.load * full
        #: acceleration (counts/s^2) per volt across the armature with the shaft still
        self.accel_per_volt = full / p.amp_volts
        if p.reversed:
            self.accel_per_volt = -self.accel_per_volt
        self.decay, self.gain = decay_and_gain(self.rate, sample_s)
        self.reset()

    def reset(self) -> None:
        self.angle = float(self.params.start_position)  #: shaft angle, counts
        self.speed = 0.0  #: counts/s

    def run(self, volts: float) -> None:
        """Run one sample with ``volts`` across the armature."""
        if self.params.stall:
            self.speed = 0.0
            return
        self.angle, self.speed = motor_step(
            self.angle, self.speed, volts * self.accel_per_volt - self.load_accel,
            self.coulomb_accel, self.rate, self.decay, self.gain, self.sample_s)

    @property
    def count(self) -> int:
        """The encoder's 4x count (whole counts since power-on, unwrapped); with A and B not
        connected (``encoder_wired``) the count where the shaft stood at power-on."""
        if not self.params.encoder_wired:
            return floor(self.params.start_position)
        return floor(self.angle)

    def index_between(self, c0: int, c1: int) -> int | None:
        """The first count at which the index fired moving from count ``c0`` to ``c1``.

        [model choice 20] The index count is ``index_offset`` counts past a multiple of
        4 x lines; it is seen if the encoder stood on it at either sample or passed it.
        """
        if not self.params.index_wired:
            return None
        n = self.counts_per_rev
        k = self.index_k
        if c1 >= c0:
            first = c0 + (k - c0) % n
            return first if first <= c1 else None
        first = c0 - (c0 - k) % n
        return first if first >= c1 else None
