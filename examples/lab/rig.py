"""A lab script: shuttle an axis between two points and report how closely it followed.

    python rig.py --port /dev/ttyACM0 --travel 2000 --cycles 5

Its tests are test_rig.py beside it (docs/testing.md walks through both).
"""

from __future__ import annotations

import argparse

import lm629_host
from lm629_host import LM629, MoveResult

#: a trapezoid that a small bench motor follows closely: 4 counts/sample (15625 counts/s at
#: 8 MHz, 256 us a sample), reached in 80 samples
VELOCITY = 4 * 65536  # 16.16 counts/sample
ACCELERATION = 65536 // 20  # 0.05 counts/sample^2


def prepare(chip: LM629, kp: int = 20, kd: int = 200) -> None:
    """Load the gains this rig was tuned with and take them into use."""
    chip.load_filter(kp=kp, kd=kd)
    chip.update_filter()


def shuttle(chip: LM629, travel: int, cycles: int) -> list[MoveResult]:
    """Out to ``travel`` and back to 0, ``cycles`` times; every move waits until the shaft
    rests on target (lm629_host.MotionError, motor stopped, otherwise)."""
    results = []
    for _ in range(cycles):
        for target in (travel, 0):
            move = chip.move_to(target, velocity=VELOCITY, acceleration=ACCELERATION)
            results.append(move.wait())
    return results


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--port", default="sim://")
    ap.add_argument("--travel", type=int, default=2000)
    ap.add_argument("--cycles", type=int, default=3)
    args = ap.parse_args(argv)
    with lm629_host.open(args.port) as chip:
        chip.reset()
        prepare(chip)
        results = shuttle(chip, args.travel, args.cycles)
    worst = max(abs(r.error) for r in results)
    print(f"{len(results)} moves, worst error at rest {worst} counts")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
