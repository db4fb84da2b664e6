"""Two CPU-burning processes beside each test that asserts timed behaviour under load (marked
``under_load``), in the same run as every other test (``pytest --cpu-hogs 2``).

A lab PC plots and compiles while the bench runs: a failsafe's bound, a late host, a watch's
rows must hold beside that.  A served bench that is not about timing gains nothing from the
hogs, so they burn only while an ``under_load`` test runs, on any worker: the process that
starts the run starts them stopped (SIGSTOP), and each worker wakes them (SIGCONT) when its
first ``under_load`` test begins and stops them when the last one on any worker ends; a count
in a file under an flock says how many run now.  Two ``under_load`` tests on two workers share
the same two hogs, as two scripts on one busy lab PC would (tests/conftest.py runs the
``under_load`` tests first, so that they overlap).
"""

from __future__ import annotations

import fcntl
import os
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: the hogs' pids and the count file, for the workers (set by :func:`start` in the process
#: that starts the run, before any worker exists)
PIDS_ENV = "LM629_HOG_PIDS"
COUNT_ENV = "LM629_HOG_COUNT"


def spawn(n: int) -> list[subprocess.Popen]:
    """``n`` processes that each burn a CPU (``while True: pass``: two on a 2-core machine leave
    every other process waiting for a core)."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"],
                             stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
            for _ in range(max(0, n))]


def end(procs: list[subprocess.Popen]) -> None:
    """Kill and reap hogs from :func:`spawn`."""
    for p in procs:
        p.kill()
    for p in procs:
        p.wait()


class Hogs:
    """``n`` hog processes, stopped until a test asks for them (:func:`beside`)."""

    def __init__(self, n: int) -> None:
        self.procs = spawn(n)
        for p in self.procs:
            os.kill(p.pid, signal.SIGSTOP)
        fd, path = tempfile.mkstemp(prefix="lm629-hogs-")
        os.write(fd, b"0")
        os.close(fd)
        self.count = Path(path)
        os.environ[PIDS_ENV] = ",".join(str(p.pid) for p in self.procs)
        os.environ[COUNT_ENV] = path

    def close(self) -> None:
        end(self.procs)
        self.count.unlink(missing_ok=True)
        os.environ.pop(PIDS_ENV, None)
        os.environ.pop(COUNT_ENV, None)


def _signal_all(sig: int) -> None:
    for pid in filter(None, os.environ.get(PIDS_ENV, "").split(",")):
        try:
            os.kill(int(pid), sig)
        except ProcessLookupError:  # the run is ending: the hogs are gone
            pass


def _add(delta: int) -> int:
    """Add ``delta`` to the number of ``under_load`` tests running now; the new number."""
    with open(os.environ[COUNT_ENV], "r+") as f:
        fcntl.flock(f, fcntl.LOCK_EX)  # released when the file closes
        n = max(0, int(f.read() or 0) + delta)
        f.seek(0)
        f.truncate()
        f.write(str(n))
        f.flush()
        if delta > 0 and n == 1:
            _signal_all(signal.SIGCONT)
        elif delta < 0 and n == 0:
            _signal_all(signal.SIGSTOP)
        return n


@contextmanager
def beside() -> Iterator[int]:
    """The run's hogs burn for the duration of the block (and of any other worker's): yields
    how many hogs there are (0: the run has none)."""
    pids = [p for p in os.environ.get(PIDS_ENV, "").split(",") if p]
    if not pids or not os.environ.get(COUNT_ENV):
        yield 0
        return
    _add(+1)
    try:
        yield len(pids)
    finally:
        _add(-1)


def count() -> int:
    """How many under_load tests run now, on every worker (read under the count's lock)."""
    with open(os.environ[COUNT_ENV]) as f:
        fcntl.flock(f, fcntl.LOCK_SH)
        return int(f.read() or 0)


def running() -> list[bool]:
    """Whether each hog is burning now (its state in /proc: R, not T), for the suite's test."""
    out = []
    for pid in filter(None, os.environ.get(PIDS_ENV, "").split(",")):
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        out.append(state != "T")
    return out
