"""A miswired data bus between the adapter and the chip: ``wiring=d5-low,d2-d3`` on every
simulated URL (``sim://``, ``sim+emu://``, ``sim+avr://``, ``sim+ftdi://``, ``lm629 sim serve
--url``), so that ``lm629 wiring --check`` and bring-up can be rehearsed on a bench with a bad
wire.

The fault sits on the wires, between the adapter's pins and the chip's D0-D7, so both ways
are bent, as a real wire bends them: a byte the adapter drives reaches the chip bent
(:meth:`Miswiring.to_chip`), a byte the chip drives reaches the adapter bent
(:meth:`Miswiring.to_host`).  Where it is applied: at the model's bus for ``sim://`` and for
the Python bridge far end (``sim+emu://``, :class:`BentChip`), where the simavr harness
connects the AVR's pins to the chip for the real firmware (``lm629_host.sim.avr``), and at the
emulated FT232H's ACBUS pins (``lm629_host.sim.ftdi.device``).

The forms (the names are the LM629's lines, D0-D7, pins 4-11 of the DIP):

* ``dN-low``: LM629 DN shorted to ground: reads 0 at both ends;
* ``dN-high``: shorted to +5 V: reads 1 at both ends;
* ``dN-open``: the wire is missing.  **Model choice**: an open line reads 1 at both ends, as
  the bus's pull-ups leave it.  The chip model already reads an undriven bus as FF (model
  choice 32, a select with no chip on it); docs/bridge.md recommends 10 kOhm pull-ups on
  D0-D7 for that reason (an open line then reads 1 and the wiring check finds it; without
  them a CMOS input floats, often to the last value driven, which no check can rely on).
  So, to the logic, an open line is a line stuck high, and the check names it "reads 1
  always: open, or shorted to +5 V";
* ``dN-dM``: the wires of DN and DM are swapped (the adapter's DN line lands on the chip's DM
  and the other way round).

Several faults are separated by commas (``wiring=d5-low,d2-d3``); a line may take part in one
fault only.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from ..urls import Option, parse_options, query_params

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


def _parse(text: str) -> Miswiring | None:
    return Miswiring.parse(text) if text.strip() else None


#: the URL option (``urls.Option`` with a parser: a bad value names the URL, the option and
#: the known forms)
OPTION = Option("wiring", "str", None, parse=_parse, unit="dN-low|dN-high|dN-open|dN-dM")


def wiring_of(url: str) -> Miswiring | None:
    """The URL's ``wiring=`` (None: a correct bench)."""
    if "wiring" not in query_params(url):
        return None
    value: Any = parse_options(url, [OPTION], ignore=set(query_params(url)) - {"wiring"})
    return value["wiring"]  # type: ignore[no-any-return]  # OPTION's parser returns Miswiring | None


class BentChip:
    """A chip (or a :class:`~.model.ChipBus`) seen by the adapter through miswired data lines:
    its four strobes bend the byte, everything else is the chip's own."""

    def __init__(self, chip: Any, wiring: Miswiring) -> None:
        self.chip = chip
        self.wiring = wiring

    def read_status(self) -> int:
        return self.wiring.to_host(self.chip.read_status())

    def read_data(self) -> int:
        return self.wiring.to_host(self.chip.read_data())

    def write_command(self, byte: int) -> None:
        self.chip.write_command(self.wiring.to_chip(byte))

    def write_data(self, byte: int) -> None:
        self.chip.write_data(self.wiring.to_chip(byte))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.chip, name)


__all__ = ["BentChip", "FORMS", "Miswiring", "OPTION", "wiring_of"]
