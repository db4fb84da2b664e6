"""What ``lm629 panel`` delivers to a page, and what it costs: updates and rows a second on the
event stream, the largest gap between updates, the panel's CPU, and how long a stop takes from
the POST to the answer, on sim:// and on a served bench (``lm629 sim serve``, the Python far
end: real time over a pty).

    python3 tools/bench_panel.py [--seconds 5]

Each figure is printed beside the issue's floor (20 updates a second) as a ratio, in the same
run; absolute numbers depend on the machine and what else runs on it.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "panel")]

from panel_helpers import command, events, panel  # noqa: E402 - the tests' helpers, by path
from served import serve  # noqa: E402 - as above

FLOOR_UPDATES = 20.0  #: issue 48: at least 20 updates a second


def _cpu_s(pid: int) -> float:
    import os
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def measure(port: str, seconds: float) -> dict[str, float]:
    with panel(port) as p:
        token = p.page_token()
        with events(p, token) as stream:
            hello = next(stream)
            for m in stream:  # the first rows: the stream is running
                if m["type"] == "rows":
                    break
            cpu0, t0 = _cpu_s(p.proc.pid), time.monotonic()
            stamps: list[float] = []
            rows = 0
            for m in stream:
                if m["type"] == "rows":
                    stamps.append(time.monotonic())
                    rows += len(m["rows"])
                if time.monotonic() - t0 >= seconds:
                    break
            span = time.monotonic() - t0
            cpu = _cpu_s(p.proc.pid) - cpu0
            command(p, token, {"cmd": "move", "target": "100000", "client": hello["client"]})
            time.sleep(0.3)
            s0 = time.monotonic()
            command(p, token, {"cmd": "stop", "client": hello["client"]})
            stop_s = time.monotonic() - s0
    gaps = [b - a for a, b in zip(stamps, stamps[1:])]
    return {"updates/s": len(stamps) / span, "rows/s": rows / span,
            "median gap ms": statistics.median(gaps) * 1e3, "max gap ms": max(gaps) * 1e3,
            "cpu %": 100 * cpu / span, "stop answered ms": stop_s * 1e3}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    args = ap.parse_args()
    results = {"sim://": measure("sim://", args.seconds)}
    with tempfile.TemporaryDirectory() as tmp, serve(Path(tmp), "python") as bench:
        bench.ready()
        results["served (python far end)"] = measure(f"serial://{bench.link}", args.seconds)
    for where, r in results.items():
        print(f"{where}: {r['updates/s']:.1f} updates/s ({r['updates/s'] / FLOOR_UPDATES:.2f}x "
              f"the 20/s floor), {r['rows/s']:.1f} rows/s, gap median {r['median gap ms']:.0f} "
              f"ms / max {r['max gap ms']:.0f} ms, panel CPU {r['cpu %']:.1f} % of a core, stop "
              f"answered in {r['stop answered ms']:.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
