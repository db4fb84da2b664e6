#!/usr/bin/env python3
"""Recording on the far side and fewer exchanges (bridge-timed rows; batches and one-program moves), measured.

    python3 tools/bench_record.py [--query 'usb=uno&'] [--avr/--no-avr]

For ``sim://``, ``sim+emu://?fast_baud=1000000`` and ``sim+avr://?fast_baud=1000000`` (the
compiled firmware; ``--query`` is put in front of the link's parameters, e.g. a USB adapter
model): ``chip.record(1e-3, 0.5)`` during a 4-count/sample move (rows, the share 1 ms +- 20 us
apart, the longest gap, the desired position's step per row, exchanges), the exchanges of
``move_to``, of a 10-call ``batch()`` and of ``move_to(4000).wait()`` with its duration, all in
simulated time.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import lm629_host


def measure(url: str) -> str:
    with lm629_host.open(url) as chip:
        st = chip.transport.stats
        chip.reset()
        chip.load_filter(kp=20, kd=100)
        chip.update_filter()
        before = st.round_trips
        move = chip.move_to(100_000, velocity=4 * 65536, acceleration=6553)
        start = st.round_trips - before
        chip.clock.sleep(0.05)
        before = st.round_trips
        tr = chip.record(1e-3, 0.5)
        rec = st.round_trips - before
        gaps = [b - a for a, b in zip(tr.t, tr.t[1:])]
        on_time = sum(1 for d in gaps if abs(d - 1e-3) <= 20e-6) / len(gaps)
        steps = [b - a for a, b in zip(tr.desired, tr.desired[1:])]
        chip.load_trajectory(stop="abrupt", start=True)
        del move
        before = st.round_trips
        with chip.batch() as b:
            for _ in range(5):
                b.read_real_position()
                b.read_desired_position()
        batch = st.round_trips - before
        chip.reset()
        chip.load_filter(kp=20, kd=100)
        chip.update_filter()
        before = st.round_trips
        r = chip.move_to(4000, velocity=4 * 65536, acceleration=6553).wait()
        wait = st.round_trips - before
    return (f"{url}: record(1e-3, 0.5) {len(tr)} rows, {100 * on_time:.1f} % 1 ms +- 20 us "
            f"apart, longest gap {max(gaps) * 1e3:.3f} ms, desired {min(steps)}..{max(steps)} "
            f"counts/row, {len(tr.missing)} missing, {rec} exchange(s); move_to {start} "
            f"exchange(s); batch of 10: {batch}; move_to(4000).wait(): {wait} exchanges, "
            f"done {r.duration * 1e3:.1f} ms after the start")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--query", default="", help="put before the links' parameters, e.g. 'usb=uno&'")
    ap.add_argument("--no-avr", action="store_true", help="leave out sim+avr:// (no toolchain)")
    a = ap.parse_args()
    urls = ["sim://", f"sim+emu://?{a.query}fast_baud=1000000"]
    if not a.no_avr:
        urls.append(f"sim+avr://?{a.query}fast_baud=1000000")
    for url in urls:
        print(measure(url), flush=True)


if __name__ == "__main__":
    main()
