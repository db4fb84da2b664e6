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

import enum
import signal
import warnings
from collections.abc import Generator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

import lm629_host

from lm629_host.errors import LM629Error
from lm629_host.bus.opcodes import COMMANDS, STOP_FLAGS, Cmd, Direction, Status
from lm629_host.bus.program import STATUS_OPS, BusOp, Op, Program, ProgramResult
from lm629_host.chip.safety import StopSignals, emergency_stop
from lm629_host.transports import DEFAULT_URL, transport_class
from lm629_host.transports.base import BusObserver, Transport
from lm629_host.transports.sim import ModelChips
from lm629_host.transports.ports import PortSpec, profile_port, resolve_port, twin_port
from lm629_host.urls import PortURL, query_params, with_query

#: the fixtures that open the port (a collected test using one makes the run check the port)
FIXTURES = ("lm629", "lm629_board")
#: how many lines of bus programs the failure report keeps (a run of identical programs is
#: one line)
TRACE_PROGRAMS = 40
#: the commands that only read the chip: a program of these alone changes nothing in it
_READ_COMMANDS = frozenset(int(c) for c, info in COMMANDS.items()
                           if info.direction is Direction.READ)

MARKERS = {
    "lm629_sim": "lm629_sim(params='inertia=4e-5&load_torque=0.002&axes=2', **params): this "
                 "test's simulated chip and motor (sim:// URL parameters); skipped on a real port",
    "lm629_hardware": "lm629_hardware: runs only on a real --lm629-port (skipped on a simulator)",
    "lm629_motion": "lm629_motion: this test moves a motor; on a real port it needs "
                    "--lm629-allow-motion (skipped without it)",
}


class PortError(Exception):
    """The chosen port cannot be opened: one message for the whole run."""


class MotionNotAllowed(LM629Error):
    """An unmarked test started a trajectory on a real port without --lm629-allow-motion."""


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


# ---------------------------------------------------------------------------- the run
class PortSession:
    """The run's port: what it is, whether it is simulated, and the open transport of a real
    one (kept for the run)."""

    def __init__(self, config: pytest.Config) -> None:
        self.profile: Path | None = None
        self.profile_data: Any = None  #: the loaded lm629_host.config.profile.Profile
        profile = config.getoption("lm629_profile", None)
        port = config.getoption("lm629_port", None)
        if profile is not None:
            self.profile = Path(profile)
            self.profile_data = _load_profile(self.profile)
            if port is None:
                try:
                    port = profile_port(self.profile_data)
                except ValueError as exc:
                    raise pytest.UsageError(f"--lm629-profile {profile}: {exc}") from None
        self.url: str | PortURL = port or DEFAULT_URL
        self.allow_motion: bool = bool(config.getoption("lm629_allow_motion", False))
        self._transport: Transport | None = None
        self._signals = StopSignals(_interrupted)
        self._checked = False
        try:
            self.simulated = transport_class(self.url).simulated
        except LM629Error as exc:
            raise pytest.UsageError(f"--lm629-port {self.url}: {exc}") from None
        if self.simulated and self.profile_data is not None:
            # a simulated port with a profile: the twin of its bench, built from the plants
            self.url = twin_port(self.profile_data, self.url)

    def check(self) -> None:
        """Open the port once (a simulator: build one chip and drop it), or PortError."""
        if self._checked:
            return
        if self.simulated:
            try:
                resolve_port(_sim_url(self.url, {})).open_transport().close()
            except (LM629Error, ValueError) as exc:
                raise PortError(f"--lm629-port {self.url}: {exc}") from None
        else:
            self.transport()
        self._checked = True

    def transport(self) -> Transport:
        """The real port's transport, opened at the first call."""
        if self._transport is None:
            try:
                self._transport = resolve_port(self.url).open_transport()
            except (LM629Error, ValueError, OSError) as exc:
                raise PortError(f"--lm629-port {self.url} cannot be opened: {exc}") from None
            self._install_signals(self._transport)
        return self._transport

    def _install_signals(self, transport: Transport) -> None:
        """Ctrl-C, SIGTERM and SIGHUP (a CI job's timeout, a closed terminal) end the run as
        an interrupted one, so that the fixtures' teardown stops a moving motor (without this
        SIGTERM and SIGHUP would kill pytest where it stands).  A signal that arrives during a
        bus program is held until the program has ended, as the CLI does
        (:class:`~lm629_host.chip.safety.StopSignals`), so that the stop starts on a clean bus."""
        self._signals.guard(transport)
        self._signals.install()

    def close(self) -> None:
        self._signals.restore()
        if self._transport is not None:
            self._transport.close()
            self._transport = None


