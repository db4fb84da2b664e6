"""Shared test set-up.

Every simulated chip in the suite is strict by default (``LM629_SIM_STRICT=1``): any host
protocol violation (a write while busy, a word without a command...) raises at once.  Tests
that provoke violations on purpose say ``strict=0`` in their URL.

The firmware-in-the-loop tests (a third of the suite) need the AVR toolchain.  Without it they
skip, and the run says so in a red line at its end (and at its start); with
``LM629_REQUIRE_AVR=1`` (``.ci/run`` sets it) the run stops at once with a failure instead.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from collections.abc import Iterator

os.environ.setdefault("LM629_SIM_STRICT", "1")

import pytest

import lm629_host
from lm629_host.sim import harness
from lm629_host.bus.program import BusCycle

import hogs
import warm
from selection import auto_workers, is_slow, what_runs
from served import CPU_HOGS_ENV, cpu_hogs, is_served, served_docs
from sim_urls import BEHIND_USB_URLS, FAST_LINK_URLS, SIM_URLS, available

# The suite starts some 600 Python processes (xdist workers, `lm629`, `lm629 sim serve`,
# pytest): with PYTHONDONTWRITEBYTECODE set (some machines' environments set it, this one's
# does) none keeps its compiled modules, and each compiles the package and rewrites the tests
# from source again, every run (a second quick loop 32 s instead of 27).  The suite writes its
# caches in the checkout, as pytest writes .pytest_cache.
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
sys.dont_write_bytecode = False

_REQUIRE_AVR = "LM629_REQUIRE_AVR"

#: the ``firmware_built`` fixture, for every test module that asks for it by name; pytester
#: runs the lm629 pytest plugin (tests/integrations/test_pytest_plugin.py); xdist_groups keeps
#: the tests that share a fixture on one worker (``-n``)
pytest_plugins = ("firmware_helpers", "pytester", "xdist_groups")


def _avr_missing() -> list[str]:
    return harness.toolchain_missing()


#: the CPU hogs of ``--cpu-hogs``, stopped but while an under_load test runs (tests/hogs.py)
_HOGS: list[hogs.Hogs] = []


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--cpu-hogs", type=int, default=int(os.environ.get(CPU_HOGS_ENV) or 0),
                     metavar="N", help="N CPU-burning processes beside each test marked under_load "
                     f"(also {CPU_HOGS_ENV}=N; CI: 2); the other tests run without them")
    parser.addoption("--long", action="store_true", default=bool(os.environ.get(LONG_ENV)),
                     help="the release run (docs/testing.md): the tests marked long as well, "
                     f"and the crossings machine at its long budget (also {LONG_ENV}=1)")


#: the long mode's switch (``pytest --long``): what does not fit in CI's four minutes
LONG_ENV = "LM629_LONG"


def pytest_configure(config: pytest.Config) -> None:
    if config.getoption("--long"):
        # tests/crossings/test_api_state_machine.py reads its budget at import, after this
        os.environ.setdefault("LM629_CROSSINGS", "long")


def pytest_sessionstart(session: pytest.Session) -> None:
    if warm.warming():  # the warm-up's own collection (tests/warm.py): it builds nothing
        return
    controller = not hasattr(session.config, "workerinput")
    collection = None
    if controller and session.config.getoption("numprocesses", None):
        # before the workers start: the package compiled, then the test files rewritten by one
        # collection beside the firmware's build (tests/warm.py; current caches cost a look at
        # the files' times and the copies' headers)
        warm.compile_package(Path(lm629_host.__file__).parent)
        config = session.config
        collection = warm.start_collection(
            config.rootpath, Path(__file__).parent,
            [(config.invocation_params.dir / a.split("::")[0]).resolve() for a in config.args])
    n_hogs = session.config.getoption("--cpu-hogs")
    if n_hogs and controller:  # once, before any xdist worker
        _HOGS.append(hogs.Hogs(n_hogs))
    missing = _avr_missing()
    if missing and os.environ.get(_REQUIRE_AVR) == "1":
        pytest.exit(f"{_REQUIRE_AVR}=1 but the AVR toolchain is missing ({', '.join(missing)}):"
                    f" apt-get install {harness.PACKAGES}", returncode=1)
    # the firmware and the simavr harness are built once, by the process that starts the run,
    # before any xdist worker exists: two workers running make in one build directory could
    # load a half-written image (a failed build is reported by the tests that need it)
    if not missing and controller:
        # the firmware's host-side C tests too (`make test`'s two programs, ASan): run by
        # tests/firmware/test_firmware_build.py and by docs/bridge.md's `make -C firmware_bridge
        # test` on two workers, which would otherwise both compile them into one build/ at once
        # (a half-written program run); a few milliseconds when they are current.  Built
        # beside the firmware (each target one compiler run of its own: 2.5 s in a fresh clone)
        tests_built = subprocess.Popen(["make", "-s", "-C", str(harness.FIRMWARE_DIR),
                                        "build/test_link", "build/fuzz_link"],
                                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            harness.ensure_built()
        except harness.HarnessError:
            pass
        tests_built.wait()  # a failure: the tests say it
    if collection is not None:  # a failure: each worker's own collection says it
        try:
            collection.wait(timeout=warm.WAIT_S)
        except subprocess.TimeoutExpired:  # a module hangs at import: the workers will say so
            collection.kill()
            collection.wait()


def pytest_sessionfinish(session: pytest.Session) -> None:
    while _HOGS:
        _HOGS.pop().close()


@pytest.fixture(autouse=True)
def _under_load_beside_the_hogs(request: pytest.FixtureRequest) -> Iterator[None]:
    """A test marked under_load runs beside the run's CPU hogs (``--cpu-hogs N``): they burn
    from before its own (function-scoped) fixtures are made until after they are finalized; a
    bench its module shares is started before, outside the load."""
    if request.node.get_closest_marker("under_load") is None:
        yield
        return
    with hogs.beside():
        yield


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto``: three workers a core, two for the quick loop (tests/selection.py's
    ``auto_workers``: half of a whole run's time is spent waiting in real time)."""
    return auto_workers(config.getoption("markexpr"), len(os.sched_getaffinity(0)))


