"""Software model of an LM628/LM629: the host interface and the registers.

The model is driven one bus cycle at a time, as the pins would drive it:
:meth:`ChipModel.read_status`, :meth:`write_command`, :meth:`write_data` and
:meth:`read_data` are one /RD or /WR strobe each (one byte), :meth:`reset_pulse` is the rising
edge of /RST.  Time is the chip's own clock count (``tick``, integer chip clocks since power-on);
whoever drives the model (the ``sim://`` transport, the simavr harness, the emulated FT232H)
advances it with :meth:`advance_to` before each strobe.  The model never looks at the wall
clock.

What happens at the sample tick (every 2048 clocks) is delegated to :class:`~.motion.Motion`:
trajectory generator, PID filter, output stage, motor and encoder.  This module keeps the
registers the host sees (status, signals, mask, buffers) and the events that are pure register
logic (breakpoint, excessive position error).  What a finished command does to them (LTRJ,
LFIL, STT, the interrupt commands, the data-reporting reads) is :mod:`.commands`'
:class:`~.commands.CommandDecoder`, a mixin of :class:`ChipModel`.

The model knows nothing of the driver: it takes bytes and answers bytes.

Host-interface behaviour, from the spec (where the spec is silent, the model choices 1-6 of
:mod:`lm629_host.sim.model` apply: ignored strobes and the byte phase, stray data bytes and unknown
opcodes, busy after RESET, PORT12 on an LM629, the busy and reset times):

* busy is set after a command byte and after the second byte of a data word, for
  ``ChipParams.busy_s``; a write while busy is ignored, a read while busy returns the stale
  byte of the I/O register; neither sets the command-error bit (as on silicon);
  [model choice 1] for the byte phase;
* a new command byte aborts an unfinished command;
* a data transfer in the wrong direction sets the command-error bit and is ignored
  ([model choice 2] for the other transfers that do);
* after /RST the status reads 00 (busy clear) until the reset completes ``reset_s`` later, then
  84 or C4; [model choice 3] for busy after the RESET command;
* ``strict`` raises :class:`~lm629_host.errors.ProtocolViolation` at once on anything a correct
  host never does: a write or data read while busy, a data byte without a command, a wrong
  direction, an aborted command, an unknown opcode, a cycle during the /RST window, a
  velocity or acceleration word above 3FFFFFFF; without ``strict`` each is recorded in
  ``violations`` as a :class:`Violation` (the message, with its simulated ``time``).
"""

from __future__ import annotations

from collections.abc import Callable

from lm629_host.errors import ProtocolViolation
from lm629_host.bus.bits import (
    STATUS_BREAKPOINT as _BREAKPOINT,
    STATUS_BUSY as _BUSY,
    STATUS_COMMAND_ERROR as _CMD_ERROR,
    STATUS_INTERRUPTS as _INTERRUPTS,
    STATUS_MOTOR_OFF as _MOTOR_OFF,
    STATUS_POSITION_ERROR as _POSITION_ERROR,
    STATUS_TRAJECTORY_COMPLETE as _TRAJ_DONE,
    SIGNALS_EIGHT_BIT_OUTPUT as _EIGHT_BIT_OUTPUT,
    SIGNALS_FILTER_UPDATED as _FILTER_UPDATED,
    SIGNALS_FORWARD as _FORWARD,
    SIGNALS_HOST_INTERRUPT as _HOST_INTERRUPT,
    SIGNALS_ON_TARGET as _ON_TARGET,
    SIGNALS_STOP_ON_ERROR as _STOP_ON_ERROR,
    SIGNALS_VELOCITY_MODE as _VELOCITY_MODE,
)
from lm629_host.bus.opcodes import (
    wrap_counts,
    COEFFICIENT_MAX,
    SAMPLE_CLOCKS,
    Cmd,
    Direction,
)
from lm629_host.sim.model.commands import OPCODES, CommandDecoder
from lm629_host.sim.model.fastloop import py_loop, run_fast
from lm629_host.sim.model.motion import Motion
from lm629_host.sim.model.params import ChipParams, MotorParams
from lm629_host.sim.model.registers import FilterRegisters, TrajectoryBuffer

