"""The link's PROFILE scheduler: a shaped move's pieces handed to the bridge, which issues each
(LTRJ of a new maximum velocity, then STT) on its own timer (PROTOCOL.md, PROFILE).
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from lm629_host.bridge.protocol.constants import PROFILE_MAX_PIECES, PROFILE_MAX_SCHEDULE, FrameType, Result
from lm629_host.bridge.protocol.framing import wire_size
from lm629_host.bridge.protocol.profile import PROFILE_REPLY_PAYLOAD, profile_payload
from lm629_host.errors import TransportError
from lm629_host.transports.reports import ProfileState

if TYPE_CHECKING:
    from lm629_host.transports.failsafe import LinkFailsafe
    from lm629_host.transports.session import LinkSession


#: a stream is topped up when the host gets to it (any program on the link, a query) at most
#: this often: the bridge holds PROFILE_MAX_SCHEDULE pieces, at least 10 ms apart (0.64 s)
REFILL_S = 0.05


@dataclass
class _Stream:
    """A shaped move's pieces on one chip select, more than the bridge holds at once: the
    host keeps the rest and tops the bridge's schedule up as its pieces fall due."""

    cs: int
    #: host clock when the bridge's schedule started (the pieces' times count from it): the
    #: NEW frame's reply, by when the bridge had started its clock at the latest
    start: float
    times: list[tuple[int, int]]  #: every piece: (us from the start, velocity word)
    sent: int = 0  #: pieces handed to the bridge so far
    last: float = 0.0  #: host clock of the last top-up

    def due_by(self, elapsed_us: float) -> int:
        """Pieces whose time has come (the bridge issued them, or is about to)."""
        return bisect_right(self.times, (elapsed_us, 1 << 62))


