"""Several LM628/LM629 on one bus: a multi-axis board.

The chips share the data bus, the strobes and /RST; each has its own /CS.  A bus program may
switch chip select (``Program.select``), so work on several axes, above all a synchronized
start, is one program: one round trip on a bridge, one USB exchange on the FT232H.

    with lm629_host.open_board("sim://?axes=2") as board:
        board.reset()                 # one /RST, every chip checked (ResetError names the axis)
        x, y = board.axes             # LM629 objects sharing the board's transport
        board.start()                 # STT on every axis in one program
        m = board.move_linear({x: 12000, y: 6000}, velocity=65536, acceleration=1000)
        m.wait(timeout=10)            # all axes; MotionError names the axis

Straight lines: :func:`~lm629_host.physics.linear.plan_linear` plans them (pure
arithmetic); :meth:`Board.move_linear` runs the plan.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from lm629_host.errors import ArgumentError, AxisError, CommandError, MotionError
from lm629_host.chip.lm629 import LM629
from lm629_host.bus.snapshot import Snapshot
from lm629_host.errors import check_int
from lm629_host.chip.reset import reset_chips
from lm629_host.chip.move import MOVE_FLAGS, Move, MoveResult, MoveRules, check_duration
from lm629_host.chip.wraparound import short_way
from lm629_host.bus.opcodes import (
    ACCELERATION_MAX,
    INTERRUPTS,
    POSITION_MAX,
    POSITION_MIN,
    VELOCITY_MAX,
    Cmd,
    Status,
)
from lm629_host.bus.program import DEFAULT_BUSY_TIMEOUT_S, Op, Program
from lm629_host.chip.safety import emergency_stop, stop_if_moving
from lm629_host.bus.snapshot import add_snapshot, snapshot_at
from lm629_host.transports.ports import profile_port, resolve_port
from lm629_host.urls import PortURL, query_params
from lm629_host.transports import DEFAULT_URL
from lm629_host.clock import Clock
from lm629_host.transports.base import Transport

if TYPE_CHECKING:
    from lm629_host.chip.batch import Batch
    from lm629_host.bridge.protocol.failsafe import FailsafeState
    from lm629_host.config.profile import Profile
    from lm629_host.physics.linear import LinearPlan

log = logging.getLogger("lm629_host")

def extended_target(chip: LM629, start: Snapshot, target: int) -> int:
    """The extended position a target (a register value, or already extended) stands for on
    ``chip`` moving from ``start``: the short way round the register from its desired
    position, as the chip goes (AN-706 6.5.2)."""
    return start.desired_position + short_way(
        chip.positions.to_register(target) - chip.positions.to_register(start.desired_position))


# ---------------------------------------------------------------------------- the board
class BoardMove:
    """Moves started together on several axes (one :class:`~lm629_host.Move` per axis, all
    with the same start time); :meth:`wait` waits for all of them."""

    def __init__(self, board: Board, moves: Sequence[Move], plan: LinearPlan | None = None) -> None:
        self.board = board
        self.moves = tuple(moves)
        self.plan = plan

    @property
    def targets(self) -> dict[int, int]:
        return {m.chip.chip_select: m.target for m in self.moves}

    def wait(self, timeout: float | None = None, tolerance: int | None = None, *,
             rules: MoveRules | None = None,
             progress: Callable[[Snapshot], None] | None = None) -> list[MoveResult]:
        """Like :meth:`Move.wait <lm629_host.Move.wait>` for every axis (same ``timeout``
        from the common start, same ``tolerance``); returns their results, axis order.

        Every poll reads the snapshot of every axis still moving in one bus program and checks
        each against its own move's rules (:class:`~lm629_host.chip.move.MoveWatch`): a stall, a
        runaway, a position-error flag or a drive found off on *any* axis ends the wait at
        once.  A motion fault on one axis stops every axis and raises :class:`MotionError`
        naming the axis (``exc.axis``).  ``progress`` is called with every snapshot read."""
        watches = {m: m.watch(timeout, tolerance, rules) for m in self.moves if m.result is None}
        clock = self.board.clock
        try:
            while watches:
                pending = list(watches.items())
                snaps = self.board.snapshots([m.chip.chip_select for m, _ in pending])
                for (m, w), snap in zip(pending, snaps):
                    if progress is not None:
                        progress(snap)
                    try:
                        done = w.check(snap)
                    except MotionError as exc:
                        self.board._stop_all()
                        raise exc.on_axis(m.chip.chip_select) from exc
                    if done is not None:
                        del watches[m]
                if watches:
                    clock.sleep(min(w.rules.poll for w in watches.values()))
        except MotionError:
            raise
        except BaseException:
            self.board._stop_all()
            raise
        return [m.result for m in self.moves if m.result is not None]


class Board:
    """Several chips behind one transport: ``axes`` are :class:`LM629` objects, one per chip
    select, that share it.  Use :func:`open_board`."""

    def __init__(self, transport: Transport, axes: int | None = None, *, chip: str = "lm629",
                 busy_timeout: float = DEFAULT_BUSY_TIMEOUT_S, reset_attempts: int = 2,
                 clock_hz: float | None = None) -> None:
        available = transport.chip_selects
        n = available if axes is None else axes
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"axes={axes!r} must be a whole number of chips, at least 1")
        if n > available:
            raise AxisError(n - 1, available, transport.describe())
        self.transport = transport
        self.axes: tuple[LM629, ...] = tuple(
            LM629(transport, chip=chip, busy_timeout=busy_timeout, axis=k,
                  reset_attempts=reset_attempts, clock_hz=clock_hz) for k in range(n))
        self.busy_timeout = busy_timeout
        self.reset_attempts = reset_attempts

    # ------------------------------------------------------------------ plumbing
    @property
    def clock(self) -> Clock:
        return self.transport.clock

    def close(self) -> None:
        self.transport.close()

    def __enter__(self) -> Board:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        """Left by an exception: stop every axis that moves (abrupt stop, the PID holding)
        before the link closes; left normally: the axes stay as the block left them."""
        if exc_type is not None:
            for ax in self.axes:
                stop_if_moving(ax)
        self.close()

    def clear_failsafe(self) -> FailsafeState | None:
        """Acknowledge the bridge's latched failsafe trip; returns the trip (a
        :class:`~lm629_host.bridge.protocol.FailsafeState`) or None."""
        return self.transport.clear_failsafe()

    def __len__(self) -> int:
        return len(self.axes)

    def __repr__(self) -> str:
        return f"<Board {len(self.axes)} axes on {self.transport.describe()}>"

    #: the profile the board was opened with (``open_board(profile=...)``), else None
    profile: Profile | None = None

    def __getitem__(self, which: str | int) -> LM629:
        """``board["x"]``: the axis of that name in the board's profile; ``board[1]``: the
        axis on chip select 1."""
        if isinstance(which, str):
            if self.profile is None:
                raise KeyError(f"{which!r}: this board was opened without a profile, so its "
                               "axes have no names (board[0], or open_board(profile=...))")
            try:
                return self.axis(self.profile.axis(which).cs)
            except ValueError as exc:  # a mapping's missing key
                raise KeyError(str(exc)) from None
        return self.axis(which)

    def axis(self, which: LM629 | int | str) -> LM629:
        """The axis ``which`` (an index, one of :attr:`axes`, or a name of the board's profile,
        as ``board["x"]``); AxisError when it is not one of this board's, KeyError for a name
        the profile does not have."""
        if isinstance(which, str):
            return self[which]
        if isinstance(which, LM629):
            if which not in self.axes:
                raise AxisError(which.axis, len(self.axes), "this board")
            return which
        if isinstance(which, bool) or not isinstance(which, int) or not 0 <= which < len(self.axes):
            raise AxisError(which, len(self.axes), repr(self))
        return self.axes[which]

    def _pick(self, axes: Sequence[LM629 | int]) -> list[LM629]:
        chosen = [self.axis(a) for a in axes] if axes else list(self.axes)
        if len({a.chip_select for a in chosen}) != len(chosen):
            raise ValueError(f"an axis is named twice: {[a.chip_select for a in chosen]}")
        return chosen

    def program(self) -> _BoardProgram:
        return _BoardProgram(busy_timeout_s=self.busy_timeout)

    def batch(self) -> Batch:
        """Typed calls on several axes queued into one bus program, run when the ``with``
        block ends: one exchange on a bridge, the axes switched by SELECT inside it.  Each
        call names its axis as ``board[...]`` does::

            with board.batch() as b:
                px = b["x"].read_real_position()
                py = b["y"].read_real_position()
            print(px.value, py.value)

        The rules are :meth:`LM629.batch`'s (:mod:`lm629_host.chip.batch`)."""
        from lm629_host.chip.batch import Batch
        return Batch(self.transport, axis_of=self._axis_named)

    def _axis_named(self, which: LM629 | str | int) -> LM629:
        return self.axis(which) if isinstance(which, LM629) else self[which]

    # ------------------------------------------------------------------ reset
    def reset(self) -> list[Status]:
        """One /RST for every chip (the line is shared), then AN-706 4.4.1's check on each:
        00 at once, 84/C4 after 1.5 ms, 80/C0 after MSKI/RSTI 0000.  Two programs in all
        (:func:`~lm629_host.chip.reset.reset_chips`, which :meth:`LM629.reset` runs for one chip).
        Retries ``reset_attempts`` times, then raises :class:`ResetError` naming the first
        axis that failed, with its status bytes."""
        return reset_chips(self.axes, pulse=self.transport.has_reset_line,
                           attempts=self.reset_attempts)[0]

    # ------------------------------------------------------------------ synchronized start
    def start_program(self, axes: Sequence[LM629 | int] = (), prefix: Program | None = None,
                      clear: Status | int = 0) -> tuple[_BoardProgram, list[LM629]]:
        """The program of :meth:`start` (after ``prefix``, e.g. the loads), without running it:
        RSTI of ``clear`` (and of the command-error flag where it may be set), a busy-clear
        status of each axis, then the STTs back to back (each a status read and the command
        byte on its chip), then each axis's status once busy is clear."""
        chosen = self._pick(axes)
        p = self.program()
        if prefix is not None:
            p.extend(prefix)
        for a in chosen:
            flags = a.start_flags(clear)
            if flags:
                p.on(a.chip_select).command(Cmd.RSTI).write(int(INTERRUPTS & ~flags))
        for a in chosen:
            p.on(a.chip_select).sync()
        for a in chosen:
            p.on(a.chip_select).command(Cmd.STT)
        for a in chosen:
            p.on(a.chip_select).sync()
        return p, chosen

    def start(self, *axes: LM629 | int, prefix: Program | None = None,
              clear: Status | int = 0) -> list[Status]:
        """STT on every axis (or on ``axes``) in one bus program; raises
        :class:`CommandError` naming the axis whose chip refused its STT."""
        p, chosen = self.start_program(axes, prefix, clear)
        for a in chosen:  # AN-706 4.6.2: no axis updated sooner than 10 ms after its last STT
            a.hold_update()
        statuses = self.transport.execute(p).statuses
        n = len(chosen)
        before, after = statuses[-2 * n:-n], statuses[-n:]
        refused = None
        for a, b, s in zip(chosen, before, after):
            if a.start_checked(b, s) and refused is None:
                refused = (a, s)
        if refused is not None:
            raise CommandError(f"STT on axis {refused[0].chip_select}", refused[1])
        return [Status(s) for s in after]

    # ------------------------------------------------------------------ moves
    def _launch(self, words: Mapping[LM629, tuple[int, int, int]],
                plan: LinearPlan | None, starts: Mapping[LM629, Snapshot]) -> BoardMove:
        """Load (acceleration, velocity, target) on each axis and start them together, flags
        a move reports cleared in the same program (as :meth:`LM629.move_to` does)."""
        loads = self.program()
        for a, (acc, vel, target) in words.items():  # the register value of each target
            loads.on(a.chip_select).extend(a.trajectory_program(acc, vel,
                                                                a.positions.to_register(target)))
        self.start(*words, prefix=loads, clear=MOVE_FLAGS)
        t0 = self.clock.now()
        # each move's target extended as its chip reaches it: the short way from its start
        return BoardMove(self, [Move(a, extended_target(a, starts[a], target), vel, acc,
                                     starts[a], t0)
                                for a, (acc, vel, target) in words.items()], plan)

    def move(self, targets: Mapping[LM629 | int | str, int], *,
             velocity: int | Mapping[LM629 | int | str, int],
             acceleration: int | Mapping[LM629 | int | str, int]) -> BoardMove:
        """Absolute moves on several axes, each with its own (or a common) velocity and
        acceleration word, loaded and started in one program (all STTs together)."""
        resolved = {self.axis(k): v for k, v in targets.items()}

        def per(value: int | Mapping[LM629 | int | str, int], a: LM629, name: str) -> int:
            if isinstance(value, Mapping):
                m = {self.axis(k): v for k, v in value.items()}
                if a not in m:
                    raise ValueError(f"{name}: no value for axis {a.chip_select}")
                value = m[a]
            hi = VELOCITY_MAX if name == "velocity" else ACCELERATION_MAX
            return check_int(f"{name} of axis {a.chip_select}", value, 1, hi, hex_digits=8)

        words = {a: (per(acceleration, a, "acceleration"), per(velocity, a, "velocity"),
                     check_int(f"target of axis {a.chip_select}", t, POSITION_MIN, POSITION_MAX,
                               hex_digits=8))
                 for a, t in resolved.items()}
        for a, (acc, vel, target) in words.items():  # before any read (soft limits)
            if a.limits is not None:
                a.limits.check_trajectory(acc, vel, a.positions.near_register(target))
        starts = {a: a.snapshot() for a in words}
        for a, (acc, vel, target) in words.items():  # the length of each, before any moves
            check_duration(a.move_rules, extended_target(a, starts[a], target)
                           - starts[a].desired_position, vel, acc,
                           a.move_rules.clock_hz or a.clock_hz,
                           f"board.move: axis {a.chip_select} to {target}")
        return self._launch(words, None, starts)

    def plan_linear(self, targets: Mapping[LM629 | int | str, int], *, velocity: int,
                    acceleration: int, starts: Mapping[LM629, Snapshot] | None = None
                    ) -> LinearPlan:
        """:func:`plan_linear` from where the axes are now (their desired positions)."""
        from lm629_host.physics.linear import plan_linear  # here: straight lines only

        resolved = {self.axis(k): v for k, v in targets.items()}
        for a, t in resolved.items():
            check_int(f"target of axis {a.chip_select}", t, POSITION_MIN, POSITION_MAX, hex_digits=8)
        check_int("velocity", velocity, 1, VELOCITY_MAX, hex_digits=8)
        check_int("acceleration", acceleration, 1, ACCELERATION_MAX, hex_digits=8)
        if starts is None:
            starts = {a: a.snapshot() for a in resolved}
        # the targets are register values, reached the short way round (as LM629.move_to's):
        # planned as extended counts from the starts (a line across the wrap is short)
        return plan_linear({a.chip_select: (starts[a].desired_position,
                                             extended_target(a, starts[a], t))
                            for a, t in resolved.items()}, velocity, acceleration)

    def move_linear(self, targets: Mapping[LM629 | int | str, int], *, velocity: int,
                    acceleration: int) -> BoardMove:
        """A straight line in count space from where the axes are (their desired positions)
        to ``targets``: each axis's words scaled by its share of the path
        (:func:`plan_linear`), loaded and started in one program."""
        resolved = [self.axis(k) for k in targets]
        for a, t in zip(resolved, targets.values()):  # before any read (soft limits); the
            if a.limits is not None:                  # words are checked as they are loaded
                a.limits.check_position(a.positions.near_register(t),
                                        f"target of axis {a.chip_select}")
        starts = {a: a.snapshot() for a in resolved}
        # the line's length, before it is planned and before anything moves: every axis takes
        # the path's time, held to the strictest axis's max_duration
        check_int("velocity", velocity, 1, VELOCITY_MAX, hex_digits=8)
        check_int("acceleration", acceleration, 1, ACCELERATION_MAX, hex_digits=8)
        travel = [extended_target(a, starts[a], t) - starts[a].desired_position
                  for a, t in zip(resolved, targets.values())]
        if resolved:
            strictest = min(resolved, key=lambda a: a.move_rules.max_duration)
            check_duration(strictest.move_rules, round(math.hypot(*travel)), velocity,
                           acceleration, strictest.move_rules.clock_hz or strictest.clock_hz,
                           f"board.move_linear to {dict(zip((a.chip_select for a in resolved), targets.values()))}")
        plan = self.plan_linear(targets, velocity=velocity, acceleration=acceleration,
                                starts=starts)
        words = {self.axes[ap.axis]: (ap.acceleration, ap.velocity, ap.target)
                 for ap in plan.axes if ap.distance}
        if not words:
            return BoardMove(self, [], plan)
        return self._launch(words, plan, starts)

    def stop(self, axes: Sequence[LM629 | int] = ()) -> list[str]:
        """Abrupt stop, then motor off, on every axis (or ``axes``); each axis's line of how
        its motor was left (see :func:`~lm629_host.chip.safety.emergency_stop`)."""
        return [emergency_stop(a)[1] for a in self._pick(axes)]

    def _stop_all(self) -> None:
        """Every axis: abrupt stop, then motor off (each tried even when another fails)."""
        for a in self.axes:
            emergency_stop(a)

    def statuses(self, axes: Sequence[LM629 | int] = ()) -> list[Status]:
        """The status byte of every axis, one program."""
        p = self.program()
        chosen = self._pick(axes)
        for a in chosen:
            p.on(a.chip_select).status()
        return [Status(s) for s in self.transport.execute(p).statuses]

    def snapshots(self, axes: Sequence[LM629 | int] = ()) -> list[Snapshot]:
        """:meth:`LM629.snapshot` of every axis (or ``axes``), in one bus program, each
        axis's positions extended past the register's wraparound as its own reads are."""
        chosen = self._pick(axes)
        p = self.program()
        for a in chosen:  # each with the RSTI of a wraparound bit it saw, as its own reads
            p.on(a.chip_select).extend(a.clearing_wrap(add_snapshot(a.program())))
        r = self.transport.execute(p)
        now = self.clock.now()
        return [a.extended(snapshot_at(r, k, now)) for k, a in enumerate(chosen)]


