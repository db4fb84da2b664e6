"""One test's bench in the pytest plugin: its transport (a fresh simulator, or the run's real
port), the chips it hands out, the motion guard (an unmarked start refused before it reaches
the chip on a real port, a warning on a simulator), and the programs kept for the report."""

from __future__ import annotations

import warnings
from typing import Any

import pytest

import lm629_host
from lm629_host.bus.opcodes import STOP_FLAGS, Cmd
from lm629_host.bus.program import Op, Program, ProgramResult
from lm629_host.chip.safety import emergency_stop
from lm629_host.errors import LM629Error
from lm629_host.integrations.pytest_port import PortError, PortSession, sim_url
from lm629_host.integrations.pytest_report import ProgramLog, Run, snapshot_line
from lm629_host.transports.base import BusObserver, Transport
from lm629_host.transports.ports import PortSpec, resolve_port
from lm629_host.transports.sim import ModelChips
from lm629_host.urls import query_params


class MotionNotAllowed(LM629Error):
    """An unmarked test started a trajectory on a real port without --lm629-allow-motion."""


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
            self.url = sim_url(session.url, marker_params(self.item))
            problem = None
            try:
                self.transport = resolve_port(self.url).open_transport()
            except (LM629Error, ValueError) as exc:
                problem = f"{marker_text(self.item)}: {exc}; also axes (chips on the bus)"
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
        self.log.add(Run(transport.clock.now(), tuple(program.ops), result, text))

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
            named = name_axes(board, prof)
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
                out.append(snapshot_line(s, a.chip_select))
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


def marker_params(item: pytest.Item) -> dict[str, str]:
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


def marker_text(item: pytest.Item) -> str:
    marker = item.get_closest_marker("lm629_sim")
    if marker is None:
        return "--lm629-port"
    args = [repr(a) for a in marker.args] + [f"{k}={v!r}" for k, v in marker.kwargs.items()]
    return f"@pytest.mark.lm629_sim({', '.join(args)})"


def name_axes(board: lm629_host.Board, prof: Any) -> dict[str, lm629_host.LM629]:
    """Give each axis of ``board`` the profile's name, soft limits, chip variant and clock
    (as ``open_board(profile=...)`` does, on this test's transport); nothing is sent."""
    from lm629_host.config import profile as profiles
    return profiles.name_axes(board, prof)