class ProfileScheduler:
    """PROFILE over one link (a bridge with capability bit 10).  A schedule longer than the
    bridge holds (:data:`PROFILE_MAX_SCHEDULE` pieces) is streamed: the first pieces go out at
    once, the rest in top-ups (PROFILE without NEW: appended, times from the same start) each
    time the host gets to the link (every program and every query of the schedule, at most
    every :data:`REFILL_S`), so the pieces stay timed by the bridge, never by the host."""

    def __init__(self, link: LinkSession, failsafe: LinkFailsafe, cs: int) -> None:
        self.link = link
        self.failsafe = failsafe
        self.cs = cs  #: the chip select of the transport's own chip
        self._streams: dict[int, _Stream] = {}
        #: host clock of the last NEW frame's reply (a stream's start)
        self._started = 0.0

    @property
    def streaming(self) -> bool:
        """True while a schedule has pieces the bridge does not hold yet."""
        return bool(self._streams)

    def send(self, axis: int | None, pieces: Sequence[tuple[float, int]], *,
             new: bool) -> ProfileState:
        """Hand ``pieces`` (seconds from the schedule's start, velocity word) to the bridge:
        ``new`` starts a schedule (dropping an older one's pieces, those the host still holds
        too); without ``new`` they are appended; no pieces and no ``new``: a query, which also
        tops a stream up.  Returns what the bridge reports, with the pieces the host still
        holds (``queued``).  A schedule the bridge refuses is a :class:`TransportError`."""
        if pieces:  # a query only reads what the schedule did (a trip's cancel among it)
            self.failsafe.check()
        cs = self.cs if axis is None else axis
        times = [(round(t * 1e6), v) for t, v in pieces]
        clock = self.link.clock
        if new:
            self._streams.pop(cs, None)
            stream = _Stream(cs, clock.now(), times)
            if len(times) <= PROFILE_MAX_SCHEDULE:
                return self._frames(cs, times, new=True)
            self._streams[cs] = stream
            return self._top_up(stream)
        going = self._streams.get(cs)
        if going is not None:
            going.times += times
            return self._top_up(going)
        return self._frames(cs, times, new=False)

    def refill(self) -> None:
        """Top every stream up (the link calls it before each program): cheap when nothing
        is due, one PROFILE exchange when pieces fell due since the last top-up."""
        now = self.link.clock.now()
        for stream in list(self._streams.values()):
            if now - stream.last >= REFILL_S:
                self._top_up(stream)

    def _top_up(self, stream: _Stream) -> ProfileState:
        with self.link.request_lock:  # the keep-alive's thread tops up too
            return self._top_up_locked(stream)

    def _top_up_locked(self, stream: _Stream) -> ProfileState:
        now = self.link.clock.now()
        stream.last = now
        elapsed_us = (now - stream.start) * 1e6
        held = stream.sent - min(stream.sent, stream.due_by(elapsed_us))
        # one to spare: the start is the NEW reply's arrival, when the bridge's clock had run
        # for that reply's wire time already, so it holds no more than ``held``; the spare
        # covers a piece it issues between reading its clock and taking the frame
        room = PROFILE_MAX_SCHEDULE - held - 1
        batch = stream.times[stream.sent:stream.sent + max(0, room)]
        new = stream.sent == 0
        state = self._frames(stream.cs, batch, new=new)
        if new:
            stream.start = self._started
        if batch and state.cancelled:
            self._streams.pop(stream.cs, None)  # a stop dropped the schedule: so is the rest
            return state
        stream.sent += len(batch)
        queued = len(stream.times) - stream.sent
        if not queued:
            self._streams.pop(stream.cs, None)
        return ProfileState(state.issued, state.pending, state.late_max_s, state.cancelled,
                            queued)

    def _frames(self, cs: int, times: list[tuple[int, int]], *, new: bool) -> ProfileState:
        """PROFILE frames of PROFILE_MAX_PIECES pieces each (the first one ``new``): the
        bridge issues each piece on its own timer, its times counted from the first NEW
        frame's arrival (so the link's latency shifts them all alike and jitters none)."""
        chunks = [times[k:k + PROFILE_MAX_PIECES]
                  for k in range(0, len(times), PROFILE_MAX_PIECES)] or [[]]
        link = self.link
        state = ProfileState(0, 0, 0.0)
        for k, chunk in enumerate(chunks):
            payload = profile_payload(new and k == 0, cs, chunk)
            frame = link.request(FrameType.PROFILE, payload, f"PROFILE of {len(chunk)} piece(s)",
                                 wire_size(PROFILE_REPLY_PAYLOAD.size + 4), resync=False)
            if len(frame.payload) != PROFILE_REPLY_PAYLOAD.size:
                raise TransportError("the bridge's PROFILE_REPLY has the wrong length: reflash "
                                     "the firmware that matches this host", port=link.url)
            result, issued, pending, late_us = PROFILE_REPLY_PAYLOAD.unpack(frame.payload)
            if result == Result.FAILSAFE_TRIPPED:
                self._streams.pop(cs, None)
                raise self.failsafe.tripped_error("nothing of the shaped move was scheduled")
            if result == Result.BAD_PROFILE:
                self._streams.pop(cs, None)
                raise TransportError(
                    f"the bridge refused the shaped move's pieces (BAD_PROFILE): pieces out of "
                    f"order or closer than 10 ms, a velocity above 3FFFFFFF, chip select {cs} "
                    "or more pieces than it holds; nothing was scheduled", port=link.url)
            state = ProfileState(issued, pending, late_us * 1e-6,
                                 result == Result.PROFILE_CANCELLED)
            if new and k == 0:
                # the bridge starts the schedule's clock when this frame arrives, which is
                # after it went out by its wire time (a full frame at 115200 baud: 22 ms, more
                # than a 20 ms piece): counting the pieces from when it went out would have
                # the host think the bridge issued pieces it had not, and top up past the
                # PROFILE_MAX_SCHEDULE it holds (refused: BAD_PROFILE)
                self._started = link.clock.now()
        return state


__all__ = ["REFILL_S", "ProfileScheduler"]
