"""The reset of one chip or of every chip of a board (AN-706 3.7 / 4.4.1), checked.

:meth:`LM629.reset <lm629_host.LM629.reset>` and
:meth:`Board.reset <lm629_host.motion.board.Board.reset>` run the one routine here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

from lm629_host.bus.opcodes import (
    RESET_CLEARED_STATUSES,
    RESET_DONE_STATUSES,
    RESET_WAIT_S,
    Cmd,
    Status,
)
from lm629_host.bus.program import Program
from lm629_host.errors import ResetError
from lm629_host.transports.base import Transport


class ResetChip(Protocol):
    """What a reset needs of a chip (an :class:`~lm629_host.LM629`)."""

    chip_select: int
    transport: Transport

    @property
    def busy_timeout(self) -> float: ...

    @property
    def port12_selected(self) -> bool: ...

    def reset_done(self) -> None: ...


class ResettableChip(ResetChip, Protocol):
    """What :class:`ResetMixin` needs of the chip it is mixed into."""

    reset_attempts: int

    @property
    def uses_reset_line(self) -> bool: ...

    def reset_statuses(self) -> tuple[Status, list[int]]: ...


def reset_chips(chips: Sequence[ResetChip], *, pulse: bool,
                attempts: int) -> tuple[list[Status], dict[int, list[int]]]:
    """The AN-706 3.7 / 4.4.1 initialisation of one chip or of every chip of a board, in two
    programs per attempt: /RST once (``pulse``; the line is shared) or the RESET command on
    each chip, each chip's status (00 expected at once after /RST), 1.5 ms, each status (84 or
    C4); then, only once every chip checked out, so that nothing is ever written into a chip
    still in reset, MSKI 0000 and RSTI 0000 on each, its status once busy is clear (80 or C0),
    and PORT12 where it was selected.  ``attempts`` in all, then :class:`ResetError` naming
    the first chip that failed (its axis on a board of several) with its status bytes.

    Returns each chip's status after the reset and every status byte read, per chip select.
    """
    transport = chips[0].transport
    seen: dict[int, list[int]] = {c.chip_select: [] for c in chips}
    failed = chips[0]

    def program() -> tuple[Program, Callable[[ResetChip], Program]]:
        p = Program(busy_timeout_s=chips[0].busy_timeout)
        at = [0]  # a program starts on chip select 0

        def on(chip: ResetChip) -> Program:
            if chip.chip_select != at[0]:
                p.select(chip.chip_select)
                at[0] = chip.chip_select
            return p
        return p, on

    for _ in range(attempts):
        p, on = program()
        if pulse:
            p.reset()
        else:
            for c in chips:
                on(c).command(Cmd.RESET)
        for c in chips:
            on(c).status()
        p.wait(round(RESET_WAIT_S * 1e6))
        for c in chips:
            on(c).status()
        st = transport.execute(p).statuses
        n = len(chips)
        bad = None
        for k, c in enumerate(chips):
            first, done = st[k], st[n + k]
            seen[c.chip_select] += (first, done)
            if bad is None and ((pulse and first != 0) or done not in RESET_DONE_STATUSES):
                bad = c
        if bad is not None:
            failed = bad
            continue
        q, on = program()
        for c in chips:
            on(c).command(Cmd.MSKI).write(0).command(Cmd.RSTI).write(0).sync()
            if c.port12_selected:
                q.command(Cmd.PORT12)
        cleared = transport.execute(q).statuses
        for c, s in zip(chips, cleared):
            seen[c.chip_select].append(s)
        bad = next((c for c, s in zip(chips, cleared) if s not in RESET_CLEARED_STATUSES), None)
        if bad is None:
            for c in chips:
                c.reset_done()
            return [Status(s) for s in cleared], seen
        failed = bad
    expected = ("00 at once, 84 or C4 after 1.5 ms, 80 or C0 after MSKI/RSTI 0000" if pulse
                else "84 or C4 after the RESET command, 80 or C0 after MSKI/RSTI 0000")
    raise ResetError(seen[failed.chip_select], expected, attempts,
                     axis=failed.chip_select if len(chips) > 1 else None)


class ResetMixin:
    """:class:`~lm629_host.LM629`'s reset: :func:`reset_chips` on this chip alone."""

    axis: int | None
    chip_select: int
    reset_attempts: int
    transport: Transport

    @property
    def uses_reset_line(self) -> bool:
        """True when :meth:`reset` pulses /RST.  An axis of a multi-axis board sends the
        RESET command instead: /RST is shared and would reset every chip on the bus
        (:meth:`Board.reset <lm629_host.motion.board.Board.reset>` pulses it for all of them)."""
        return self.transport.has_reset_line and self.axis is None

    def reset(self: ResettableChip) -> Status:
        """Reset the chip and check that it came back, as AN-706 4.4.1 prescribes.

        Pulses /RST (or sends the RESET command when the transport has no reset line), checks
        status 00 at once (hardware reset only: a chip that does not read 00 did not see /RST),
        84 or C4 after 1.5 ms, then masks and clears all interrupts and checks 80 or C0.
        Retries ``reset_attempts`` times in all, then raises :class:`ResetError` with every
        status byte seen (:func:`reset_chips`, shared with a board's reset).
        """
        return self.reset_statuses()[0]

    def reset_statuses(self: ResettableChip) -> tuple[Status, list[int]]:
        """:meth:`reset`, also returning every status byte its programs read (bring-up)."""
        statuses, seen = reset_chips([self], pulse=self.uses_reset_line,
                                     attempts=self.reset_attempts)
        return statuses[0], seen[self.chip_select]
