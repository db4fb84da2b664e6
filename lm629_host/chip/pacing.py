"""A chip's trajectory updates (STT): spaced apart, and each checked for a refusal.

AN-706 4.6.2: a new STT aborts the chip's trajectory calculation and holds its output, so an
update waits until ``update_interval`` (10 ms) after the last one, on the transport's clock
(the simulated one on ``sim://``), or is refused before any bus cycle
(:class:`~lm629_host.errors.UpdateTooSoon`) under ``update_rule = "raise"``.  A stop is not an
update: it goes out at once.

The status read just before the STT (busy clear) and the one after it, once busy has cleared
after the STT, in the same bus program, say whether the chip refused it (the command-error
flag: acceleration changed while moving with the drive on, relative velocity below zero).  The
documents do not say when the chip raises the flag; the model raises it while it processes the
STT, before busy clears (see the model's choice list).  The flag is cleared in the same program first unless it
is known to be clear (after an earlier refusal, a ``raw`` command, or on a chip not reset by
this object it may not be), so that a refusal is never hidden behind a stale flag.  Every STT, a
chip's own or a board's (:meth:`Board.start <lm629_host.motion.board.Board.start>`), goes
through :meth:`UpdatePacing.checked`.
"""

from __future__ import annotations

import copy
import logging
from typing import Protocol

from lm629_host.bus.opcodes import INTERRUPTS, Cmd, Status
from lm629_host.bus.program import Program, ProgramResult
from lm629_host.clock import ROUNDING_S, Clock
from lm629_host.errors import ArgumentError, CommandError, UpdateTooSoon, check_int

log = logging.getLogger("lm629_host")


class PacedChip(Protocol):
    """What the pacing needs of its chip (an :class:`~lm629_host.LM629`): its settings, its
    clock, its programs, and its own check of an STT (which also forgets where it rests)."""

    update_interval: float
    update_rule: str

    @property
    def clock(self) -> Clock: ...

    def program(self) -> Program: ...

    def run(self, program: Program) -> ProgramResult: ...

    def start_flags(self, clear: Status | int = 0) -> Status: ...

    def start_checked(self, before: int, after: int) -> bool: ...


class UpdatePacing:
    """One chip's record of its STTs: when the last went out and whether the command-error
    flag is known clear; spaces the next update and runs the STT with its check."""

    def __init__(self, chip: PacedChip) -> None:
        self.chip = chip
        #: the transport clock just after the chip's last STT (None: none yet, or a reset since)
        self.last_update: float | None = None
        #: True while the command-error flag is known to be clear (after a reset, after a good
        #: STT); otherwise a start clears it first, so that it can tell whether its own STT was
        #: refused instead of missing it behind a stale flag
        self.ce_clear = False

    def bound_to(self, chip: PacedChip) -> UpdatePacing:
        """A copy of this record for ``chip`` (a chip's shadow): its own from then on."""
        twin = copy.copy(self)
        twin.chip = chip
        return twin

    def reset_done(self) -> None:
        """A reset cleared the flag and aborted nothing: the next update may go at once."""
        self.last_update = None
        self.ce_clear = True

    def due(self) -> float:
        """Seconds until the next update may go out, 0 when it may now."""
        interval = self.chip.update_interval
        if self.last_update is None or interval <= 0:
            return 0.0
        return max(0.0, self.last_update + interval - self.chip.clock.now())

    def hold(self) -> None:
        """Wait until the next update is due, or raise :class:`UpdateTooSoon` under
        ``update_rule = "raise"``."""
        chip = self.chip
        if chip.update_rule not in ("wait", "raise"):
            raise ValueError(f"update_rule={chip.update_rule!r} must be 'wait' or 'raise'")
        due = self.due()
        if due <= ROUNDING_S:  # a clock's rounding of a sleep to the due time is on time
            return
        if chip.update_rule == "raise":
            assert self.last_update is not None
            raise UpdateTooSoon(chip.clock.now() - self.last_update, chip.update_interval)
        chip.clock.sleep(due)

    def flags(self, clear: Status) -> Status:
        """``clear``, and the command-error flag unless it is known to be clear."""
        return clear if self.ce_clear else clear | Status.COMMAND_ERROR

    def checked(self, before: int, after: int) -> bool:
        """True when the chip refused the STT between the status ``before`` it and ``after``
        it; the clock now is the last update's time."""
        self.last_update = self.chip.clock.now()
        if not after & Status.COMMAND_ERROR:
            self.ce_clear = True
            return False
        self.ce_clear = False
        if not before & Status.COMMAND_ERROR:
            return True
        # the flag was set again inside this program, before the STT: only a transport that
        # had to repeat a damaged transfer does that (it says so in its stats and log)
        log.warning("command-error flag set before STT in the same program (status %02X): "
                    "cannot tell whether STT was refused; check transport.stats.retries", before)
        return False

    def start(self, program: Program, clear: Status | int = 0, head: Program | None = None, *,
              update: bool = True) -> tuple[Status, ProgramResult]:
        """Run ``program`` with the STT appended (after an RSTI of the flags a start clears),
        ``head`` first in the same program (a move's snapshot: one exchange); return the status
        after the STT and the program's result, or raise :class:`CommandError` when the chip
        refused it.  ``update``: the STT is a trajectory update, spaced (a stop is not)."""
        chip = self.chip
        if update:
            self.hold()
        flags = chip.start_flags(clear)
        if flags:  # RSTI: a 0 bit clears
            program = chip.program().command(Cmd.RSTI).write(int(INTERRUPTS & ~flags)) \
                .extend(program)
        if head is not None:
            program = head.extend(program)
        program.sync().command(Cmd.STT).sync()
        result = chip.run(program)
        before, after = result.statuses[-2:]
        if chip.start_checked(before, after):
            raise CommandError("STT", after)
        return Status(after), result


