"""What the chip reports, read in one bus program: :meth:`LM629.snapshot
<lm629_host.LM629.snapshot>` returns one; moves, the CLI's watch, captures and tuning read it."""

from __future__ import annotations

from dataclasses import dataclass

from .opcodes import Signals, Status


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


__all__ = ["Snapshot"]
