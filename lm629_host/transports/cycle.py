"""The one cycle loop: a transport that performs the chip's bus cycles one at a time (the
simulator's strobes into the model, a bit-banged adapter), with the busy check done here.

A bridge or the FT232H run a whole program on their side (:mod:`.link`, :mod:`.ftdi`); a
cycle-level transport gives this loop its five strobes and, where it knows more, a faster busy
check (:class:`~.sim.SimTransport` skips the polls its model's busy deadline answers).
"""

from __future__ import annotations

import abc

from lm629_host.bus.opcodes import BUSY_BIT
from lm629_host.bus.program import WAIT_STATUS_POLL_US, BusCycle, Op, Program, ProgramResult
from lm629_host.clock import WallClock
from lm629_host.errors import BusyTimeout
from lm629_host.transports.base import Transport

_BUSY = BUSY_BIT  # a plain int (opcodes.BUSY_BIT)
# the operations compared by identity on the hot path (an enum member is a singleton: ``is``
# costs no call, where ``int(o.op)`` and ``==`` on an IntEnum each do)
_STATUS, _COMMAND, _WRITE, _READ = Op.STATUS, Op.COMMAND, Op.WRITE, Op.READ
_RESET, _WAIT, _SYNC, _WAIT_STATUS, _SELECT = Op.RESET, Op.WAIT, Op.SYNC, Op.WAIT_STATUS, Op.SELECT


class CycleTransport(Transport):
    """A transport that performs bus cycles one at a time, with the busy check done here.

    Subclasses implement the primitive cycles below; they return at once (the cycle's own
    duration is accounted in the subclass's clock).
    """

    #: time between two busy polls while the chip is busy
    poll_interval_s: float = 2e-6
    has_wait_status = True

    @property
    def records_on_far_side(self) -> bool:
        """On a simulated clock each row's strobes reach the chip at its due time: exact."""
        return not isinstance(self.clock, WallClock)

    @abc.abstractmethod
    def _read_status(self) -> int: ...

    @abc.abstractmethod
    def _write_command(self, byte: int) -> None: ...

    @abc.abstractmethod
    def _write_word(self, word: int) -> None: ...

    @abc.abstractmethod
    def _read_word(self) -> int: ...

    @abc.abstractmethod
    def _pulse_reset(self) -> None: ...

    def _hi(self) -> bool | None:
        return None

    def _select_chip(self, chip: int) -> None:
        """/CS of ``chip`` for the following cycles (a program starts on chip 0); one chip:
        nothing to switch (:meth:`execute` refused any other chip select)."""

    def _skip_busy_polls(self, deadline: float) -> int:
        """Hook for a transport that knows when busy will clear (the chip model does): advance
        the clock over the busy polls whose answer is already known to be "busy", exactly as
        the poll loop would have (same cycle and sleep times, none past ``deadline``), and
        return how many were skipped; the poll that finds busy clear is still a real read.
        The default knows nothing and skips none."""
        return 0

    def _sleep_until_status(self, mask: int, deadline: float) -> None:
        """Hook: let time pass before the next status read of a WAIT_STATUS (one poll period
        of a bridge, never past ``deadline``); a simulator may go straight to the change."""
        clock = self._inner_clock  # execute holds the lock
        clock.sleep(min(WAIT_STATUS_POLL_US * 1e-6, deadline - clock.now()))

    def _wait_status(self, mask: int, timeout_s: float, tracing: bool) -> int:
        """Op.WAIT_STATUS: real status reads until one has a bit of ``mask`` or the timeout."""
        clock = self._inner_clock  # execute holds the lock
        deadline = clock.now() + timeout_s
        stats = self.stats
        while True:
            status = self._read_status()
            stats.bus_cycles += 1
            if tracing:
                self._emit(BusCycle("status", status))
            if status & mask or clock.now() >= deadline:
                return status
            self._sleep_until_status(mask, deadline)

    def _wait_not_busy(self, program: Program, index: int, words: list[int],
                       tracing: bool = True) -> int:
        clock = self._inner_clock  # execute holds the lock
        deadline = clock.now() + program.busy_timeout_s
        stats = self.stats
        if not tracing:  # a trace shows every poll: then they are all made
            skipped = self._skip_busy_polls(deadline)
            stats.bus_cycles += skipped
            stats.busy_polls += skipped
        while True:
            status = self._read_status()
            stats.bus_cycles += 1
            stats.busy_polls += 1
            if tracing:
                self._emit(BusCycle("status", status))
            if not status & _BUSY:
                return status
            if clock.now() >= deadline:
                raise BusyTimeout(program.ops[index].describe(), program.busy_timeout_s,
                                  status, index, words)
            clock.sleep(self.poll_interval_s)

    def _execute(self, program: Program) -> ProgramResult:
        stats = self.stats
        stats.round_trips += 1
        words: list[int] = []
        statuses: list[int] = []
        status: int | None = None
        if self.chip_selects > 1:
            self._select_chip(0)
        # plain ints on the hot path, and no BusCycle objects made unless someone looks at them
        # (the one cycle loop: every cycle-level transport, the simulator's included, runs it
        # with its own strobes and busy skip)
        tracing = self._tracing()
        emit = self._emit
        wait_not_busy = self._wait_not_busy
        write_command, write_word, read_word = self._write_command, self._write_word, self._read_word
        cycles = 0  # the strobes below, added to the counters once (the busy checks add theirs)
        try:
            for index, o in enumerate(program.ops):
                op = o.op
                if op is _COMMAND or op is _WRITE or op is _READ:
                    status = wait_not_busy(program, index, words, tracing)
                    if op is _COMMAND:
                        cycles += 1
                        write_command(o.arg)
                        if tracing:
                            emit(BusCycle("command", o.arg))
                    elif op is _WRITE:
                        cycles += 2
                        write_word(o.arg)
                        if tracing:
                            emit(BusCycle("write", o.arg))
                    else:
                        cycles += 2
                        w = read_word()
                        words.append(w)
                        if tracing:
                            emit(BusCycle("read", w))
                elif op is _STATUS:
                    status = self._read_status()
                    cycles += 1
                    statuses.append(status)
                    if tracing:
                        emit(BusCycle("status", status))
                elif op is _SYNC:
                    status = wait_not_busy(program, index, words, tracing)
                    statuses.append(status)
                elif op is _RESET:
                    self._pulse_reset()
                    cycles += 1
                    if tracing:
                        emit(BusCycle("reset", 0))
                elif op is _WAIT:
                    self._inner_clock.sleep(o.arg * 1e-6)
                elif op is _SELECT:
                    self._select_chip(o.arg)
                    if tracing:
                        emit(BusCycle("select", o.arg))
                elif op is _WAIT_STATUS:
                    status = self._wait_status(o.arg >> 16, (o.arg & 0xFFFF) * 1e-3, tracing)
                    statuses.append(status)
                else:  # pragma: no cover - Op is closed
                    raise AssertionError(op)
        finally:
            stats.bus_cycles += cycles
        return ProgramResult(tuple(words), tuple(statuses), status, self._hi())


__all__ = ["CycleTransport"]
