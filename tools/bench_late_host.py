#!/usr/bin/env python3
"""How late the failsafe's keep-alive gets on a busy machine, and whether the bridge trips.

    python3 tools/bench_late_host.py                 # 60 s per case, two CPU hogs beside it
    python3 tools/bench_late_host.py --seconds 180 --hogs 2 --far-end firmware

A served bench (``lm629 sim serve --pty``, the Python far end or the firmware in simavr, in
real time) in its own process; this process opens it with the default failsafe (0.5 s, fed by
the keep-alive thread after 0.125 s of quiet) and spends ``--seconds`` in each case: idle
(``time.sleep``), a main thread burning CPU in Python, and that burning done while holding
``transport.lock``.  ``--hogs`` processes burn CPU beside it all the while.  Printed per case:
the keep-alive thread's worst gap between two turns (it turns every 31 ms when it can), how
many turns came later than the feed period, and whether the bridge tripped.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import lm629_host
from lm629_host.transports.link import LinkTransport


def _burn(seconds: float) -> None:
    end = time.monotonic() + seconds
    x = 0
    while time.monotonic() < end:
        for k in range(1000):
            x += k * k


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--hogs", type=int, default=2)
    ap.add_argument("--far-end", choices=("python", "firmware"), default="python")
    args = ap.parse_args()
    exe = str(Path(sys.executable).with_name("lm629"))
    with tempfile.TemporaryDirectory() as tmp:
        link = os.path.join(tmp, "bench")
        argv = [exe, "sim", "serve", "--pty", link]
        if args.far_end == "firmware":
            argv += ["--firmware", "--url", "sim://?axes=4"]
        server = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True)
        hogs = [subprocess.Popen([sys.executable, "-c", "while 1: pass"])
                for _ in range(args.hogs)]
        try:
            assert server.stdout is not None
            print(server.stdout.readline().strip())
            chip = lm629_host.open(f"serial://{link}")
            t = chip.transport
            assert isinstance(t, LinkTransport)
            ka = t.failsafe.keepalive
            assert ka is not None
            print(f"failsafe {t.failsafe.timeout_s} s, fed after {t.failsafe.feed_period_s} s quiet; "
                  f"{args.hogs} CPU hog(s); {os.cpu_count()} CPU(s); {args.seconds:g} s a case")
            cases = {"idle": lambda: time.sleep(args.seconds),
                     "busy main thread": lambda: _burn(args.seconds)}

            def locked() -> None:
                with t.lock:
                    _burn(args.seconds)
            cases["busy, holding transport.lock"] = locked
            for name, run in cases.items():
                ka.worst_gap_s, ka.gaps = 0.0, 0
                run()
                state = t.failsafe_state()
                assert state is not None
                print(f"{name:30s} worst keep-alive gap {ka.worst_gap_s * 1e3:6.1f} ms, "
                      f"{ka.gaps} turn(s) later than {t.failsafe.feed_period_s * 1e3:.0f} ms, "
                      f"{'TRIPPED' if state.tripped else 'not tripped'}", flush=True)
                if state.tripped:
                    t.clear_failsafe()
            chip.close()
        finally:
            for h in hogs:
                h.kill()
            server.terminate()
            server.wait(timeout=20)


if __name__ == "__main__":
    main()