class _BoardProgram(Program):
    """A program that remembers its chip select, so that ``on(k)`` adds a SELECT only when
    the chip changes (a program starts on chip 0)."""

    def __init__(self, busy_timeout_s: float = DEFAULT_BUSY_TIMEOUT_S) -> None:
        super().__init__(busy_timeout_s=busy_timeout_s)
        self._chip = 0

    def on(self, chip: int | None) -> _BoardProgram:
        chip = chip or 0
        if chip != self._chip:
            self.select(chip)
        return self

    def select(self, chip: int) -> _BoardProgram:
        super().select(chip)
        self._chip = chip
        return self

    def extend(self, other: Program) -> _BoardProgram:
        # an axis's own program starts with its select (axis > 0): keep track of it
        for o in other.ops:
            if o.op is Op.SELECT:
                if o.arg == self._chip:
                    continue
                self._chip = o.arg
            self.ops.append(o)
        self.top_select = max(self.top_select, other.top_select)
        return self


def open_board(url: str | PortURL | None = None, *, axes: int | None = None, chip: str | None = None,
               clock: float | str | None = None, trace=None,
               busy_timeout: float = DEFAULT_BUSY_TIMEOUT_S,
               profile: str | os.PathLike[str] | Profile | None = None,
               apply: bool | str = "auto") -> Board:
    """Open every chip behind ``url``: ``sim://?axes=2``, a multi-axis bridge, an FT232H with
    two /CS lines.  The number of axes is ``axes`` or the URL's ``axes=`` (both: they must
    agree, :func:`lm629_host.transports.ports.resolve_port`), else what the transport reports (the
    simulator's chips, the bridge's chip selects from HELLO, the FT232H's /CS lines).  More
    axes than the board has chip selects is an :class:`AxisError`; ``cs=`` (one chip) is an
    error here.

    ``profile``: a bench profile (:mod:`lm629_host.config.profile`, a path or a loaded one): the port
    (when ``url`` is None), the chip and clock come from it, ``board["x"]`` is its axis ``x``,
    every named axis gets its soft limits (``ValueError`` for a move outside them, before any
    bus cycle), and ``apply`` says what is sent at open: ``"auto"`` (default) applies the
    profile to each axis that has lost its settings (reset or powered up since: one RDSIGS
    each; a warning is logged for each one applied), True applies it to every axis, False
    sends nothing.  A bad profile is a :class:`~lm629_host.config.profile.ProfileError` (ValueError)
    before the port is opened."""
    prof = None
    if profile is not None:
        from lm629_host.config.profile import Profile, load_profile
        prof = profile if isinstance(profile, Profile) else load_profile(profile)
        if apply not in (True, False, "auto"):
            raise ValueError(f"apply={apply!r}: expected True, False or 'auto'")
        if url is None:
            url = profile_port(prof)
        if axes is None and "axes" not in query_params(url) and prof.axes:
            # the profile describes the board: its chip selects, not every select the
            # bridge offers (a four-select bridge with two chips wired has two axes)
            axes = max(a.cs for a in prof.axes.values()) + 1
        chip = prof.chip if chip is None else chip
        clock = prof.clock_hz if clock is None else clock
    if url is None:
        url = DEFAULT_URL
    board = _open_board(url, axes, chip, clock, trace, busy_timeout)
    if prof is not None:
        try:
            _with_profile(board, prof, apply)
        except BaseException:
            board.close()
            raise
    return board


def _with_profile(board: Board, prof: Profile, apply: bool | str) -> None:
    from lm629_host.config.profile import apply_profile, ensure_applied, name_axes
    named = name_axes(board, prof)
    if apply == "auto":
        ensure_applied(named, prof, log.warning)
    elif apply:
        apply_profile(named, prof)


def _open_board(url: str | PortURL, axes: int | None, chip: str | None, clock: float | str | None,
                trace: Any, busy_timeout: float) -> Board:
    spec = resolve_port(url, chip=chip, clock=clock, axes=axes)
    if spec.cs is not None:
        raise ArgumentError("cs", spec.cs, f"cs={spec.cs} names one chip: open_board opens "
                                           "every chip of the board (lm629_host.open takes cs=)")
    transport = spec.open_transport(trace)
    n = spec.axes
    if n is None:
        n = transport.chip_count  # a simulator: the chips it built, not its adapter's selects
    try:
        return Board(transport, n, chip=spec.chip, busy_timeout=busy_timeout,
                     clock_hz=spec.clock_hz)
    except BaseException:
        transport.close()
        raise


__all__ = ["Board", "BoardMove", "open_board"]
