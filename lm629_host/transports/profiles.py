"""The link's PROFILE scheduler: a shaped move's pieces handed to the bridge, which issues each
(LTRJ of a new maximum velocity, then STT) on its own timer (PROTOCOL.md, PROFILE).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from lm629_host.bridge.protocol import (
    PROFILE_MAX_PIECES,
    PROFILE_REPLY_PAYLOAD,
    FrameType,
    Result,
    profile_payload,
    wire_size,
)
from lm629_host.errors import TransportError
from lm629_host.transports.base import ProfileState

if TYPE_CHECKING:
    from lm629_host.transports.failsafe import LinkFailsafe
    from lm629_host.transports.session import LinkSession


class ProfileScheduler:
    """PROFILE over one link (a bridge with capability bit 10)."""

    def __init__(self, link: LinkSession, failsafe: LinkFailsafe, cs: int) -> None:
        self.link = link
        self.failsafe = failsafe
        self.cs = cs  #: the chip select of the transport's own chip

    def send(self, axis: int | None, pieces: Sequence[tuple[float, int]], *,
                new: bool) -> ProfileState:
        """PROFILE frames (PROFILE_MAX_PIECES pieces each, the first one ``new``): the bridge
        issues each piece on its own timer, its times counted from the first frame's arrival
        (so the link's latency shifts them all alike and jitters none).  A schedule the bridge
        refuses is a :class:`TransportError` naming why."""
        if pieces:  # a query only reads what the schedule did (a trip's cancel among it)
            self.failsafe.check()
        cs = self.cs if axis is None else axis
        times = [(round(t * 1e6), v) for t, v in pieces]
        chunks = [times[k:k + PROFILE_MAX_PIECES]
                  for k in range(0, len(times), PROFILE_MAX_PIECES)] or [[]]
        state = ProfileState(0, 0, 0.0)
        for k, chunk in enumerate(chunks):
            payload = profile_payload(new and k == 0, cs, chunk)
            frame = self.link._exchange(FrameType.PROFILE, payload,
                                   self.link.reply_timeout(wire_size(len(payload) + 4),
                                                      wire_size(PROFILE_REPLY_PAYLOAD.size + 4)),
                                   f"PROFILE of {len(chunk)} piece(s)", self.link.retries)
            if len(frame.payload) != PROFILE_REPLY_PAYLOAD.size:
                raise TransportError("the bridge's PROFILE_REPLY has the wrong length: reflash "
                                     "the firmware that matches this host", port=self.link.url)
            result, issued, pending, late_us = PROFILE_REPLY_PAYLOAD.unpack(frame.payload)
            if result == Result.FAILSAFE_TRIPPED:
                raise self.failsafe.tripped_error("nothing of the shaped move was scheduled")
            if result == Result.BAD_PROFILE:
                raise TransportError(
                    f"the bridge refused the shaped move's pieces (BAD_PROFILE): pieces out of "
                    f"order or closer than 10 ms, a velocity above 3FFFFFFF, chip select {cs} "
                    "or more pieces than it holds; nothing was scheduled", port=self.link.url)
            state = ProfileState(issued, pending, late_us * 1e-6,
                                 result == Result.PROFILE_CANCELLED)
        return state


__all__ = ["ProfileScheduler"]
