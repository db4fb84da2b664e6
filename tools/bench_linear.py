#!/usr/bin/env python3
"""How straight and how together ``Board.move_linear``'s plans run, on the chip's own
trajectory generator (the model's integer arithmetic, sample by sample, no motor).

For seeded random two-axis moves (distances up to 20000 counts, path velocities 1/16 to 3
counts/sample, accelerations 50 to 5000 words) it plans with :func:`lm629_host.physics.linear.plan_linear`,
runs each axis's LTRJ words through the generator and reports: the difference between the
samples at which the axes finish, and the largest distance of the desired point (whole counts,
as RDDP reads) from the straight line.

    python3 tools/bench_linear.py            # 300 moves
    python3 tools/bench_linear.py --n 1000 --seed 7
"""

from __future__ import annotations

import argparse
import math
import random

from lm629_host.physics.linear import plan_linear
from lm629_host.sim.model.trajectory import Trajectory


def run(plan) -> tuple[int, float]:
    trs = []
    for ap in plan.axes:
        t = Trajectory()
        t.position, t.target = ap.start << 16, ap.target
        t.acceleration, t.max_velocity, t.done = ap.acceleration, ap.velocity, False
        trs.append(t)
    d = [ap.target - ap.start for ap in plan.axes]
    length = math.sqrt(sum(x * x for x in d))
    ends: list[int | None] = [None] * len(trs)
    n, dev = 0, 0.0
    while any(e is None for e in ends):
        n += 1
        for i, t in enumerate(trs):
            if ends[i] is None:
                finished, _ = t.step()
                if finished or t.done:
                    ends[i] = n
        p = [(t.position >> 16) - ap.start for t, ap in zip(trs, plan.axes)]
        along = sum(a * b for a, b in zip(p, d)) / length
        dev = max(dev, math.sqrt(max(0.0, sum(x * x for x in p) - along * along)))
    return max(ends) - min(ends), dev  # type: ignore[type-var,operator]  # ends are numbers


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rnd = random.Random(args.seed)
    spreads, devs, skipped = [], [], 0
    by_speed: dict[int, list[int]] = {}
    for _ in range(args.n):
        x, y = rnd.randint(1, 20000), rnd.randint(1, 20000) * rnd.choice((1, -1))
        v = rnd.choice((65536 // 16, 65536 // 4, 65536, 3 * 65536))
        a = rnd.choice((50, 163, 1000, 5000))
        try:
            plan = plan_linear({0: (0, x), 1: (0, y)}, v, a)
        except ValueError:
            skipped += 1  # an axis's share of the acceleration below one word
            continue
        spread, dev = run(plan)
        spreads.append(spread)
        devs.append(dev)
        by_speed.setdefault(v, []).append(spread)
    n = len(spreads)
    devs.sort()
    print(f"{n} straight-line moves on two axes ({skipped} refused: an axis's acceleration "
          "share below one word)")
    for k in (0, 1, 2, 5):
        print(f"  axes finish within {k} sample(s) of each other: "
              f"{sum(s <= k for s in spreads) / n * 100:5.1f} %")
    print(f"  worst arrival difference: {max(spreads)} samples")
    for v, sp in sorted(by_speed.items()):
        print(f"    path velocity {v / 65536:g} counts/sample: within 1 sample "
              f"{sum(s <= 1 for s in sp) / len(sp) * 100:5.1f} %, worst {max(sp)}")
    print(f"  distance from the line (whole counts): median {devs[n // 2]:.2f}, "
          f"95 % {devs[int(n * 0.95)]:.2f}, worst {devs[-1]:.2f}")


if __name__ == "__main__":
    main()
