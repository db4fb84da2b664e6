#!/usr/bin/env python3
"""Twins of six benches with hidden parameters: the plant identified, saved, and simulated.

Each bench is a ``sim://`` URL whose motor the host does not know (inertia x0.3 and x10,
viscous friction, dry friction, a constant load, a lower amplifier voltage).  For each:

1. a fresh profile (``lm629 profile init``), then ``lm629 --profile FILE --port BENCH tune
   --travel 5000 --save --yes`` (gains and ``[axis.x.plant]``), and the twin
   ``sim://?profile=FILE&axis=x``;
2. on a fresh bench ``lm629 ... identify --travel 5000 --save --yes`` (the plant identified
   again, the profile's gains loaded back), and its twin;
3. the tuner's trapezoid move (2000 counts out and back at the words the tuner chose for the
   plant, the worse of out and back; ``tuning.measure_move``, recorded on the far side) with
   the saved gains on the bench and on both twins: overshoot and settle time after the
   profile's end.  Holds: each twin's overshoot within 2 counts or 10 % of the bench's and its
   settle time within 5 ms or 10 % (whichever larger);
4. ``lm629 twin check`` on the same bench (expect "matches", exit 0), with the bench's inertia
   doubled, and with its load doubled where it has one (expect "differs", exit 1).

``--transport uno``: the bench is the Python bridge far end behind an Uno's USB chip
(``sim+emu://?usb=uno&fast_baud=1000000``, simulated time); ``--transport served``: a served
bench, ``lm629 sim serve --pty LINK --url BENCH&usb=uno`` in its own process, in real time
(slow: tuning takes tens of seconds of wall time per bench).  The twins are ``sim://``.

    python3 tools/bench_twin.py                       # sim:// and uno
    python3 tools/bench_twin.py --transport served --bench "10x inertia"
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import sysconfig
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import lm629_host
from lm629_host.physics.pid import STEP_ACCELERATION, STEP_VELOCITY, sample_period_s
from lm629_host.config.profile import load_profile
from lm629_host.bench.tuning_session import measure_move
from lm629_host.physics.axis import Gains
from lm629_host.bench.twin import (
    MATCH_OVERSHOOT,
    SETTLE_BAND,
    Plant,
    Side,
    close,
    judged_side,
    settle_close,
    twin_profile,
)

#: name, the bench's hidden motor parameters, the same bench heavier, and with double load
BENCHES = (
    ("0.3x inertia", "inertia=1.2e-6", "inertia=2.4e-6", None),
    ("10x inertia", "inertia=4e-5", "inertia=8e-5", None),
    ("viscous friction", "friction=2e-4", "friction=2e-4&inertia=8e-6", None),
    ("dry friction", "coulomb=2e-3", "coulomb=2e-3&inertia=8e-6", None),
    ("constant load", "load_torque=0.003", "load_torque=0.003&inertia=8e-6",
     "load_torque=0.006"),
    ("amplifier 6 V", "amp_volts=6", "amp_volts=6&inertia=8e-6", None),
)
TRANSPORTS = {"sim": "sim://", "uno": "sim+emu://?usb=uno&fast_baud=1000000",
              "served": "served"}
TRAVEL = 5000
DISTANCE = 2000
DURATION = 0.6  #: seconds recorded after the move's profile


def exe() -> str:
    for path in (os.path.join(sysconfig.get_path("scripts"), "lm629"), shutil.which("lm629")):
        if path and os.path.exists(path):
            return path
    sys.exit("the lm629 console script is not installed (pip install -e .)")


def with_params(url: str, params: str) -> str:
    return url if not params else f"{url}{'&' if '?' in url else '?'}{params}"


def lm629(*args: str) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("LM629_PORT", "LM629_PROFILE")}
    return subprocess.run([exe(), *args], capture_output=True, text=True, env=env, timeout=600)


@contextmanager
def bench(transport: str, params: str, tmp: Path) -> Iterator[str]:
    """The bench's port URL, fresh: reset, holding at kp = 20 (a served one in its process)."""
    if transport != "served":
        url = with_params(TRANSPORTS[transport], params)
        yield url
        return
    link = tmp / "bench"
    proc = subprocess.Popen([exe(), "sim", "serve", "--pty", str(link), "--url",
                             with_params(with_params("sim://", params), "usb=uno")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        banner = proc.stdout.readline() if proc.stdout else ""
        if not banner.startswith("serving "):
            raise RuntimeError(banner + (proc.stderr.read() if proc.stderr else ""))
        yield f"serial://{link}"
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=30)


def fresh(url: str) -> lm629_host.LM629:
    """The bench reset, holding the shaft where it is at kp = 20 (the drive on: on a served
    bench time passes between commands, and a loaded shaft left with the drive off after the
    reset would fall meanwhile)."""
    chip = lm629_host.open(url)
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=STEP_ACCELERATION, velocity=STEP_VELOCITY,
                         position=chip.read_real_position(), start=True)
    return chip


def trapezoid(url: str, gains: Gains, plant: Plant) -> Side:
    move = twin_profile(plant, sample_period_s(8e6))
    with fresh(url) as chip:
        m, rec = measure_move(chip, gains, distance=DISTANCE, travel=TRAVEL,
                              duration_s=DURATION, tolerance=SETTLE_BAND, profile=move)
    return judged_side(m, rec, SETTLE_BAND)


