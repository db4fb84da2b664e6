"""What a miswired data bus does to a byte: stuck, open and swapped lines between the adapter
and the LM629's D0-D7.

One definition for both sides: the simulators bend the bytes with it (``wiring=`` on a
simulated URL, :mod:`lm629_host.sim.wiring`), and the wiring check
(:mod:`lm629_host.bench.wiring_check`) predicts with it what each suspect wire would make the host read.

Open lines: an open line reads 1 at both ends (the data bus's pull-ups; see
:mod:`lm629_host.sim.wiring` for the model choice), so to the logic it is a line stuck high.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

#: the forms of a ``wiring=`` value, for the error message of an unknown one
FORMS = "dN-low, dN-high, dN-open, dN-dM (swapped), N = 0..7; several separated by commas"

_ONE = re.compile(r"^d([0-7])-(low|high|open|d([0-7]))$")


@dataclass(frozen=True)
class Miswiring:
    """Stuck and swapped data lines, named by the LM629's lines (bit N = DN)."""

    low: int = 0  #: lines shorted to ground
    high: int = 0  #: lines shorted to +5 V, or open (the pull-up): both read 1
    swaps: tuple[tuple[int, int], ...] = ()  #: pairs of lines whose wires are exchanged
    text: str = ""  #: the ``wiring=`` value it was parsed from

    @classmethod
    def parse(cls, text: str) -> Miswiring:
        """``d5-low,d2-d3`` -> a Miswiring; ValueError naming the part and the known forms."""
        low = high = 0
        swaps: list[tuple[int, int]] = []
        used: set[int] = set()
        for part in (p.strip().lower() for p in text.split(",")):
            m = _ONE.match(part)
            if not m:
                raise ValueError(f"{part!r} is not a wiring fault; known forms: {FORMS}")
            a = int(m.group(1))
            lines = {a} if m.group(3) is None else {a, int(m.group(3))}
            if m.group(3) is not None and len(lines) == 1:
                raise ValueError(f"{part!r} swaps a line with itself; known forms: {FORMS}")
            if lines & used:
                raise ValueError(f"{part!r}: line d{min(lines & used)} already has a fault "
                                 f"in {text!r}; known forms: {FORMS}")
            used |= lines
            if m.group(2) == "low":
                low |= 1 << a
            elif m.group(2) in ("high", "open"):
                high |= 1 << a
            else:
                swaps.append((a, int(m.group(3))))
        return cls(low, high, tuple(swaps), text)

    def _permute(self, byte: int) -> int:
        for a, b in self.swaps:
            if ((byte >> a) ^ (byte >> b)) & 1:
                byte ^= (1 << a) | (1 << b)
        return byte

    def to_chip(self, byte: int) -> int:
        """What the chip's D0-D7 latch when the adapter drives ``byte``."""
        return (self._permute(byte) & ~self.low | self.high) & 0xFF

    def to_host(self, byte: int) -> int:
        """What the adapter reads when the chip drives ``byte`` (the stuck lines are the
        chip's, so they are forced before the swapped wires carry them across)."""
        return self._permute((byte & ~self.low | self.high) & 0xFF)

    def __str__(self) -> str:
        return self.text



__all__ = ["FORMS", "Miswiring"]
