#!/usr/bin/env python3
"""Synchronized start on several axes: the skew between the first and the last STT strobe,
and the round trips a start costs, on every transport.

The STT strobes are timed where the chips see them: each chip model's ``write_command`` is
wrapped here (the bench only, not the library) to note the model's clock tick when an STT byte
arrives; the model's clock is the transport's simulated time (the AVR's cycle count through
the simavr harness, the emulated FT232H's nanoseconds, the Python bridge's bus cycles).  The
skew is set against one sample period (2048 chip clocks: 256 us at 8 MHz): below it, the
axes start in the same sample unless a sample boundary falls between two strobes, which
happens with probability skew / 256 us.

    python3 tools/bench_multiaxis.py                 # two axes on every transport
    python3 tools/bench_multiaxis.py --axes 4 --runs 20
"""

from __future__ import annotations

import argparse
import statistics

import lm629_host
from lm629_host.sim.model import chips_of
from lm629_host.bus.opcodes import Cmd

TRANSPORTS = [
    ("sim://", "sim://"),
    ("sim+emu:// 115200 baud", "sim+emu://?baud=115200"),
    ("sim+emu:// 1 Mbaud", "sim+emu://?baud=1000000"),
    ("sim+avr:// 115200 baud (firmware 1.1)", "sim+avr://?baud=115200"),
    ("sim+avr:// 1 Mbaud", "sim+avr://?baud=1000000"),
    ("sim+ftdi://", "sim+ftdi://"),
]
#: the most axes each wiring has (the FT232H: two /CS lines)
LIMITS = {"sim+ftdi": 2, "sim+avr": 4, "sim+emu": 4, "sim": 8}


def measure(url: str, axes: int, runs: int) -> dict[str, float]:
    board = lm629_host.open_board(url, axes=axes)
    models = chips_of(board.transport.model)  # type: ignore[attr-defined]  # a simulator's
    strobes: list[tuple[int, int]] = []  # (chip, tick) of each STT byte
    for k, m in enumerate(models):
        original = m.write_command

        def wrapped(byte: int, _k: int = k, _m=m, _w=original) -> None:
            if byte == Cmd.STT:
                strobes.append((_k, _m.tick))
            _w(byte)
        m.write_command = wrapped  # type: ignore[method-assign]  # a benchmark's probe
    board.reset()
    hz = models[0].clock_hz
    skews, trips, programs, sample_same = [], [], [], 0
    for _ in range(runs):
        for a in board.axes:  # a short move each, the same on every axis; rest between runs
            a.load_trajectory(acceleration=4000, velocity=4 * 65536, position=0)
        strobes.clear()
        before = board.transport.stats.round_trips, board.transport.stats.programs
        board.start()
        trips.append(board.transport.stats.round_trips - before[0])
        programs.append(board.transport.stats.programs - before[1])
        ticks = [t for _, t in strobes]
        assert sorted(k for k, _ in strobes) == list(range(axes)), strobes
        skews.append((max(ticks) - min(ticks)) / hz)
        # the sample each STT lands before: the same for all when no boundary falls between
        sample = models[0].sample_clocks
        sample_same += len({(t - models[0].next_sample) // sample for t in ticks}) == 1
        board.clock.sleep(0.05)
    board.close()
    return {"skew_us": statistics.mean(skews) * 1e6, "skew_max_us": max(skews) * 1e6,
            "round_trips": statistics.mean(trips), "programs": statistics.mean(programs),
            "sample_us": models[0].sample_clocks / hz * 1e6, "same": sample_same, "runs": runs}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--axes", type=int, default=2)
    ap.add_argument("--runs", type=int, default=10)
    args = ap.parse_args()
    print(f"synchronized start (board.start()) on {args.axes} axes, {args.runs} runs each; "
          "skew = last STT strobe - first, at the chips' pins")
    print(f"{'transport':40s} {'skew mean':>10s} {'skew max':>10s} {'of a sample':>12s} "
          f"{'programs':>9s} {'round trips':>12s} {'same sample':>12s}")
    for name, url in TRANSPORTS:
        scheme = url.split("://")[0]
        if args.axes > LIMITS[scheme]:
            print(f"{name:40s} (the wiring has {LIMITS[scheme]} chip selects)")
            continue
        r = measure(url, args.axes, args.runs)
        print(f"{name:40s} {r['skew_us']:8.2f} us {r['skew_max_us']:8.2f} us "
              f"{r['skew_max_us'] / r['sample_us'] * 100:10.1f} % {r['programs']:9.0f} "
              f"{r['round_trips']:12.0f} {r['same']:>7d} of {r['runs']}")


if __name__ == "__main__":
    main()
