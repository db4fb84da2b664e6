#!/usr/bin/env python3
"""Every single wiring fault on the simulated benches: does ``lm629 wiring --check`` name it?

Runs the check on a correct bench and on each of the 44 single faults (``wiring=dN-low``,
``dN-high``, ``dN-dM``; ``dN-open`` reads as ``dN-high``) per URL and prints, per URL, how many
are named right (the suspects are exactly the LM629 lines of the fault, and each message names
the adapter's pin), the wrong ones in full, and the wall time per check.

    python3 tools/wiring_faults.py                       # sim://, sim+emu://, sim+avr://, sim+ftdi://
    python3 tools/wiring_faults.py 'sim+emu://?usb=uno'  # any simulated URLs
"""

from __future__ import annotations

import logging
import re
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import lm629_host
from lm629_host.wiring.connections import adapter_pin
from lm629_host.bench.wiring_check import adapter_for, check_wiring, suspects_of_data_bus

URLS = ["sim://", "sim+emu://", "sim+avr://", "sim+ftdi://"]


def main(urls: list[str]) -> int:
    logging.disable(logging.WARNING)  # the FT232H's busy repeats under a fault: one per command
    bad_total = 0
    for url in urls or URLS:
        adapter = adapter_for(url)
        sep = "&" if "?" in url else "?"
        wrong = []
        t0 = time.perf_counter()
        faults = [""] + [n for n, _ in suspects_of_data_bus()] + ["d3-open"]
        for fault in faults:
            with lm629_host.open(url + (f"{sep}wiring={fault}" if fault else "")) as chip:
                report = check_wiring(chip)
            want = {f"D{x}" for x in re.findall(r"d(\d)", fault)}
            got = {s.line for s in report.suspects}
            named = all(adapter_pin(adapter, s.line) in s.message for s in report.suspects)
            if got != want or not named or (fault and len(report.suspects) != len(want)):
                wrong.append((fault or "correct", report.lines()))
        dt = (time.perf_counter() - t0) / len(faults)
        print(f"{url:40s} {len(faults) - len(wrong)}/{len(faults)} named right "
              f"(a correct bench and {len(faults) - 1} faults), {dt * 1e3:.0f} ms per check")
        for fault, lines in wrong:
            print(f"    {fault}: {' | '.join(lines)}")
        bad_total += len(wrong)
    return 1 if bad_total else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