_SESSION = pytest.StashKey[PortSession]()


def _interrupted(signum: int) -> KeyboardInterrupt:
    """A stop signal as pytest's interrupted run, naming the signal."""
    return KeyboardInterrupt(f"{signal.Signals(signum).name}: the lm629 fixtures stop the motor")


def _load_profile(path: Path) -> Any:
    """The board profile at ``path`` (:mod:`lm629_host.config.profile`), or one usage error naming
    the file, the line and the key."""
    from lm629_host.config import profile as profiles
    try:
        return profiles.load_profile(path)
    except ValueError as exc:  # ProfileError: file, line and key in one line
        raise pytest.UsageError(f"--lm629-profile {path}: {exc}") from None


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


# ---------------------------------------------------------------------------- one test's bench
@dataclass
class _Run:
    """One bus program of the test, as the failure report shows it, or a run of identical
    ones (``count``: from ``time`` to ``last``)."""

    time: float  #: the transport's clock when it ended
    ops: tuple[BusOp, ...]
    result: ProgramResult | None  #: None: it raised
    error: str = ""
    count: int = 1
    last: float = 0.0

    @property
    def changes_chip(self) -> bool:
        """True when the program may have changed the chip (anything but status reads and
        data-reporting commands: LFIL, LTRJ, STT, a reset...)."""
        return any(o.op is Op.RESET or (o.op is Op.COMMAND and o.arg not in _READ_COMMANDS)
                   for o in self.ops)


class ProgramLog:
    """The last bus programs of a test, for its failure report: a program identical to the one
    before it (same operations, same answers) is counted on that line, and when the log is
    full the oldest program that only read the chip goes first, so that the commands that
    set a move up (LFIL, LTRJ, STT) stay in view behind any number of wait polls."""

    def __init__(self, lines: int = TRACE_PROGRAMS) -> None:
        self.lines = lines
        self.runs: list[_Run] = []
        self.dropped = 0  #: programs no longer shown

    def add(self, run: _Run) -> None:
        runs = self.runs
        if runs:
            prev = runs[-1]
            if prev.ops == run.ops and prev.result == run.result and prev.error == run.error:
                prev.count += 1
                prev.last = run.time
                return
        runs.append(run)
        if len(runs) > self.lines:
            gone = next((k for k, r in enumerate(runs) if not r.changes_chip), 0)
            self.dropped += runs.pop(gone).count

    def text_lines(self) -> list[str]:
        out = [f"  ({self.dropped} older program(s) not shown: those that only read the chip "
               "go first)"] \
            if self.dropped else []
        for r in self.runs:
            line = f"  {r.time * 1e3:12.4f}  {_program_text(r)}"
            if r.count > 1:
                line += f"  (x{r.count}, the last at {r.last * 1e3:.4f})"
            out.append(line)
        return out


