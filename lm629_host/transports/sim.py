"""``sim://``: the bundled chip model, in-process.

URL parameters (all optional)::

    sim://?chip=lm628&clock=6000000&strict=1&fault=reset|busy|rst&record=1
          &lines=500&reversed=1&...      (motor and encoder: see model.params.MotorParams)
          &axes=2                        (N chips, each with its own motor, on one bus and clock)

Each bus strobe costs ``CYCLE_S`` of simulated time (a fast host's bus cycle); while the chip
is busy, the busy check polls every ``poll_interval_s``.  ``chip.clock`` is the model's clock:
``sleep()`` runs the chip (and its motor) forward, it never sleeps on the wall clock.
"""

from __future__ import annotations

import math
import os

from ..errors import AxisError
from ..model import ChipBus, ChipModel, ChipParams, MotorParams, chips_of
from ..model.params import apply_params
from ..program import TraceCallback
from . import query_params
from .base import Clock, CycleTransport

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


def build_model(url: str, *, allowed: frozenset[str] = frozenset()) -> ChipModel:
    """A :class:`ChipModel` configured from a simulator URL's query string.

    Used by every simulated transport (``sim://``, ``sim+avr://``, ``sim+ftdi://``), so that
    the same parameters mean the same thing everywhere.  Parameters in ``allowed`` belong to
    the calling transport and are skipped here; any other unknown name is an error.
    """
    values = {_ALIASES.get(k, k): v for k, v in query_params(url).items()}
    chip, motor = ChipParams(), MotorParams()
    # LM629_SIM_STRICT=1 makes strict the default (the test suite runs that way); a URL's own
    # strict=0 still wins, for tests that provoke violations on purpose.
    chip.strict = os.environ.get("LM629_SIM_STRICT", "") not in ("", "0")
    used = apply_params(chip, values, url=url) | apply_params(motor, values, url=url)
    unknown = set(values) - used - set(allowed)
    if unknown:
        raise ValueError(f"{url}: unknown simulator parameter(s) {', '.join(sorted(unknown))}")
    chip.variant = chip.variant.lower()
    if chip.fault not in FAULTS:
        raise ValueError(f"{url}: fault={chip.fault!r}: expected one of "
                         f"{', '.join(f for f in FAULTS if f)}")
    return ChipModel(chip, motor)


#: the most chips a simulated bus takes (``axes=``)
MAX_AXES = 8


def axes_of(url: str, limit: int = MAX_AXES) -> int:
    """The URL's ``axes=`` (default 1), checked against ``limit`` chip selects."""
    raw = query_params(url).get("axes", "1")
    try:
        n = int(raw)
    except ValueError:
        raise ValueError(f"{url}: axes={raw!r} is not a whole number of chips") from None
    if n < 1:
        raise ValueError(f"{url}: axes={n}: a bus needs at least one chip")
    if n > limit:
        raise AxisError(n - 1, limit, f"the simulated adapter of {url}")
    return n


def build_bus(url: str, *, allowed: frozenset[str] = frozenset(),
              limit: int = MAX_AXES) -> ChipModel | ChipBus:
    """The chip (``axes=1``, the default) or the :class:`ChipBus` of ``axes=N`` chips, each
    with its own motor, all configured from the same URL parameters."""
    n = axes_of(url, limit)
    allowed = allowed | {"axes"}
    if n == 1:
        return build_model(url, allowed=allowed)
    return ChipBus([build_model(url, allowed=allowed) for _ in range(n)])


class SimTransport(CycleTransport):
    """Bus cycles straight into an in-process :class:`ChipModel`."""

    scheme = "sim"
    has_reset_line = True

    def __init__(self, model: ChipModel | ChipBus, url: str = "sim://", *,
                 trace: TraceCallback | None = None) -> None:
        super().__init__(url, trace=trace)
        self.model = model
        #: the chips on the bus, chip select 0 first (one chip: ``[model]``)
        self.models = chips_of(model)
        self.chip_selects = len(self.models)
        self.clock = SimClock(model)
        self._cycle_clocks = max(1, round(CYCLE_S * model.clock_hz))

    @classmethod
    def from_url(cls, url: str, *, trace: TraceCallback | None = None) -> SimTransport:
        return cls(build_bus(url), url, trace=trace)

    def describe(self) -> str:
        p = self.model.params
        n = f"{len(self.models)} x " if len(self.models) > 1 else ""
        return f"{self.url} (simulated {n}{p.variant.upper()} at {p.clock_hz / 1e6:g} MHz)"

    def _select_chip(self, chip: int) -> None:
        if isinstance(self.model, ChipBus):
            self.model.select(chip)
        else:
            super()._select_chip(chip)

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
