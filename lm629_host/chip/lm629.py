"""The typed command layer: one method per LM628/LM629 user command.

Each method validates its arguments against the chip's ranges first (``ValueError`` naming the
argument, the value and the range, and no bus traffic at all), then builds one bus program and
runs it on the transport.  The busy check before every command byte and every data word is
part of the program (see :mod:`lm629_host.bus.program`), so it cannot be forgotten here.

Words go most significant byte first, 32-bit values as two words with the most significant
word first, positions in two's complement (spec "Bus cycles").
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

from lm629_host.bus.bits import SIGNALS_MOTOR_OFF, SIGNALS_ON_TARGET
from lm629_host.bus.opcodes import (
    ACCELERATION_MAX,
    COEFFICIENT_MAX,
    DERIVATIVE_INTERVAL_MAX,
    FILTER_ORDER,
    INTERRUPTS,
    NOMINAL_CLOCK_HZ,
    POSITION_MAX,
    POSITION_MIN,
    UPDATE_INTERVAL_S,
    VELOCITY_MAX,
    Cmd,
    Signals,
    Status,
    TrajectoryFlags,
    lfil_control,
    lfil_interval,
    s16,
    s32_words,
)
from lm629_host.bus.program import DEFAULT_BUSY_TIMEOUT_S, Program, ProgramResult
from lm629_host.bus.snapshot import Snapshot, add_snapshot, snapshot_at
from lm629_host.chip.waiting import WaitsMixin
from lm629_host.chip.move import MoveRules
from lm629_host.chip.mover import Mover, MovesMixin
from lm629_host.chip.pacing import PacingMixin, UpdatePacing, check_flags
from lm629_host.chip.recording import RecordingMixin
from lm629_host.chip.reset import ResetMixin
from lm629_host.chip.routing import ProgramRouting
from lm629_host.chip.wraparound import PositionTracker, check_register_position
from lm629_host.clock import Clock
from lm629_host.errors import ArgumentError, AxisError, check_int
from lm629_host.physics.limits import SoftLimits
from lm629_host.transports import exiting
from lm629_host.chip.safety import stop_at_exit, stop_if_moving
from lm629_host.transports.base import Transport

if TYPE_CHECKING:
    from lm629_host.bridge.protocol.failsafe import FailsafeState
    from lm629_host.chip.batch import Batch

#: busy timeout bounds: "well above" the chip's 100 us worst case; 65.535 ms is the largest a
#: bridge RUN request carries (PROTOCOL.md, busy_timeout_us)
BUSY_TIMEOUT_MIN_S = 200e-6
BUSY_TIMEOUT_MAX_S = 65.535e-3

#: signals bits 10 and 7: the shaft is meant to rest where the desired position is (a snapshot
#: then tells a later move where it starts), as a plain int (every snapshot tests it)
_RESTING = SIGNALS_ON_TARGET | SIGNALS_MOTOR_OFF

_STOPS = {
    None: TrajectoryFlags(0),
    "smooth": TrajectoryFlags.STOP_SMOOTH,
    "abrupt": TrajectoryFlags.STOP_ABRUPT,
    "off": TrajectoryFlags.MOTOR_OFF,
}


class LM629(ProgramRouting, ResetMixin, PacingMixin, MovesMixin, WaitsMixin, RecordingMixin):
    """One LM628 or LM629 behind a transport.  Use :func:`lm629_host.open` to make one.

    Threads may share one object: every bus program runs whole under the transport's lock
    (:attr:`Transport.lock <lm629_host.transports.base.Transport.lock>`), so calls from
    several threads never interleave on the bus.  A sequence of calls (load, then start) is
    not atomic: hold ``chip.transport.lock`` around it when another thread might move the
    motor in between.
    """

    #: when :meth:`move_to`'s moves are done or a motion fault (settable per object)
    move_rules: MoveRules = MoveRules()
    #: the axis's soft limits (a profile sets them): every trajectory is checked against them
    #: in :meth:`trajectory_program`, before any bus cycle (:mod:`lm629_host.physics.limits`)
    limits: SoftLimits | None = None
    #: the shortest time between two trajectory updates (STT) on this chip, seconds: AN-706
    #: 4.6.2 (a new STT aborts the chip's trajectory calculation and holds its output) asks for
    #: 10 ms.  0 turns the rule off, for a chip measured to keep up (settable per object)
    update_interval: float = UPDATE_INTERVAL_S
    #: what an update sooner than ``update_interval`` does: ``"wait"`` until it is due, on the
    #: transport's clock (the simulated one on ``sim://``), or ``"raise"`` :class:`UpdateTooSoon`
    #: before any bus cycle.  A stop (LTRJ stop bits) is never held back
    update_rule: str = "wait"

    def __init__(self, transport: Transport, *, chip: str = "lm629", reset_attempts: int = 2,
                 busy_timeout: float = DEFAULT_BUSY_TIMEOUT_S, axis: int | None = None,
                 clock_hz: float | None = None):
        super().__init__()
        chip = chip.lower()
        if chip not in ("lm628", "lm629"):
            raise ValueError(f"chip={chip!r}: expected 'lm628' or 'lm629'")
        if axis is not None and (isinstance(axis, bool) or not isinstance(axis, int)
                                 or not 0 <= axis < transport.chip_selects):
            raise AxisError(axis, transport.chip_selects, transport.describe())
        #: the chip select this object addresses on a multi-axis board (None: the only chip);
        #: every program it builds starts with ``select(axis)`` (a program starts on chip 0)
        self.axis = axis
        #: the chip select its programs address (``axis``, or 0 for the only chip)
        self.chip_select: int = axis or 0
        self.busy_timeout = busy_timeout
        self.transport = transport
        self.variant = chip
        self.reset_attempts = reset_attempts
        self._clock_hz = clock_hz  # the clock said by the caller (a URL's clock=, --clock)
        self._ds = 1  # derivative interval, samples, re-sent with every LFIL (AN-706 4.5.1)
        self._port12 = False  # re-issued after every reset (LM628 with a 12-bit DAC)
        #: the extended positions (AN-706 6.5.2): every position this object reads goes
        #: through it, so that a wraparound of the register is no jump (:mod:`.wraparound`)
        self.positions = PositionTracker()
        self._pacing = UpdatePacing(self)  # its STTs: spaced, checked (:mod:`.pacing`)
        self._mover = Mover(self, self._pacing)  # its moves started (:mod:`.mover`)
        # a script that ends without close(): its normal exit stops this chip if it moves
        # before the link closes (lm629_host/transports/exiting.py)
        exiting.stop_at_exit(transport, self.chip_select, lambda: stop_at_exit(self))

    # ------------------------------------------------------------------ plumbing
    @property
    def busy_timeout(self) -> float:
        """Seconds a busy check may wait before :class:`BusyTimeout` (default 5 ms)."""
        return self._busy_timeout

    @busy_timeout.setter
    def busy_timeout(self, seconds: float) -> None:
        if not isinstance(seconds, (int, float)) or not BUSY_TIMEOUT_MIN_S <= seconds <= \
                BUSY_TIMEOUT_MAX_S:
            raise ArgumentError(
                "busy_timeout", seconds, f"busy_timeout={seconds!r} s is outside {BUSY_TIMEOUT_MIN_S * 1e3:g}.."
                f"{BUSY_TIMEOUT_MAX_S * 1e3:g} ms (well above the chip's 100 us worst case, "
                "within what the bridge protocol carries)", lo=BUSY_TIMEOUT_MIN_S,
                hi=BUSY_TIMEOUT_MAX_S)
        self._busy_timeout = float(seconds)

    def program(self) -> Program:
        """A new, empty bus program with this chip's busy timeout (and its chip select)."""
        p = Program(busy_timeout_s=self._busy_timeout)
        if self.axis:
            p.select(self.axis)
        return p

    @property
    def clock(self) -> Clock:
        """The transport's clock: simulated on ``sim://``, the wall clock on hardware."""
        return self.transport.clock

    @property
    def clock_hz(self) -> float:
        """The chip's clock input (Hz): the transport's when it knows it (a simulator's model),
        else the one given when it was opened (``clock=``), else the nominal 8 MHz.  Used for
        default timeouts, expected move times and the sample period of tuning."""
        return self.transport.clock_hz or self._clock_hz or NOMINAL_CLOCK_HZ

    def shadow(self, runner: Callable[[Program], ProgramResult]) -> LM629:
        """A copy of this object whose bus programs all go to ``runner`` (never to the
        transport): the same transport, chip select and settings, and the host-side state this
        object keeps of the chip (the derivative interval last sent, whether the command-error
        flag is known clear...) as it is now, its own from then on.  A batch builds its
        programs on one, so that building changes nothing here."""
        twin = self._rerouted(runner)
        twin.positions = self.positions.copy()  # its reads are answered with dummy words
        twin._pacing = self._pacing.bound_to(twin)
        twin._mover = self._mover.bound_to(twin, twin._pacing)
        return twin

    def batch(self) -> Batch:
        """Queue typed calls into one bus program, run when the ``with`` block ends (one
        exchange on a bridge); reads return handles whose ``.value`` is set then::

            with chip.batch() as b:
                p = b.read_real_position()
                b.load_filter(kp=20)
                b.update_filter()
            print(p.value)

        A command error (or a busy timeout) inside it names the call.  It captures this
        thread's calls on ``b`` only: direct calls on the chip inside the block run at once,
        and a second batch on the same bus inside the block is refused.  See
        :mod:`lm629_host.chip.batch`."""
        from lm629_host.chip.batch import Batch
        return Batch(self.transport, self)

    def close(self) -> None:
        self.transport.close()

    def __enter__(self) -> LM629:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        """Left by an exception: stop the axis if it moves (abrupt stop, the PID holding)
        before the link closes; left normally: the axis stays as the block left it."""
        if exc_type is not None:
            stop_if_moving(self)
        self.close()

    def clear_failsafe(self) -> FailsafeState | None:
        """Acknowledge the bridge's latched failsafe trip (its transport's); returns the trip
        (a :class:`~lm629_host.bridge.protocol.FailsafeState`) or None."""
        return self.transport.clear_failsafe()

    def __repr__(self) -> str:
        where = f" axis {self.axis}" if self.axis is not None else ""
        return f"<LM629 {self.variant}{where} on {self.transport.describe()}>"

    def _command(self, cmd: Cmd) -> None:
        self.run(self.program().command(cmd))

    def _read(self, cmd: Cmd, words: int) -> tuple[int, ...]:
        return self.run(self.program().command(cmd).read(words)).words

    # ------------------------------------------------------------------ reset
    def reset_done(self) -> None:
        """What a reset (this object's or a board's) leaves: the derivative interval back to
        one sample, the command-error flag clear."""
        self._ds = 1
        self._pacing.reset_done()
        self.positions.restart()
        self.positions.pending = False  # the reset cleared the bit
        self._mover.rest_desired = None

    @property
    def port12_selected(self) -> bool:
        """True after :meth:`port12`: every reset issues PORT12 again."""
        return self._port12

    # ------------------------------------------------------------------ status
    def read_status(self) -> Status:
        """RDSTAT: the status byte (no busy check; valid at any time)."""
        return Status(self.run(self.program().status()).statuses[0])

    def sync(self) -> Status:
        """Wait until the busy bit is clear (bounded by ``busy_timeout``); return the status."""
        return Status(self.run(self.program().sync()).statuses[0])

    def is_moving(self) -> bool:
        """True while the trajectory generator runs with the drive on (RDSIGS: neither on
        target nor motor off).  The chip refuses a new acceleration then (AN-706 4.6.1)."""
        return not self.read_signals() & (Signals.ON_TARGET | Signals.MOTOR_OFF)

    def read_signals(self) -> Signals:
        """RDSIGS: the 16-bit signals register."""
        return Signals(self._read(Cmd.RDSIGS, 1)[0])

    def snapshot_program(self) -> Program:
        """The bus program of :meth:`snapshot` (status, then :data:`SNAPSHOT_READS`)."""
        return add_snapshot(self.program())

    def snapshot(self) -> Snapshot:
        """Status, signals, positions, velocities and integration sum in one bus program; the
        positions extended past the register's wraparound (:meth:`extended`)."""
        r = self.run(self.clearing_wrap(self.snapshot_program()))
        return self.extended(snapshot_at(r, 0, self.clock.now()))

    def extended(self, s: Snapshot) -> Snapshot:
        """``s`` (just read from this chip) with its positions extended past the register's
        wraparound (:class:`~lm629_host.chip.wraparound.PositionTracker`); a wraparound bit in its
        status is cleared by this object's next position read."""
        self.positions.saw(s.status)
        s = self.positions.snapshot(s)
        self._mover.rest_desired = s.desired_position if int(s.signals) & _RESTING else None
        return s

    def clearing_wrap(self, program: Program) -> Program:
        """``program`` with an RSTI of the wraparound bit in front when a read has seen it
        (AN-706 6.5.2: the host notes the wrap and resets the bit), in the same exchange.
        Every program that reads positions for this object goes through here (its reads, its
        snapshots, a move's start and wait, a board's snapshots), on every transport, so
        that one script counts the same crossings (``positions.wraps``) on all of them."""
        if not self.positions.pending:
            return program
        self.positions.pending = False
        return self.program().command(Cmd.RSTI).write(int(INTERRUPTS & ~Status.WRAPAROUND)) \
            .extend(program)

    def _read_position(self, cmd: Cmd, name: str) -> int:
        """RDDP or RDRP, extended; the status its busy checks read shows a wraparound."""
        r = self.run(self.clearing_wrap(self.program().command(cmd).read(2)))
        if r.status is not None:
            self.positions.saw(r.status)
        near = "desired" if name == "real" else None
        return self.positions.extend(name, s32_words(*r.words), near=near)

    # ------------------------------------------------------------------ interrupts
    def mask_interrupts(self, flags: Status | int) -> None:
        """MSKI: the interrupt conditions (status bits 1..6) that drive HI."""
        value = check_flags("flags", flags)
        self.run(self.program().command(Cmd.MSKI).write(int(value)))

    def reset_interrupts(self, flags: Status | int = INTERRUPTS) -> None:
        """RSTI: clear exactly ``flags`` (default: all six) and, with them, HI (RSTI resets the
        HI line; it rises again at once if another enabled flag is still set)."""
        value = check_flags("flags", flags)
        self.run(self.program().command(Cmd.RSTI).write(int(INTERRUPTS & ~value)))
        if value & Status.COMMAND_ERROR:
            self._pacing.ce_clear = True

    # ------------------------------------------------------------------ homing, index, limits
    def define_home(self) -> None:
        """DFH: the current position becomes 0 (the extended positions restart there)."""
        self._command(Cmd.DFH)
        self.positions.restart()
        self._mover.rest_desired = None

    def set_index_position(self) -> None:
        """SIP: latch the position at the next index pulse (read it with read_index_position)."""
        self._command(Cmd.SIP)

    def load_position_error(self, threshold: int, stop: bool = False) -> None:
        """LPEI (flag only) or, with ``stop=True``, LPES (flag and motor off)."""
        value = check_int("threshold", threshold, 0, COEFFICIENT_MAX, hex_digits=4)
        self.run(self.program().command(Cmd.LPES if stop else Cmd.LPEI).write(value))

    def set_breakpoint(self, position: int, relative: bool = False) -> None:
        """SBPA, or SBPR (relative to the current target position) with ``relative=True``."""
        value = check_int("position", position, POSITION_MIN, POSITION_MAX, hex_digits=8)
        self.run(self.program().command(Cmd.SBPR if relative else Cmd.SBPA).write32(value))

    # ------------------------------------------------------------------ filter
    def filter_program(self, kp: int | None = None, ki: int | None = None, kd: int | None = None,
                       il: int | None = None, derivative_interval: int | None = None, *,
                       ds: int | None = None) -> Program:
        """Validate and build LFIL without running it (the derivative interval is not
        remembered until the program has run).  ``ds`` is the derivative interval by the
        name a profile and the CLI give it; ``derivative_interval`` is kept for scripts."""
        values = {"kp": kp, "ki": ki, "kd": kd, "il": il}
        for name, v in values.items():
            if v is not None:
                values[name] = check_int(name, v, 0, COEFFICIENT_MAX, hex_digits=4)
        if ds is not None and derivative_interval is not None:
            raise ArgumentError("ds", ds, f"ds={ds!r} and derivative_interval="
                                          f"{derivative_interval!r} are one setting: give ds alone")
        given, name = (ds, "ds") if ds is not None else (derivative_interval, "derivative_interval")
        ds = self._ds
        if given is not None:
            ds = check_int(name, given, 1, DERIVATIVE_INTERVAL_MAX)
        control = lfil_control(ds)
        for flag in FILTER_ORDER:
            if values[(flag.name or "").lower()] is not None:
                control |= flag
        p = self.program().command(Cmd.LFIL).write(control)
        for flag in FILTER_ORDER:
            v = values[(flag.name or "").lower()]
            if v is not None:
                p.write(v)
        return p

    def load_filter(self, kp: int | None = None, ki: int | None = None, kd: int | None = None,
                    il: int | None = None, derivative_interval: int | None = None, *,
                    ds: int | None = None) -> None:
        """LFIL: load the given coefficients into the filter's input buffers (UDF applies them).

        ``ds``, the derivative interval (``derivative_interval`` is the same, by its older
        name), is in samples, 1..256; when omitted the last value sent is sent again (the chip
        takes it from every LFIL control word, AN-706 4.5.1).
        """
        p = self.filter_program(kp, ki, kd, il, derivative_interval, ds=ds)
        self.run(p)
        self._ds = lfil_interval(p.ops[1].arg)

    def update_filter(self) -> None:
        """UDF: input buffers -> working filter registers at the next sample."""
        self._command(Cmd.UDF)

    @property
    def derivative_interval(self) -> int:
        """The derivative interval (samples) last sent with LFIL."""
        return self._ds

    # ------------------------------------------------------------------ trajectory
    def trajectory_program(self, acceleration: int | None = None, velocity: int | None = None,
                           position: int | None = None, *, acceleration_relative: bool = False,
                           velocity_relative: bool = False, position_relative: bool = False,
                           velocity_mode: bool = False, forward: bool = True,
                           stop: str | None = None) -> Program:
        """Validate and build LTRJ without running it."""
        if stop not in _STOPS:
            raise ValueError(f"stop={stop!r} must be one of None, 'smooth', 'abrupt', 'off'")
        acc_lo = -ACCELERATION_MAX - 1 if acceleration_relative else 0
        vel_lo = -VELOCITY_MAX - 1 if velocity_relative else 0
        if acceleration is not None:
            acceleration = check_int("acceleration", acceleration, acc_lo, ACCELERATION_MAX,
                                     hex_digits=8)
        if velocity is not None:
            velocity = check_int("velocity", velocity, vel_lo, VELOCITY_MAX, hex_digits=8)
        if position is not None:
            position = check_register_position("position", position)
        if velocity_mode and position is not None:
            raise ValueError("position cannot be given with velocity_mode=True: a velocity-mode "
                             "move has no target position")
        if stop is not None and (position is not None or velocity is not None
                                 or acceleration is not None):
            raise ValueError(
                f"stop={stop!r} cannot be combined with new acceleration/velocity/position: the "
                "chip would not move (spec: stop bits only stop an ongoing move). Send the stop, "
                "then load the next move")
        if self.limits is not None and stop is None:  # a stop is never refused
            # the limits are extended counts: the target the chip reaches the short way round
            self.limits.check_trajectory(
                acceleration, velocity,
                position if position is None or position_relative
                else self.positions.near_register(position),
                acceleration_relative=acceleration_relative,
                velocity_relative=velocity_relative, position_relative=position_relative,
                velocity_mode=velocity_mode)
        control = _STOPS[stop]
        if velocity_mode:
            control |= TrajectoryFlags.VELOCITY_MODE
            if forward:
                control |= TrajectoryFlags.FORWARD
        p = self.program().command(Cmd.LTRJ)
        words = self.program()
        for value, flag, rel_flag, relative in (
                (acceleration, TrajectoryFlags.ACCELERATION, TrajectoryFlags.ACCELERATION_RELATIVE,
                 acceleration_relative),
                (velocity, TrajectoryFlags.VELOCITY, TrajectoryFlags.VELOCITY_RELATIVE,
                 velocity_relative),
                (position, TrajectoryFlags.POSITION, TrajectoryFlags.POSITION_RELATIVE,
                 position_relative)):
            if value is not None:
                control |= flag | (rel_flag if relative else 0)
                words.write32(value)
        return p.write(int(control)).extend(words)

    def load_trajectory(self, acceleration: int | None = None, velocity: int | None = None,
                        position: int | None = None, *, acceleration_relative: bool = False,
                        velocity_relative: bool = False, position_relative: bool = False,
                        velocity_mode: bool = False, forward: bool = True,
                        stop: str | None = None, start: bool = False) -> None:
        """LTRJ: load trajectory parameters (raw 16.16 words for acceleration and velocity,
        counts for position).  Nothing moves until STT; ``start=True`` appends the STT to the
        same bus program (one round trip on a bridge) and checks it like :meth:`start`."""
        p = self.trajectory_program(
            acceleration, velocity, position, acceleration_relative=acceleration_relative,
            velocity_relative=velocity_relative, position_relative=position_relative,
            velocity_mode=velocity_mode, forward=forward, stop=stop)
        if start and velocity_mode and not self.positions.knows("desired"):
            # a run may cross the register's wrap before its first read: the snapshot it
            # starts from, in the same program, is where its extended positions go on from
            _, r = self._pacing.start(p, update=stop is None,
                                      head=self.clearing_wrap(self.snapshot_program()))
            self.extended(snapshot_at(r, 0, self.clock.now()))
            self._mover.rest_desired = None  # read before the STT: the run goes on now
        elif start:
            self._pacing.start(p, update=stop is None)
        else:
            self.run(p)

    def start_checked(self, before: int, after: int) -> bool:
        """Take the status read just before this chip's STT (busy clear) and the one after it;
        return True when the chip refused that STT (the caller raises :class:`CommandError`).
        Every STT, this object's or a board's, goes through here."""
        self._mover.rest_desired = None  # the trajectory may run from here on
        return self._pacing.checked(before, after)

    # ------------------------------------------------------------------ output port
    def port8(self) -> None:
        """PORT8: 8-bit output (the reset default; required setting on the LM629)."""
        self._command(Cmd.PORT8)
        self._port12 = False

    def port12(self) -> None:
        """PORT12: 12-bit DAC output, LM628 only; re-issued by :meth:`reset`."""
        if self.variant != "lm628":
            raise ValueError(
                f"port12() is for an LM628 with a 12-bit DAC; this chip is an {self.variant.upper()}"
                " (open it with chip='lm628' if it really is an LM628)")
        self._command(Cmd.PORT12)
        self._port12 = True

    # ------------------------------------------------------------------ data reporting
    def read_desired_position(self) -> int:
        """RDDP: desired position, counts, extended past the register's wraparound (a Python
        int; the register itself reads C0000000..3FFFFFFF: :mod:`lm629_host.chip.wraparound`)."""
        return self._read_position(Cmd.RDDP, "desired")

    def read_real_position(self) -> int:
        """RDRP: real (encoder) position, counts, extended past the register's wraparound."""
        return self._read_position(Cmd.RDRP, "real")

    def read_index_position(self) -> int:
        """RDIP: position latched at the index pulse after SIP, extended as the real position
        nearest to it."""
        return self.positions.near_register(s32_words(*self._read(Cmd.RDIP, 2)), "real")

    def read_desired_velocity(self) -> int:
        """RDDV: desired velocity, signed 16.16 (65536 = 1 count/sample)."""
        return s32_words(*self._read(Cmd.RDDV, 2))

    def read_real_velocity(self) -> int:
        """RDRV: real velocity, integer counts/sample (signed 16-bit)."""
        return s16(self._read(Cmd.RDRV, 1)[0])

    def read_integration_sum(self) -> int:
        """RDSUM: the integration term (signed 16-bit)."""
        return s16(self._read(Cmd.RDSUM, 1)[0])

    # ------------------------------------------------------------------ experts
    def raw(self, command: int, write: Iterable[int] = (), read: int = 0) -> tuple[int, ...]:
        """Send any command byte with data words to write, or a count of words to read."""
        command = check_int("command", command, 0, 0xFF, hex_digits=2)
        words = [check_int("word", w, 0, 0xFFFF, hex_digits=4) for w in write]
        read = check_int("read", read, 0, 16)
        if words and read:
            raise ValueError("a command either writes words or reads them, not both")
        p = self.program().command(command)
        for w in words:
            p.write(w)
        self._pacing.ce_clear = False  # any byte may provoke a command error
        return self.run(p.read(read)).words


__all__ = ["LM629"]