# The status bits are plain ints here (lm629_host.bus.bits): the status byte is computed for
# every busy poll, so ``flags`` is always kept as a plain int.
#: signals bits 7..1 repeat the status byte (the rest of the signals word is kept apart)
_STATUS_IN_SIGNALS = _INTERRUPTS | _MOTOR_OFF
# the transfer directions and RESET as module names: an enum member looked up on its class
# (``Direction.READ``) is a descriptor call, and the strobe handlers run for every bus cycle
_NONE, _READ, _WRITE = Direction.NONE, Direction.READ, Direction.WRITE
_RESET = Cmd.RESET


class Violation(str):
    """One recorded host protocol violation: the message, with the simulated time it happened.

    A ``str`` (so that logs and ``"; ".join`` keep working) carrying ``tick`` (chip clocks since
    power-on) and ``time`` (simulated seconds), for a harness that drives the model from
    outside and must line the violation up with its own trace.
    """

    tick: int
    time: float

    def __new__(cls, what: str, tick: int, clock_hz: int) -> Violation:
        v = super().__new__(cls, what)
        v.tick = tick
        v.time = tick / clock_hz
        return v


class CommandRecord(list):
    """The record of ``sim://?record=1``: a list of (command, words), bounded.

    It keeps at least the latest ``window`` commands (``record_window``) and drops the oldest
    in blocks of ``window // 8`` (so an append stays O(1) amortised and memory stays bounded
    in a long run: a plain list grew by ~137 bytes a command); ``dropped`` counts them.  It is
    a list, so that code reading the record slices and compares it as one."""

    def __init__(self, window: int) -> None:
        super().__init__()
        if window < 1:
            raise ValueError(f"record_window={window} must be at least 1")
        self.window = window
        self.dropped = 0
        self._limit = window + max(1, window // 8)

    def append(self, item: tuple[int, tuple[int, ...]]) -> None:
        super().append(item)
        if len(self) > self._limit:
            n = len(self) - self.window
            del self[:n]
            self.dropped += n

    def clear(self) -> None:
        super().clear()
        self.dropped = 0


def _sample_loop(choice: str) -> Callable[[tuple, tuple], tuple] | None:
    """The steady-state sample loop named by ``ChipParams.fast``."""
    choice = str(choice).lower()
    if choice in ("0", "false", "off", "no"):
        return None
    if choice in ("py", "python"):
        return py_loop
    if choice not in ("auto", "1", "true", "c"):
        raise ValueError(f"fast={choice!r}: expected auto, c, py or 0")
    try:
        from lm629_host.sim.model._fastloop import run
    except ImportError:
        if choice == "c":
            raise ValueError("fast=c: the C sample loop lm629_host/sim/model/_fastloop.c is not built "
                             "(pip install -e . builds it; it needs a C compiler and the Python "
                             "headers)") from None
        return py_loop
    return run


class ChipModel(CommandDecoder):
    """One LM628 or LM629 with its motor, as seen from its pins."""

    # set by _reset_registers (declared here: the sample loop reads them before, in the file)
    signals_extra: int
    breakpoint: int
    filter_buffer: FilterRegisters
    _udf_pending: bool

    def __init__(self, params: ChipParams | None = None, motor: MotorParams | None = None):
        self.params = params or ChipParams()
        if self.params.variant not in ("lm628", "lm629"):
            raise ValueError(f"chip variant {self.params.variant!r}: expected lm628 or lm629")
        if not 1_000_000 <= self.params.clock_hz <= 8_000_000:
            raise ValueError(f"clock {self.params.clock_hz} Hz is outside the chip's 1-8 MHz")
        self.motor_params = motor or MotorParams()
        self.clock_hz = self.params.clock_hz
        self.tick = 0
        self.busy_clocks = max(1, round(self.params.busy_s * self.clock_hz))
        #: the busy time after each command byte that has its own (``command_busy_s``), clocks
        self.command_busy_clocks = {int(cmd): max(1, round(s * self.clock_hz))
                                    for cmd, s in self.params.command_busy_s.items()}
        self.reset_clocks = max(8, round(self.params.reset_s * self.clock_hz))
        self.next_sample = SAMPLE_CLOCKS
        self.samples = 0
        #: the latest commands that reached the chip, with their words (when ``params.record``)
        self.history = CommandRecord(self.params.record_window)
        #: every host protocol violation, in order, each with its simulated time (``.time``)
        self.violations: list[Violation] = []
        #: run steady-state samples through :func:`.fastloop.run_fast` (False: only the readable
        #: per-sample code; the two are cross-checked by tests/sim/test_model_fastloop.py)
        self.fast = _sample_loop(self.params.fast)
        if not (self.motor_params.index_wired and self.motor_params.encoder_wired):
            self.fast = None  # an unwired encoder line is the readable loop's alone (motor.py)
        self.motion = Motion(self, self.motor_params)
        # power-on: as if /RST had been pulsed long ago and the reset had completed
        self._power_on_reset()
        self._reset_done_at: int | None = None
        self._in_hw_reset = False
        self._complete_reset()
        if self.params.fault == "reset":
            self._in_hw_reset = True
            self._reset_done_at = None
        #: the first clock at which :meth:`advance_to` has more to do than count: the next
        #: sample, or the end of the reset in progress when sooner.  Below it a chip's clock
        #: is only a count, which is how a :class:`~.bus.ChipBus` moves its chips' ``tick``
        #: between two events without a call per chip (kept by :meth:`_events_changed`)
        self.next_event = self.next_sample
        self._events_changed()

    # ------------------------------------------------------------------ time
    @property
    def sample_clocks(self) -> int:
        return SAMPLE_CLOCKS

    def describe(self, count: int = 1) -> str:
        """``simulated LM629 at 8 MHz`` (``count`` chips: ``simulated 2 x LM629 ...``): how
        every simulator names what it runs."""
        n = f"{count} x " if count > 1 else ""
        return f"simulated {n}{self.params.variant.upper()} at {self.clock_hz / 1e6:g} MHz"

    def now(self) -> float:
        """Simulated seconds since power-on."""
        return self.tick / self.clock_hz

    def advance(self, seconds: float) -> None:
        self.advance_to(self.tick + max(0, round(seconds * self.clock_hz)))

    def advance_to(self, tick: int) -> None:
        """Run the chip up to clock ``tick``: reset completion and samples, in time order."""
        if tick < self.next_event:
            # nothing happens before ``tick`` but time: the case of nearly every bus strobe
            # (hundreds of strobes fit in one sample), taken without the event loop below
            if tick > self.tick:
                self.tick = tick
            return
        if tick <= self.tick:
            return
        while True:
            event = self.next_sample
            done = self._reset_done_at
            if done is not None and done <= event and done <= tick:
                self.tick = done
                self._complete_reset()
                continue
            if event > tick:
                break
            # run every whole sample up to the next reset event or `tick`
            limit = tick if done is None else min(tick, done - 1)
            n = (limit - event) // SAMPLE_CLOCKS + 1
            if n <= 0:
                break
            self._run_samples(n)
        self.tick = tick
        self._events_changed()

    def _events_changed(self) -> None:
        """Keep :attr:`next_event` after a sample ran or a reset was started or ended."""
        done = self._reset_done_at
        self.next_event = self.next_sample if done is None else min(done, self.next_sample)

    def _run_samples(self, n: int) -> None:
        """Run ``n`` consecutive samples, the first at ``self.next_sample``."""
        motion = self.motion
        while n > 0:
            if self.fast and not (self._in_hw_reset or self._reset_done_at is not None
                                  or self._udf_pending or motion.abort_pending
                                  or self.signals_extra & _FILTER_UPDATED):
                ran = run_fast(self, n, self.fast)
                n -= ran
                self.samples += ran
                self.next_sample += ran * SAMPLE_CLOCKS
                self.tick = self.next_sample - SAMPLE_CLOCKS
                if n and motion.quiescent():
                    motion.skip(n)
                    self.samples += n
                    self.next_sample += n * SAMPLE_CLOCKS
                    self.tick = self.next_sample - SAMPLE_CLOCKS
                    return
                continue
            n -= 1
            self.tick = self.next_sample
            self.next_sample += SAMPLE_CLOCKS
            self.samples += 1
            if self._in_hw_reset or self._reset_done_at is not None:
                # the chip's microcode is busy resetting: its registers, trajectory and filter
                # wait, the shaft and the encoder go on with zero drive [model choice 31]
                motion.run_plant_only()
                if n and motion.plant_at_rest():
                    self.samples += n
                    self.next_sample += n * SAMPLE_CLOCKS
                    self.tick = self.next_sample - SAMPLE_CLOCKS
                    return
                continue
            flags, sig = self.flags, self.signals_extra
            self._sample(motion)
            if n and flags == self.flags and sig == self.signals_extra and motion.quiescent():
                # skip-ahead: nothing the host can see would change before it next acts
                motion.skip(n)
                self.samples += n
                self.next_sample += n * SAMPLE_CLOCKS
                self.tick = self.next_sample - SAMPLE_CLOCKS
                return

    def _sample(self, motion: Motion) -> None:
        sig = self.signals_extra
        if self._udf_pending:
            self.filter = self.filter_buffer.copy()
            self._udf_pending = False
            motion.filter_changed()
            sig |= _FILTER_UPDATED
        else:
            sig &= ~_FILTER_UPDATED
        self.signals_extra = sig
        before = motion.desired_position
        was_off = self.motor_off
        events = motion.sample()
        after = motion.desired_position
        # breakpoint [model choice 19]: the desired position reached it during this sample
        step = wrap_counts(after - before)
        to_bp = wrap_counts(self.breakpoint - before)
        if 0 <= to_bp <= step or step <= to_bp <= 0:
            events |= _BREAKPOINT
        if not self.motor_off:
            error = motion.position_error()
            if abs(error) > self.position_error_threshold:
                events |= _POSITION_ERROR
                if self.signals_extra & _STOP_ON_ERROR:
                    self.turn_motor_off()
        if self.motor_off and not was_off:
            events |= _TRAJ_DONE
        self.flags |= int(events) & _INTERRUPTS

    # ------------------------------------------------------------------ reset
    def _power_on_reset(self) -> None:
        self.position_error_threshold = COEFFICIENT_MAX
        self._reset_registers()

    def _reset_registers(self) -> None:
        """What any reset sets (spec: "What reset sets")."""
        self.flags = 0  # latched interrupt bits 1..6
        self.motor_off = True
        self.mask = _INTERRUPTS & ~_BREAKPOINT  # 003E-equivalent
        self.signals_extra = _EIGHT_BIT_OUTPUT  # bits 8..15 and 0 not derived elsewhere
        self.breakpoint = 0
        self.filter = FilterRegisters()
        self.filter_buffer = FilterRegisters()
        self.trajectory = TrajectoryBuffer()
        self._udf_pending = False
        self._abort_transfer()
        self._io_word = 0
        self._busy_until = 0
        self._last_stt: int | None = None  # chip tick of the last executed STT
        self.motion.reset(self.params.reset_position)

    def _abort_transfer(self) -> None:
        self._cmd: int | None = None
        self._dir = _NONE
        self._words_left = 0
        self._words: list[int] = []
        self._hi_byte: int | None = None
        self._out: list[int] = []
        self._read_phase_low = False

    def _complete_reset(self) -> None:
        self._reset_done_at = None  # (advance_to, which completes it, updates next_event)
        self._in_hw_reset = False
        self._reset_registers()
        self.flags |= _TRAJ_DONE  # 84 / C4 once reset has finished

    def reset_pulse(self) -> None:
        """/RST rising edge (after at least 8 clocks low)."""
        if self.params.fault == "rst":
            return  # the /RST line is not connected: the chip never sees the pulse
        self._check_cycle("/RST pulse", allow_reset=True)
        self.position_error_threshold = COEFFICIENT_MAX
        self._abort_transfer()
        self._in_hw_reset = True
        self.motion.output = 0  # [model choice 31] zero drive from /RST on
        self._busy_until = 0
        self._reset_done_at = None if self.params.fault == "reset" else self.tick + self.reset_clocks
        self._events_changed()

    # ------------------------------------------------------------------ registers
    @property
    def busy(self) -> bool:
        if self.params.fault == "busy":
            return True
        return self.tick < self._busy_until

    def busy_deadline(self) -> int | None:
        """The clock tick from which the status reads busy clear, as things stand (a past tick
        when it is clear now; None when busy has no known end: ``fault=busy``).  Busy only
        changes on host strobes and at the end of a reset, which ends with it, so a host may
        skip status reads before this tick knowing they would read busy."""
        if self.params.fault == "busy":
            return None
        return 0 if self._in_hw_reset else self._busy_until

    def read_status(self) -> int:
        """/PS low, /RD strobe: the status byte.  Valid at any time, and it changes nothing:
        :attr:`status` is this same function (a busy poll costs one call, not two)."""
        if self._in_hw_reset:
            return _BUSY if self.params.fault == "busy" else 0
        s = self.flags | (_MOTOR_OFF if self.motor_off else 0)
        if self.tick < self._busy_until or self.params.fault == "busy":
            s |= _BUSY
        return s

    status = property(read_status, doc="The status byte as RDSTAT would read it now.")

    @property
    def interrupt(self) -> bool:
        """The chip's host interrupt: any latched interrupt flag that the mask enables
        (signals bit 15, and the HI pin when it is wired)."""
        return not self._in_hw_reset and bool(self.flags & self.mask)

    @property
    def hi(self) -> bool:
        """The HI pin as the adapter sees it: the host interrupt, low when HI is not wired
        (``ChipParams.hi_wired``, ``wiring=hi-open``)."""
        return self.params.hi_wired and self.interrupt

    @property
    def signals(self) -> int:
        m = self.motion
        s = (int(self.signals_extra) & ~_STATUS_IN_SIGNALS) | (self.status & _STATUS_IN_SIGNALS)
        if self.interrupt:
            s |= _HOST_INTERRUPT
        if m.on_target:
            s |= _ON_TARGET
        if m.velocity_mode:
            s |= _VELOCITY_MODE
            if m.forward:
                s |= _FORWARD
        return s

    def turn_motor_off(self) -> None:
        """Drive off (LTRJ bit 8 or LPES); trajectory complete is motor off OR on target."""
        if not self.motor_off:
            self.flags |= _TRAJ_DONE
        self.motor_off = True
        self.motion.drive_off()

    # ------------------------------------------------------------------ bus cycles
    def _violation(self, what: str) -> None:
        self.violations.append(Violation(what, self.tick, self.clock_hz))
        if self.params.strict:
            raise ProtocolViolation(f"host protocol violation at {self.now() * 1e6:.1f} us: {what}")

    def _check_cycle(self, what: str, allow_reset: bool = False) -> bool:
        """False (and a violation) when the chip cannot take this cycle now."""
        if self._in_hw_reset and not allow_reset:
            if self.params.fault == "reset":
                return False  # a dead chip: the host cannot know, so it is no violation
            self._violation(f"{what} during the /RST window (wait 1.5 ms after /RST)")
            return False
        return True

    def _set_busy(self, clocks: int | None = None) -> None:
        self._busy_until = self.tick + (self.busy_clocks if clocks is None else clocks)

    def _command_error(self, why: str) -> None:
        self.flags |= _CMD_ERROR
        self._violation(why)

    # (the status strobe, read_status, is with the status register above)

    # The three strobes below test in one expression whether the chip takes the cycle (no /RST
    # window, not busy, the transfer expected) and hand any other case to a ``_refuse_*``
    # method, which checks the causes one by one in the chip's order and says which: the
    # common case costs no call, no enum and no message formatted (every bus cycle of
    # ``sim://`` comes here).

    def write_command(self, byte: int) -> None:
        """/PS low, /WR strobe: a command byte."""
        byte &= 0xFF
        if self._in_hw_reset or self.tick < self._busy_until or self.params.fault == "busy":
            self._refuse(f"command {byte:02X}", "written while busy (ignored)")
            return
        if self._dir is not _NONE and (self._words_left or self._hi_byte is not None):
            self._violation(f"command {byte:02X} aborts command {self._cmd:02X} with "
                            f"{self._words_left} word(s) still expected")
        self._abort_transfer()
        if self.params.record:
            self.history.append((byte, ()))
        known = OPCODES.get(byte)
        if known is None:
            self._set_busy()
            self._command_error(f"unknown command {byte:02X}")
            return
        cmd, info = known
        self._cmd = byte
        self._dir = direction = info.direction
        self._words_left = info.words
        if cmd is _RESET:
            self.motion.output = 0  # [model choice 31] zero drive while the chip resets
            self._set_busy(self.reset_clocks)
            self._reset_done_at = None if self.params.fault == "reset" else self.tick + self.reset_clocks
            self._events_changed()
            return
        self._busy_until = self.tick + self.command_busy_clocks.get(byte, self.busy_clocks)
        if direction is _READ:
            self._out = self._read_words(cmd)
        elif direction is _NONE:
            self._execute(cmd, [])

    def write_data(self, byte: int) -> None:
        """/PS high, /WR strobe: one byte of a data word (high byte first)."""
        byte &= 0xFF
        if (self._in_hw_reset or self.tick < self._busy_until or self.params.fault == "busy"
                or self._dir is not _WRITE or self._words_left == 0):
            self._refuse_write(byte)
            return
        if self._hi_byte is None:
            self._hi_byte = byte
            return
        word = (self._hi_byte << 8) | byte
        self._hi_byte = None
        self._io_word = word
        self._busy_until = self.tick + self.busy_clocks
        self._accept_word(word)

    def read_data(self) -> int:
        """/PS high, /RD strobe: one byte of a data word (high byte first)."""
        out = self._out
        if (self._in_hw_reset or self.tick < self._busy_until or self.params.fault == "busy"
                or self._dir is not _READ or not out):
            return self._refuse_read()
        word = out[0]
        self._io_word = word
        if not self._read_phase_low:
            self._read_phase_low = True
            return word >> 8
        self._read_phase_low = False
        del out[0]
        self._words_left -= 1
        self._busy_until = self.tick + self.busy_clocks
        if not out:
            self._dir = _NONE
        return word & 0xFF

    def _refuse(self, what: str, while_busy: str) -> None:
        """A strobe the chip does not take: during the /RST window or while busy."""
        if self._check_cycle(what) and self.busy:
            self._violation(f"{what} {while_busy}")

    def _refuse_write(self, byte: int) -> None:
        """A data byte the chip does not take (see :meth:`write_data`): why, in order."""
        what = f"data byte {byte:02X}"
        if self._in_hw_reset or self.busy:
            self._refuse(what, "written while busy (ignored)")
            return
        expected = "a read command" if self._dir is _READ else "no command expecting data"
        self._command_error(f"{what} written with {expected}")

    def _refuse_read(self) -> int:
        """A data read the chip does not answer (see :meth:`read_data`): why, in order; the
        I/O register's stale byte is what the host reads."""
        stale = (self._io_word & 0xFF) if self._read_phase_low else (self._io_word >> 8)
        if self._in_hw_reset or self.busy:
            self._refuse("data read", "while busy (stale byte returned)")
            return stale
        what = "a write command" if self._dir is _WRITE else "no command to read"
        self._command_error(f"data read with {what}")
        return stale

    # ------------------------------------------------------------------ conveniences
    def set_motor_params(self, **values: object) -> None:
        """Change motor/encoder parameters (``MotorParams`` fields) from Python, mid-run.

        The shaft keeps its angle and speed; e.g. ``chip.set_motor_params(stall=True)`` locks
        the rotor from the next sample, ``load_torque=0.01`` hangs a weight on it.
        """
        p = self.motor_params
        for name in values:
            if not hasattr(p, name):
                raise ValueError(f"set_motor_params: no motor parameter {name!r} (see MotorParams)")
        old = {name: getattr(p, name) for name in values}
        for name, value in values.items():
            setattr(p, name, value)
        motor = self.motion.motor
        try:
            fresh = type(motor)(p, motor.sample_s)
        except ValueError:
            for name, value in old.items():
                setattr(p, name, value)
            raise
        fresh.angle, fresh.speed = motor.angle, motor.speed
        self.motion.motor = fresh

    def record_clear(self) -> None:
        self.history.clear()
