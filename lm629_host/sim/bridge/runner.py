"""The far end's program runner: RUN's checks, then its operations on the chip model with the
busy discipline, the waits (WAIT, WAIT_STATUS, with the pieces due meanwhile issued at their
time and a host byte ending a WAIT_STATUS as the firmware's does), the bus strobes and what
they count."""

from __future__ import annotations

import math

from lm629_host.bridge.protocol.constants import MAX_FRAME, RUN_REPLY_OVERHEAD, Capability, Result
from lm629_host.bridge.protocol.run import BadProgram, RunReply, decode_program
from lm629_host.bus.opcodes import BUSY_BIT, Cmd
from lm629_host.bus.program import STATUS_OPS, WAIT_STATUS_POLL_US, BusOp, Op
from lm629_host.sim.bridge.parts import BridgeParts
from lm629_host.sim.clock import SimClock
from lm629_host.sim.model import ChipModel

_BUSY = BUSY_BIT  # a plain int (opcodes.BUSY_BIT)

#: one /RD or /WR strobe of the emulated bridge, recovery included (an AVR at 16 MHz needs
#: about 16 instructions per strobe with the data bus split over two ports)
BUS_CYCLE_S = 1e-6
#: /RST held low by the emulated bridge (the datasheet asks for 8 chip clocks)
RESET_PULSE_S = 4e-6



#: the longest a WAIT_STATUS runs on the model before it looks for the host's bytes (a served
#: bench's far end waits there in real time: a byte is heard within this)
HOST_LOOK_S = 0.005

#: the busy timeout of a sample program (the firmware's default)
FIRMWARE_BUSY_TIMEOUT_S = 5e-3


class _NoChip:
    """An unwired chip select: writes reach nothing, reads find the bus floating (FF)."""

    hi = False

    def read_status(self) -> int:
        return 0xFF

    read_data = read_status

    def write_command(self, byte: int) -> None:
        pass

    write_data = write_command


NO_CHIP = _NoChip()


class RunSide(BridgeParts):
    """RUN on the model: the checks before anything runs, then the operations."""

    _by_cs: dict[int, ChipModel]
    _cycle_ticks: int
    _no_chip: object

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

    #: False: make every busy poll (the reference the skip is tested against,
    #: tests/sim/test_emulator_busy_skip.py)
    skip_known_busy = True

    def _wait_not_busy(self, timeout_s: float) -> tuple[bool, int]:
        """The firmware's busy loop: a status read per strobe until busy is clear or
        ``timeout_s`` has passed.  The reads the chip's busy deadline already answers are
        counted, not made (:meth:`_skip_known_busy`)."""
        m = self.model
        deadline = m.tick + math.ceil(timeout_s * m.clock_hz)
        while True:
            self._skip_known_busy(deadline)
            status = self._strobe().read_status()
            self.stats.busy_polls += 1
            if not status & _BUSY:
                return True, status
            if m.tick >= deadline:
                return False, status

    def _skip_known_busy(self, deadline: int) -> None:
        """Skip the busy polls the selected chip's busy deadline already answers.

        The loop reads the status at ``t0 + k c`` (``c`` the strobe's clocks, k = 1, 2, ...);
        every read before the chip's busy deadline reads busy, and the loop ends at the first
        read at or past ``deadline``.  The reads before both are skipped: the model is
        advanced to the same tick (the same samples, in fewer steps) and they are counted as
        made; the next read is made for real.  Never through miswired lines, nor on an
        unwired select, nor when busy has no known end (``fault=busy``)."""
        chip = self._chip()
        if not self.skip_known_busy or not isinstance(chip, ChipModel):  # BentChip: miswired lines
            return
        until = chip.busy_deadline()
        m, c = self.model, self._cycle_ticks
        t0 = m.tick
        if until is None or until <= t0 + c:
            return
        k = min(-(-(until - t0) // c), -(-(deadline - t0) // c)) - 1
        if k > 0:
            m.advance_to(t0 + k * c)
            self.stats.bus_cycles += k
            self.stats.busy_polls += k

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
            if self.host_byte_waiting or heard is not None and heard(t) is not None:
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



__all__ = ["BUS_CYCLE_S", "FIRMWARE_BUSY_TIMEOUT_S", "HOST_LOOK_S", "RESET_PULSE_S", "NO_CHIP",
           "RunSide"]