class Bench(BusObserver):
    """What one test uses: its transport (a fresh simulator, or the run's real port), its last
    bus programs (for the failure report), the motion guard, and the chips handed out."""

    def __init__(self, session: PortSession, request: pytest.FixtureRequest) -> None:
        self.session = session
        self.item = request.node
        self.simulated = session.simulated
        self.moving_allowed = (self.simulated or session.allow_motion
                               or self.item.get_closest_marker("lm629_motion") is not None)
        self.motion_marked = self.item.get_closest_marker("lm629_motion") is not None
        self.log = ProgramLog()
        self.chips: list[lm629_host.LM629] = []
        self.board: lm629_host.Board | None = None
        self.outcome: str | None = None  #: the call phase's outcome, None while not known
        self._last_ltrj: dict[int, int | None] = {}
        self._warned = False
        if self.simulated:
            self.url = _sim_url(session.url, _marker_params(self.item))
            problem = None
            try:
                self.transport = resolve_port(self.url).open_transport()
            except (LM629Error, ValueError) as exc:
                problem = f"{_marker_text(self.item)}: {exc}; also axes (chips on the bus)"
            if problem is not None:  # outside the except: one message, no chained traceback
                pytest.fail(problem, pytrace=False)
            self.owned = True
        else:
            self.url = session.url
            problem = None
            try:
                self.transport = session.transport()
            except PortError as exc:
                problem = str(exc)
            if problem is not None:  # one stop for the run (the check after collection missed it)
                pytest.exit(problem, returncode=pytest.ExitCode.USAGE_ERROR)
            self.owned = False
        self._attach()

    def _attach(self) -> None:
        self.transport.add_observer(self)

    def _detach(self) -> None:
        self.transport.remove_observer(self)

    # -- the trace and the guard: every bus program of the test, as an observer of the
    # transport (programs only, not cycles, so the simulator keeps its fast path)
    def program_starting(self, transport: Transport, program: Program) -> None:
        """Refuse an unmarked start (nothing is sent), or warn about it on a simulator."""
        starts = self._starts(program)
        if starts and not self.motion_marked:
            self._unmarked_start(starts)

    def program_ended(self, transport: Transport, program: Program,
                      result: ProgramResult | None, error: BaseException | None) -> None:
        """Keep the program for the report: commands, words, status bytes (what the program
        itself carries and read; busy polls are not listed)."""
        text = "" if error is None else f"{type(error).__name__}: {error}"
        self.log.add(_Run(transport.clock.now(), tuple(program.ops), result, text))

    def _starts(self, program: Program) -> list[int]:
        """The chips on which ``program`` starts a trajectory that is not a stop: an STT after
        an LTRJ without a stop or motor-off bit (or after no LTRJ seen in this test)."""
        chip, expect_control, starts = 0, False, []
        for o in program.ops:
            if o.op is Op.SELECT:
                chip = o.arg
            elif o.op is Op.COMMAND:
                expect_control = o.arg == Cmd.LTRJ
                if o.arg == Cmd.STT:
                    control = self._last_ltrj.get(chip)
                    if control is None or not control & STOP_FLAGS:
                        starts.append(chip)
                elif o.arg == Cmd.RESET:
                    self._last_ltrj[chip] = None
            elif o.op is Op.WRITE and expect_control:
                self._last_ltrj[chip] = o.arg
                expect_control = False
            elif o.op is Op.RESET:
                self._last_ltrj.clear()
        return starts

    def _unmarked_start(self, chips: list[int]) -> None:
        where = ", ".join(str(c) for c in chips)
        if not self.moving_allowed:
            raise MotionNotAllowed(
                f"this test starts a trajectory on chip {where} of the real port {self.url} but "
                "is not marked @pytest.mark.lm629_motion, and --lm629-allow-motion was not "
                "given: nothing was sent. Mark the test, and run with --lm629-allow-motion "
                "when the axis is free to move")
        if self.simulated and not self._warned:
            self._warned = True
            warnings.warn(pytest.PytestWarning(
                f"{self.item.nodeid} starts a trajectory (chip {where}) but is not marked "
                "@pytest.mark.lm629_motion: on a real port without --lm629-allow-motion it "
                "will fail"), stacklevel=1)

    # -- the chips
    def _spec(self) -> PortSpec:
        """The port settled (lm629_host.transports.ports: chip=, clock=, axes=, cs=), checked when the
        transport opened; a bad value fails the test with the option named."""
        try:
            return resolve_port(self.url)
        except ValueError as exc:
            pytest.fail(f"{self.url}: {exc}", pytrace=False)

    def chip(self) -> lm629_host.LM629:
        spec = self._spec()
        chip = lm629_host.LM629(self.transport, chip=spec.chip, axis=spec.cs,
                                clock_hz=spec.clock_hz)
        self.chips.append(chip)
        chip.reset()
        return chip

    def open_board(self) -> lm629_host.Board:
        spec = self._spec()
        prof = self.session.profile_data
        n = spec.axes if spec.axes is not None else self.transport.chip_count
        if spec.axes is None and prof is not None and prof.axes:
            # the chips the profile names, not every chip select the bridge has: an unwired
            # select fails a reset
            need = 1 + max(ax.cs for ax in prof.axes.values())
            n = need if n is None else min(n, need)
        board = lm629_host.Board(self.transport, n, chip=prof.chip if prof is not None else spec.chip,
                                 clock_hz=spec.clock_hz)
        self.board = board
        if prof is not None:
            named = _name_axes(board, prof)
        board.reset()
        if prof is not None:
            # a reset chip has lost every setting: the profile's gains, LPES, PORT12 again
            from lm629_host.config import profile as profiles
            profiles.apply_profile(named, prof)
        return board

    def axes(self) -> list[lm629_host.LM629]:
        axes = list(self.chips)
        if self.board is not None:
            axes += [a for a in self.board.axes if all(a.chip_select != c.chip_select for c in axes)]
        return axes

    def moving(self) -> bool:
        """True when an axis used is neither on target nor off (a trajectory runs)."""
        try:
            return any(a.is_moving() for a in self.axes())
        except LM629Error:
            return True  # cannot tell: stop to be safe

    # -- the report
    def new_violations(self) -> list[Any]:
        """Protocol violations recorded by a strict simulator since the last look."""
        t = self.transport
        if not isinstance(t, ModelChips):
            return []
        found = t.take_violations()
        return found if t.strict else []

    def trace_text(self) -> str:
        clock = "simulated" if self.simulated else "wall"
        lines = [f"last bus programs on {self.url}, oldest first, one a line (t: {clock} time in ms "
                 "when it ended; words in hex; <- read; [status] the last one its busy checks read):"]
        lines += self.log.text_lines() or ["  (no bus program)"]
        return "\n".join(lines)

    def snapshot_text(self) -> str:
        """A snapshot of every axis used, read now (status, signals, positions, velocities)."""
        axes = self.axes()
        if not axes:
            return "chip snapshot: no chip was opened"
        out = []
        with self._lenient():
            for a in axes:
                try:
                    s = a.snapshot()
                except Exception as exc:  # noqa: BLE001 - the report says what the link did
                    out.append(f"chip snapshot cs{a.chip_select}: could not be read: {exc}")
                    continue
                out.append(
                    f"chip snapshot cs{a.chip_select} at t={s.time * 1e3:.4f} ms: status {int(s.status):02X} "
                    f"({_flag_names(Status, int(s.status))}), signals {int(s.signals):04X} "
                    f"({_flag_names(type(s.signals), int(s.signals))}), desired position "
                    f"{s.desired_position}, real position {s.real_position}, following error "
                    f"{s.following_error}, desired velocity {s.desired_velocity / 65536:.4f} counts/sample, "
                    f"real velocity {s.real_velocity} counts/sample, integration sum {s.integration_sum}")
        return "\n".join(out)

    def stop(self) -> str:
        """Abrupt stop, then motor off, on every axis used: the lines saying how each was left."""
        notes = []
        with self._lenient():
            for a in self.axes():
                _ok, note = emergency_stop(a)
                notes.append(f"cs{a.chip_select}: {note}")
        return "; ".join(notes)

    class _LenientCm:
        def __init__(self, bench: Bench) -> None:
            self.bench = bench
            self.strict: bool | None = None

        def __enter__(self) -> None:
            # the report's own reads and the stop must not trip strict mode again (a violation
            # may have left a command half written): the simulator is lenient meanwhile
            t = self.bench.transport
            if isinstance(t, ModelChips):
                self.strict = t.set_strict(False)
            self.bench.motion_marked = True  # the plugin's own stop is no unmarked start

        def __exit__(self, *exc: object) -> None:
            t = self.bench.transport
            if isinstance(t, ModelChips) and self.strict is not None:
                t.set_strict(self.strict)
                t.take_violations()  # the report's own: not the test's

    def _lenient(self) -> Bench._LenientCm:
        return Bench._LenientCm(self)

    def close(self) -> None:
        self._detach()
        if self.owned:
            self.transport.close()