def check_flags(name: str, flags: object) -> Status:
    """``flags`` as interrupt conditions (status bits 1..6), what MSKI, RSTI and a start's
    ``clear`` take, or :class:`ArgumentError` naming the bits that are not."""
    value = check_int(name, int(flags) if isinstance(flags, Status) else flags, 0, 0xFF)
    extra = value & ~INTERRUPTS
    if extra:
        raise ArgumentError(
            name, value,
            f"{name}={value:#04x} has bits that are not interrupt conditions ({extra:#04x}); "
            f"allowed: {INTERRUPTS!r} (status bits 1..6)")
    return Status(value)


class PacingMixin:
    """:class:`~lm629_host.LM629`'s trajectory updates: the front doors of its
    :class:`UpdatePacing`."""

    _pacing: UpdatePacing

    def start_flags(self, clear: Status | int = 0) -> Status:
        """The flags a program must clear (RSTI) before its STT on this chip: ``clear``, and
        the command-error flag unless it is known to be clear (:mod:`.pacing`)."""
        return self._pacing.flags(check_flags("clear", clear))

    @property
    def last_update(self) -> float | None:
        """The transport clock just after this chip's last STT (None: none since the reset)."""
        return self._pacing.last_update

    def update_due(self) -> float:
        """Seconds until the next trajectory update may go out (``update_interval`` after the
        last STT), 0 when it may now."""
        return self._pacing.due()

    def hold_update(self) -> None:
        """Hold a trajectory update back to ``update_interval`` after the last STT (AN-706
        4.6.2), or raise :class:`UpdateTooSoon` under ``update_rule = "raise"``.  Every STT
        that is an update passes here: this chip's own, and a board's (:meth:`Board.start`)."""
        self._pacing.hold()

    def start(self) -> Status:
        """STT: trajectory input buffers -> working registers; the move begins.

        Raises :class:`CommandError` when the chip refuses it, checked in the same bus program
        (an RSTI of the command-error flag first unless it is known clear).  Spaced
        ``update_interval`` (10 ms) after the last STT (AN-706 4.6.2): it waits on the
        transport's clock, or raises :class:`UpdateTooSoon` under ``update_rule = "raise"``
        (:mod:`lm629_host.chip.pacing`)."""
        return self._pacing.start(self._pacing.chip.program())[0]
