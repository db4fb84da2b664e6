"""What the far end's parts share: the emulator's state (its counters, a recording under
way, a shaped move's schedule), and the calls one part makes to another (each part is a mixin
of :class:`~.link.BridgeEmulator`, in a module of its own, as the host link's parts are in
:mod:`lm629_host.transports`)."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from lm629_host.bridge.protocol.constants import FailsafeAction, Result
from lm629_host.bridge.protocol.failsafe import FailsafeState
from lm629_host.bridge.protocol.hello import HelloInfo
from lm629_host.bridge.protocol.run import RunReply
from lm629_host.bus.program import BusOp
from lm629_host.sim.model import ChipBus, ChipModel

@dataclass
class EmuStats:
    """What happened on the far side (for the fault tests: nothing runs twice)."""

    frames: int = 0  #: good frames received
    bad_frames: int = 0  #: frames dropped for COBS, length or CRC errors
    runs: int = 0  #: RUN programs executed
    recordings: int = 0  #: RECORD requests that started recording
    rows: int = 0  #: RECORD_ROW frames sent
    pieces: int = 0  #: PROFILE pieces issued
    cache_hits: int = 0  #: RUN repeats answered from the cache
    trips: int = 0  #: failsafe trips
    feeds: int = 0  #: FAILSAFE_FEED frames taken during a recording
    replies: int = 0  #: frames sent
    busy_polls: int = 0  #: status reads made only for the busy check
    bus_cycles: int = 0  #: strobes and /RST pulses


@dataclass
class Recording:
    """A recording under way: its RECORD's seq, sample program, period (s), rows asked (0:
    until stopped), rows sent, and when the next is due (model seconds)."""

    seq: int
    ops: list[BusOp]
    period: float
    rows: int
    due: float
    index: int = 0

    def __post_init__(self) -> None:
        self.start = self.due  #: the first row's time: the stamps count from it


@dataclass
class Schedule:
    """A shaped move's pieces on the bridge: its chip select, the schedule's start (model
    seconds), the pieces still to issue (us from the start, velocity word), how many went out,
    the largest lateness of one (us), how the schedule ended, and the soonest the next piece
    may go out."""

    cs: int = 0
    start: float = 0.0
    pending: deque[tuple[int, int]] = field(default_factory=deque)
    issued: int = 0
    late_us: int = 0
    result: Result = Result.OK
    #: the next piece goes out no sooner than this (model seconds): 10 ms after the last
    not_before: float = 0.0


class BridgeParts:
    """The state every part of the far end reads (set by :class:`~.link.BridgeEmulator` and
    each part's own ``_init_*``), and the parts' methods the others call."""

    model: ChipModel | ChipBus
    info: HelloInfo
    stats: EmuStats
    host_byte_at: Callable[[float], float | None] | None
    host_byte_waiting: bool
    _cs: int  #: the chip select the bus talks to now
    _cache: tuple[int, int, bytes] | None  #: the last reply: seq, crc, encoded frame
    _fs_ms: int
    _fs_action: FailsafeAction
    _fs_last: float
    _fs_trip: FailsafeState | None
    _feed_matched: int
    _rec: Recording | None
    _profile: Schedule

    if TYPE_CHECKING:  # the parts' methods, for the checker (each part defines its own)
        def run_ops(self, ops: list[BusOp], timeout_s: float) -> RunReply: ...

        def _strobe(self) -> ChipModel: ...

        def _error(self, seq: int, code: Result) -> bytes: ...

        def _cancel_profile(self, ops: Sequence[BusOp]) -> None: ...

        @property
        def failsafe_due(self) -> float | None: ...

        def failsafe_trip(self) -> None: ...

        @property
        def profile_due(self) -> float | None: ...

        def profile_step(self) -> None: ...


__all__ = ["BridgeParts", "EmuStats", "Recording", "Schedule"]
