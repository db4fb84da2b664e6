"""The pytest plugin: a lab script's tests on the simulator, and the same tests on a bench.

Installing lm629-host registers it (entry point group ``pytest11``, name ``lm629``); it adds

* fixtures ``lm629`` (an :class:`~lm629_host.LM629`, reset before the test) and
  ``lm629_board`` (a :class:`~lm629_host.Board`, every axis reset);
* options ``--lm629-port URL`` (default ``sim://``), ``--lm629-profile FILE`` and
  ``--lm629-allow-motion``;
* markers ``lm629_sim("inertia=4e-5&axes=2")`` (this test's simulated chip and motor),
  ``lm629_hardware`` (only on a real port) and ``lm629_motion`` (this test moves a motor);
* strict simulation: a host protocol violation fails the test, with the chip model's message
  (which carries the simulated time), even when the test catches the exception;
* a report section on every failure: the last bus cycles decoded and a snapshot of the chip.

Why the choices (docs/testing.md has the user's side):

* On a simulator every test gets a fresh simulated bus of its own (as the CLI's ``sim://``), so
  a marker can configure it and tests cannot leak state.  On a real port the transport is
  opened once for the run and kept: opening a bridge resets an Arduino Uno (DTR) and
  handshakes, and a bench is one board whatever the number of tests.  Every test resets it.
* Motion: a test that moves says so with ``@pytest.mark.lm629_motion``.  On a real port
  without ``--lm629-allow-motion`` those are skipped, and an unmarked test that starts a
  trajectory anyway fails before its STT reaches the chip (the plugin reads every bus program
  first); on a simulator the same unmarked start is a warning, so the missing marker shows up
  before the file meets a bench.  Stops (LTRJ with a stop or motor-off bit) are always allowed.
* A port that cannot be opened is one error for the whole run: the plugin opens it once after
  collection when a collected test uses a fixture, and stops the run with the transport's own
  message (what to check on the bench).
"""

from __future__ import annotations

import warnings
from collections.abc import Generator, Iterator
from typing import Any

import pytest

import lm629_host
from lm629_host.integrations.pytest_guard import Bench, MotionNotAllowed
from lm629_host.integrations.pytest_port import PortError, PortSession
from lm629_host.transports import DEFAULT_URL

#: the fixtures that open the port (a collected test using one makes the run check the port)
FIXTURES = ("lm629", "lm629_board")

MARKERS = {
    "lm629_sim": "lm629_sim(params='inertia=4e-5&load_torque=0.002&axes=2', **params): this "
                 "test's simulated chip and motor (sim:// URL parameters); skipped on a real port",
    "lm629_hardware": "lm629_hardware: runs only on a real --lm629-port (skipped on a simulator)",
    "lm629_motion": "lm629_motion: this test moves a motor; on a real port it needs "
                    "--lm629-allow-motion (skipped without it)",
}


#: the run's port, in the config's stash; one test's bench, in its item's
_SESSION = pytest.StashKey[PortSession]()
_BENCH = pytest.StashKey[Bench]()


# ---------------------------------------------------------------------------- options
def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("lm629", "lm629-host: LM628/LM629 lab scripts (lm629 and lm629_board fixtures)")
    group.addoption("--lm629-port", dest="lm629_port", default=None, metavar="URL",
                    help=f"the port the lm629 fixtures open: {DEFAULT_URL} (default: a fresh "
                         "simulated chip per test), serial:///dev/ttyACM0, /dev/ttyACM0, "
                         "socket://HOST:PORT, ftdi://... (env LM629_PORT is NOT read: a test run "
                         "reaches a bench only when asked to)")
    group.addoption("--lm629-profile", dest="lm629_profile", default=None, metavar="FILE",
                    help="a bench profile (TOML): its port unless --lm629-port is given; "
                         "lm629_board names the axes (board['x']), with their soft limits, and "
                         "applies the profile after the reset")
    group.addoption("--lm629-allow-motion", dest="lm629_allow_motion", action="store_true",
                    help="on a real port, run the tests marked lm629_motion (skipped without it) "
                         "and let any test start a trajectory")


