"""Piece timing of a shaped move: the bridge's timer (PROFILE) against pieces timed from the
host, on the simulated transports (AN-706 4.5.3; docs/python.md, "Shaped moves").

    python3 tools/bench_profile.py [URL ...]

Default URLs: the firmware in simavr and the Python far end behind an Uno's USB chip, and
sim://.  The move: 20000 counts along SCurve(20000 counts/s, 150000 counts/s^2, 3e6 counts/s^3),
59 pieces of 20 ms after the first.  Prints, per URL, the bridge's largest lateness of a piece
on its own clock, then the same move with the pieces timed from the host (``far_profiles``
turned off): their largest and mean lateness on the transport's clock.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import lm629_host
from lm629_host.chip.shapes import SCurve

URLS = ("sim+avr://?usb=uno&fast_baud=1000000", "sim+emu://?usb=uno&fast_baud=1000000", "sim://")


def main(urls: list[str]) -> int:
    for url in urls or URLS:
        for far in (True, False):
            with lm629_host.open(url) as chip:
                chip.reset()
                chip.load_filter(kp=20, kd=100)
                chip.update_filter()
                if not far and not chip.transport.far_profiles:
                    continue  # the host times them anyway: printed once, below
                chip.transport.far_profiles = far and chip.transport.far_profiles
                move = chip.move_profile(20000, SCurve(20000, 150000, 3e6))
                result = move.wait()
                late = move.jitter[1:]
                if move.far and move.far_state is not None:
                    how = (f"bridge's timer: {move.far_state.issued} pieces, largest lateness "
                           f"{move.far_state.late_max_s * 1e3:.3f} ms")
                else:
                    how = (f"host-timed: {len(late)} pieces, lateness max "
                           f"{max(late) * 1e3:.3f} ms, mean {sum(late) / len(late) * 1e3:.3f} ms")
                print(f"{url}: {how}; ended {result.error:+d} counts from the target")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