@pytest.fixture
def cpu_hogs_beside():
    """``with cpu_hogs_beside(2): ...``: CPU-burning processes for part of one test."""
    return cpu_hogs


@pytest.hookimpl(tryfirst=True)  # before xdist's, which reads the xdist_group marks
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    docs = served_docs(items)
    for item in items:
        served = is_served(item, docs)
        if served:
            item.add_marker(pytest.mark.served)
        if is_slow(item, served):
            item.add_marker(pytest.mark.slow)
    if not config.getoption("--long"):
        kept = [i for i in items if i.get_closest_marker("long") is None]
        if len(kept) < len(items):
            config.hook.pytest_deselected(items=[i for i in items if i not in kept])
            items[:] = kept
    if hasattr(config, "workerinput"):
        # an xdist worker: the under_load tests first, so that they overlap on the workers
        # and share the hogs' minutes (tests/hogs.py), then the slow ones (a stable sort:
        # each module's order is kept); xdist hands out the rest one test at a time
        # (xdist_groups.py), and a run that ends on quick tests ends with every worker busy
        items.sort(key=lambda i: (i.get_closest_marker("under_load") is None,
                                  i.get_closest_marker("slow") is None))


def pytest_report_header(config: pytest.Config) -> list[str]:
    """What this run runs, in words a newcomer's plain ``pytest`` prints first."""
    lines = [what_runs(config.getoption("markexpr"), config.getoption("--long"),
                       config.getoption("--cpu-hogs"), config.getoption("numprocesses", None))]
    missing = _avr_missing()
    if missing:
        lines.append(f"!!! AVR toolchain missing ({', '.join(missing)}): the firmware-in-the-loop "
                     f"tests will be SKIPPED (apt-get install {harness.PACKAGES})")
    return lines


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    ran = not_run = 0
    for reports in terminalreporter.stats.values():
        for r in reports:
            if getattr(r, "when", None) in ("call", "setup"):
                for name, value in getattr(r, "user_properties", ()):
                    if name == "docs_examples":  # tests/test_docs.py's DOCS_PROPERTY
                        ran += value[0]
                        not_run += value[1]
    if ran or not_run:
        terminalreporter.write_sep(
            "-", f"docs examples: {ran} ran, {not_run} not run "
            "(marked so, or a tool missing here) (README.md, docs/*.md)")
    for link, examples, steps, seconds, profile in _properties(terminalreporter, "crossings"):
        # tests/crossings/test_api_state_machine.py's FIGURES_PROPERTY
        terminalreporter.write_sep(
            "-", f"crossings ({profile}): {link} {examples} examples, {steps} steps, "
            f"{seconds:.1f} s")
    missing = _avr_missing()
    if not missing:
        return
    skipped = terminalreporter.stats.get("skipped", [])
    n = sum(1 for r in skipped if "toolchain" in str(getattr(r, "longrepr", "")).lower()
            or "sim+avr" in str(getattr(r, "longrepr", "")))
    terminalreporter.write_sep(
        "!", f"AVR toolchain missing ({', '.join(missing)}): {n} firmware-in-the-loop tests "
        f"SKIPPED, the firmware is UNTESTED. apt-get install {harness.PACKAGES}, or run "
        f".ci/run as root (it installs them and sets {_REQUIRE_AVR}=1)", red=True, bold=True)


