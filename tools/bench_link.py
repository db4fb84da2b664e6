#!/usr/bin/env python3
"""Figures of the bridge link (host side), printed; nothing is asserted.

1. Position polling in SIMULATED time over ``sim+emu://`` (LinkTransport to the Python bridge)
   at 115200 and 1,000,000 baud: microseconds per ``read_real_position()``, bytes on the wire
   per poll, the wire limit (bytes x 10 / baud) and the ratio limit/actual (target >= 70 %).
   With ``--avr`` the same through ``sim+avr://`` (the compiled firmware), when available.
2. Round trips per typed command: LTRJ with six words + STT as one program, a poll, a reset.
3. Host CPU per poll in WALL time: ``sim+emu://`` against ``sim://`` in the same process
   (the link's framing, CRC and emulated far end, as a ratio to the direct model).
4. ``serial://`` on a real pseudo-terminal served by ``lm629 sim serve``'s server: measured
   round trip (median PING) and polls per second.

Run:  python3 tools/bench_link.py [--n 2000] [--avr]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import lm629_host


def poll_sim_time(url: str, n: int) -> tuple[float, float]:
    """(seconds per poll on the transport's clock, bytes per poll on the wire)."""
    with lm629_host.open(url) as chip:
        chip.reset()
        st = chip.transport.stats
        st.reset()
        t0 = chip.clock.now()
        for _ in range(n):
            chip.read_real_position()
        per = (chip.clock.now() - t0) / n
        return per, (st.bytes_out + st.bytes_in) / n


def wall_per_call(url: str, n: int) -> float:
    with lm629_host.open(url) as chip:
        chip.reset()
        chip.read_real_position()
        t0 = time.perf_counter()
        for _ in range(n):
            chip.read_real_position()
        return (time.perf_counter() - t0) / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--avr", action="store_true", help="also sim+avr:// (the real firmware)")
    args = ap.parse_args()
    n = args.n

    print("1. read_real_position() back to back, simulated time")
    schemes = ["sim+emu"] + (["sim+avr"] if args.avr else [])
    for scheme in schemes:
        for baud in (115200, 1_000_000):
            try:
                per, nbytes = poll_sim_time(f"{scheme}://?baud={baud}", n if scheme == "sim+emu"
                                            else max(50, n // 20))
            except Exception as exc:  # noqa: BLE001 - report and go on
                print(f"   {scheme}:// at {baud}: not available ({exc})")
                continue
            wire = nbytes * 10 / baud
            print(f"   {scheme}:// {baud:>8} baud: {per * 1e6:8.1f} us/poll, {nbytes:.0f} bytes, "
                  f"wire limit {wire * 1e6:7.1f} us -> {wire / per * 100:5.1f} % of the wire limit")

    print("2. round trips per typed command (sim+emu://)")
    with lm629_host.open("sim+emu://") as chip:
        st = chip.transport.stats
        for name, fn in [
            ("reset (AN-706 4.4.1 program)", chip.reset),
            ("load_filter(kp, ki, kd, il)", lambda: chip.load_filter(kp=20, ki=1, kd=100, il=50)),
            ("LTRJ six words + STT", lambda: chip.load_trajectory(
                acceleration=100, velocity=65536, position=4000, start=True)),
            ("read_real_position()", chip.read_real_position),
            ("snapshot() (6 commands, 9 words)", chip.snapshot),
        ]:
            st.reset()
            fn()
            print(f"   {name:34s} {st.round_trips} round trip(s), {st.bytes_out} bytes out, "
                  f"{st.bytes_in} bytes in")

    print("3. host CPU per poll, wall time")
    direct = wall_per_call("sim://", n)
    link = wall_per_call("sim+emu://?baud=0", n)
    print(f"   sim://      {direct * 1e6:7.1f} us/poll (baseline)")
    print(f"   sim+emu://  {link * 1e6:7.1f} us/poll = {link / direct:.2f} x baseline "
          "(framing + CRC + emulated bridge)")

    print("4. serial:// on a pseudo-terminal (real time, lm629 sim serve's server)")
    from lm629_host.sim.serve import SimServer
    from lm629_host.transports.serial import SerialTransport
    with tempfile.TemporaryDirectory() as d:
        srv = SimServer(Path(d) / "lm629", "sim://").start()
        try:
            with lm629_host.open(f"serial://{srv.link}") as chip:
                t = chip.transport
                assert isinstance(t, SerialTransport)
                rtts = [t.ping() for _ in range(200)]
                chip.reset()
                m = min(n, 1000)
                t0 = time.perf_counter()
                for _ in range(m):
                    chip.read_real_position()
                dt = (time.perf_counter() - t0) / m
                print(f"   PING round trip: median {statistics.median(rtts) * 1e3:.3f} ms, "
                      f"p95 {sorted(rtts)[int(len(rtts) * 0.95)] * 1e3:.3f} ms; "
                      f"low latency: {t.low_latency}")
                print(f"   read_real_position(): {dt * 1e3:.3f} ms each, {1 / dt:.0f} polls/s")
        finally:
            srv.close()


if __name__ == "__main__":
    main()
