"""The chip's user commands once their words are in: decoding and execution.

:class:`CommandDecoder` is the part of :class:`~.chip.ChipModel` that turns a finished
command (its opcode and data words) into register changes: LTRJ and LFIL into their input
buffers, STT, UDF and the other control commands, the interrupt commands (MSKI, RSTI, SBPA/SBPR,
LPEI/LPES) and the data-reporting reads (RDxx).  The host interface (strobes, busy, byte
phase, violations) and the registers themselves stay in :mod:`.chip`; this is a mixin of
that class (the same object and state), so that the per-command path costs no extra call or
attribute hop: LTRJ's path is on every move's host cost on ``sim://``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from lm629_host.bus.bits import (
    STATUS_BREAKPOINT as _BREAKPOINT,
    STATUS_COMMAND_ERROR as _CMD_ERROR,
    STATUS_INTERRUPTS as _INTERRUPTS,
    SIGNALS_ACCELERATION_LOADED as _ACCELERATION_LOADED,
    SIGNALS_ACQUIRE_INDEX as _ACQUIRE_INDEX,
    SIGNALS_EIGHT_BIT_OUTPUT as _EIGHT_BIT_OUTPUT,
    SIGNALS_STOP_ON_ERROR as _STOP_ON_ERROR,
    TRAJ_ACCELERATION as _ACCELERATION_BIT,
    TRAJ_FORWARD,
    TRAJ_STOP_FLAGS as _STOP_BITS,
    TRAJ_VELOCITY_MODE,
)
from lm629_host.bus.opcodes import (
    lfil_interval,
    COMMANDS,
    FILTER_ORDER,
    VELOCITY_MAX,
    Cmd,
    CommandInfo,
    Direction,
    TrajectoryFlags,
    lfil_word_count,
    ltrj_word_count,
    s32,
    s32_words,
)

if TYPE_CHECKING:
    from lm629_host.sim.model.motion import Motion
    from lm629_host.sim.model.params import ChipParams
    from lm629_host.sim.model.registers import FilterRegisters, TrajectoryBuffer

# The bits are plain ints here (lm629_host.bus.bits: an IntFlag's operators are Python calls,
# a quarter of an LTRJ's host cost on sim://); ``signals_extra`` stays a plain int (an IntFlag
# in it would make every test of it in the sample loop an enum call).
_MODE_BITS = TRAJ_VELOCITY_MODE | TRAJ_FORWARD
#: LTRJ's words in the order they follow the control word: (bit, the bit of its relative
#: flag, the buffer's field)
_TRAJECTORY_WORDS = tuple((int(f), int(f) >> 1, name) for f, name in (
    (TrajectoryFlags.ACCELERATION, "acceleration"), (TrajectoryFlags.VELOCITY, "velocity"),
    (TrajectoryFlags.POSITION, "position")))

#: opcode byte -> (its command, its :class:`CommandInfo`), built once from the one table
#: (:data:`~lm629_host.bus.opcodes.COMMANDS`): a dict look-up where ``Cmd(byte)`` costs an
#: enum call, on every command strobe of ``sim://``
OPCODES: dict[int, tuple[Cmd, CommandInfo]] = {int(c): (c, info) for c, info in COMMANDS.items()}
#: the 32-bit registers the two-word reads report (the Motion attribute each reads)
_REGISTER_READS = {Cmd.RDDV: "desired_velocity", Cmd.RDDP: "desired_position",
                   Cmd.RDIP: "index_position", Cmd.RDRP: "real_position"}
# the commands compared on the per-command path, as module names (``Cmd.X`` looked up on
# the class is a descriptor call)
_LFIL, _LTRJ, _RDSIGS, _RDRV, _RDSUM = Cmd.LFIL, Cmd.LTRJ, Cmd.RDSIGS, Cmd.RDRV, Cmd.RDSUM
_NONE = Direction.NONE


class CommandDecoder:
    """Decoding and execution of the user commands, mixed into :class:`~.chip.ChipModel`."""

    if TYPE_CHECKING:  # the state and host interface ChipModel provides
        params: ChipParams
        motion: Motion
        tick: int
        clock_hz: int
        history: list[tuple[int, tuple[int, ...]]]  # a chip.CommandRecord
        flags: int
        mask: int
        motor_off: bool
        signals_extra: int
        breakpoint: int
        position_error_threshold: int
        filter_buffer: FilterRegisters
        trajectory: TrajectoryBuffer
        _udf_pending: bool
        _last_stt: int | None
        _cmd: int | None
        _dir: Direction
        _words_left: int
        _words: list[int]

        @property
        def signals(self) -> int: ...

        def turn_motor_off(self) -> None: ...

        def _violation(self, what: str) -> None: ...

    def _accept_word(self, word: int) -> None:
        cmd = OPCODES[self._cmd][0]  # type: ignore[index]  # a command is under way: _cmd is set
        self._words.append(word)
        self._words_left -= 1
        if len(self._words) == 1 and cmd is _LFIL:
            self._words_left += lfil_word_count(word)
        elif len(self._words) == 1 and cmd is _LTRJ:
            self._words_left += ltrj_word_count(word)
        if self._words_left == 0:
            words, self._words = self._words, []
            self._dir = _NONE
            if self.params.record and self.history:
                self.history[-1] = (self.history[-1][0], tuple(words))
            self._execute(cmd, words)

    def _read_words(self, cmd: Cmd) -> list[int]:
        m = self.motion
        if cmd is _RDSIGS:
            return [self.signals]
        if cmd is _RDRV:
            return [m.real_velocity & 0xFFFF]
        if cmd is _RDSUM:
            return [m.integration_sum & 0xFFFF]
        value = getattr(m, _REGISTER_READS[cmd]) & 0xFFFFFFFF
        return [value >> 16, value & 0xFFFF]

    def _execute(self, cmd: Cmd, words: list[int]) -> None:
        m = self.motion
        if cmd is Cmd.STT:
            buf = self.trajectory
            if not m.start(buf):
                # [model choice 13] refused and ignored: the input buffer keeps what was
                # loaded (signals bit 14 included) for an STT that can execute it, except a
                # value out of range, which start() dropped
                self._command_error_silent()
                if not buf.loaded & TrajectoryFlags.ACCELERATION:
                    self.signals_extra &= ~_ACCELERATION_LOADED
                return
            stop = buf.stop
            self._update_rate(stop)
            buf.loaded = 0
            buf.stop = 0  # [model choice 13] a stop bit acts once
            self.signals_extra &= ~_ACCELERATION_LOADED
            if stop & TrajectoryFlags.MOTOR_OFF:
                self.turn_motor_off()
            else:
                self.motor_off = False
        elif cmd is Cmd.DFH:
            m.define_home()
        elif cmd is Cmd.SIP:
            self.signals_extra |= _ACQUIRE_INDEX
            m.arm_index()
        elif cmd is Cmd.UDF:
            self._udf_pending = True
        elif cmd is Cmd.PORT8:
            self.signals_extra |= _EIGHT_BIT_OUTPUT
        elif cmd is Cmd.PORT12:
            if self.params.variant == "lm629":
                # [model choice 4] the LM629 has no 12-bit port; a correct host may send it
                # once to learn which part it talks to (lm629 selftest): no violation
                self._command_error_silent()
            else:
                self.signals_extra &= ~_EIGHT_BIT_OUTPUT
        elif cmd in (Cmd.LPES, Cmd.LPEI):
            self.position_error_threshold = words[0]
            if cmd is Cmd.LPES:
                self.signals_extra |= _STOP_ON_ERROR
            else:
                self.signals_extra &= ~_STOP_ON_ERROR
        elif cmd is Cmd.MSKI:
            self.mask = words[0] & _INTERRUPTS
        elif cmd is Cmd.RSTI:
            self.flags &= (words[0] & _INTERRUPTS) | ~_INTERRUPTS
            # [model choice 19] the breakpoint condition is level-held: cleared while the
            # desired position sits on the breakpoint, bit 6 reads 1 again at once
            if m.desired_position == self.breakpoint:
                self.flags |= _BREAKPOINT
        elif cmd is Cmd.LFIL:
            self._load_filter(words)
        elif cmd is Cmd.LTRJ:
            self._load_trajectory(words)
        elif cmd in (Cmd.SBPA, Cmd.SBPR):
            value = s32_words(words[0], words[1])
            if cmd is Cmd.SBPR:
                value = s32(m.target_position + value)
            self.breakpoint = value

    def _update_rate(self, stop: int) -> None:
        """An executed STT [model choice 34]: one within ``update_s`` of the last aborts the
        trajectory calculation in progress (the next sample keeps the output), and is a host
        protocol violation unless it stops the motor (AN-706 4.6.2)."""
        last, self._last_stt = self._last_stt, self.tick
        window = round(self.params.update_s * self.clock_hz)
        if last is None or self.tick - last >= window:
            return
        self.motion.abort_pending = True
        if not stop:
            self._violation(f"STT {(self.tick - last) / self.clock_hz * 1e3:.2f} ms after the "
                            f"last one: the chip aborts the trajectory calculation (AN-706 4.6.2:"
                            f" at most one update per {self.params.update_s * 1e3:g} ms)")

    def _command_error_silent(self) -> None:
        """A command error that a correct host can provoke (not a protocol violation)."""
        self.flags |= _CMD_ERROR

    def _load_filter(self, words: list[int]) -> None:
        control, values = words[0], iter(words[1:])
        buf = self.filter_buffer
        buf.ds = lfil_interval(control)
        for flag in FILTER_ORDER:
            if control & flag:
                setattr(buf, (flag.name or "").lower(), next(values))

    def _load_trajectory(self, words: list[int]) -> None:
        control, values = words[0], iter(words[1:])
        buf = self.trajectory
        out_of_range: list[str] = []
        buf.control = control
        # [model choice 27] an LTRJ with a stop bit only stops: its mode bits do not replace
        # the running trajectory's; any other LTRJ sets the mode and cancels a pending stop
        buf.stop = control & _STOP_BITS
        if not buf.stop:
            buf.mode = control & _MODE_BITS
        for flag, relative, name in _TRAJECTORY_WORDS:
            if not control & flag:
                continue
            word = (next(values) << 16) | next(values)
            if name == "position" or control & relative:
                value = s32(word)
            else:
                value = word
                if word > VELOCITY_MAX:  # == ACCELERATION_MAX
                    # [model choice 30] outside the 30-bit range (AN-706 2.7): the STT that
                    # would execute it is refused; a correct host never sends it
                    out_of_range.append(f"LTRJ {name} word {word:08X} is above 3FFFFFFF "
                                        "(AN-706 2.7: 30-bit unsigned range)")
            if control & relative and buf.loaded & flag:
                # [model choice 29] relative to the value previously loaded (not yet started)
                value += getattr(buf, name)
                keep = buf.loaded & relative  # absolute + relative stays absolute
            else:
                keep = control & relative
            setattr(buf, name, value)
            buf.loaded = (buf.loaded & ~(flag | relative)) | flag | keep
        if control & _ACCELERATION_BIT:
            self.signals_extra |= _ACCELERATION_LOADED
        for what in out_of_range:
            self._violation(what)
