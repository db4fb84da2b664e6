"""What the chip reports, read in one bus program: :meth:`LM629.snapshot
<lm629_host.LM629.snapshot>` returns one; moves, the CLI's watch, captures and tuning read it."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeVar

from lm629_host.bus.opcodes import Cmd, Signals, Status, s16, s32_words
from lm629_host.bus.program import Program, ProgramResult

P = TypeVar("P", bound=Program)


@dataclass(frozen=True)
class Snapshot:
    """Everything the chip reports, read in one bus program (one round trip on a bridge)."""

    status: Status
    signals: Signals
    desired_position: int
    real_position: int
    desired_velocity: int  #: signed 16.16
    real_velocity: int
    integration_sum: int
    time: float  #: the transport clock when the snapshot was taken

    @property
    def following_error(self) -> int:
        return self.desired_position - self.real_position


#: the reads of a snapshot after its status byte: (command, words)
SNAPSHOT_READS = ((Cmd.RDSIGS, 1), (Cmd.RDDP, 2), (Cmd.RDRP, 2), (Cmd.RDDV, 2), (Cmd.RDRV, 1),
                  (Cmd.RDSUM, 1))
#: the words one snapshot reads (after its status byte)
SNAPSHOT_WORDS = sum(n for _, n in SNAPSHOT_READS)


def add_snapshot(p: P, reads: Sequence[tuple[Cmd, int]] = SNAPSHOT_READS) -> P:
    """Append a snapshot's bus operations to ``p``: a status read, then ``reads`` (a recording's
    basic rows read fewer registers, in the same shape).  Every program that reads a snapshot
    builds it here, so that :func:`snapshot_of` decodes them all."""
    p.status()
    for cmd, n in reads:
        p.command(cmd).read(n)
    return p


#: every status byte as its Status (the flags a snapshot carries), made once: ``Status(byte)``
#: is an enum call, on every snapshot a wait polls
_STATUSES = tuple(Status(b) for b in range(256))


def snapshot_of(status: int, w: Sequence[int], time: float) -> Snapshot:
    """A :class:`Snapshot` from its status byte and the words of :data:`SNAPSHOT_READS`."""
    return Snapshot(_STATUSES[status], Signals(w[0]), s32_words(w[1], w[2]),
                    s32_words(w[3], w[4]), s32_words(w[5], w[6]), s16(w[7]), s16(w[8]), time)


def snapshot_at(result: ProgramResult, k: int, time: float, status_at: int | None = None
                ) -> Snapshot:
    """The ``k``-th snapshot a program of several read (its words are the ``k``-th
    :data:`SNAPSHOT_WORDS`); its status byte is ``result.statuses[status_at]`` (default ``k``:
    a program whose only status reads are its snapshots')."""
    return snapshot_of(result.statuses[k if status_at is None else status_at],
                       result.words[k * SNAPSHOT_WORDS:(k + 1) * SNAPSHOT_WORDS], time)


__all__ = ["SNAPSHOT_READS", "SNAPSHOT_WORDS", "Snapshot", "add_snapshot", "snapshot_at",
           "snapshot_of"]
