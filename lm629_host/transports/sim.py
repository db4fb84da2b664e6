"""``sim://``: the bundled chip model, in-process.

URL parameters (all optional)::

    sim://?chip=lm628&clock=6000000&strict=1&fault=reset|busy|rst&record=1
          &lines=500&reversed=1&...      (motor and encoder: see model.params.MotorParams)

Each bus strobe costs ``CYCLE_S`` of simulated time (a fast host's bus cycle); while the chip
is busy, the busy check polls every ``poll_interval_s``.  ``chip.clock`` is the model's clock:
``sleep()`` runs the chip (and its motor) forward, it never sleeps on the wall clock.
"""

from __future__ import annotations

import math
import os

from ..model import ChipModel, ChipParams, MotorParams
from ..program import TraceCallback
from ..urls import Option, dataclass_options, parse_options
from .base import Clock, CycleTransport, PortInfo

#: simulated duration of one /RD or /WR strobe cycle, recovery included
CYCLE_S = 0.5e-6


class SimClock(Clock):
    """The model's simulated time.  ``sleep`` advances the model."""

    def __init__(self, model: ChipModel) -> None:
        self.model = model

    def now(self) -> float:
        return self.model.tick / self.model.clock_hz

    def sleep(self, seconds: float) -> None:
        self.model.advance(seconds)

    def advance_to(self, t: float) -> None:
        """Run the model up to simulated time ``t`` (seconds), rounded up to a whole clock."""
        m = self.model
        m.advance_to(math.ceil(t * m.clock_hz - 1e-6))


_ALIASES = {"chip": "variant", "clock": "clock_hz"}

#: the bench failures the simulators rehearse: the chip never leaves reset, busy stuck high,
#: the /RST line not connected
FAULTS = (None, "reset", "busy", "rst")

#: the URL options of the simulated chip: every field of ChipParams and MotorParams
_CHIP_OPTIONS = dataclass_options(ChipParams, [
    Option("clock_hz", "hz", unit="Hz"),  # the model checks the range
    Option("fault", "str", choices=tuple(f for f in FAULTS if f), optional=True)])
_MOTOR_OPTIONS = dataclass_options(MotorParams)


def build_model(url: str, *, allowed: frozenset[str] = frozenset()) -> ChipModel:
    """A :class:`ChipModel` configured from a simulator URL's query string.

    Used by every simulated transport (``sim://``, ``sim+avr://``, ``sim+ftdi://``), so that
    the same parameters mean the same thing everywhere.  Parameters in ``allowed`` belong to
    the calling transport and are skipped here; any other unknown name is an error.
    """
    chip, motor = ChipParams(), MotorParams()
    # LM629_SIM_STRICT=1 makes strict the default (the test suite runs that way); a URL's own
    # strict=0 still wins, for tests that provoke violations on purpose.
    chip.strict = os.environ.get("LM629_SIM_STRICT", "") not in ("", "0")
    values = parse_options(url, _CHIP_OPTIONS + _MOTOR_OPTIONS, what="simulator",
                           ignore=allowed, aliases=_ALIASES, given_only=True)
    for name, value in values.items():
        if name == "clock_hz":
            value = round(value)
        elif name == "variant":
            value = value.lower()
        setattr(chip if hasattr(chip, name) else motor, name, value)
    return ChipModel(chip, motor)


class SimTransport(CycleTransport):
    """Bus cycles straight into an in-process :class:`ChipModel`."""

    scheme = "sim"
    simulated = True
    has_reset_line = True

    def __init__(self, model: ChipModel, url: str = "sim://", *,
                 trace: TraceCallback | None = None) -> None:
        super().__init__(url, trace=trace)
        self.model = model
        self.clock = SimClock(model)
        self._cycle_clocks = max(1, round(CYCLE_S * model.clock_hz))

    @classmethod
    def from_url(cls, url: str, *, trace: TraceCallback | None = None) -> SimTransport:
        return cls(build_model(url), url, trace=trace)

    @classmethod
    def list_ports(cls) -> list[PortInfo]:
        return [PortInfo("sim://", "the bundled chip simulator (always there)")]

    def describe(self) -> str:
        p = self.model.params
        return f"{self.url} (simulated {p.variant.upper()} at {p.clock_hz / 1e6:g} MHz)"

    def _strobe(self) -> ChipModel:
        m = self.model
        m.advance_to(m.tick + self._cycle_clocks)
        return m

    def _read_status(self) -> int:
        return self._strobe().read_status()

    def _write_command(self, byte: int) -> None:
        self._strobe().write_command(byte)

    def _write_word(self, word: int) -> None:
        self._strobe().write_data(word >> 8)
        self._strobe().write_data(word & 0xFF)

    def _read_word(self) -> int:
        hi = self._strobe().read_data()
        return (hi << 8) | self._strobe().read_data()

    def _pulse_reset(self) -> None:
        m = self.model
        m.advance_to(m.tick + 8)  # /RST held low for 8 clocks, the datasheet minimum
        m.reset_pulse()

    def _hi(self) -> bool:
        return self.model.hi
