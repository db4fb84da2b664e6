#!/usr/bin/env python3
"""How fast the chip model runs: simulated seconds per wall second on ``sim://``.

Scenarios (8 MHz: 3906 samples per simulated second):

  hold      the loop holding a settled shaft (kp = 20): the chip is quiescent, so it skips ahead
  hold-load the loop holding against a load torque with the integrator working (no skip-ahead)
  move      a 10 s move with the PID active, the shaft turning all the time
  idle      motor off, shaft at rest (skip-ahead)

Each runs three times in this process: with the C sample loop (``fast=c``, the default when
it was built), the same loop in Python (``fast=py``, the fallback) and only the readable
per-sample code (``fast=0``), the baseline for the ratios.  The host polls the status every
``--poll`` simulated seconds, as a waiting test does.

    python3 tools/bench_model.py [--poll 0.1] [--seconds 10]
"""

from __future__ import annotations

import argparse
import time

import lm629_host
from lm629_host import Status

ONE = 65536


def _setup(scenario: str, fast: str):
    params = {"hold": "", "hold-load": "load_torque=0.003", "move": "", "idle": ""}[scenario]
    chip = lm629_host.open(f"sim://?fast={fast}&{params}")
    chip.reset()
    if scenario == "hold":
        chip.load_filter(kp=20)
        chip.update_filter()
        chip.start()
        chip.clock.sleep(0.5)
    elif scenario == "hold-load":
        chip.load_filter(kp=400, ki=20, kd=2000, il=4000)
        chip.update_filter()
        chip.start()
        chip.clock.sleep(0.5)
    elif scenario == "move":
        chip.load_filter(kp=400, kd=2000)
        chip.update_filter()
    return chip


def measure(scenario: str, fast: str, seconds: float, poll: float) -> tuple[float, int]:
    """(simulated seconds per wall second, samples run)."""
    chip = _setup(scenario, fast)
    model = chip.transport.model
    if scenario == "move":
        # 10 s move: 1 count/sample cruise (3906 counts/s, ~117 rpm), ramps of 0.25 s
        counts = int(3906 * (seconds - 0.25))
        chip.load_trajectory(acceleration=ONE // 977, velocity=ONE, position=counts, start=True)
    s0, t0, n0 = chip.clock.now(), time.perf_counter(), model.samples
    end = s0 + seconds
    while chip.clock.now() < end:
        chip.clock.sleep(min(poll, end - chip.clock.now()))
        chip.read_status()
    wall = time.perf_counter() - t0
    if scenario == "move":
        assert chip.read_status() & Status.TRAJECTORY_COMPLETE or chip.clock.now() >= end
    chip.close()
    return (chip.clock.now() - s0) / wall, model.samples - n0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per scenario")
    ap.add_argument("--poll", type=float, default=0.1, help="host status poll interval, s")
    args = ap.parse_args()
    print(f"chip model speed, {args.seconds:g} simulated s per scenario, host polls every "
          f"{args.poll:g} s (8 MHz: 3906 samples per simulated s)")
    loops = ["c", "py", "0"]
    try:
        import lm629_host.sim.model._fastloop  # noqa: F401 - only whether it was built
    except ImportError:
        loops.remove("c")
        print("(the C loop is not built: pip install -e . with a C compiler)")
    print(f"{'scenario':<10}" + "".join(f"{'fast=' + f:>12}" for f in loops)
          + f"{'c / 0':>9}{'py / 0':>9}  samples per wall s (first column)")
    for scenario in ("hold", "hold-load", "move", "idle"):
        ratios = {f: measure(scenario, f, args.seconds, args.poll)[0] for f in loops}
        line = f"{scenario:<10}" + "".join(f"{ratios[f]:>11.0f}x" for f in loops)
        if "c" in ratios:
            line += f"{ratios['c'] / ratios['0']:>8.1f}x"
        line += f"{ratios['py'] / ratios['0']:>8.1f}x  {ratios[loops[0]] * 3906:>12,.0f}"
        print(line)

if __name__ == "__main__":
    main()
