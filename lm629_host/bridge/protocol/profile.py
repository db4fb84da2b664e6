"""PROFILE's payloads: a shaped move's pieces that the bridge issues on its own timer."""

from __future__ import annotations

import struct
from collections.abc import Sequence

from lm629_host.bridge.protocol.constants import PROFILE_HEADER, PROFILE_MAX_PIECES, PROFILE_NEW, PROFILE_PIECE
from lm629_host.bus.opcodes import Cmd, TrajectoryFlags
from lm629_host.bus.program import BusOp, Op

#: PROFILE_REPLY's payload: result, pieces issued, pieces pending, largest lateness (us)
PROFILE_REPLY_PAYLOAD = struct.Struct(">BHHI")


def profile_payload(new: bool, cs: int, pieces: Sequence[tuple[int, int]]) -> bytes:
    """PROFILE's payload: ``pieces`` as (us from the schedule's start, velocity word)."""
    if len(pieces) > PROFILE_MAX_PIECES:
        raise ValueError(f"{len(pieces)} pieces: a PROFILE frame carries {PROFILE_MAX_PIECES}")
    return PROFILE_HEADER.pack(PROFILE_NEW if new else 0, cs) + b"".join(
        PROFILE_PIECE.pack(t, v) for t, v in pieces)


def profile_piece_ops(velocity: int) -> list[BusOp]:
    """The bus program of one piece: LTRJ with a new maximum velocity only, then STT (a
    velocity may change on the fly, AN-706 4.6.1)."""
    return [BusOp(Op.COMMAND, int(Cmd.LTRJ)), BusOp(Op.WRITE, int(TrajectoryFlags.VELOCITY)),
            BusOp(Op.WRITE, velocity >> 16), BusOp(Op.WRITE, velocity & 0xFFFF),
            BusOp(Op.COMMAND, int(Cmd.STT))]


def ends_a_profile(ops: Sequence[BusOp]) -> bool:
    """A program the bridge drops a schedule for: one that loads a trajectory (a stop, a new
    move) or pulses /RST: no later piece may restart what it stopped."""
    return any((o.op is Op.COMMAND and o.arg == Cmd.LTRJ) or o.op is Op.RESET for o in ops)
