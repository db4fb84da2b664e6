"""The far end's link: frames in, frames out; HELLO, PING, SET_BAUD and the RUN family (with
the reply cache and the programs kept by code) answered here, RECORD, FAILSAFE and PROFILE
handed to their parts (:mod:`.recorder`, :mod:`.failsafe`, :mod:`.profiles`), the programs run
by :mod:`.runner`; and what the bridge does by itself between requests (``far_due``)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from lm629_host.wiring import uno as bridge_pins
from lm629_host.bridge.protocol.constants import (
    BAUD_WINDOW_MS,
    CODE_BYTES,
    CODE_SLOTS,
    FIRMWARE_VERSION,
    MAX_FRAME,
    MAX_PING,
    RUN_OVERHEAD,
    Capability,
    FrameType,
    Result,
)
from lm629_host.bridge.protocol.framing import Frame, FrameError, FrameReader, encode_frame
from lm629_host.bridge.protocol.hello import HelloInfo
from lm629_host.bridge.protocol.run import BadProgram, RunReply, decode_program, short_reply_payload
from lm629_host.sim.bridge.failsafe import FailsafeSide
from lm629_host.sim.bridge.profiles import ProfileSide
from lm629_host.sim.bridge.recorder import RecorderSide
from lm629_host.sim.bridge.parts import EmuStats
from lm629_host.sim.bridge.runner import BUS_CYCLE_S, NO_CHIP, RunSide
from lm629_host.sim.model import ChipBus, ChipModel, chips_of
from lm629_host.sim.wiring import BentChip, Miswiring


#: the firmware release this emulator implements (HELLO_REPLY): the one the firmware reports
EMU_FIRMWARE = FIRMWARE_VERSION
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


@dataclass
class BridgeEmulator(RunSide, FailsafeSide, RecorderSide, ProfileSide):
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
    #: a byte from the host came in the same delivery as the frame that runs now (an
    #: in-process line hands the far end every byte that has arrived at once): a WAIT_STATUS
    #: ends at once, as the firmware's does on a byte in its UART
    host_byte_waiting: bool = False

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
        self._by_cs = dict(zip(selects, chips))
        self._cs = 0
        self._reader = FrameReader()
        self._cache = None  # seq, crc, encoded reply
        self._codes: dict[int, bytes] = {}  # programs kept for RUN_CODE
        self._cycle_ticks = max(1, round(BUS_CYCLE_S * self.model.clock_hz))
        self._no_chip = NO_CHIP if self.wiring is None else BentChip(NO_CHIP, self.wiring)
        self._init_recorder()
        self._init_profiles()
        self._init_failsafe()
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
        # a frame followed by more of these bytes runs with a host byte already arrived: its
        # WAIT_STATUS ends at once, as the firmware's does (host_byte_waiting)
        start = 0
        while start < len(data):
            end = data.find(0, start)
            stop = len(data) if end < 0 else end + 1
            self.host_byte_waiting = stop < len(data)
            try:
                for item in self._reader.feed(data[start:stop]):
                    if isinstance(item, FrameError):
                        self.stats.bad_frames += 1  # never answered: the host's retry covers it
                        continue
                    self.stats.frames += 1
                    self._fs_last = self.model.now()  # every good frame feeds the failsafe
                    reply = self._handle(item)
                    if reply is not None:
                        self.stats.replies += 1
                        out.append(reply)
            finally:
                self.host_byte_waiting = False
            start = stop
        return out


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

    def _error(self, seq: int, code: Result) -> bytes:
        return encode_frame(FrameType.ERROR_REPLY, seq, bytes((code,)))

    # ------------------------------------------------------------------ PROFILE
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



__all__ = ["EMU_FIRMWARE", "MULTI_AXIS_INFO", "ONE_CHIP_INFO", "BridgeEmulator"]
