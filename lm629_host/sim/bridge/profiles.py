"""The far end's shaped-move schedule (PROTOCOL.md, PROFILE): pieces checked before any is
kept, issued on the bridge's clock (never within 10 ms of the last one's STT), dropped by a
program that stops or restarts the chip."""

from __future__ import annotations

from collections.abc import Sequence

from lm629_host.bridge.protocol.constants import (
    PROFILE_HEADER,
    PROFILE_MAX_SCHEDULE,
    PROFILE_MIN_SPACING_US,
    PROFILE_NEW,
    PROFILE_PIECE,
    FrameType,
    Result,
)
from lm629_host.bridge.protocol.framing import Frame, encode_frame
from lm629_host.bridge.protocol.profile import PROFILE_REPLY_PAYLOAD, ends_a_profile, profile_piece_ops
from lm629_host.bus.program import BusOp
from lm629_host.sim.bridge.parts import BridgeParts, Schedule
from lm629_host.sim.bridge.runner import FIRMWARE_BUSY_TIMEOUT_S


class ProfileSide(BridgeParts):
    """PROFILE on the far end: one schedule at a time."""

    def _init_profiles(self) -> None:
        self._profile = Schedule()

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
                    self._profile = sched = Schedule(cs=cs, start=self.model.now())
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


__all__ = ["ProfileSide"]
