"""Several chip models on one host bus and one clock: a multi-axis board.

The chips share D0-D7, /RD, /WR, /PS and /RST; each has its own /CS (and its own HI line where
the adapter has a pin for it) and its own motor and encoder.  They are clocked from one
oscillator, so their clock counts (``tick``) never differ: every advance moves all of them,
and since one /RST resets them together, they also sample at the same ticks.

:class:`ChipBus` offers the strobe interface of a single :class:`~.chip.ChipModel`
(``read_status``, ``write_command``, ``write_data``, ``read_data``, ``reset_pulse``,
``advance_to``...), routing each strobe to the chip whose /CS is low (:meth:`select`) and
/RST and time to all of them, so that the simulated transports (``sim://``, the Python bridge,
the simavr harness, the emulated FT232H) drive N chips with the code that drives one.
Like the chip model, it knows nothing of the driver.

A bus may have more /CS lines than chips (``lines``: a four-select bridge with two chips on
it): a strobe on an unwired select reaches nothing, a read finds the data bus floating and
reads FF [model choice 32].
"""

from __future__ import annotations

from collections.abc import Sequence

from lm629_host.sim.model.chip import ChipModel, Violation
from lm629_host.sim.model.params import ChipParams


class ChipBus:
    """N :class:`ChipModel` on one bus: strobes go to the selected chip, time and /RST to all."""

    def __init__(self, chips: Sequence[ChipModel], lines: int | None = None) -> None:
        if not chips:
            raise ValueError("a chip bus needs at least one chip")
        hz = {c.clock_hz for c in chips}
        if len(hz) != 1:
            raise ValueError(f"the chips of one bus share one clock; got {sorted(hz)} Hz")
        self.chips: list[ChipModel] = list(chips)
        tick = max(c.tick for c in self.chips)
        #: one record of protocol violations for the whole bus
        self.violations: list[Violation] = []
        for c in self.chips:
            c.advance_to(tick)
            c.violations = self.violations
        self.selected = 0
        #: /CS lines on the bus (chips on the first ``len(chips)`` of them)
        self.lines = len(self.chips) if lines is None else lines
        if self.lines < len(self.chips):
            raise ValueError(f"{len(self.chips)} chips need {len(self.chips)} /CS lines, "
                             f"not {self.lines}")

    # ------------------------------------------------------------------ wiring
    def __len__(self) -> int:
        return len(self.chips)

    def select(self, index: int) -> ChipModel:
        """/CS of chip ``index`` low (the others high) for the strobes that follow."""
        if not 0 <= index < self.lines:
            raise ValueError(f"chip select {index} is outside 0..{self.lines - 1} "
                             f"(this bus has {self.lines} /CS line(s))")
        self.selected = index
        return self.chips[index] if index < len(self.chips) else None  # type: ignore[return-value]  # an unwired select: no chip

    @property
    def chip(self) -> ChipModel:
        """The chip whose /CS is low."""
        return self.chips[self.selected]

    @property
    def params(self) -> ChipParams:
        return self.chips[0].params

    # ------------------------------------------------------------------ time: all chips
    @property
    def clock_hz(self) -> int:
        return self.chips[0].clock_hz

    @property
    def tick(self) -> int:
        return self.chips[0].tick

    def now(self) -> float:
        return self.tick / self.clock_hz

    def advance(self, seconds: float) -> None:
        self.advance_to(self.tick + max(0, round(seconds * self.clock_hz)))

    def advance_to(self, tick: int) -> None:
        """Every chip up to clock ``tick``.  Before every chip's next sample or reset end
        (:attr:`ChipModel.next_event <.chip.ChipModel.next_event>`: the case of nearly every
        strobe) the chips' clocks are only counts, set here without a call per chip; from the
        first chip with an event due, every chip runs its own advance (one already counted to
        ``tick`` has nothing left to do)."""
        for c in self.chips:
            if tick >= c.next_event:
                break
            if tick > c.tick:
                c.tick = tick
        else:
            return
        for c in self.chips:
            c.advance_to(tick)

    # ------------------------------------------------------------------ strobes: one chip
    def read_status(self) -> int:
        k = self.selected
        return self.chips[k].read_status() if k < len(self.chips) else 0xFF

    def write_command(self, byte: int) -> None:
        if self.selected < len(self.chips):
            self.chips[self.selected].write_command(byte)

    def write_data(self, byte: int) -> None:
        if self.selected < len(self.chips):
            self.chips[self.selected].write_data(byte)

    def read_data(self) -> int:
        k = self.selected
        return self.chips[k].read_data() if k < len(self.chips) else 0xFF

    def busy_deadline(self) -> int | None:
        """The selected chip's :meth:`~.chip.ChipModel.busy_deadline` (None: no chip there)."""
        k = self.selected
        return self.chips[k].busy_deadline() if k < len(self.chips) else None

    @property
    def busy(self) -> bool:
        k = self.selected
        return self.chips[k].busy if k < len(self.chips) else True

    @property
    def busy_clocks(self) -> int:
        return self.chips[self.selected].busy_clocks

    @busy_clocks.setter
    def busy_clocks(self, clocks: int) -> None:
        self.chips[self.selected].busy_clocks = clocks

    @property
    def hi(self) -> bool:
        """HI of the selected chip (each chip drives its own HI line)."""
        k = self.selected
        return self.chips[k].hi if k < len(self.chips) else False

    @property
    def his(self) -> tuple[bool, ...]:
        """Every chip's HI line, chip 0 first."""
        return tuple(c.hi for c in self.chips)

    # ------------------------------------------------------------------ /RST: all chips
    def reset_pulse(self) -> None:
        """/RST rising edge: the line is shared, every chip resets."""
        for c in self.chips:
            c.reset_pulse()


def chips_of(model: ChipModel | ChipBus) -> list[ChipModel]:
    """The chip models behind a transport's ``model`` (one chip or a bus)."""
    return list(model.chips) if isinstance(model, ChipBus) else [model]


__all__ = ["ChipBus", "chips_of"]
