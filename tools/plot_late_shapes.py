"""What a late host does to a host-timed S-curve: the chip's velocity at every sample of the
simulated chip, on time and with the host late, plotted for docs/python.md (AN-706 4.5.3).

    python3 tools/plot_late_shapes.py [--png docs/late-shapes.png]

The move: 30000 counts along `SCurve(20000, 150000, 3e6)` (counts/s, /s^2, /s^3) in 20 ms
pieces, 85 of them (more than a bridge holds: timed from the host), kp 20 kd 100, on
`sim://?fast=0` (the model's readable sample loop: the simulator's view, not a bus recording).
The host is on time; calls `wait()` 50 ms late; or stalls 0.2 s (the simulated clock runs on
while it does nothing) 0.1 s into the move, half-way, or 0.12 s before the plan's end.
Prints, for each, where the move ended, when, how far the host's schedule fell behind the
plan (`move.lag`) and how often it re-found its place from the chip's position.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import lm629_host
from lm629_host.chip.shapes import SCurve
from lm629_host.physics.pid import sample_period_s
from generated import save_figure

D = 30000
CURVE = SCurve(20000.0, 150000.0, 3e6)
#: (label, seconds late before wait(), when the stall starts: s from the STT, "half" the plan,
#: "end" 0.12 s before the plan's end, or None)
CASES: list[tuple[str, float, float | str | None]] = [
    ("on time", 0.0, None),
    ("wait() 50 ms late", 0.05, None),
    ("0.2 s stall at 0.1 s (speeding up)", 0.0, 0.1),
    ("0.2 s stall half-way (cruising)", 0.0, "half"),
    ("0.2 s stall 0.12 s before the end (slowing)", 0.0, "end"),
]


def run(late_s: float, stall: float | str | None
        ) -> tuple[list[float], list[float], str]:
    """(times s, desired velocity counts/s, outcome) of one move."""
    chip = lm629_host.open("sim://?fast=0")
    with chip:
        chip.reset()
        chip.load_filter(kp=20, kd=100)
        chip.update_filter()
        model = chip.transport.model  # type: ignore[attr-defined]  # sim://'s chip model
        rows: list[tuple[float, float]] = []
        sample = model._sample
        t_s = sample_period_s(chip.clock_hz)

        def observed(motion: Any) -> None:  # the model's Motion
            sample(motion)
            rows.append((model.now(), abs(motion.desired_velocity) / 65536 / t_s))

        model._sample = observed
        move = chip.move_profile(D, CURVE)
        plan = move.plan
        at = (plan.duration / 2 if stall == "half" else plan.duration - 0.12 if stall == "end"
              else stall if isinstance(stall, float) else None)
        stalled: list[float] = []

        def progress(s: Any) -> None:
            if at is not None and not stalled and s.time - move.t0 >= at:
                stalled.append(s.time)
                chip.clock.sleep(0.2)

        if late_s:
            chip.clock.sleep(late_s)
        result = move.wait(progress=progress)
        end = chip.read_desired_position()
        outcome = (f"desired {end} (target {D}), error {result.error:+d}, done in "
                   f"{result.duration:.3f} s (planned {plan.duration:.3f} s), lag "
                   f"{move.lag * 1e3:.0f} ms, {move.resyncs} resync(s), {len(move.words)} caps")
    keep = [r for r in rows if r[0] >= move.t0]
    return [r[0] - move.t0 for r in keep], [r[1] for r in keep], outcome


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--png", default="docs/late-shapes.png")
    args = ap.parse_args()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4.5))
    for label, late_s, stall in CASES:
        t, v, outcome = run(late_s, stall)
        print(f"{label}: {outcome}")
        ax.plot(t, v, label=label, linewidth=1.2)
    ax.set_xlabel("time after the move's STT (s)")
    ax.set_ylabel("desired velocity (counts/s)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower center", fontsize=8)
    ax.set_title(f"{D} counts, S-curve 20000 counts/s, 150000 counts/s^2, 3e6 counts/s^3, "
                 "20 ms pieces timed from the host")
    return save_figure(fig, args.png)


if __name__ == "__main__":
    sys.exit(main())