_BENCH = pytest.StashKey[Bench]()


def _sim_url(base: str | PortURL, params: dict[str, str]) -> str | PortURL:
    """The simulator URL of a test: the port's own parameters, the marker's over them, and
    ``strict=1`` unless one of them says otherwise."""
    values = dict(params)
    if "strict" not in query_params(base) and "strict" not in values:
        values["strict"] = "1"
    return with_query(base, values)


def _marker_params(item: pytest.Item) -> dict[str, str]:
    """``lm629_sim("a=1&b=2", c=3)``: the parameters of the closest marker, as URL text."""
    marker = item.get_closest_marker("lm629_sim")
    if marker is None:
        return {}
    params: dict[str, str] = {}
    for arg in marker.args:
        params.update(query_params("sim://?" + str(arg).lstrip("?")))
    for name, value in marker.kwargs.items():
        params[name] = ("1" if value else "0") if isinstance(value, bool) else str(value)
    return params


def _marker_text(item: pytest.Item) -> str:
    marker = item.get_closest_marker("lm629_sim")
    if marker is None:
        return "--lm629-port"
    args = [repr(a) for a in marker.args] + [f"{k}={v!r}" for k, v in marker.kwargs.items()]
    return f"@pytest.mark.lm629_sim({', '.join(args)})"


