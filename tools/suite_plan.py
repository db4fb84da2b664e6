"""How a test run's work spreads over the xdist workers: replays measured test durations
through xdist's schedulers and prints each worker's busy time and the run's end.

    python3 -m pytest -q --durations=0 [-m ...] > run.txt     # or --junitxml=run.xml
    python3 tools/suite_plan.py run.txt [-m "not slow"] [--workers 4]

The durations are measured on whatever machine ran them (on a shared machine all of them are
inflated alike); the figures that matter are ratios within one replay: the run's end against
its lower bound (all the work / the workers), ``--dist loadfile`` (each file on one worker,
the suite's distribution before) against ``--dist loadgroup`` with tests/xdist_groups.py's
groups (the suite now).  The collection (its order, its groups and marks) is the checkout's own,
collected here in a child process; tests missing from the measurement count as 0 s.
"""

from __future__ import annotations

import argparse
import heapq
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from xml.etree import ElementTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from selection import auto_workers  # noqa: E402  (-n auto's rule, in one home)

_DUMP = """
import json, sys, pytest
class Dump:
    def pytest_collection_finish(self, session):
        out = [{"id": i.nodeid, "slow": i.get_closest_marker("slow") is not None,
                "group": [m.args[0] for m in i.iter_markers("xdist_group")]}
               for i in session.items]
        json.dump(out, open(sys.argv[1], "w"))
sys.exit(pytest.main(["--collect-only", "-q", "-n", "0", "-p", "no:cacheprovider",
                      *sys.argv[2:]], plugins=[Dump()]))
"""


def durations(path: Path) -> dict[str, float]:
    """Test id -> seconds (setup + call + teardown), from a junit XML or ``--durations=0``."""
    out: dict[str, float] = {}
    if path.suffix == ".xml":
        for case in ElementTree.parse(path).iter("testcase"):
            mod = case.get("classname", "").replace(".", "/")
            out[f"{mod}.py::{case.get('name')}"] = float(case.get("time") or 0)
        return out
    for line in path.read_text().splitlines():
        m = re.match(r"([\d.]+)s (setup|call|teardown)\s+(\S.*)$", line)
        if m:
            key = m[3].split("@")[0]
            out[key] = out.get(key, 0.0) + float(m[1])
    return out


def collect(args: list[str]) -> list[dict]:
    with tempfile.TemporaryDirectory() as tmp:
        dump = Path(tmp) / "items.json"
        p = subprocess.run([sys.executable, "-c", _DUMP, str(dump), *args], cwd=ROOT,
                           capture_output=True, text=True)
        if p.returncode:
            sys.exit(p.stdout[-2000:] + p.stderr[-2000:])
        return json.loads(dump.read_text())


def units(items: list[dict], dist: str) -> list[list[dict]]:
    """The work units xdist makes, in the order it hands them out (its scheduler reorders
    scopes by their number of tests, the largest first: ``loadscopereorder``)."""
    scopes: dict[str, list[dict]] = {}
    if dist == "loadgroup":  # on the workers, the slow tests first (tests/conftest.py)
        items = sorted(items, key=lambda i: not i["slow"])
    for it in items:
        if dist == "loadfile":
            key = it["id"].split("::")[0]
        else:
            key = "_".join(sorted(it["group"])) if it["group"] else it["id"]
        scopes.setdefault(key, []).append(it)
    return sorted(scopes.values(), key=len, reverse=True)


def replay(work: list[list[dict]], seconds: dict[str, float], workers: int) -> list[float]:
    """Each worker's busy time when every unit goes to the first worker free."""
    free = [(0.0, w) for w in range(workers)]
    busy = [0.0] * workers
    for unit in work:
        t, w = heapq.heappop(free)
        cost = sum(seconds.get(it["id"].split("@")[0], 0.0) for it in unit)
        busy[w] += cost
        heapq.heappush(free, (t + cost, w))
    return busy


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("measured", type=Path, help="junit XML, or pytest output with --durations=0")
    ap.add_argument("-m", dest="markexpr", default="", help="the run's marker expression")
    ap.add_argument("--workers", type=int, default=None,
                    help="default: as -n auto for the run's -m (tests/selection.py)")
    a = ap.parse_args(argv)
    if a.workers is None:
        a.workers = auto_workers(a.markexpr, len(os.sched_getaffinity(0)))
    seconds = durations(a.measured)
    items = collect(["-m", a.markexpr] if a.markexpr else [])
    known = [it for it in items if it["id"].split("@")[0] in seconds]
    total = sum(seconds.get(it["id"].split("@")[0], 0.0) for it in items)
    print(f"{len(items)} tests collected, {len(known)} measured: {total:.1f} s of work, "
          f"at best {total / a.workers:.1f} s on {a.workers} workers")
    for dist in ("loadfile", "loadgroup"):
        busy = replay(units(items, dist), seconds, a.workers)
        print(f"--dist {dist:9}: ends at {max(busy):7.1f} s ({max(busy) / (total / a.workers):.2f}"
              f" x the best); workers busy " + ", ".join(f"{b:.1f}" for b in busy))


if __name__ == "__main__":
    main()
