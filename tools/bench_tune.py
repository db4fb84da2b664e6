#!/usr/bin/env python3
"""Tuned gains against the best of a grid search, on motors of different kinds (``sim://``).

For each motor: ``autotune`` (travel 5000, a 2000-count step out and back and a 2000-count
trapezoid move out and back as its test moves) from a fresh chip holding at kp = 20; then every
point of a kp x ki x kd grid on a fresh chip, each measured with the same two test moves
(``tuning.measure_move``, guarded like tuning: a point that would leave the band is stopped and
counted as a fault; the move at the profile the tuner chose for that motor, 0x40000 and 0x2000
where the axis follows them).  The tuned gains are measured again the same way.  "Best" is the
smallest sum of ``tuning.score`` over the two moves (settle time within the tolerance, with
penalties for overshoot and for ending outside it): the same yardstick for both.  Each row
gives the step's figures and the move's (its settle counted from the profile's end).

    python3 tools/bench_tune.py            # the full grid (a few minutes on one core)
    python3 tools/bench_tune.py --quick    # a coarse grid
    python3 tools/bench_tune.py --url 'sim+avr://'   # through the compiled bridge firmware
    python3 tools/bench_tune.py --matrix   # the tuner's acceptance: 5 transports x 3 motors

``--matrix``: on each transport the tuner must hold on (``sim://``, ``sim+emu://``, ``sim+avr://``,
``sim+ftdi://``, ``sim+emu://?usb=uno&fast_baud=1000000``) and each of its motors (default,
10x inertia, a holding load of 0.005 N m), ``autotune(chip, travel=2000)`` from a fresh chip
holding at kp = 20, then with the gains it leaves loaded the 2000-count step and the
2000-count trapezoid move at the tuner's profile, each out and back (``measure_move``, band
+/-5000: travel 2000 allows the tuner test moves of 1500 at most), the worse of out and back.
A combination holds when the move ends within 3 counts with an overshoot of at most 20 counts
(1 % of the move); the step's figures are shown beside it.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import lm629_host
from lm629_host.errors import MotionError
from lm629_host.bench.tuning import autotune, measure_move
from lm629_host.physics.axis import Gains
from lm629_host.physics.metrics import MoveMetrics, score
from lm629_host.physics.predict import MoveProfile

MOTORS = (
    ("default", ""),
    ("10x inertia", "inertia=4e-5"),
    ("holding load", "load_torque=0.004"),
    ("holding load 0.005", "load_torque=0.005"),
    ("low friction", "friction=2e-7&coulomb=2e-5"),
    ("slow amplifier (3 V)", "amp_volts=3"),
)
TRAVEL = 5000
DISTANCE = 2000
TOLERANCE = 2
DURATION = 1.0  #: seconds recorded after each step of the test move (every motor settles)
POLL = 0.002


def url_of(base: str, params: str) -> str:
    if not params:
        return base
    return base + ("&" if "?" in base else "?") + params


def fresh(url: str) -> lm629_host.LM629:
    chip = lm629_host.open(url)
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    return chip


Measured = tuple[MoveMetrics, MoveMetrics] | None  #: (step, move), None: a fault


def measure(url: str, g: Gains, profile: MoveProfile) -> Measured:
    out = []
    for p in (None, profile):
        with fresh(url) as chip:
            try:
                m, _rec = measure_move(chip, g, distance=DISTANCE, travel=TRAVEL,
                                       duration_s=DURATION, tolerance=TOLERANCE, poll_s=POLL,
                                       profile=p)
            except MotionError:
                return None
        out.append(m)
    return out[0], out[1]


def cost(m: Measured) -> float:
    return float("inf") if m is None else sum(score(x, DURATION, TOLERANCE) for x in m)


def _figures(m: MoveMetrics) -> str:
    settle = "-" if m.settle_s is None else f"{m.settle_s * 1e3:.0f}"
    return (f"{m.final_error:+d} | {m.overshoot} | {settle} | {abs(m.peak_following_error)} | "
            f"{m.hunt}")


def row(name: str, what: str, g: Gains, m: Measured) -> str:
    if m is None:
        return f"| {name} | {what} | {g} | fault | | | | | fault | | | | |"
    return f"| {name} | {what} | {g} | {_figures(m[0])} | {_figures(m[1])} |"


MATRIX_URLS = ("sim://", "sim+emu://", "sim+avr://", "sim+ftdi://",
               "sim+emu://?usb=uno&fast_baud=1000000")
MATRIX_MOTORS = (("default", ""), ("10x inertia", "inertia=4e-5"),
                 ("holding load 0.005 N m", "load_torque=0.005"))
MATRIX_TRAVEL = 2000  #: autotune's travel in the acceptance matrix


def matrix(urls: list[str]) -> int:
    """The acceptance table; the number of combinations that hold."""
    print(f"autotune(chip, travel={MATRIX_TRAVEL}), then {DISTANCE}-count moves out and back "
          f"with the gains loaded (worse of the two); holds: the move within 3 counts, "
          f"overshoot <= {DISTANCE // 100}")
    print("| transport | motor | gains | step: final error | overshoot | move: final error | "
          "overshoot | peak following error | holds | wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    held = 0
    for base in urls:
        for name, params in MATRIX_MOTORS:
            t = time.perf_counter()
            with fresh(url_of(base, params)) as chip:
                try:
                    r = autotune(chip, travel=MATRIX_TRAVEL)
                    assert r.profile is not None
                    step, _ = measure_move(chip, None, distance=DISTANCE, travel=TRAVEL,
                                           duration_s=DURATION, tolerance=TOLERANCE)
                    move, _ = measure_move(chip, None, distance=DISTANCE, travel=TRAVEL,
                                           duration_s=DURATION, tolerance=TOLERANCE,
                                           profile=r.profile)
                except MotionError as exc:
                    print(f"| {base} | {name} | fault: {str(exc)[:120]} | | | | | | no | "
                          f"{time.perf_counter() - t:.0f} |")
                    sys.stdout.flush()
                    continue
            ok = abs(move.final_error) <= 3 and move.overshoot <= DISTANCE // 100
            held += ok
            print(f"| {base} | {name} | {r.gains} | {step.final_error:+d} | {step.overshoot} | "
                  f"{move.final_error:+d} | {move.overshoot} | {abs(move.peak_following_error)} "
                  f"| {'yes' if ok else 'NO'} | {time.perf_counter() - t:.0f} |")
            sys.stdout.flush()
    print(f"{held} of {len(urls) * len(MATRIX_MOTORS)} hold")
    return held


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--url", default="sim://", help="base URL (motor parameters are appended)")
    ap.add_argument("--quick", action="store_true", help="a coarse grid")
    ap.add_argument("--motor", action="append", help="only these motors (names as listed)")
    ap.add_argument("--matrix", action="store_true",
                    help="the acceptance matrix: autotune(travel=2000) on 5 transports x 3 "
                         "motors, then 2000-count moves (--url: only that transport)")
    args = ap.parse_args()
    if args.matrix:
        matrix([args.url] if args.url != "sim://" or "--url" in sys.argv else list(MATRIX_URLS))
        return
    if args.quick:
        grid = list(itertools.product((25, 100, 400), (0, 16), (0, 1000, 4000, 16000)))
    else:
        grid = list(itertools.product((25, 50, 100, 200, 400, 800), (0, 4, 16, 64),
                                      (0, 300, 1000, 3000, 10000, 30000)))
    print(f"grid: {len(grid)} points (kp x ki x kd, il 4000, ds 1); test moves "
          f"{DISTANCE:+d} counts out and back (a step, and a trapezoid at the tuner's profile), "
          f"tolerance {TOLERANCE}, {DURATION:g} s per move after its profile")
    print("| motor | gains from | gains | step: final error | overshoot | settle ms | "
          "peak following error | hunting | move: final error | overshoot | settle ms after "
          "the profile | peak following error | hunting |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, params in MOTORS:
        if args.motor and name not in args.motor:
            continue
        url = url_of(args.url, params)
        t = time.perf_counter()
        with fresh(url) as chip:
            result = autotune(chip, travel=TRAVEL, distance=DISTANCE, tolerance=TOLERANCE)
        tune_s = time.perf_counter() - t
        assert result.profile is not None
        tuned = measure(url, result.gains, result.profile)
        best = None
        faults = 0
        t = time.perf_counter()
        for kp, ki, kd in grid:
            g = Gains(kp, ki, kd, 4000 if ki else 0)
            m = measure(url, g, result.profile)
            faults += m is None
            if best is None or cost(m) < cost(best[1]):
                best = (g, m)
        grid_s = time.perf_counter() - t
        assert best is not None
        print(row(f"{name} (`{params or 'defaults'}`, move {result.profile})",
                  f"tune ({tune_s:.1f} s wall)", result.gains, tuned))
        print(row("", f"grid best of {len(grid)} ({grid_s:.0f} s wall, {faults} left the band)",
                  best[0], best[1]))
        sys.stdout.flush()


if __name__ == "__main__":
    main()