def _name_axes(board: lm629_host.Board, prof: Any) -> dict[str, lm629_host.LM629]:
    """Give each axis of ``board`` the profile's name, soft limits, chip variant and clock
    (as ``open_board(profile=...)`` does, on this test's transport); nothing is sent."""
    from lm629_host.config import profile as profiles
    return profiles.name_axes(board, prof)


def _program_text(run: _Run) -> str:
    """``cs0: LTRJ 0008 0004 0000; STT; sync C0 (BREAKPOINT|MOTOR_OFF)``: one program decoded."""
    words = iter(run.result.words if run.result else ())
    statuses = iter(run.result.statuses if run.result else ())
    parts: list[str] = []
    chip = 0
    for o in run.ops:
        op = o.op
        if op is Op.COMMAND:
            try:
                parts.append(Cmd(o.arg).name)
            except ValueError:
                parts.append(f"command {o.arg:02X}")
        elif op is Op.WRITE:
            parts[-1:] = [(parts[-1] if parts else "write") + f" {o.arg:04X}"]
        elif op is Op.READ:
            w = next(words, None)
            text = f"{w:04X}" if w is not None else "????"
            if parts and "<-" in parts[-1]:
                parts[-1] += f" {text}"
            else:
                parts[-1:] = [(parts[-1] if parts else "read") + f" <- {text}"]
        elif op in STATUS_OPS:
            st = next(statuses, None)
            name = {Op.STATUS: "status", Op.SYNC: "sync"}.get(op, f"wait for {o.arg >> 16:02X}")
            parts.append(f"{name} {_status_text(st)}")
        elif op is Op.RESET:
            parts.append("/RST")
        elif op is Op.WAIT:
            parts.append(f"wait {o.arg} us")
        elif op is Op.SELECT:
            chip = o.arg
            parts.append(f"cs{chip}:")
    if not run.ops or run.ops[0].op is not Op.SELECT:
        parts.insert(0, "cs0:")  # a program starts on chip 0
    text = "; ".join(parts).replace(":;", ":")
    result = run.result
    if result is not None and result.status is not None and (
            not result.statuses or result.statuses[-1] != result.status):
        text += f"  [status {_status_text(result.status)}]"
    if run.error:
        text += f"  !! {run.error.splitlines()[0][:160]}"
    return text


def _status_text(status: int | None) -> str:
    if status is None:
        return "??"
    return f"{status:02X} ({_flag_names(Status, status)})"


def _flag_names(flags: type[enum.Flag], value: int) -> str:
    names = [f.name for f in flags if value & f.value]
    return "|".join(n for n in names if n) or "none"


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


__all__ = ["Bench", "FIXTURES", "MARKERS", "MotionNotAllowed", "PortError", "PortSession"]