def pytest_configure(config: pytest.Config) -> None:
    for text in MARKERS.values():
        config.addinivalue_line("markers", text)
    config.stash[_SESSION] = PortSession(config)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Skip what this port cannot run, with the reason; that is known before any test runs."""
    s = config.stash[_SESSION]
    for item in items:
        if s.simulated:
            if item.get_closest_marker("lm629_hardware"):
                item.add_marker(pytest.mark.skip(
                    reason=f"lm629_hardware: needs a real board (--lm629-port is {s.url}, simulated)"))
            continue
        if item.get_closest_marker("lm629_sim"):
            item.add_marker(pytest.mark.skip(
                reason=f"lm629_sim configures a simulated chip; --lm629-port {s.url} is a real port"))
        elif item.get_closest_marker("lm629_motion") and not s.allow_motion:
            item.add_marker(pytest.mark.skip(
                reason=f"lm629_motion: moves the motor on the real port {s.url}; "
                       "pass --lm629-allow-motion to run it"))


def pytest_collection_finish(session: pytest.Session) -> None:
    """One check of the port for the whole run, before the first test, when a test uses it."""
    if session.config.option.collectonly:
        return
    if not any(set(FIXTURES) & set(getattr(item, "fixturenames", ())) for item in session.items):
        return
    try:
        session.config.stash[_SESSION].check()
    except PortError as exc:
        raise pytest.UsageError(str(exc)) from None


def pytest_unconfigure(config: pytest.Config) -> None:
    s = config.stash.get(_SESSION, None)
    if s is not None:
        s.close()


def pytest_report_header(config: pytest.Config) -> str | None:
    s = config.stash.get(_SESSION, None)
    if s is None:
        return None
    if s.simulated:
        return f"lm629: {s.url} (simulated: a fresh chip per test, simulated time, strict)"
    motion = "motion allowed" if s.allow_motion else "no motion (--lm629-allow-motion to allow)"
    return f"lm629: real port {s.url}, {motion}"


# ---------------------------------------------------------------------------- fixtures
@pytest.fixture
def _lm629_bench(request: pytest.FixtureRequest) -> Iterator[Bench]:
    """The transport of one test (internal: use lm629 or lm629_board)."""
    bench = Bench(request.config.stash[_SESSION], request)
    request.node.stash[_BENCH] = bench
    try:
        yield bench
    finally:
        try:
            if bench.outcome not in ("passed", "stopped") and bench.axes():
                # failed, or interrupted (Ctrl-C: no report was made): stop, then motor off
                bench.stop()
            elif bench.outcome == "passed" and not bench.simulated and bench.moving():
                note = bench.stop()
                warnings.warn(pytest.PytestWarning(
                    f"{request.node.nodeid} passed but left a motor moving on {bench.url}: {note}"),
                    stacklevel=1)
        finally:
            bench.close()


@pytest.fixture
def lm629(_lm629_bench: Bench) -> lm629_host.LM629:
    """An LM629 on --lm629-port (default sim://), reset before the test (AN-706 4.4.1).

    On a simulator: a fresh strict chip model per test, configured by @pytest.mark.lm629_sim,
    on simulated time.  On a real port: the run's port, reset again for this test.  After a
    failed or interrupted test the motor is stopped, then switched off.  A URL's ?cs=k picks
    the chip of a multi-axis board."""
    return _lm629_bench.chip()


@pytest.fixture
def lm629_board(_lm629_bench: Bench) -> lm629_host.Board:
    """A Board: every chip on --lm629-port (sim:// with @pytest.mark.lm629_sim("axes=2") for
    two), all reset before the test; with --lm629-profile the profile's named axes.  Stopped,
    then motor off, after a failed or interrupted test."""
    return _lm629_bench.open_board()


# ---------------------------------------------------------------------------- reports
@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Generator[None, Any, None]:
    outcome = yield
    bench = item.stash.get(_BENCH, None)
    if bench is None:
        return
    rep = outcome.get_result()
    if rep.when == "call":
        new = bench.new_violations()
        if rep.passed and new:
            # the test caught the ProtocolViolation (or a far end recorded it): still a failure
            rep.outcome = "failed"
            rep.longrepr = "\n".join(
                f"lm629 host protocol violation at {v.time * 1e6:.1f} us of simulated time: {v}"
                for v in new)
        bench.outcome = rep.outcome
    if rep.failed and rep.when in ("setup", "call"):
        text = bench.trace_text() + "\n" + bench.snapshot_text()
        if bench.axes():
            text += "\nafter the failure: " + bench.stop()
            bench.outcome = "stopped"
        rep.sections.append(("lm629: last bus programs and chip snapshot", text))


#: the name a test file imports from here (docs/testing.md): what an unmarked start raises
__all__ = ["MotionNotAllowed"]
