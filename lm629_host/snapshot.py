"""What the chip reports, read in one bus program: :meth:`LM629.snapshot
<lm629_host.LM629.snapshot>` returns one; moves, the CLI's watch, captures and tuning read it."""

from __future__ import annotations

from dataclasses import dataclass

from .opcodes import Cmd, Signals, Status, s16, s32


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


def snapshot_of(status: int, w: tuple[int, ...], time: float) -> Snapshot:
    """A :class:`Snapshot` from its status byte and the words of :data:`SNAPSHOT_READS`."""
    return Snapshot(Status(status), Signals(w[0]), s32((w[1] << 16) | w[2]),
                    s32((w[3] << 16) | w[4]), s32((w[5] << 16) | w[6]), s16(w[7]), s16(w[8]),
                    time)


__all__ = ["SNAPSHOT_READS", "Snapshot", "snapshot_of"]
