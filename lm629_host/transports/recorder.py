"""The link's recorder: RECORD hands a sample program to the bridge, which runs it on its own
timer and streams stamped rows (PROTOCOL.md, RECORD); this module asks for them, reads them,
turns them into :class:`~lm629_host.transports.base.RawRow` and ends a recording early.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING, cast

from lm629_host.bridge.protocol.constants import (
    FIRMWARE_DEFAULT_BUSY_TIMEOUT_US,
    NONE_BYTE,
    RECORD_MIN_PERIOD_US,
    RECORD_TICK_US,
    FrameType,
    Result,
)
from lm629_host.bridge.protocol.framing import Frame, FrameError, wire_size
from lm629_host.bridge.protocol.record import END_PAYLOAD, ROW_HEADER, check_record_program, record_payload, row_wire_bytes
from lm629_host.bridge.protocol.run import BadProgram, decode_short_reply
from lm629_host.bus.program import BusOp, Op, Program
from lm629_host.errors import BusyTimeout, LinkError, TransportError
from lm629_host.transports.reports import RawRow

if TYPE_CHECKING:
    from lm629_host.transports.failsafe import LinkFailsafe
    from lm629_host.transports.session import LinkSession

#: what a recording's rows are, in the CLI's and the errors' words
FAR_NOTE = ("rows sampled by the bridge on its own timer and stamped with its clock "
            f"({RECORD_TICK_US} us ticks): the link's latency changes only when they arrive")


class LinkRecorder:
    """RECORD over one link (a bridge with capability bit 8: :attr:`available`)."""

    def __init__(self, link: LinkSession, failsafe: LinkFailsafe) -> None:
        self.link = link
        self.failsafe = failsafe
        self.available = False  #: the bridge records on its own timer (HELLO's bit 8)

    #: the bridge's bus time for a sample program, per data-reporting command (busy check,
    #: strobe, the chip busy with it) and per byte read: a generous estimate for the rate check
    RECORD_US_PER_COMMAND = 25.0
    RECORD_US_PER_READ = 4.0

    def max_rate(self, program: Program) -> float:
        """Rows per second the line carries for ``program``: the bridge sends each row before
        it samples the next, so a row costs its bus time plus its wire time (at 11 bits a byte,
        what a two-stop-bit UART or simavr takes), with 10 % to spare."""
        _, read = self._check_sample(program)
        n_cmd = sum(1 for o in program.ops if o.op is Op.COMMAND)
        n_read = sum(1 for o in program.ops if o.op in (Op.READ, Op.STATUS))
        bus_s = (n_cmd * self.RECORD_US_PER_COMMAND + n_read * self.RECORD_US_PER_READ) * 1e-6
        wire_s = row_wire_bytes(read) * 11 / self.link.baud if self.link.baud else 0.0
        return min(0.9 / (bus_s + wire_s), 1e6 / RECORD_MIN_PERIOD_US)

    def _check_sample(self, program: Program) -> tuple[int, int]:
        try:
            return check_record_program(program.ops, self.link.chip_selects)
        except BadProgram as exc:
            raise ValueError(f"not a sample program: {exc}") from None

    def rows(self, program: Program, period_s: float, rows: int) -> Iterator[RawRow]:
        """RECORD: the bridge runs ``program`` every ``period_s`` on its own timer and streams
        the rows, each stamped with its clock; the host only reads them.  One exchange (a
        request no row answers within its time is sent again, with a new ``seq``: the program
        only reads, so a recording started twice changes nothing on the chip).  A row lost on
        the line is missing from what is yielded (its index is the gap).  Closing the iterator
        early stops the bridge (any byte from the host ends a recording)."""
        if self.link.closed:
            raise TransportError("the port is closed", port=self.link.url)
        _, read = self._check_sample(program)
        ticks = max(1, round(period_s * 1e6 / RECORD_TICK_US))
        period_us = ticks * RECORD_TICK_US
        if period_us < RECORD_MIN_PERIOD_US or not 0 <= rows <= 0xFFFF:
            raise ValueError(f"period {period_s * 1e6:g} us / {rows} rows: the bridge records "
                             f"every {RECORD_MIN_PERIOD_US} us or slower, up to 65535 rows")
        period = period_us * 1e-6
        ops = program.ops
        payload = record_payload(period_us, rows, ops)
        row_wire = row_wire_bytes(read)
        clock = self.link.clock
        stats = self.link.stats
        with self.link.lock:
            self.link.resync()
            stats.programs += 1
            pending: deque[Frame] = deque()
            first = self.link.request(
                FrameType.RECORD, payload, "RECORD", row_wire, ops=ops,
                busy_timeout_s=FIRMWARE_DEFAULT_BUSY_TIMEOUT_US * 1e-6, extra_s=period,
                pending=pending, resync=False)
            seq = first.seq
            ended = False
            self.failsafe.recording = True  # from now on the feeds are FAILSAFE_FEED
            try:
                last_index = -1
                last_us = None
                t_us = 0
                silence = max(0.25, 20 * period) + self.link.margin_s
                end_at = clock.now() + rows * period if rows else None
                frame: Frame | None = first
                while True:
                    if frame is None:
                        if end_at is None:
                            raise LinkError(f"no row from the bridge for {silence:g} s during "
                                            f"a recording: {self.link.quality()}", port=self.link.url,
                                            may_have_run=True)
                        return  # the last rows (and the end) were lost: they are gaps
                    if frame.type == FrameType.RECORD_END:
                        ended = True
                        self._end_of_recording(frame, ops)
                        return
                    if frame.type == FrameType.RECORD_ROW:
                        row = self._decode_row(frame.payload, ops)
                        if row is not None:
                            idx16, stamp, words, statuses = row
                            index = last_index + ((idx16 - last_index) & 0xFFFF) \
                                if last_index >= 0 else idx16
                            t_us = stamp if last_us is None else t_us + ((stamp - last_us) & 0xFFFFFFFF)
                            last_index, last_us = index, stamp
                            self.link.count_cycles(ops, words, statuses)  # as a RUN's
                            yield RawRow(index, t_us * 1e-6, words, statuses)
                            if rows and index >= rows - 1:
                                # the end follows at once: take it, or leave it to be ignored
                                nxt = self._next_frame(seq, clock.now() + self.link.reply_timeout(
                                    wire_size(9), wire_size(9)), pending)
                                ended = nxt is not None and nxt.type == FrameType.RECORD_END
                                if ended:
                                    self._end_of_recording(cast(Frame, nxt), ops)
                                return
                    else:
                        self.link.stale_replies += 1
                    wait = silence
                    if end_at is not None:
                        wait = max(wait, end_at - clock.now() + silence)
                    frame = self._next_frame(seq, clock.now() + wait, pending)
            finally:
                with self.link.write_lock:  # no feed of the recording after it
                    self.failsafe.recording = False
                if not ended:
                    self._stop_recording(seq, pending, period)

    def _next_frame(self, seq: int, deadline: float, pending: deque[Frame]) -> Frame | None:
        """The next frame of the recording ``seq``, or None at ``deadline``.  A bad frame
        does not end the wait: it was a row, and a lost row is a gap.  With the failsafe armed
        the host feeds it while it waits (a recording counts as alive only while it sends)."""
        fs = self.failsafe
        ka = fs.keepalive if fs.recording and fs.feed_period_s else None
        return self.link.await_reply(seq, deadline, pending, bad_ends_wait=False,
                                     tick=ka.turn if ka is not None else None,
                                     every=fs.feed_period_s)

    def _decode_row(self, payload: bytes, ops: Sequence[BusOp]
                    ) -> tuple[int, int, tuple[int, ...], tuple[int, ...]] | None:
        """(row, t_us, words, statuses) of a RECORD_ROW, or None for one that passed its CRC
        but does not hold what ``ops`` read (line damage: a gap, counted as a bad frame)."""
        n = ROW_HEADER.size
        if len(payload) < n:
            self.link.bad_frames += 1
            return None
        idx16, stamp = ROW_HEADER.unpack_from(payload)
        try:
            r = decode_short_reply(payload[n:] + b"\x00", ops)
        except FrameError:
            self.link.bad_frames += 1
            return None
        return idx16, stamp, r.words, r.statuses

    def _end_of_recording(self, frame: Frame, ops: Sequence[BusOp]) -> None:
        """RECORD_END: OK, or the error that stopped (or refused) the recording."""
        if len(frame.payload) != END_PAYLOAD.size:
            return  # damaged past its CRC: the rows already say what was recorded
        result, index, sent = END_PAYLOAD.unpack(frame.payload)
        if result == Result.OK:
            return
        if result == Result.BUSY_TIMEOUT and index < len(ops):
            raise BusyTimeout(ops[index].describe(), FIRMWARE_DEFAULT_BUSY_TIMEOUT_US * 1e-6,
                              NONE_BYTE, index, [])
        try:
            name = Result(result).name
        except ValueError:
            name = f"unknown result {result}"
        raise LinkError(f"the bridge refused the recording ({name}, after {sent} row(s)): host "
                        "and firmware disagree on RECORD; reflash the firmware that matches "
                        "this host (lm629 bridge flash)", port=self.link.url, may_have_run=False)

    def _stop_recording(self, seq: int, pending: deque[Frame], period: float) -> None:
        """End a recording early: one byte stops the bridge; its RECORD_END (or a row already
        on its way) is read and dropped, so that the next request starts on a quiet line."""
        try:
            self.link.send_unsolicited(b"\x00", feeds=False)
            deadline = self.link.clock.now() + 2 * period + self.link.reply_timeout(
                wire_size(64), wire_size(64))
            while True:
                f = self._next_frame(seq, deadline, pending)
                if f is None or f.type == FrameType.RECORD_END:
                    return
        except (OSError, TransportError):  # the port went away: nothing left to stop
            return


__all__ = ["FAR_NOTE", "LinkRecorder"]
