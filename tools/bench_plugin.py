#!/usr/bin/env python3
"""What the pytest plugin costs: a 60000-count move (3.86 s of motion, examples/lab) through
the ``lm629`` fixture against the same move on a plain ``lm629_host.open("sim://?strict=1")``,
both in this process, in wall seconds; and the simulated seconds the move lasted.

The plugin adds a check of every bus program (the motion guard) and keeps it for the failure
report; the ratio is that cost over the plain driver.  ``--n`` moves each, best of them.

Run:  python3 tools/bench_plugin.py [--n 3]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import pytest

import lm629_host

VELOCITY, ACCELERATION = 4 * 65536, 65536 // 20  # examples/lab/rig.py

TEST = '''
import json, os, time
import pytest

@pytest.mark.lm629_motion
@pytest.mark.parametrize("k", range({n}))
def test_move(lm629, k):
    lm629.load_filter(kp=20, kd=200)
    lm629.update_filter()
    t0 = time.perf_counter()
    r = lm629.move_to(60000, velocity={v}, acceleration={a}).wait()
    wall = time.perf_counter() - t0
    with open(os.environ["BENCH_PLUGIN_OUT"], "a") as f:
        f.write(json.dumps({{"wall": wall, "simulated": r.duration}}) + "\\n")
'''


def plain() -> tuple[float, float]:
    with lm629_host.open("sim://?strict=1") as chip:
        chip.reset()
        chip.load_filter(kp=20, kd=200)
        chip.update_filter()
        t0 = time.perf_counter()
        r = chip.move_to(60000, velocity=VELOCITY, acceleration=ACCELERATION).wait()
        return time.perf_counter() - t0, r.duration


def through_plugin(n: int) -> list[tuple[float, float]]:
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        (d / "test_bench.py").write_text(TEST.format(v=VELOCITY, a=ACCELERATION, n=n))
        out = d / "out.jsonl"
        os.environ["BENCH_PLUGIN_OUT"] = str(out)
        code = pytest.main(["-q", "-p", "no:cacheprovider", "--rootdir", tmp, str(d / "test_bench.py")])
        if code != 0:
            raise SystemExit(f"the plugin run failed (pytest exit {code})")
        rows = [json.loads(line) for line in out.read_text().splitlines()]
    return [(r["wall"], r["simulated"]) for r in rows]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=3)
    args = ap.parse_args()
    base = min(plain() for _ in range(args.n))
    runs = min(through_plugin(args.n))
    print(f"60000-count move, {base[1]:.3f} s simulated")
    print(f"  plain sim://?strict=1   {base[0]:8.3f} s wall")
    print(f"  lm629 fixture (plugin)  {runs[0]:8.3f} s wall   {runs[0] / base[0]:.2f}x plain, "
          f"{runs[1] / runs[0]:.0f}x faster than real time")


if __name__ == "__main__":
    main()