def holds(bench: Side, twin: Side) -> bool:
    """Overshoot within 2 counts or 10 %, settle within 5 ms or 10 % (to within a count of
    the band: :func:`lm629_host.bench.twin.settle_close`)."""
    return settle_close(bench, twin) and close(bench.metrics.overshoot, twin.metrics.overshoot,
                                               *MATCH_OVERSHOOT)


def figures(side: Side) -> str:
    m = side.metrics

    def ms(s: float | None) -> str:
        return "never" if s is None else f"{s * 1e3:.1f}"

    lo, hi = side.settle_range
    return f"{m.overshoot} | {ms(m.settle_s)} ({ms(lo)}-{ms(hi)})"


def verdict(p: subprocess.CompletedProcess[str], expected: int = 0) -> str:
    if p.returncode != expected:  # the whole table, to see why
        print(p.stdout + p.stderr, file=sys.stderr)
    last = p.stdout.strip().splitlines()[-1] if p.stdout.strip() else p.stderr.strip()[-80:]
    return f"{last} ({p.returncode})"


def run_bench(transport: str, name: str, params: str, heavier: str, loaded: str | None,
              tmp: Path) -> tuple[str, bool]:
    path = tmp / "bench.toml"
    t0 = time.perf_counter()
    with bench(transport, params, tmp) as url:
        path.unlink(missing_ok=True)
        p = lm629("--port", "sim://", "profile", "init", str(path))
        if p.returncode:
            raise RuntimeError(p.stderr)
        fresh(url).close()
        p = lm629("--profile", str(path), "--port", url, "tune", "--travel", str(TRAVEL),
                  "--yes", "--save")
        if p.returncode:
            return f"| {name} | tune failed: {p.stderr.strip()[-200:]} |", False
        prof = load_profile(path)
        ax = prof.axis("x")
        assert ax.kp is not None and ax.plant is not None
        gains = Gains(ax.kp, ax.ki or 0, ax.kd or 0, ax.il or 0, ax.ds)
        tuned_plant = Plant.from_values(ax.plant)
        print(f"{name}: tune's plant {tuned_plant.values()}", file=sys.stderr)
        shutil.copy(path, tmp / "tuned.toml")
        fresh(url).close()
        p = lm629("--profile", str(path), "--port", url, "identify", "--travel", str(TRAVEL),
                  "--yes", "--save")
        if p.returncode:
            return f"| {name} | identify failed: {p.stderr.strip()[-200:]} |", False
        ident_plant = Plant.from_values(load_profile(path).axis("x").plant or {})
        m_bench = trapezoid(url, gains, tuned_plant)
        m_tuned = trapezoid(f"sim://?profile={tmp / 'tuned.toml'}&axis=x", gains, tuned_plant)
        m_ident = trapezoid(f"sim://?profile={path}&axis=x", gains, tuned_plant)
        fresh(url).close()
        same = lm629("--profile", str(path), "--port", url, "twin", "check", "--travel",
                     str(TRAVEL), "--yes")
    ok = holds(m_bench, m_tuned) and holds(m_bench, m_ident) and same.returncode == 0
    checks = [verdict(same)]
    for changed in (heavier, loaded):
        if changed is None:
            continue
        with bench(transport, changed, tmp) as url2:
            fresh(url2).close()
            p = lm629("--profile", str(path), "--port", url2, "twin", "check", "--travel",
                      str(TRAVEL), "--yes")
        checks.append(verdict(p, 1))
        ok = ok and p.returncode == 1
    plant = ", ".join(f"{k}={v}" for k, v in ident_plant.values().items() if k != "reversed")
    row = (f"| {name} (`{params}`) | {gains} | {plant} | {figures(m_bench)} | "
           f"{figures(m_tuned)} | {figures(m_ident)} | {' / '.join(checks)} | "
           f"{'yes' if ok else 'NO'} | {time.perf_counter() - t0:.0f} |")
    return row, ok


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--transport", action="append", choices=sorted(TRANSPORTS),
                    help="sim (sim://), uno (sim+emu:// behind an Uno's USB), served (a "
                         "served bench behind usb=uno, real time); default sim and uno")
    ap.add_argument("--bench", action="append", help="only these benches (names as listed)")
    args = ap.parse_args()
    transports = args.transport or ["sim", "uno"]
    print(f"tune --save and identify --save (travel {TRAVEL}), then the tuner's trapezoid "
          f"move, {DISTANCE} counts out and back (worse of the two; settle after the "
          "profile's end) on the bench and on its twins; twin check on the same bench, then "
          "with its inertia doubled, and its load doubled where it has one")
    held = total = 0
    for transport in transports:
        print(f"\n{transport}: {TRANSPORTS[transport]}")
        print("| bench | tuned gains | plant (identify) | bench: overshoot ct | settle ms (band +/-1) | "
              "twin (tune): overshoot | settle | twin (identify): overshoot | settle | "
              "twin check: same / 2x inertia / 2x load | holds | wall s |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for name, params, heavier, loaded in BENCHES:
            if args.bench and name not in args.bench:
                continue
            with tempfile.TemporaryDirectory() as tmp:
                row, ok = run_bench(transport, name, params, heavier, loaded, Path(tmp))
            print(row)
            sys.stdout.flush()
            held += ok
            total += 1
    print(f"\n{held} of {total} hold")


if __name__ == "__main__":
    main()
