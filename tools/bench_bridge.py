#!/usr/bin/env python3
"""Figures of the bridge firmware, measured on the compiled firmware in simavr (``sim+avr://``);
printed, nothing asserted.

1. Position polling in SIMULATED time (AVR cycles / 16 MHz) at 115200 and 1,000,000 baud:
   microseconds per ``read_real_position()`` back to back (its program sent by its code once
   the bridge keeps it: PROTOCOL.md, "The compact RUN"), bytes on the wire per poll, the
   wire limit (bytes x 10 / baud) and its ratio to the measured time (target >= 70 %).  Also
   the limit of the simulated line itself (simavr sends 11 bit times a byte, and 115200 on a
   16 MHz AVR is really 117647 baud) and what is left for the firmware per poll.
2. Round trips per typed command (exactly 1 each: LTRJ with six words, LTRJ + STT as one).
3. Simulation speed in WALL time: sim+avr:// per poll against sim:// in the same process.
4. Flash and RAM use of the firmware (``make size``).

Run:  python3 tools/bench_bridge.py [--n 300]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import lm629_host  # noqa: E402 - after sys.path.insert
from lm629_host.sim.harness import ensure_built  # noqa: E402 - after sys.path.insert

#: the rate the AVR's UART really runs at: 16 MHz / 8 / (UBRR + 1) with U2X
REAL_BAUD = {115200: 16e6 / 8 / 17, 1_000_000: 16e6 / 8 / 2}


def poll(url: str, n: int) -> tuple[float, float, float]:
    """(simulated s per poll, bytes per poll, wall s per poll)."""
    with lm629_host.open(url) as chip:
        chip.reset()
        chip.read_real_position()
        st = chip.transport.stats
        st.reset()
        t0, w0 = chip.clock.now(), time.perf_counter()
        for _ in range(n):
            chip.read_real_position()
        return ((chip.clock.now() - t0) / n, (st.bytes_out + st.bytes_in) / n,
                (time.perf_counter() - w0) / n)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=300)
    args = ap.parse_args()
    ensure_built()
    n = args.n

    print("1. read_real_position() back to back through the compiled firmware, simulated time")
    walls = {}
    for baud in (115200, 1_000_000):
        per, nbytes, wall = poll(f"sim+avr://?baud={baud}", n)
        walls[baud] = (wall, per)
        wire = nbytes * 10 / baud
        line = nbytes * 11 / REAL_BAUD[baud]
        print(f"   {baud:>8} baud: {per * 1e6:7.1f} us/poll, {nbytes:.0f} bytes on the wire, "
              f"wire limit {wire * 1e6:6.1f} us -> {wire / per * 100:5.1f} % of the wire limit; "
              f"simulated line {line * 1e6:6.1f} us ({line / per * 100:5.1f} %), "
              f"firmware + bus {max(0.0, per - line) * 1e6:5.1f} us")

    print("2. round trips per typed command (sim+avr://)")
    with lm629_host.open("sim+avr://") as chip:
        st = chip.transport.stats
        for name, fn in [
            ("reset()", chip.reset),
            ("load_filter(kp, ki, kd, il)", lambda: chip.load_filter(kp=20, ki=1, kd=100, il=50)),
            ("LTRJ six words", lambda: chip.load_trajectory(
                acceleration=100, velocity=65536, position=4000)),
            ("LTRJ six words + STT, one program", lambda: chip.load_trajectory(
                acceleration=100, velocity=65536, position=-4000, start=True)),
            ("read_real_position()", chip.read_real_position),
            ("read_status()", chip.read_status),
        ]:
            st.reset()
            t0 = chip.clock.now()
            fn()
            print(f"   {name:34s} {st.round_trips} round trip(s), {st.bytes_out:3d} bytes out, "
                  f"{st.bytes_in:3d} in, {(chip.clock.now() - t0) * 1e6:7.0f} us simulated")

    print("3. simulation speed, wall time per poll")
    _, _, direct = poll("sim://", n * 10)
    for baud, (wall, per) in walls.items():
        print(f"   sim+avr:// at {baud:>8}: {wall * 1e6:7.0f} us/poll wall = {wall / direct:6.1f} x "
              f"sim:// ({direct * 1e6:.1f} us); {per / wall:5.2f} x real time")

    print("4. firmware size (make size)")
    r = subprocess.run(["make", "-s", "-C", str(ROOT / "firmware_bridge"), "size"],
                       capture_output=True, text=True)
    print("   " + r.stdout.strip())


if __name__ == "__main__":
    main()
