"""The bridge's far side in Python, over a :class:`~lm629_host.sim.model.ChipModel`.

An independent implementation of what ``firmware_bridge/`` does, written from PROTOCOL.md:
it reads frames, answers HELLO and PING, runs RUN programs with the busy discipline against the
model's clock, keeps the last RUN's ``seq``/CRC/reply and answers a repeat from that cache.
It serves two benches that need no AVR toolchain:

* :class:`EmuPipe`, an in-process :class:`~lm629_host.bridge.protocol.Pipe` whose clock is the model's
  clock, with the serial wire's byte time at a chosen baud rate: the link tests and the fault
  tests run on it without ever sleeping on the wall clock;
* ``lm629 sim serve --pty PATH`` (:mod:`lm629_host.sim.serve`), where it answers a real
  pseudo-terminal in real time.

The chip model knows nothing of this module; this module only strobes the model's pins.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from lm629_host.wiring import uno as bridge_pins
from lm629_host.bridge.protocol import (
    BAUD_WINDOW_MS,
    CODE_BYTES,
    CODE_SLOTS,
    END_PAYLOAD,
    FAILSAFE_FEED,
    FAILSAFE_MAX_MS,
    FAILSAFE_MIN_MS,
    FAILSAFE_STOP_BITS,
    FIRMWARE_VERSION,
    MAX_FRAME,
    MAX_PING,
    RUN_OVERHEAD,
    NONE_BYTE,
    PROFILE_HEADER,
    PROFILE_MAX_SCHEDULE,
    PROFILE_MIN_SPACING_US,
    PROFILE_NEW,
    PROFILE_PIECE,
    PROFILE_REPLY_PAYLOAD,
    RECORD_HEADER,
    RECORD_MIN_PERIOD_US,
    RECORD_TICK_US,
    ROW_HEADER,
    RUN_REPLY_OVERHEAD,
    BadProgram,
    Capability,
    Frame,
    FrameError,
    FrameReader,
    FrameType,
    FailsafeAction,
    FailsafeCmd,
    FailsafeState,
    HelloInfo,
    Result,
    RunReply,
    check_record_program,
    decode_program,
    encode_frame,
    ends_a_profile,
    profile_piece_ops,
    short_reply_payload,
)
from lm629_host.bus.opcodes import BUSY_BIT, Cmd
from lm629_host.bus.program import STATUS_OPS, WAIT_STATUS_POLL_US, BusOp, Op
from lm629_host.sim.clock import SimClock
from lm629_host.sim.wiring import BentChip, Miswiring
from lm629_host.sim.model import ChipBus, ChipModel, chips_of

_BUSY = BUSY_BIT  # a plain int (opcodes.BUSY_BIT)

#: the firmware release this emulator implements (HELLO_REPLY): the one the firmware reports
EMU_FIRMWARE = FIRMWARE_VERSION
#: one /RD or /WR strobe of the emulated bridge, recovery included (an AVR at 16 MHz needs
#: about 16 instructions per strobe with the data bus split over two ports)
BUS_CYCLE_S = 1e-6
#: /RST held low by the emulated bridge (the datasheet asks for 8 chip clocks)
RESET_PULSE_S = 4e-6


@dataclass
class EmuStats:
    """What happened on the far side (for the fault tests: nothing runs twice)."""

    frames: int = 0  #: good frames received
    bad_frames: int = 0  #: frames dropped for COBS, length or CRC errors
    runs: int = 0  #: RUN programs executed
    recordings: int = 0  #: RECORD requests that started recording
    rows: int = 0  #: RECORD_ROW frames sent
    pieces: int = 0  #: PROFILE pieces issued
    cache_hits: int = 0  #: RUN repeats answered from the cache
    trips: int = 0  #: failsafe trips
    feeds: int = 0  #: FAILSAFE_FEED frames taken during a recording
    replies: int = 0  #: frames sent
    busy_polls: int = 0  #: status reads made only for the busy check
    bus_cycles: int = 0  #: strobes and /RST pulses


#: what this emulator is by default: the multi-axis firmware's chip selects, SELECT runs
MULTI_AXIS_INFO = HelloInfo(
    firmware=EMU_FIRMWARE, chip_selects=len(bridge_pins.CHIP_SELECTS),
    capabilities=int(Capability.RESET_LINE | Capability.HI_LINE | Capability.BUSY_ON_BRIDGE
                     | Capability.WAIT_STATUS | Capability.SELECT | Capability.COMPACT_RUN
                     | Capability.PROGRAM_CODES | Capability.BAUD_SWITCH | Capability.RECORD
                     | Capability.FAILSAFE | Capability.PROFILE))
#: a one-chip bridge (``sim+emu://?bridge=1``): one chip select, no SELECT op (nor
#: WAIT_STATUS): firmware 1.0's capabilities, so it reports 1.0.0
ONE_CHIP_INFO = HelloInfo(firmware=(1, 0, 0), chip_selects=1)


class _NoChip:
    """An unwired chip select: writes reach nothing, reads find the bus floating (FF)."""

    hi = False

    def read_status(self) -> int:
        return 0xFF

    read_data = read_status

    def write_command(self, byte: int) -> None:
        pass

    write_data = write_command


_NO_CHIP = _NoChip()


@dataclass
class BridgeEmulator:
    """The far end of the link: frames in, frames out, programs run on ``model`` (one chip,
    or a :class:`~lm629_host.sim.model.ChipBus` whose chips sit on chip selects 0, 1, ...,
    or on the chip selects ``selects`` names, one per chip: a board may leave a select
    without a chip between two that have one)."""

    model: ChipModel | ChipBus
    info: HelloInfo = field(default_factory=lambda: MULTI_AXIS_INFO)
    stats: EmuStats = field(default_factory=EmuStats)
    #: ``wiring=``: the data lines between the bridge's pins and the chips (None: correct)
    wiring: Miswiring | None = None
    #: the chip select of each chip of ``model``, in order (None: 0, 1, ...)
    selects: Sequence[int] | None = None
    #: where a program's WAIT_STATUS learns of the host's next byte, as the firmware's does
    #: (it ends the wait: a host waits for the reply before it sends again, so a byte now is
    #: one that gave up, a new client's HELLO): ``host_byte_at(t)`` is the model time the
    #: first byte not yet received arrived at, if one had by model time ``t``, else None; a
    #: caller that learns of bytes as they come (a served bench, in real time) may wait there
    #: until ``t``.  None: no byte comes while a program runs (programs run straight through)
    host_byte_at: Callable[[float], float | None] | None = None

    def __post_init__(self) -> None:
        chips = chips_of(self.model)
        if self.wiring is not None:  # the bus is shared: every chip behind the same wires
            chips = [BentChip(c, self.wiring) for c in chips]  # type: ignore[misc]  # BentChip has a chip's strobes
        selects = list(range(len(chips))) if self.selects is None else list(self.selects)
        if len(selects) != len(chips) or len(set(selects)) != len(selects) \
                or not all(0 <= k < self.info.chip_selects for k in selects):
            raise ValueError(f"selects={self.selects}: one distinct chip select of "
                             f"0..{self.info.chip_selects - 1} for each of the {len(chips)} chip(s)")
        #: the chip behind each wired chip select (the others float)
        self._by_cs: dict[int, ChipModel] = dict(zip(selects, chips))
        self._cs = 0
        self._reader = FrameReader()
        self._cache: tuple[int, int, bytes] | None = None  # seq, crc, encoded reply
        self._codes: dict[int, bytes] = {}  # programs kept for RUN_CODE
        self._cycle_ticks = max(1, round(BUS_CYCLE_S * self.model.clock_hz))
        self._rec: _Recording | None = None
        self._profile = _Schedule()
        self._no_chip = _NO_CHIP if self.wiring is None else BentChip(_NO_CHIP, self.wiring)
        #: the failsafe: timeout (0: disarmed), action, when the host last sent a good frame
        #: (model seconds), the latched trip (None: none), bytes of FAILSAFE_FEED matched
        #: during a recording
        self._fs_ms = 0
        self._fs_action = FailsafeAction.ABRUPT
        self._fs_last = 0.0
        self._fs_trip: FailsafeState | None = None
        self._feed_matched = 0
        if self.info.max_program > MAX_FRAME - RUN_OVERHEAD:
            raise ValueError(f"max_program={self.info.max_program} does not fit MAX_FRAME")

    # ------------------------------------------------------------------ frames
    def receive(self, data: bytes) -> list[bytes]:
        """Bytes from the host; returns the encoded reply frames, in order.  Programs run on
        the model at its current time (the caller advances it to the arrival of the bytes)."""
        out: list[bytes] = []
        if data and self._rec is not None:
            data = self._feed_during_recording(data)
            if data:  # any other byte from the host ends a recording
                out.append(self._end_recording(Result.OK))
                self.stats.replies += 1
        for item in self._reader.feed(data):
            if isinstance(item, FrameError):
                self.stats.bad_frames += 1  # never answered: the host's retry covers it
                continue
            self.stats.frames += 1
            self._fs_last = self.model.now()  # every good frame feeds the failsafe
            reply = self._handle(item)
            if reply is not None:
                self.stats.replies += 1
                out.append(reply)
        return out

    def _feed_during_recording(self, data: bytes) -> bytes:
        """During a recording, take FAILSAFE_FEED byte by byte (each whole one feeds the
        failsafe); return the bytes from the first one that does not match on (they end the
        recording and are read as usual; a feed's matched start before them is dropped, as
        the firmware drops it)."""
        for i, b in enumerate(data):
            if b != FAILSAFE_FEED[self._feed_matched]:
                self._feed_matched = 0
                return data[i:]
            self._feed_matched += 1
            if self._feed_matched == len(FAILSAFE_FEED):
                self._feed_matched = 0
                self._fs_last = self.model.now()
                self.stats.feeds += 1
        return b""

    # ------------------------------------------------------------------ the failsafe
    @property
    def failsafe_due(self) -> float | None:
        """When the failsafe expires (model seconds), None when it is disarmed or tripped."""
        if not self._fs_ms or self._fs_trip is not None:
            return None
        return self._fs_last + self._fs_ms * 1e-3

    @property
    def failsafe(self) -> FailsafeState:
        """The failsafe's state as FAILSAFE_REPLY reports it."""
        trip = self._fs_trip
        return FailsafeState(Result.OK, self._fs_ms, self._fs_action, trip is not None,
                             trip.chips if trip else 0, trip.silent_ms if trip else 0,
                             trip.at_ms if trip else 0)

    def failsafe_trip(self) -> None:
        """The host has been silent past the timeout (the caller advanced the model to
        :attr:`failsafe_due`): stop every chip select that answers (a status read of FF is
        a bus no chip drives) with LTRJ <action's stop bit>, STT, each with the busy
        discipline, and latch the trip."""
        m = self.model
        now = m.now()
        bits = FAILSAFE_STOP_BITS[FailsafeAction(self._fs_action)]
        stop = [BusOp(Op.STATUS), BusOp(Op.COMMAND, int(Cmd.LTRJ)), BusOp(Op.WRITE, bits),
                BusOp(Op.COMMAND, int(Cmd.STT))]
        self._cancel_profile(stop)  # first: no pending piece may restart a motor stopped here
        chips = 0
        cs = self._cs
        for k in range(self.info.chip_selects):
            self._cs = k
            if self._strobe().read_status() == 0xFF:
                continue
            if self.run_ops(stop[1:], FIRMWARE_BUSY_TIMEOUT_S).result == Result.OK:
                chips |= 1 << k
        self._cs = cs
        self.stats.trips += 1
        self._fs_trip = FailsafeState(tripped=True, chips=chips,
                                      silent_ms=round((now - self._fs_last) * 1e3),
                                      at_ms=round(now * 1e3))

    def _failsafe_request(self, frame: Frame) -> bytes:
        """FAILSAFE: report (empty payload), arm, disarm or acknowledge; never cached (each
        is idempotent, so a repeat does no harm)."""
        p = frame.payload
        result = Result.OK
        if p:
            cmd = p[0]
            if cmd == FailsafeCmd.ARM and len(p) == 4:
                ms, action = int.from_bytes(p[1:3], "big"), p[3]
                if FAILSAFE_MIN_MS <= ms <= FAILSAFE_MAX_MS and action in FAILSAFE_STOP_BITS:
                    self._fs_ms, self._fs_action = ms, FailsafeAction(action)
                else:
                    result = Result.BAD_FAILSAFE
            elif cmd == FailsafeCmd.DISARM and len(p) == 1:
                self._fs_ms = 0
            elif cmd == FailsafeCmd.ACKNOWLEDGE and len(p) == 1:
                self._fs_trip = None
            else:
                result = Result.BAD_FAILSAFE
        return encode_frame(FrameType.FAILSAFE_REPLY, frame.seq,
                            replace(self.failsafe, result=result).encode())

    #: the line's rate at the far end (EmuPipe sets it), the rate it goes back to and until
    #: when (after SET_BAUD, until a good frame comes at the new rate), a switch answered
    rate: int = 0
    _back: tuple[int, float] | None = None
    _pending: int = 0

    def expire(self, t: float) -> None:
        """At time ``t``: no good frame came at the new rate within BAUD_WINDOW_MS: back."""
        if self._back is not None and t > self._back[1]:
            self.rate, self._back = self._back[0], None

    def switch_after_reply(self, t: float) -> None:
        """The reply to SET_BAUD has left at ``t`` (at the old rate): switch now."""
        if self._pending:
            self._back = (self.rate, t + BAUD_WINDOW_MS * 1e-3)
            self.rate, self._pending = self._pending, 0

    def _handle(self, frame: Frame) -> bytes | None:
        t = frame.type
        self._back = None  # a good frame: the rate works
        if t == FrameType.SET_BAUD and self.info.capabilities & Capability.BAUD_SWITCH \
                and len(frame.payload) == 4:
            baud = int.from_bytes(frame.payload, "big")
            div = (self.info.cpu_hz // 8 + baud // 2) // baud if baud else 0
            made = self.info.cpu_hz // 8 // div if div else 0
            ok = 1 <= div <= 4096 and abs(made - baud) * 50 <= baud
            self._pending = made if ok else 0
            return encode_frame(FrameType.BAUD_REPLY, frame.seq,
                                bytes((Result.OK if ok else Result.BAD_BAUD,)) + made.to_bytes(4, "big"))
        if t == FrameType.HELLO:
            self._cache = None
            self._codes.clear()
            return encode_frame(FrameType.HELLO_REPLY, frame.seq, self.info.encode())
        if t == FrameType.PING:
            if len(frame.payload) > MAX_PING:
                return self._error(frame.seq, Result.BAD_REQUEST)
            return encode_frame(FrameType.PONG, frame.seq, frame.payload)
        if t == FrameType.RUN:
            if len(frame.payload) < 3:
                return self._error(frame.seq, Result.BAD_REQUEST)
            cache = self._cache
            if cache is not None and cache[0] == frame.seq and cache[1] == frame.crc:
                self.stats.cache_hits += 1
                return cache[2]
            reply = encode_frame(FrameType.RUN_REPLY, frame.seq, self._run(frame.payload).encode())
            self._cache = (frame.seq, frame.crc, reply)
            return reply
        caps = self.info.capabilities
        if (t == FrameType.RUN_SHORT and caps & Capability.COMPACT_RUN) or (
                caps & Capability.PROGRAM_CODES and (
                    (t == FrameType.RUN_STORE and len(frame.payload) >= 1)
                    or (t == FrameType.RUN_CODE and len(frame.payload) == 1))):
            cache = self._cache
            if cache is not None and cache[0] == frame.seq and cache[1] == frame.crc:
                self.stats.cache_hits += 1
                return cache[2]
            program: bytes | None = frame.payload
            if t != FrameType.RUN_SHORT:
                code = frame.payload[0]
                if t == FrameType.RUN_STORE:
                    program = frame.payload[1:]
                    if code < CODE_SLOTS:
                        self._codes.pop(code, None)
                        try:  # a program that checks out is kept, whatever its run does
                            if len(program) <= CODE_BYTES and \
                                    self._check(decode_program(program)) is None:
                                self._codes[code] = program
                        except BadProgram:
                            pass
                    else:
                        program = None
                else:
                    program = self._codes.get(code)
            if program is None:
                result = RunReply(Result.UNKNOWN_CODE)
            else:
                if t == FrameType.RUN_STORE and len(program) > CODE_BYTES:
                    result = RunReply(Result.PROGRAM_TOO_LONG)
                else:
                    # cs 0 and the default busy timeout, then as RUN
                    result = self._run(bytes((0, 0, 0)) + program)
            # a program that ran to its end is answered in the compact form, else as a RUN
            if result.result == Result.OK and program is not None:
                reply = encode_frame(FrameType.RUN_SHORT_REPLY, frame.seq,
                                     short_reply_payload(decode_program(program), result))
            else:
                reply = encode_frame(FrameType.RUN_REPLY, frame.seq, result.encode())
            self._cache = (frame.seq, frame.crc, reply)
            return reply
        if t == FrameType.RECORD and caps & Capability.RECORD:
            return self._start_recording(frame)
        if t == FrameType.FAILSAFE and caps & Capability.FAILSAFE:
            return self._failsafe_request(frame)
        if t == FrameType.PROFILE and caps & Capability.PROFILE:
            return self._profile_frame(frame)
        if t & 0x80:
            return None  # a reply type from the host: not a request, ignore it
        return self._error(frame.seq, Result.BAD_REQUEST)

    # ------------------------------------------------------------------ RECORD
    @property
    def record_due(self) -> float | None:
        """When the next row of a recording is due (model seconds), None when not recording."""
        return None if self._rec is None else self._rec.due

    def _start_recording(self, frame: Frame) -> bytes | None:
        """RECORD, as the firmware takes it: the program checked before anything runs (a
        refusal is a RECORD_END at once); the reply cache is emptied (a recording is not
        repeated from it: its program only reads); the first row is due now."""
        p = frame.payload
        if len(p) < RECORD_HEADER.size:
            return self._error(frame.seq, Result.BAD_REQUEST)
        self._cache = None
        period_us, rows = RECORD_HEADER.unpack_from(p)
        try:
            ops = decode_program(p[RECORD_HEADER.size:])
            check_record_program(ops, self.info.chip_selects)
        except BadProgram as exc:
            return self._end(frame.seq, Result.BAD_PROGRAM, exc.index, 0)
        except ValueError:
            return self._end(frame.seq, Result.PROGRAM_TOO_LONG, NONE_BYTE, 0)
        if period_us < RECORD_MIN_PERIOD_US:
            return self._end(frame.seq, Result.BAD_RATE, NONE_BYTE, 0)
        self.stats.recordings += 1
        self._feed_matched = 0
        period = period_us // RECORD_TICK_US * RECORD_TICK_US * 1e-6
        self._rec = _Recording(frame.seq, ops, period, rows, self.model.now())
        return None

    def _end(self, seq: int, result: int, index: int, rows: int) -> bytes:
        return encode_frame(FrameType.RECORD_END, seq, END_PAYLOAD.pack(result, index,
                                                                        rows & 0xFFFF))

    def _end_recording(self, result: int, index: int = NONE_BYTE) -> bytes:
        rec, self._rec = self._rec, None
        assert rec is not None
        return self._end(rec.seq, result, index, rec.index)

    def record_step(self) -> list[bytes]:
        """The row due now: stamp the bridge's clock (4 us ticks from the first row), run the sample program,
        and return its RECORD_ROW (and the RECORD_END after the last row or a busy timeout).
        The caller has advanced the model to :attr:`record_due`."""
        rec = self._rec
        assert rec is not None
        m = self.model
        # the firmware's clock counts 4 us ticks from the first row
        stamp = round((m.now() - rec.start) * 1e6 / RECORD_TICK_US) * RECORD_TICK_US & 0xFFFFFFFF
        self._cs = 0
        reply = self.run_ops(rec.ops, FIRMWARE_BUSY_TIMEOUT_S)
        if reply.result != Result.OK:
            self.stats.replies += 1
            return [self._end_recording(reply.result, reply.index)]
        out = [encode_frame(FrameType.RECORD_ROW, rec.seq,
                            ROW_HEADER.pack(rec.index & 0xFFFF, stamp)
                            + short_reply_payload(rec.ops, reply)[:-1])]
        self.stats.rows += 1
        self.stats.replies += 1
        rec.index += 1
        rec.due += rec.period
        if rec.rows and rec.index >= rec.rows:
            out.append(self._end_recording(Result.OK))
            self.stats.replies += 1
        return out

    def _error(self, seq: int, code: Result) -> bytes:
        return encode_frame(FrameType.ERROR_REPLY, seq, bytes((code,)))

    # ------------------------------------------------------------------ PROFILE
    @property
    def profile_due(self) -> float | None:
        """When the next piece of a shaped move is due (model seconds), None when none is."""
        sched = self._profile
        if not sched.pending:
            return None
        # never sooner than PROFILE_MIN_SPACING_US after the last piece (as the firmware): a
        # piece that went out late must not bring the next STT within 10 ms of its own
        return max(sched.start + sched.pending[0][0] * 1e-6, sched.not_before)

    def _profile_frame(self, frame: Frame) -> bytes:
        """PROFILE, as the firmware takes it: every piece checked before any is scheduled
        (a refusal schedules nothing); NEW starts the schedule's clock now; the reply says
        what the schedule has done.  Answered again for a repeat (the reply cache)."""
        cache = self._cache
        if cache is not None and cache[0] == frame.seq and cache[1] == frame.crc:
            self.stats.cache_hits += 1
            return cache[2]
        p = frame.payload
        sched = self._profile
        body = p[PROFILE_HEADER.size:]
        if len(p) < PROFILE_HEADER.size or len(body) % PROFILE_PIECE.size:
            return self._error(frame.seq, Result.BAD_REQUEST)
        flags, cs = PROFILE_HEADER.unpack_from(p)
        pieces = [PROFILE_PIECE.unpack_from(body, k) for k in range(0, len(body),
                                                                    PROFILE_PIECE.size)]
        new = bool(flags & PROFILE_NEW)
        last = None if new or not sched.pending else sched.pending[-1][0]
        if not new and not pieces:
            result = sched.result
        else:
            result = Result.OK
            held = 0 if new else len(sched.pending)
            if cs >= self.info.chip_selects or held + len(pieces) > PROFILE_MAX_SCHEDULE:
                result = Result.BAD_PROFILE
            for t_us, velocity in pieces:
                if velocity > 0x3FFFFFFF or (last is not None
                                             and t_us < last + PROFILE_MIN_SPACING_US):
                    result = Result.BAD_PROFILE
                last = t_us
            if result == Result.OK and pieces and self._fs_trip is not None:
                result = Result.FAILSAFE_TRIPPED  # pieces carry STT: refused as a RUN's are
            if result == Result.OK:
                if new:
                    self._profile = sched = _Schedule(cs=cs, start=self.model.now())
                sched.pending.extend(pieces)
        reply = encode_frame(FrameType.PROFILE_REPLY, frame.seq, PROFILE_REPLY_PAYLOAD.pack(
            result, sched.issued & 0xFFFF, len(sched.pending), sched.late_us & 0xFFFFFFFF))
        self._cache = (frame.seq, frame.crc, reply)
        return reply

    def profile_step(self) -> None:
        """Issue the piece due now on its chip select (the caller has advanced the model to
        :attr:`profile_due`); a piece that fails (busy timeout) drops the schedule."""
        sched = self._profile
        t_us, velocity = sched.pending.popleft()
        late = max(0, round((self.model.now() - sched.start) * 1e6) - t_us)
        sched.late_us = max(sched.late_us, late)
        cs, self._cs = self._cs, sched.cs
        reply = self.run_ops(profile_piece_ops(velocity), FIRMWARE_BUSY_TIMEOUT_S)
        sched.not_before = self.model.now() + PROFILE_MIN_SPACING_US * 1e-6  # after its STT
        self._cs = cs
        sched.issued += 1
        self.stats.pieces += 1
        if reply.result != Result.OK:
            sched.pending.clear()
            sched.result = Result(reply.result)

    def _cancel_profile(self, ops: Sequence[BusOp]) -> None:
        """A program that stops or restarts the chip ends the schedule (PROFILE_CANCELLED)."""
        sched = self._profile
        if sched.pending and ends_a_profile(ops):
            sched.pending.clear()
            sched.result = Result.PROFILE_CANCELLED

    @property
    def far_due(self) -> float | None:
        """The next thing the bridge does by itself: a row, a piece or the failsafe's expiry
        (model seconds)."""
        dues = [d for d in (self.record_due, self.profile_due, self.failsafe_due)
                if d is not None]
        return min(dues) if dues else None

    def far_step(self) -> list[bytes]:
        """Do what is due now (:attr:`far_due`): the failsafe's trip first (it drops the
        pieces, as the firmware's main loop checks the failsafe before the schedule), else a
        piece, else a row; the frames it sends."""
        fs, due, row = self.failsafe_due, self.profile_due, self.record_due
        if fs is not None and all(d is None or fs <= d for d in (due, row)):
            self.failsafe_trip()
            return []
        if due is not None and (row is None or due <= row):
            self.profile_step()
            return []
        return self.record_step()

    # ------------------------------------------------------------------ programs
    def _run(self, payload: bytes) -> RunReply:
        cs = payload[0]
        timeout_us = int.from_bytes(payload[1:3], "big") or 5000
        body = payload[3:]
        if cs >= self.info.chip_selects:
            return RunReply(Result.BAD_CHIP_SELECT)
        if len(body) > self.info.max_program:
            return RunReply(Result.PROGRAM_TOO_LONG)
        try:
            ops = decode_program(body)
        except BadProgram as exc:
            return RunReply(Result.BAD_PROGRAM, exc.index)
        refused = self._check(ops)
        if refused is not None:
            return refused
        if self._fs_trip is not None:  # no motion until a host acknowledges the trip
            for i, o in enumerate(ops):
                if o.op is Op.COMMAND and o.arg == Cmd.STT:
                    return RunReply(Result.FAILSAFE_TRIPPED, i)
        self._cancel_profile(ops)
        self._cs = cs
        self.stats.runs += 1
        return self.run_ops(ops, timeout_us * 1e-6)

    def _check(self, ops: list[BusOp]) -> RunReply | None:
        """Why the bridge refuses decoded ``ops`` (a SELECT it cannot make, limits), or None."""
        for i, o in enumerate(ops):
            if o.op is Op.SELECT:
                if not self.info.capabilities & Capability.SELECT:
                    return RunReply(Result.BAD_PROGRAM, i)  # an older bridge knows no SELECT
                if o.arg >= self.info.chip_selects:
                    return RunReply(Result.BAD_CHIP_SELECT, i)
        reads = sum(1 for o in ops if o.op is Op.READ)
        n_status = sum(1 for o in ops if o.op in STATUS_OPS)
        if reads > self.info.max_reads or n_status > 255 \
                or RUN_REPLY_OVERHEAD + n_status + 2 * reads > MAX_FRAME:
            return RunReply(Result.PROGRAM_TOO_LONG)
        return None

    def _strobe(self) -> ChipModel:
        m = self.model
        m.advance_to(m.tick + self._cycle_ticks)
        self.stats.bus_cycles += 1
        return self._chip()

    def _chip(self) -> ChipModel:
        return self._by_cs.get(self._cs, self._no_chip)  # type: ignore[arg-type]  # an unwired select: the floating bus

    def _wait_not_busy(self, timeout_s: float) -> tuple[bool, int]:
        m = self.model
        deadline = m.tick + math.ceil(timeout_s * m.clock_hz)
        while True:
            status = self._strobe().read_status()
            self.stats.busy_polls += 1
            if not status & _BUSY:
                return True, status
            if m.tick >= deadline:
                return False, status

    def _wait_status(self, mask: int, timeout_s: float, capped: bool = False) -> int:
        """Op.WAIT_STATUS as the firmware runs it: a status read every WAIT_STATUS_POLL_US
        until one has a bit of ``mask`` or ``timeout_s`` has passed.  The reads that would find
        nothing are skipped: the clock goes to the status change (SimClock), then on to the
        firmware's next read after it, which is made for real."""
        m = self.model
        clock = SimClock(m)
        period = WAIT_STATUS_POLL_US * 1e-6
        end = m.now() + timeout_s
        due = self.failsafe_due
        if not capped and due is not None and due < end:
            # the wait counts as the host alive only up to the failsafe's timeout
            status = self._wait_status(mask, max(0.0, due - m.now()), capped=True)
            if not status & mask and m.now() >= due:  # not ended by a host byte
                self.failsafe_trip()
            return status
        heard = self.host_byte_at
        while True:
            status = self._strobe().read_status()
            t = m.now()
            if status & mask or t >= end:
                return status
            if heard is not None and heard(t) is not None:
                return status  # a byte from the host ends the wait (read after this status)
            # a piece of a shaped move falls due while the bridge waits: issued at its time
            due = self.profile_due
            stop = end if due is None else min(end, due)
            # and the host's bytes are looked for at least every HOST_LOOK_S
            look = stop if heard is None else min(stop, t + HOST_LOOK_S)
            clock.advance_until_status(mask, look)
            if due is not None and m.now() >= look and look >= due and due <= end:
                clock.advance_to(due)
                self.profile_step()
                continue
            j = max(1, math.ceil((m.now() - t) / (period + BUS_CYCLE_S) - 1e-9))
            clock.advance_to(min(end, t + j * period + (j - 1) * BUS_CYCLE_S))

    def _wait(self, seconds: float) -> None:
        """Op.WAIT: the pieces of a shaped move that fall due meanwhile go out at their time."""
        m = self.model
        end = m.tick + max(0, round(seconds * m.clock_hz))  # as ChipModel.advance rounds
        while True:
            due = self.profile_due
            if due is None or due * m.clock_hz > end:
                break
            SimClock(m).advance_to(due)
            self.profile_step()
        m.advance_to(end)

    def run_ops(self, ops: list[BusOp], timeout_s: float) -> RunReply:
        """Run decoded operations with the busy discipline; stop at a busy timeout."""
        m = self.model
        words: list[int] = []
        statuses: list[int] = []
        last = 0xFF
        for index, o in enumerate(ops):
            op = o.op
            if op is Op.COMMAND or op is Op.WRITE or op is Op.READ or op is Op.SYNC:
                ok, last = self._wait_not_busy(timeout_s)
                if not ok:
                    return RunReply(Result.BUSY_TIMEOUT, index, last, int(self._chip().hi),
                                    tuple(statuses), tuple(words))
                if op is Op.COMMAND:
                    self._strobe().write_command(o.arg)
                elif op is Op.WRITE:
                    self._strobe().write_data(o.arg >> 8)
                    self._strobe().write_data(o.arg & 0xFF)
                elif op is Op.READ:
                    hi = self._strobe().read_data()
                    words.append((hi << 8) | self._strobe().read_data())
                else:
                    statuses.append(last)
            elif op is Op.STATUS:
                last = self._strobe().read_status()
                statuses.append(last)
            elif op is Op.RESET:
                m.advance(RESET_PULSE_S)
                m.reset_pulse()
                self.stats.bus_cycles += 1
            elif op is Op.WAIT:
                self._wait(o.arg * 1e-6)
            elif op is Op.SELECT:
                self._cs = o.arg
            elif op is Op.WAIT_STATUS:
                last = self._wait_status(o.arg >> 16, (o.arg & 0xFFFF) * 1e-3)
                statuses.append(last)
        return RunReply(Result.OK, 0xFF, last, int(self._chip().hi), tuple(statuses),
                        tuple(words))


#: the longest a WAIT_STATUS runs on the model before it looks for the host's bytes (a served
#: bench's far end waits there in real time: a byte is heard within this)
HOST_LOOK_S = 0.005

#: the busy timeout of a sample program (the firmware's default)
FIRMWARE_BUSY_TIMEOUT_S = 5e-3


@dataclass
class _Recording:
    """A recording under way: its RECORD's seq, sample program, period (s), rows asked (0:
    until stopped), rows sent, and when the next is due (model seconds)."""

    seq: int
    ops: list[BusOp]
    period: float
    rows: int
    due: float
    index: int = 0

    def __post_init__(self) -> None:
        self.start = self.due  #: the first row's time: the stamps count from it


@dataclass
class _Schedule:
    """A shaped move's pieces on the bridge: its chip select, the schedule's start (model
    seconds), the pieces still to issue (us from the start, velocity word), how many went out,
    the largest lateness of one (us), how the schedule ended, and the soonest the next piece
    may go out."""

    cs: int = 0
    start: float = 0.0
    pending: deque[tuple[int, int]] = field(default_factory=deque)
    issued: int = 0
    late_us: int = 0
    result: Result = Result.OK
    #: the next piece goes out no sooner than this (model seconds): 10 ms after the last
    not_before: float = 0.0


#: the far end runs on the chip model's simulated clock (the one ``sim://`` uses)
ModelClock = SimClock


class _PipeClock(SimClock):
    """The model's clock seen from the host end of an :class:`EmuPipe`: ``sleep`` also runs
    what the bridge does on its own timer meanwhile (the pieces of a shaped move, rows, the
    bytes on the wire), as a real bridge goes on while the host sleeps."""

    def __init__(self, pipe: EmuPipe) -> None:
        super().__init__(pipe.emulator.model)
        self._pipe = pipe

    def sleep(self, seconds: float) -> None:
        self._pipe.run_far(self.now() + max(0.0, seconds))


def _last_due(queue: Sequence[tuple[Any, ...]], deadline: float) -> float:
    """Arrival time of the last byte of ``queue`` (time-ordered) due by ``deadline``; the first
    byte must be due."""
    last = queue[0][0]
    for item in queue:
        t = item[0]
        if t > deadline:
            break
        last = t
    return last


class EmuPipe:
    """An in-process serial line to a :class:`BridgeEmulator`, in the model's simulated time.

    Each byte takes ``10 / baud`` seconds on the wire in each direction (``baud=None``: no
    wire time); the far end sees a frame when its last byte has arrived, runs it (advancing the
    model) and its reply is on the wire from then on.  ``read`` advances the simulated clock up
    to the next byte or the timeout.
    """

    def __init__(self, emulator: BridgeEmulator, *, baud: int | None = 115200,
                 max_baud: int | None = None) -> None:
        self.emulator = emulator
        self.clock = _PipeClock(self)
        self.byte_s = 10.0 / baud if baud else 0.0
        self._timed = bool(baud)
        #: the host side's rate; a byte sent at another rate than the receiver's is lost (as
        #: garbage would be), and so is one above ``max_baud`` (a line or USB serial adapter
        #: that cannot carry it)
        self.rate = baud or 0
        self.max_baud = max_baud
        emulator.rate = self.rate
        self._to_far: deque[tuple[float, bytes, int]] = deque()  # (arrival time, byte, rate)
        self._to_host: deque[tuple[float, int, int]] = deque()
        self._tx_free = 0.0  # when the host->bridge wire is free again
        self._rx_free = 0.0  # when the bridge->host wire is free again
        self.closed = False

    def set_baud(self, baud: int) -> None:
        """The host side's rate (the far end's changes on SET_BAUD)."""
        self.rate = baud
        if self._timed:
            self.byte_s = 10.0 / baud

    def _carried(self, rate: int, receiver: int) -> bool:
        return rate == receiver and (self.max_baud is None or rate <= self.max_baud)

    def write(self, data: bytes) -> None:
        t = max(self.clock.now(), self._tx_free)
        bs = self.byte_s
        if bs == 0.0:
            self._to_far.append((t, bytes(data), self.rate))
        else:
            for b in data:
                t += bs
                self._to_far.append((t, bytes((b,)), self.rate))
        self._tx_free = t

    def _deliver_far(self, until: float) -> None:
        """Hand the far end every byte that has arrived by ``until`` and queue its replies."""
        chunk = bytearray()
        q = self._to_far
        emu = self.emulator
        while q and q[0][0] <= until:
            t, b, rate = q.popleft()
            emu.expire(t)
            if self._carried(rate, emu.rate):
                chunk += b
        if not chunk:
            return
        self._queue_replies(emu.receive(bytes(chunk)))

    def _queue_replies(self, replies: list[bytes]) -> None:
        emu = self.emulator
        for reply in replies:
            t = max(self.clock.now(), self._rx_free)
            bs = self.byte_s
            for byte in reply:
                t += bs
                self._to_host.append((t, byte, emu.rate))
            self._rx_free = t
            emu.switch_after_reply(t)

    def run_far(self, until: float) -> None:
        """Run the far end up to ``until`` without reading: the bytes that arrive there, what
        falls due on its timer; the replies wait for the host's next read."""
        clock = self.clock
        emu = self.emulator
        while True:
            q = self._to_far
            due = emu.far_due
            arrive = q[0][0] if q else None
            if due is not None and due <= until and (arrive is None or due < arrive):
                if due > clock.now():
                    clock.advance_to(due)
                self._queue_replies(emu.far_step())
                continue
            if arrive is not None and arrive <= until:
                t = _last_due(q, until if due is None else min(until, due))
                if t > clock.now():
                    clock.advance_to(t)
                self._deliver_far(max(t, clock.now()))
                continue
            if until > clock.now():
                clock.advance_to(until)
            return

    def read(self, timeout_s: float) -> bytes:
        clock = self.clock
        deadline = clock.now() + max(0.0, timeout_s)
        emu = self.emulator
        while True:
            now = clock.now()
            h = self._to_host
            q = self._to_far
            due = emu.far_due
            # a row of a recording, a piece or the failsafe's expiry falls due before the next
            # byte moves: at its time
            if due is not None and due <= deadline and (not q or due < q[0][0]) \
                    and (not h or due < h[0][0]):
                if due > now:
                    clock.advance_to(due)
                self._queue_replies(emu.far_step())
                continue
            limit = deadline if due is None else min(deadline, due)
            if h and h[0][0] <= limit:
                # the reply is on its way: wait for the burst that is on the wire (up to the
                # deadline), as a serial read with a short inter-byte timeout would
                last = _last_due(h, limit)
                if last > now:
                    clock.advance_to(last)
                out = bytearray()
                while h and h[0][0] <= last:
                    _, b, rate = h.popleft()
                    if self._carried(rate, self.rate):
                        out.append(b)
                self._deliver_far(max(last, clock.now()))
                return bytes(out)
            if q and q[0][0] <= limit:
                t = _last_due(q, limit)
                if t > now:
                    clock.advance_to(t)
                self._deliver_far(max(t, clock.now()))
                continue
            if due is not None and due <= deadline:
                continue  # the row comes first (the loop's head)
            if deadline > now:
                clock.advance_to(deadline)
            return b""

    def close(self) -> None:
        self.closed = True


__all__ = ["BridgeEmulator", "EmuPipe", "EmuStats", "ModelClock", "EMU_FIRMWARE", "BUS_CYCLE_S",
           ]
