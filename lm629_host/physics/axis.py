"""The axis and the gains as the tuner sees them, in the chip's own units.

Why a module of its own: the identification (:mod:`lm629_host.physics.fit`), the predictor
(:mod:`lm629_host.physics.predict`), the design (:mod:`lm629_host.physics.design`), the twin
and the bench session all speak of one axis model and one set of filter words; each of them
imports these two types from here, and none of them from another.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from lm629_host.physics.pid import U_FULL_SCALE, full_scale


@dataclass(frozen=True)
class Gains:
    """The filter's gains (LFIL) and ``ds``, the derivative interval in samples (1..256)."""

    kp: int
    ki: int = 0
    kd: int = 0
    il: int = 0
    ds: int = 1

    def as_filter(self) -> dict[str, int]:
        """Keyword arguments of :meth:`LM629.load_filter`."""
        return dict(kp=self.kp, ki=self.ki, kd=self.kd, il=self.il,
                    derivative_interval=self.ds)

    def cli(self, axis: str | None = None) -> str:
        """The ``lm629 filter`` line that sets these gains (on ``--axis axis``, when given: a
        profile's command without it means every axis)."""
        on = f"--axis {axis} " if axis is not None else ""
        return (f"lm629 {on}filter --kp {self.kp} --ki {self.ki} --kd {self.kd} --il {self.il} "
                f"--ds {self.ds}")

    def __str__(self) -> str:
        return f"kp={self.kp} ki={self.ki} kd={self.kd} il={self.il} ds={self.ds}"


@dataclass(frozen=True)
class AxisModel:
    """The axis as the tuner sees it, in the chip's units (counts, samples of 2048 clocks).

    dw/dn = accel x out / full_scale - rate x w - coulomb x sign(w) - load, with w the speed
    in counts/sample and ``out`` the output code (-128..127 on the 8-bit port; -2048..2047 in
    LM628 12-bit mode), held for a sample.  The same structure as a DC motor with the armature
    inductance neglected, so one sample is integrated exactly.
    """

    accel: float  #: counts/sample^2 at full-scale output, shaft at rest
    rate: float  #: speed decay per sample (back-EMF braking + viscous friction)
    coulomb: float = 0.0  #: dry friction, counts/sample^2
    load: float = 0.0  #: constant load, counts/sample^2 (positive pulls toward negative counts)
    twelve_bit: bool = False

    @property
    def full_scale(self) -> int:
        return full_scale(self.twelve_bit)

    @property
    def per_filter_unit(self) -> float:
        """counts/sample^2 per unit of the filter's 16-bit result (both output widths)."""
        return self.accel / U_FULL_SCALE

    def stop_distance(self, speed: float) -> float:
        """Counts the shaft needs to stop from ``speed`` counts/sample at full braking."""
        brake = max(self.accel - abs(self.load), 1e-9)
        return speed * speed / (2 * brake) + abs(speed)

    def scaled(self, factor: float) -> AxisModel:
        """The same axis with ``factor`` times the inertia (robustness check)."""
        return replace(self, accel=self.accel / factor, rate=self.rate / factor,
                       coulomb=self.coulomb / factor, load=self.load / factor)

    def describe(self, sample_s: float) -> str:
        a = self.accel / sample_s ** 2
        return (f"acceleration at full output {a:,.0f} counts/s^2, time constant "
                f"{sample_s / max(self.rate, 1e-12) * 1e3:.1f} ms, top speed "
                f"{self.accel / max(self.rate, 1e-12) / sample_s:,.0f} counts/s, dry friction "
                f"{self.coulomb / self.accel * 100:.1f} % and load "
                f"{self.load / self.accel * 100:+.1f} % of full output")



__all__ = ["AxisModel", "Gains"]
