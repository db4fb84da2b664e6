"""A trapezoid and an S-curve of the same duration on the simulated chip: velocity and following
error at every sample, plotted for docs/python.md (AN-706 4.5.3).

    python3 tools/plot_profiles.py [--png docs/profiles.png] [--inertia 4e-6,4e-5]

The move: 20000 counts, 20000 counts/s, kp 20 kd 800 (kd 100, the bring-up gains, leaves the
10x inertia ringing into a following-error fault for both shapes).  The S-curve
(`lm629_host.chip.shapes.SCurve`, 150000 counts/s^2, 3e6 counts/s^3) is run by
`chip.move_profile` in 20 ms pieces; the trapezoid takes the same velocity and the acceleration
that gives it the S-curve's planned duration.  The chip's registers are read at every sample
(the model's readable sample loop, `fast=0`): this is the simulator's view, not a bus
recording.  Prints each run's peak following error and duration.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import lm629_host
from lm629_host.errors import MotionError
from lm629_host.physics.pid import sample_period_s
from lm629_host.chip.shapes import SCurve, plan
from generated import save_figure

D, V, A, J = 20000, 20000.0, 150000.0, 3e6
KD = 800


def run(inertia: float, shaped: bool) -> tuple[list[float], list[float], list[int], str]:
    """(times s, desired velocity counts/s, following error counts, outcome) of one move."""
    chip = lm629_host.open(f"sim://?fast=0&inertia={inertia:g}")
    with chip:
        chip.reset()
        chip.load_filter(kp=20, kd=KD)
        chip.update_filter()
        model = chip.transport.model  # type: ignore[attr-defined]  # sim://'s chip model
        rows: list[tuple[float, float, int]] = []
        sample = model._sample
        t_s = sample_period_s(chip.clock_hz)

        def observed(motion: Any) -> None:  # the model's Motion
            sample(motion)
            rows.append((model.now(), motion.desired_velocity / 65536 / t_s,
                         motion.position_error()))

        model._sample = observed
        shape = SCurve(V, A, J)
        duration = plan(shape, D, t_s).duration
        t0 = chip.clock.now()
        try:
            if shaped:
                result = chip.move_profile(D, shape).wait()
            else:
                a_trap = V / (duration - D / V)
                result = chip.move_to(D, velocity=round(V * t_s * 65536),
                                      acceleration=round(a_trap * t_s * t_s * 65536)).wait()
            outcome = f"on target, done in {result.duration:.3f} s (planned {duration:.3f} s)"
        except MotionError as exc:
            outcome = f"{exc.reason.value} (planned {duration:.3f} s)"
    keep = [r for r in rows if r[0] >= t0]
    return ([r[0] - t0 for r in keep], [r[1] for r in keep], [r[2] for r in keep], outcome)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--png", default="docs/profiles.png")
    ap.add_argument("--inertia", default="4e-6,4e-5", help="kg m^2, comma-separated")
    args = ap.parse_args()
    inertias = [float(x) for x in args.inertia.split(",")]
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(inertias), figsize=(6 * len(inertias), 6), sharex=True,
                             squeeze=False)
    for col, inertia in enumerate(inertias):
        for shaped, color, name in ((False, "tab:blue", "trapezoid"),
                                    (True, "tab:red", "S-curve")):
            t, v, e, outcome = run(inertia, shaped)
            peak = max(abs(x) for x in e)
            print(f"inertia {inertia:g} kg m^2, {name}: peak following error {peak} counts, "
                  f"{outcome}")
            axes[0][col].plot(t, v, color=color, label=name)
            axes[1][col].plot(t, e, color=color, label=f"{name} (peak {peak})")
        axes[0][col].set_title(f"inertia {inertia:g} kg m^2 ({inertia / 4e-6:g} x default)")
        axes[0][col].set_ylabel("desired velocity (counts/s)")
        axes[1][col].set_ylabel("following error (counts)")
        axes[1][col].set_xlabel("time after start (s)")
        for ax in (axes[0][col], axes[1][col]):
            ax.grid(True, alpha=0.3)
            ax.legend(loc="upper right", fontsize=8)
    fig.suptitle(f"{D} counts at {V:g} counts/s, kp 20 kd {KD}: trapezoid vs S-curve "
                 f"({A:g} counts/s^2, {J:g} counts/s^3, 20 ms pieces), same planned duration")
    return save_figure(fig, args.png)


if __name__ == "__main__":
    sys.exit(main())