def _properties(terminalreporter: pytest.TerminalReporter, name: str) -> list:
    """The values of the user property ``name`` every test report of the run carries."""
    found = []
    for reports in terminalreporter.stats.values():
        for r in reports:
            if getattr(r, "when", None) == "call":
                found += [value for key, value in getattr(r, "user_properties", ()) if key == name]
    return found


def _transport(request: pytest.FixtureRequest) -> str:
    url = request.param
    if not available(url):
        pytest.skip(f"{url}: the transport (or for sim+avr:// the AVR toolchain) is not here")
    return url


@pytest.fixture(params=SIM_URLS)
def transport_url(request: pytest.FixtureRequest) -> str:
    """Every simulated transport (:data:`sim_urls.SIM_URLS`), base URL."""
    return _transport(request)


@pytest.fixture(params=FAST_LINK_URLS)
def fast_transport_url(request: pytest.FixtureRequest) -> str:
    """Every simulated transport, the serial links at 1 Mbaud (:data:`sim_urls.FAST_LINK_URLS`)."""
    return _transport(request)


@pytest.fixture(params=SIM_URLS + BEHIND_USB_URLS)
def usb_transport_url(request: pytest.FixtureRequest) -> str:
    """Every simulated transport, and the serial links behind an Uno's USB chip
    (:data:`sim_urls.BEHIND_USB_URLS`)."""
    return _transport(request)


class Recorder:
    """A trace callback that keeps every bus cycle."""

    def __init__(self) -> None:
        self.cycles: list[BusCycle] = []

    def __call__(self, cycle: BusCycle) -> None:
        self.cycles.append(cycle)

    def clear(self) -> None:
        self.cycles.clear()

    def data(self) -> list[tuple[str, int]]:
        """The cycles that carry data (commands, words, resets), without status reads."""
        return [(c.kind, c.value) for c in self.cycles if c.kind != "status"]


@pytest.fixture
def recorder() -> Recorder:
    return Recorder()


@pytest.fixture
def open_chip(recorder):
    """``open_chip(url)`` -> an LM629 whose trace goes to ``recorder``; closed after the test."""
    opened = []

    def _open(url: str = "sim://", **kw):
        chip = lm629_host.open(url, trace=recorder, **kw)
        opened.append(chip)
        return chip

    yield _open
    for chip in opened:
        chip.close()


@pytest.fixture
def opened(monkeypatch):
    """The chips the CLI opened in this test (to look at the model after the command)."""
    from lm629_host.cli import app as cli_app
    chips = []
    real = cli_app._open

    def _open(url, chip, trace):
        c = real(url, chip, trace)
        chips.append(c)
        return c
    monkeypatch.setattr(cli_app, "_open", _open)
    return chips


@pytest.fixture
def signal_on_row(monkeypatch):
    """``arm(signum, row=3)``: the CLI's chips deliver a real ``signum`` to this process during
    the bus program of the ``row``-th RDSIGS (a ``watch`` row's snapshot), as a user's Ctrl-C
    or a ``kill`` would arrive mid-program; returns the list of chips opened."""
    import os
    from lm629_host.cli import app as cli_app
    from lm629_host.bus.opcodes import Cmd

    def arm(signum: int, row: int = 3) -> list:
        chips = []
        real = cli_app._open

        def _open(url, chip, trace):
            n = [0]

            def signalling(cycle):
                if trace is not None:  # --trace given
                    trace(cycle)
                if cycle.kind == "command" and cycle.value == Cmd.RDSIGS:
                    n[0] += 1
                    if n[0] == row:
                        os.kill(os.getpid(), signum)
            c = real(url, chip, signalling)
            chips.append(c)
            return c
        monkeypatch.setattr(cli_app, "_open", _open)
        return chips
    return arm
