"""The far end's recorder (PROTOCOL.md, RECORD): the sample program checked, then run every
period on the bridge's clock, each run a stamped RECORD_ROW, and the RECORD_END."""

from __future__ import annotations


from lm629_host.bridge.protocol.constants import NONE_BYTE, RECORD_MIN_PERIOD_US, RECORD_TICK_US, FrameType, Result
from lm629_host.bridge.protocol.framing import Frame, encode_frame
from lm629_host.bridge.protocol.record import END_PAYLOAD, RECORD_HEADER, ROW_HEADER, check_record_program
from lm629_host.bridge.protocol.run import BadProgram, decode_program, short_reply_payload
from lm629_host.sim.bridge.parts import BridgeParts, Recording
from lm629_host.sim.bridge.runner import FIRMWARE_BUSY_TIMEOUT_S


class RecorderSide(BridgeParts):
    """RECORD on the far end: one recording at a time."""

    def _init_recorder(self) -> None:
        self._rec = None

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
        self._rec = Recording(frame.seq, ops, period, rows, self.model.now())
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


__all__ = ["RecorderSide"]
