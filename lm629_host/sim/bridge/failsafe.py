"""The far end's failsafe (PROTOCOL.md, FAILSAFE): the timer every good frame feeds, the feeds
a recording takes byte by byte, the trip that stops every chip select that answers, and the
FAILSAFE requests."""

from __future__ import annotations

from dataclasses import replace

from lm629_host.bridge.protocol.constants import (
    FAILSAFE_MAX_MS,
    FAILSAFE_MIN_MS,
    FAILSAFE_STOP_BITS,
    FailsafeAction,
    FailsafeCmd,
    FrameType,
    Result,
)
from lm629_host.bridge.protocol.failsafe import FAILSAFE_FEED, FailsafeState
from lm629_host.bridge.protocol.framing import Frame, encode_frame
from lm629_host.bus.opcodes import Cmd
from lm629_host.bus.program import BusOp, Op
from lm629_host.sim.bridge.parts import BridgeParts
from lm629_host.sim.bridge.runner import FIRMWARE_BUSY_TIMEOUT_S


class FailsafeSide(BridgeParts):
    """The failsafe on the far end: disarmed until a host arms it."""

    def _init_failsafe(self) -> None:
        """Timeout (0: disarmed), action, when the host last sent a good frame (model
        seconds), the latched trip (None: none), bytes of FAILSAFE_FEED matched during a
        recording."""
        self._fs_ms = 0
        self._fs_action = FailsafeAction.ABRUPT
        self._fs_last = 0.0
        self._fs_trip = None
        self._feed_matched = 0

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


__all__ = ["FailsafeSide"]
