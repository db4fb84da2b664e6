#!/usr/bin/env python3
"""Benchmark of the FT232H transport on the emulated FT232H (``sim+ftdi://``).

Prints, per typed command: USB transfers (bulk OUT + bulk IN, counted at the emulated device's
endpoints), bytes each way, bus cycles, emulated microseconds (the time the command takes on
the emulated FT232H and chip: USB transfers, MPSSE commands, the stream's busy waits), and the
host's wall-clock cost per command against ``sim://`` in the same process (how much the real
transport + pyftdi + pyusb + the emulator cost over the bare model).

    python3 tools/bench_ftdi.py            # default: usb_us=125, busy_us=100
    python3 tools/bench_ftdi.py --repeat 200 --url 'sim+ftdi://?busy_us=25'
    python3 tools/bench_ftdi.py --url 'sim+ftdi://?busy_pin=gpiol1'   # D0 wired to GPIOL1

The last column is RDRP's and LTRJ(6)+STT's emulated time over the limits of one exchange
(``bench_all.FTDI_LIMIT_US``: two 125 us microframes plus the chip's own time).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

from bench_all import FTDI_LIMIT_US  # tools/ is on the path when this script runs

import lm629_host
from lm629_host import LM629

#: the rows measured against a limit of one exchange
LIMIT_OF = {"RDRP": "rdrp", "LTRJ (6 words) + STT": "ltrj_stt"}

COMMANDS: list[tuple[str, Callable[[LM629], object]]] = [
    ("RDRP", lambda c: c.read_real_position()),
    ("LTRJ (6 words)", lambda c: c.load_trajectory(acceleration=0x1234, velocity=0x56789,
                                                   position=-1000)),
    ("STT", lambda c: c.start()),
    ("LTRJ (6 words) + STT", lambda c: c.load_trajectory(acceleration=0x1234, velocity=0x56789,
                                                         position=-1000, start=True)),
    ("LFIL (4 coeff.)", lambda c: c.load_filter(kp=20, ki=1, kd=100, il=500)),
    ("RDSTAT", lambda c: c.read_status()),
    ("snapshot (6 reads)", lambda c: c.snapshot()),
    ("reset (AN-706)", lambda c: c.reset()),
]


def prepare(chip: LM629, name: str) -> None:
    """What a command needs first (not counted)."""
    if name in ("STT", "LTRJ (6 words) + STT"):
        # the last STT started a move, and the chip refuses an acceleration change while it
        # moves with the drive on (CommandError at the next STT): motor off first
        chip.load_trajectory(stop="off", start=True)
    if name == "STT":  # an STT needs a trajectory loaded
        chip.load_trajectory(acceleration=0x1234, velocity=0x56789, position=-1000)
    # the 10 ms between trajectory updates (AN-706 4.6.2) is the rule's time, not the
    # exchange's: waited for here, on the chip's clock, before the command is timed
    chip.clock.sleep(chip.update_due())


def measure(url: str, name: str, call: Callable[[LM629], object], repeat: int) -> dict[str, float]:
    with lm629_host.open(url) as chip:
        chip.reset()
        t = chip.transport
        device = getattr(t, "device", None)
        usb = emu = wall = 0.0
        stats0 = None
        for _ in range(repeat):
            prepare(chip, name)
            before = t.stats.as_dict()
            c0 = (device.counters.bulk_out + device.counters.bulk_in) if device else 0
            e0 = chip.clock.now()
            w0 = time.perf_counter()
            call(chip)
            wall += time.perf_counter() - w0
            emu += chip.clock.now() - e0
            if device:
                usb += device.counters.bulk_out + device.counters.bulk_in - c0
            after = t.stats.as_dict()
            delta = {k: after[k] - before[k] for k in after}
            stats0 = delta if stats0 is None else {k: stats0[k] + delta[k] for k in delta}
        assert stats0 is not None
        out = {k: v / repeat for k, v in stats0.items()}
        out.update(usb=usb / repeat, emu_us=emu / repeat * 1e6, wall_us=wall / repeat * 1e6)
        return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--url", default="sim+ftdi://")
    ap.add_argument("--repeat", type=int, default=100)
    args = ap.parse_args()
    print(f"{args.url}, {args.repeat} runs per command; baseline sim:// in the same process")
    print(f"{'command':20s} {'USB xfers':>9s} {'rtrips':>6s} {'out B':>6s} {'in B':>5s} "
          f"{'cycles':>6s} {'retries':>7s} {'emul. us':>9s} {'host us':>8s} {'sim:// us':>9s} "
          f"{'x sim':>6s} {'x limit':>14s}")
    for name, call in COMMANDS:
        f = measure(args.url, name, call, args.repeat)
        base = measure("sim://", name, call, args.repeat)
        print(f"{name:20s} {f['usb']:9.1f} {f['round_trips']:6.1f} {f['bytes_out']:6.0f} "
              f"{f['bytes_in']:5.0f} {f['bus_cycles']:6.0f} {f['retries']:7.1f} "
              f"{f['emu_us']:9.1f} {f['wall_us']:8.0f} {base['wall_us']:9.1f} "
              f"{f['wall_us'] / base['wall_us']:6.1f} {limit(name, f['emu_us']):>14s}")


def limit(name: str, emu_us: float) -> str:
    """``emu_us`` over the limit of one exchange for ``name``, e.g. "1.06x of 478"."""
    key = LIMIT_OF.get(name)
    if key is None:
        return ""
    return f"{emu_us / FTDI_LIMIT_US[key]:.2f}x of {FTDI_LIMIT_US[key]:.0f}"


if __name__ == "__main__":
    main()
