"""``lm629_host.units``, the path lab scripts already import: the names live in
:mod:`lm629_host.physics.units` (``Scale`` is also at the package root)."""

from lm629_host.physics.units import (
    Scale,
    Trapezoid,
    from_fixed,
    to_fixed,
)

__all__ = [
    "Scale",
    "Trapezoid",
    "from_fixed",
    "to_fixed",
]
