#!/usr/bin/env python3
"""Host-side cost of a full LTRJ (six words) + STT on ``sim://``, in wall microseconds.

Three figures, measured in one process:

* ``build``: validating and building the bus program only (``LM629.trajectory_program``);
* ``typed``: ``chip.load_trajectory(..., start=True)`` end to end on ``sim://`` (validation,
  program, busy checks on the simulated clock, the chip model's strobes);
* ``baseline``: the same 17 strobes written straight into the chip model, with the busy time
  skipped by advancing the model's clock (the floor any transport over this model pays).

Run:  python3 tools/bench_core.py [--n 2000]
"""

from __future__ import annotations

import argparse
import time

import lm629_host
from lm629_host.sim.model import ChipModel, ChipParams
from lm629_host.bus.opcodes import Cmd


def per_call_us(fn, n: int) -> float:
    fn()  # warm up
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t0) / n * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=2000)
    args = ap.parse_args()

    chip = lm629_host.open("sim://")
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    position = [1000]

    def typed() -> None:
        # validate, build and run the whole LTRJ + STT program (the chip refuses the repeated
        # acceleration while moving: that is its business, not the host's cost)
        position[0] = -position[0]
        program = chip.trajectory_program(acceleration=100, velocity=65536, position=position[0])
        chip.run(program.command(Cmd.STT))

    def build() -> None:
        chip.trajectory_program(acceleration=100, velocity=65536, position=1000)

    m = ChipModel(ChipParams(strict=True))
    m.advance(2e-3)
    words = (0x002A, 0, 100, 1, 0, 0, 1000)

    def baseline() -> None:
        m.write_command(Cmd.LTRJ)
        m.advance_to(m.tick + m.busy_clocks)
        for w in words:
            m.write_data(w >> 8)
            m.write_data(w & 0xFF)
            m.advance_to(m.tick + m.busy_clocks)
        m.write_command(Cmd.STT)
        m.advance_to(m.tick + m.busy_clocks)

    stats = chip.transport.stats
    stats.reset()
    t_typed = per_call_us(typed, args.n)
    s = stats.as_dict()
    n = args.n + 1
    t_build = per_call_us(build, args.n)
    t_base = per_call_us(baseline, args.n)
    print(f"LTRJ (6 words) + STT on sim://, {args.n} commands")
    print(f"  build only (validate + program): {t_build:8.1f} us/command")
    print(f"  typed, end to end on sim://:     {t_typed:8.1f} us/command")
    print(f"  baseline, raw strobes to model:  {t_base:8.1f} us/command")
    print(f"  typed / baseline:                {t_typed / t_base:8.2f} x")
    print(f"  per command: {s['round_trips'] / n:.0f} round trip, {s['bus_cycles'] / n:.1f} bus "
          f"cycles, {s['busy_polls'] / n:.1f} busy polls; simulated time "
          f"{chip.clock.now() * 1e6 / n:.0f} us/command")


if __name__ == "__main__":
    main()
