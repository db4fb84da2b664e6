#!/usr/bin/env python3
"""A served bench behind the real ser2net, measured: the round trip and a read's cost through
``rfc2217://`` and ``socket://``, against the same bench on its pseudo-terminal.

    python3 tools/bench_ser2net.py [--far python|firmware] [--reads 300]

One ``lm629 sim serve --pty`` bench (its own process, real time) and, for each way in, the
ser2net that tests/lab/ser2net_fixture.py starts (127.0.0.1, a free port), with its default
options and with ``chardelay: false`` (ser2net otherwise holds what the device sends for a
few character times, hoping for more, before it goes out on TCP).  Per way: the link's rate
after the handshake, the time ``lm629_host.open`` took, the median PING round trip (the
transport's own, 5 PINGs), and the mean time of ``read_real_position()`` over ``--reads``
calls, with its ratio to the pty's in this run.  Needs ser2net (Debian's package).
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
# the ser2net the tests start, started as they start it
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "lab"))

import lm629_host
from ser2net_fixture import Ser2net, ser2net_version


def measure(url: str, reads: int) -> tuple[int, float, float, float]:
    from lm629_host.transports.serial import SerialTransport

    t_open = time.perf_counter()
    with lm629_host.open(url) as chip:
        opened = time.perf_counter() - t_open
        t = chip.transport
        assert isinstance(t, SerialTransport), t
        chip.read_real_position()
        t0 = time.perf_counter()
        for _ in range(reads):
            chip.read_real_position()
        per_read = (time.perf_counter() - t0) / reads
        return t.line_rate()[0], t.rtt_s or 0.0, per_read, opened


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--far", choices=["python", "firmware"], default="python")
    ap.add_argument("--reads", type=int, default=300)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench_ser2net_"))
    link = tmp / "bench"
    argv = ["lm629", "sim", "serve", "--pty", str(link)] + (["--firmware"] if args.far == "firmware"
                                                             else [])
    bench = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert bench.stdout is not None and bench.stderr is not None
    try:
        banner = bench.stdout.readline()
        assert banner.startswith("serving "), banner + bench.stderr.read()
        print(f"ser2net {ser2net_version()}, far end {args.far}, {args.reads} reads of RDRP each")
        print(f"{'way in':44} {'baud':>8} {'open':>7} {'round trip':>11} {'RDRP':>9} {'x pty':>6}")
        rows: list[tuple[str, str | None, dict[str, str] | None]] = [
            ("serial:// on the pty (baseline)", None, None)]
        for proto in ("rfc2217", "raw"):
            for opts in (None, {"chardelay": "false"}):
                rows.append((f"{'rfc2217://' if proto == 'rfc2217' else 'socket://'} via ser2net"
                             + (", chardelay: false" if opts else ""), proto, opts))
        base = 0.0
        for name, protocol, options in rows:
            if protocol is None:
                baud, rtt, per, opened = measure(f"serial://{link}", args.reads)
            else:
                s2n = Ser2net(link, tmp, protocol, options).start()
                try:
                    baud, rtt, per, opened = measure(s2n.url, args.reads)
                finally:
                    s2n.stop()
            base = base or per
            print(f"{name:44} {baud:>8} {opened:>5.2f} s {rtt * 1e3:>8.2f} ms {per * 1e3:>6.2f} ms "
                  f"{per / base:>5.1f}x")
    finally:
        bench.send_signal(signal.SIGTERM)
        bench.communicate(timeout=20)


if __name__ == "__main__":
    main()
