"""What the process that starts an xdist run prepares before any worker exists, so that six
workers do not each do it from nothing in a fresh clone (CI's every run): the package's
bytecode, and the test files as pytest's assertion rewriting leaves them.

A worker imports every test module to collect it.  Without a current rewritten copy in
``__pycache__`` each worker rewrites all of them itself (measured: a collection 3.1 s instead of
1.4 s); one collection ahead of them, beside the firmware's build, writes the copies once.
Measured on this 2-core machine, caches emptied, the firmware built, six workers: every worker
collected 7.6-7.8 s after the start with the warm-up, 9.4-9.8 s without.  A run whose copies
are current, or nearly, skips it (a look at each copy's header)."""

from __future__ import annotations

import compileall
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

#: how long the run waits for the warm-up's collection (1.5-6.5 s here) before it goes on
#: without it: a test module that hangs at import is then reported by the workers' own collection
WAIT_S = 120.0

#: set in the collection :func:`start_collection` starts: its conftest must not build the
#: firmware beside the run's own build, nor start the run's hogs
ENV = "LM629_WARMING"


def warming() -> bool:
    """Whether this process is the warm-up's collection (tests/conftest.py then builds nothing)."""
    return os.environ.get(ENV) == "1"


def compile_package(package_dir: Path) -> None:
    """The package compiled once, on every core (a current cache costs a look at the files'
    times): in a fresh clone each worker would compile all of it at once."""
    compileall.compile_dir(str(package_dir), quiet=1, workers=len(os.sched_getaffinity(0)))


def rewritten_copy(test_file: Path) -> Path:
    """Where pytest keeps a test file's rewritten bytecode (``__pycache__``, tagged with the
    interpreter and pytest's version)."""
    tag = f"{sys.implementation.cache_tag}-pytest-{pytest.__version__}"
    return test_file.parent / "__pycache__" / f"{test_file.stem}.{tag}.pyc"


def stale(tests_dir: Path) -> list[Path]:
    """The test modules and conftests under ``tests_dir`` whose rewritten copy is missing or
    of another source.  pytest writes its copies as checked-hash pycs (PEP 552: the magic
    number, flags 3, the source's hash), valid whatever the files' times, so the check is
    the same as pytest's.  Should pytest name or write its copies otherwise, every file is
    stale and the run pays one collection more (tests/test_suite.py checks both against a
    real collection)."""
    out = []
    for src in sorted(tests_dir.rglob("*.py")):
        if not (src.name.startswith("test_") or src.name == "conftest.py"):
            continue
        try:
            with rewritten_copy(src).open("rb") as f:
                header = f.read(16)
        except OSError:
            header = b""
        if header != (importlib.util.MAGIC_NUMBER + b"\x03\x00\x00\x00"
                      + importlib.util.source_hash(src.read_bytes())[:8]):
            out.append(src)
    return out


#: the fewest stale files worth a warm-up: its collection costs the run 0.3 s before any
#: worker starts, a file left to the workers about 15 ms of CPU in each (3.1 s against 1.4 s
#: for 104 files), 90 ms on six workers, 45 ms of two cores: below eight, the workers rewrite
#: them sooner (a developer's edited file), from eight (a fresh clone, a new pytest) the
#: warm-up does
MIN_STALE = 8


def start_collection(root: Path, tests_dir: Path, within: list[Path] | None = None
                     ) -> subprocess.Popen | None:
    """One ``pytest --collect-only`` in a child process of the stale test files
    (:func:`stale`) the run collects (under one of ``within``, the run's paths), which writes
    their rewritten copies and those of the conftests above them; None when fewer than
    :data:`MIN_STALE` are.  The caller waits for it before the workers start (a worker that
    found half-written copies would only rewrite them)."""
    todo = [f for f in stale(tests_dir) if f.name != "conftest.py"
            and (within is None or any(p == f or p in f.parents for p in within))]
    if len(todo) < MIN_STALE:
        return None
    return subprocess.Popen(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-n", "0",
         "-p", "no:cacheprovider", "--rootdir", str(root), *map(str, todo)],
        cwd=root, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        env={**os.environ, ENV: "1"})
