"""How long the bench commands take: ``lm629 bringup`` per transport, ``lm629 step``, start-up.

Prints, for each simulated transport, the wall time of the whole bring-up sequence
(:func:`lm629_host.bench.bringup.run_bringup`, in-process), the simulated time it covered and the
ratio, plus the bus programs and round trips it needed; then the wall time of a 0.5 s step
capture (CSV only) and of starting the ``lm629`` console script (``--help``) in a subprocess.

    python3 tools/bench_cli.py            # sim, sim+emu, sim+ftdi (sim+avr with --avr)
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time

import lm629_host
from lm629_host.bench.bringup import run_bringup
from lm629_host.bench.capture import capture_move, write_csv


def bench_bringup(url: str, repeats: int) -> None:
    walls = []
    for _ in range(repeats):
        with lm629_host.open(url) as chip:
            t_sim = chip.clock.now()
            t0 = time.perf_counter()
            report = run_bringup(chip)
            wall = time.perf_counter() - t0
            simulated = chip.clock.now() - t_sim
            stats = chip.transport.stats
        walls.append(wall)
    wall = min(walls)
    print(f"bringup {url:12s} {'PASS' if report.passed else 'FAIL'}  wall {wall:6.3f} s  "
          f"simulated {simulated:6.3f} s  ({simulated / wall:6.1f}x real time)  "
          f"programs {stats.programs}  round trips {stats.round_trips}")


def bench_step(repeats: int) -> None:
    walls = []
    with tempfile.TemporaryDirectory() as d:
        for _ in range(repeats):
            with lm629_host.open("sim://") as chip:
                chip.reset()
                t0 = time.perf_counter()
                cap = capture_move(chip, 200, duration_s=0.5, interval_s=0.001,
                                   filter={"kp": 20, "kd": 100})
                write_csv(cap, f"{d}/s.csv")
                walls.append(time.perf_counter() - t0)
    print(f"step    sim://        {len(cap.rows)} snapshots over 0.5 s simulated: wall "
          f"{min(walls):.3f} s ({min(walls) / len(cap.rows) * 1e6:.0f} us per snapshot)")


def bench_startup(repeats: int) -> None:
    exe = shutil.which("lm629")
    if exe is None:
        print("startup: the lm629 script is not installed (pip install -e .)")
        return
    walls = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run([exe, "--help"], capture_output=True, check=True)
        walls.append(time.perf_counter() - t0)
    print(f"startup lm629 --help  wall {min(walls):.3f} s (best of {repeats})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--avr", action="store_true", help="also sim+avr:// (builds the firmware)")
    args = ap.parse_args()
    urls = ["sim://", "sim+emu://", "sim+ftdi://"] + (["sim+avr://"] if args.avr else [])
    print(f"python {sys.version.split()[0]}, lm629-host {lm629_host.__version__}")
    for url in urls:
        bench_bringup(url, args.repeats)
    bench_step(args.repeats)
    bench_startup(args.repeats)


if __name__ == "__main__":
    main()
