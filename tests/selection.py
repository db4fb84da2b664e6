"""Which tests run where: the marks and xdist groups tests/conftest.py computes for every test
(docs/testing.md, "The project's own suite").  Computed from what a test is and uses (its
module, parameters, fixtures, the served bench its body starts), so a new test file needs no
entry here."""

from __future__ import annotations

import functools
import inspect
import re

import pytest

#: test modules that start processes (the installed script, a wheel, sigrok-cli, labgrid), tune
#: a motor or run the crossings machine: ``-m "not slow"`` leaves them out, and every served,
#: under_load and long test, and every test of the compiled firmware (docs/testing.md, the
#: quick loop)
SLOW_MODULES = frozenset({
    "test_served_bench", "test_served_bench_profile", "test_bench", "test_bench_profile",
    "test_pytest_plugin", "test_labgrid", "test_labgrid_lab", "test_wheel", "test_ci_guard", "test_tuning",
    "test_firmware_build", "test_firmware_bundle", "test_sigrok", "test_journey", "test_docs",
    "test_bench_failsafe", "test_twin", "test_faults_link", "test_api_state_machine",
    "test_suite"})
#: parameters that run the compiled firmware in simavr, or wait on a USB adapter in real time
SLOW_PARAMS = ("sim+avr", "firmware", "usb=")
#: fixtures that build or run the compiled firmware
SLOW_FIXTURES = frozenset({"firmware_built"})


#: words in a test's or its fixtures' source that start a process the test waits on (a served
#: bench, a browser, any other program) or tune a motor
SLOW_SOURCE = ("subprocess.Popen(", "with serve(", "_sim_serve()", '"sim", "serve"',
               "chromium(",
               # a whole tune: phasing, identification, the gain search's test moves
               "autotune(", '"tune", "--')


def is_slow(item: pytest.Item, served: bool) -> bool:
    """Whether the quick loop (``-m "not slow"``) leaves ``item`` out."""
    return (served or item.path.stem in SLOW_MODULES
            or any(p in item.nodeid for p in SLOW_PARAMS)
            or not SLOW_FIXTURES.isdisjoint(getattr(item, "fixturenames", ()))
            or any(item.get_closest_marker(m) for m in ("under_load", "long"))
            or _starts_a_process(item))


def _starts_a_process(item: pytest.Item) -> bool:
    """Whether the test, or a fixture it uses, starts a process or tunes a motor."""
    funcs = [getattr(item, "function", None)]
    # pytest has no public view of a test's fixture definitions at collection time
    info = getattr(item, "_fixtureinfo", None)
    for name in getattr(item, "fixturenames", ()):
        defs = info.name2fixturedefs.get(name) if info is not None else None
        if defs and "site-packages" not in str(getattr(defs[-1], "baseid", "")):
            funcs.append(defs[-1].func)
    return any(_source_has(f, SLOW_SOURCE) for f in funcs if f is not None)


@functools.cache
def _source_has(func, words: tuple[str, ...]) -> bool:
    try:
        source = inspect.getsource(func)
    except (OSError, TypeError):
        return False
    return any(w in source for w in words)


#: ``-n auto``'s workers a core: a worker of the whole suite waits in real time about half of
#: its time (a served bench's moves, a failsafe's timeout, a browser, ser2net, the
#: ``under_load`` tests beside the hogs), so three a core keep two cores busy to the end
#: (measured on a 2-core machine, CI's pytest: 4 workers 142 s, 5 139 s, 6 130-132 s, 8 131 s,
#: in one clone, one after the other; docs/testing.md).  The six overlap the ``under_load``
#: tests six at a time, so the hogs burn for a shorter window
WORKERS_PER_CORE = 3
#: ... and the quick loop's (``-m "not slow"``): it neither serves a bench nor waits, so a
#: third worker a core only adds its start (measured: 24 s on 4 workers, 26 s on 6)
QUICK_WORKERS_PER_CORE = 2


def auto_workers(markexpr: str, cores: int) -> int:
    """How many xdist workers ``-n auto`` starts for a run selected by ``markexpr``."""
    quick = re.search(r"\bnot\s+slow\b", markexpr or "") is not None
    return (QUICK_WORKERS_PER_CORE if quick else WORKERS_PER_CORE) * cores


def what_runs(markexpr: str, long: bool, hogs: int, workers: object = None) -> str:
    """One line for pytest's header: the tests selected, what is left out, how to run it."""
    out = [f"lm629-host: {f'-m {markexpr!r}' if markexpr else 'every test'}"
           + (f" on {workers} workers" if workers else f" in one process (-n auto: {WORKERS_PER_CORE} workers a core,"
                f" {QUICK_WORKERS_PER_CORE} for -m 'not slow')")]
    if long:
        out.append("with the long mode's tests and budgets (--long: the release run)")
    else:
        out.append("not the long mode's (pytest --long, before a release)")
    out.append(f"the under_load tests first, each beside {hogs} CPU hogs" if hogs else
               "under_load tests without CPU hogs (CI runs each beside two: --cpu-hogs 2)")
    out.append("quick loop: pytest -n auto -m 'not slow'; the whole CI: bash .ci/run")
    return "; ".join(out)
