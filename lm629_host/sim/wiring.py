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

from typing import Any

from lm629_host.wiring.faults import FORMS, Miswiring
from lm629_host.urls import Option, PortURL, parse_options, query_params

def _parse(text: str) -> Miswiring | None:
    return Miswiring.parse(text) if text.strip() else None


#: the URL option (``urls.Option`` with a parser: a bad value names the URL, the option and
#: the known forms)
OPTION = Option("wiring", "str", None, parse=_parse, unit="dN-low|dN-high|dN-open|dN-dM")


def wiring_of(url: str | PortURL) -> Miswiring | None:
    """The URL's ``wiring=`` (None: a correct bench)."""
    if "wiring" not in query_params(url):
        return None
    value: Any = parse_options(url, [OPTION], ignore=set(query_params(url)) - {"wiring"})
    return value["wiring"]


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
