#!/usr/bin/env python3
"""docs/twin.png: a bench against its twin, the figure of docs/twin.md.

The bench is ``sim://`` with parameters the host is not told (10x the default inertia and a
load of 0.004 N m, behind an Uno's USB chip: ``sim+emu://?usb=uno&fast_baud=1000000``);
``lm629 tune --save`` writes its gains and plant into a fresh profile, and the twin is
``sim://?profile=FILE&axis=x``.  Plotted: the tuner's trapezoid move (2000 counts out, the
gains saved) on both, recorded on the far side, and its error from the target after the
profile's end; then the same with the bench's inertia doubled (what ``twin check`` calls
"differs").

    python3 tools/plot_twin.py [--out docs/twin.png]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from click.testing import CliRunner

from lm629_host import cli
from lm629_host.physics.pid import sample_period_s
from lm629_host.config.profile import load_profile, template
from lm629_host.bench.tuning_session import measure_move
from lm629_host.physics.axis import Gains
from lm629_host.physics.predict import MoveProfile
from lm629_host.bench.twin import SETTLE_BAND, Plant, twin_profile
from generated import save_figure
from bench_tune import fresh

BENCH = "sim+emu://?usb=uno&fast_baud=1000000&inertia=4e-5&load_torque=0.004"
HEAVIER = "sim+emu://?usb=uno&fast_baud=1000000&inertia=8e-5&load_torque=0.004"


def trace(url: str, gains: Gains, move: MoveProfile) -> tuple[list[float], list[int], float]:
    """(ms after the profile's end, counts from the target, settle ms) of the move out."""
    with fresh(url) as chip:
        m, rec = measure_move(chip, gains, distance=2000, travel=5000, duration_s=0.3,
                              tolerance=SETTLE_BAND, profile=move)
    t, real, _des, _start, target = rec.judged[0]
    return [x * 1e3 for x in t], [p - target for p in real], (m.settle_s or 0) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "docs" /
                                         "twin.png"))
    args = ap.parse_args()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.toml"
        path.write_text(template(port=None))
        fresh(BENCH).close()
        r = CliRunner().invoke(cli.main, ["--profile", str(path), "--port", BENCH, "tune",
                                          "--travel", "5000", "--yes", "--save"],
                               env={"LM629_PORT": "", "LM629_PROFILE": ""})
        if r.exit_code:
            sys.exit(r.output)
        ax = load_profile(path).axis("x")
        assert ax.kp is not None and ax.plant is not None
        gains = Gains(ax.kp, ax.ki or 0, ax.kd or 0, ax.il or 0, ax.ds)
        plant = Plant.from_values(ax.plant)
        move = twin_profile(plant, sample_period_s(8e6))
        runs = [("bench (usb=uno)", BENCH, "C0", "-"),
                ("twin (sim://?profile=...)", f"sim://?profile={path}&axis=x", "C1", "--"),
                ("bench, inertia doubled", HEAVIER, "C3", ":")]
        traces = [(label, style, color, trace(url, gains, move))
                  for label, url, color, style in runs]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 7), sharex=False)
    for label, style, color, (t, err, settle) in traces:
        top.plot(t, [e + 2000 for e in err], style, color=color, label=label)
        bottom.plot(t, err, style, color=color, label=f"{label}: settle {settle:.1f} ms")
    top.set_ylabel("position, counts from the start")
    top.set_title(f"the tuner's move, 2000 counts ({move}), {gains}\n"
                  f"plant: accel {plant.accel:,.0f} counts/s^2, tau {plant.tau * 1e3:.0f} ms, "
                  f"dry {plant.dry:.1%}, load {plant.load:.1%}", fontsize=9)
    top.legend(fontsize=8)
    bottom.axhspan(-SETTLE_BAND, SETTLE_BAND, color="0.9")
    bottom.set_xlim(-20, 150)
    bottom.set_ylim(-30, 30)
    bottom.set_xlabel("ms after the profile's end")
    bottom.set_ylabel("counts from the target")
    bottom.legend(fontsize=8)
    save_figure(fig, args.out, dpi=90)


if __name__ == "__main__":
    main()
