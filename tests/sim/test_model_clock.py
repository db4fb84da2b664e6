"""The chip model's clock, advanced one clock at a time: every event at its own clock.

Between two events (a sample, the end of a reset) advancing a chip only counts its clock, and
a :class:`ChipBus` moves its chips' clocks without a call per chip (``ChipModel.next_event``);
these tests step across the events one clock at a time, on one chip and on every chip of a
bus, so that a count that ran one clock past an event (or an event forgotten) shows.

Numbers: a sample every 2048 clocks, the first at clock 2048 (the datasheet's 2048 / fclk);
the reset completes 1.0 ms = 8000 clocks after /RST or the RESET command at 8 MHz (the model's
choice inside the datasheet's 1.5 ms; ``reset_s=100e-6``: 800 clocks, ending before the next
sample), then the status reads 84 or C4: bit 6, the breakpoint (at position 0, where the shaft
sits), is masked out below (``NO_BP``).
"""

from __future__ import annotations

import pytest

from lm629_host.bus.opcodes import Cmd
from lm629_host.sim.model import ChipBus, ChipModel, ChipParams

SAMPLE = 2048
#: (reset_s, its clocks at 8 MHz): the model's default, and one shorter than a sample
RESETS = [(1.0e-3, 8000), (100e-6, 800)]
NO_BP = 0xBF  # the status bits but the breakpoint's


def board(chips: int, **params) -> tuple[ChipModel | ChipBus, list[ChipModel]]:
    """One chip, or a bus of ``chips`` chips, and the chips."""
    models = [ChipModel(ChipParams(strict=False, **params)) for _ in range(chips)]
    return (models[0] if chips == 1 else ChipBus(models)), models


@pytest.mark.parametrize("chips", [1, 2, 3])
def test_every_sample_runs_at_its_own_clock(chips):
    m, models = board(chips)
    m.advance_to(SAMPLE - 3)
    for tick in range(SAMPLE - 2, 3 * SAMPLE + 3):
        m.advance_to(tick)
        assert [(c.tick, c.samples) for c in models] == [(tick, tick // SAMPLE)] * chips, tick
    m.advance_to(5 * SAMPLE - 1)  # one step over a sample, ending a clock short of the next
    assert [c.samples for c in models] == [4] * chips
    m.advance_to(5 * SAMPLE)
    assert [c.samples for c in models] == [5] * chips


@pytest.mark.parametrize("reset_s, reset_clocks", RESETS)
@pytest.mark.parametrize("chips", [1, 2])
def test_a_hardware_reset_ends_at_its_own_clock_on_every_chip(chips, reset_s, reset_clocks):
    m, models = board(chips, reset_s=reset_s)
    m.advance_to(3 * SAMPLE + 100)
    m.reset_pulse()  # /RST is shared: every chip resets
    t0 = models[0].tick
    m.advance_to(t0 + reset_clocks - 3)
    for tick in range(t0 + reset_clocks - 2, t0 + reset_clocks + 2):
        m.advance_to(tick)
        done = tick >= t0 + reset_clocks
        assert [c.read_status() & NO_BP for c in models] == [0x84 if done else 0x00] * chips, tick


@pytest.mark.parametrize("reset_s, reset_clocks", RESETS)
def test_a_reset_command_ends_at_its_own_clock_on_its_chip_alone(reset_s, reset_clocks):
    """The RESET command resets the selected chip of a bus, ``reset_clocks`` later to the
    clock: until then its command-error bit (an unknown opcode) stands and busy is set; the
    other chip, not reset, keeps its own error bit."""
    bus, chips = board(2, reset_s=reset_s)
    bus.advance_to(SAMPLE + 10)
    for k in (0, 1):
        bus.select(k)
        bus.write_command(0x33)  # not an opcode: command error (recorded, not strict)
    bus.advance_to(bus.tick + 200)
    bus.write_command(Cmd.RESET)  # chip 1, still selected
    t0 = bus.tick
    bus.advance_to(t0 + reset_clocks - 3)
    for tick in range(t0 + reset_clocks - 2, t0 + reset_clocks + 2):
        bus.advance_to(tick)
        after = 0x84 if tick >= t0 + reset_clocks else 0x87  # error, motor off, complete, busy
        assert [c.read_status() & NO_BP for c in chips] == [0x86, after], tick
