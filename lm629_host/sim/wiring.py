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

Three more forms name a board line that is not a data wire, and go to the chip model instead
of the bytes (:func:`board_lines_of`; ``lm629 selftest`` names each, docs/selftest.md):

* ``hi-open``: HI (pin 17) is not connected to the adapter.  **Model choice**: the adapter
  reads it low (the bridge's HI input has no pull-up; the FT232H's ADBUS5 reads what the
  chip would not drive), so an interrupt the chip raises is never seen on the pin while the
  status and signals registers still show it;
* ``index-open``: the encoder's index (IN, pin 1) is not connected: no index is ever latched;
* ``encoder-open``: the encoder's A and B (pins 2 and 3) are not connected: the real position
  never counts, whatever the shaft does.
"""

from __future__ import annotations

from typing import Any

from lm629_host.wiring.faults import FORMS as DATA_FORMS, Miswiring
from lm629_host.urls import Option, PortURL, query_params, read_rows

#: the board lines a ``wiring=`` value may name besides the data lines, each with the model
#: parameter it clears (``ChipParams.hi_wired``, ``MotorParams.index_wired`` and
#: ``encoder_wired``)
BOARD_LINES = {"hi-open": "hi_wired", "index-open": "index_wired",
               "encoder-open": "encoder_wired"}

#: every form a ``wiring=`` value takes, for the error message of an unknown one
FORMS = f"{DATA_FORMS}; or a board line not connected: {', '.join(BOARD_LINES)}"


def _split(text: str) -> tuple[str, frozenset[str]]:
    """``d5-low,hi-open`` -> (``d5-low``, {``hi-open``}): the data-line faults as their text
    and the board lines named."""
    parts = [p.strip().lower() for p in text.split(",") if p.strip()]
    board = frozenset(p for p in parts if p in BOARD_LINES)
    return ",".join(p for p in parts if p not in BOARD_LINES), board


def _parse(text: str) -> tuple[Miswiring | None, frozenset[str]]:
    data, board = _split(text)
    try:
        bend = Miswiring.parse(data) if data else None
    except ValueError as exc:
        raise ValueError(f"{exc}; or a board line not connected: "
                         f"{', '.join(BOARD_LINES)}") from None
    return bend, board


#: the URL option (``urls.Option`` with a parser: a bad value names the URL, the option and
#: the known forms)
OPTION = Option("wiring", "str", None, parse=_parse,
                unit="dN-low|dN-high|dN-open|dN-dM|hi-open|index-open|encoder-open")


def _wiring(url: str | PortURL) -> tuple[Miswiring | None, frozenset[str]]:
    if "wiring" not in query_params(url):
        return None, frozenset()
    value: Any = read_rows(url, [OPTION])["wiring"]
    return value


def wiring_of(url: str | PortURL, options: dict[str, Any] | None = None) -> Miswiring | None:
    """The URL's miswired data lines (None: a correct data bus), which every far end bends
    its bytes with; ``options``: the URL as its transport parsed it."""
    if options is not None:
        return (options.get("wiring") or (None, frozenset()))[0]
    return _wiring(url)[0]


def board_lines_of(named: frozenset[str]) -> dict[str, bool]:
    """The model parameters the board lines ``named`` in ``wiring=`` set (``{"hi_wired":
    False}`` for ``hi-open``; empty: every board line connected): :mod:`lm629_host.sim.build`
    applies them to the chip and its motor."""
    return {BOARD_LINES[name]: False for name in named}


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


__all__ = ["BOARD_LINES", "BentChip", "FORMS", "Miswiring", "OPTION", "board_lines_of",
           "wiring_of"]
