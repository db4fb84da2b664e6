"""FAILSAFE's reply and the one frame that feeds the bridge's link failsafe during a recording."""

from __future__ import annotations

import struct
from dataclasses import dataclass

from lm629_host.bridge.protocol.constants import FailsafeAction, FrameType, Result
from lm629_host.bridge.protocol.framing import FrameError, encode_frame


@dataclass(frozen=True)
class FailsafeState:
    """FAILSAFE_REPLY's payload: the request's result, the timer as armed (``timeout_ms`` 0:
    disarmed) and its action, and the latched trip: whether there is one, which chip selects
    it stopped (bit k: chip select k), how long the host had been silent and the bridge's
    clock at the trip (ms since the bridge started)."""

    result: int = Result.OK
    timeout_ms: int = 0
    action: int = FailsafeAction.ABRUPT
    tripped: bool = False
    chips: int = 0
    silent_ms: int = 0
    at_ms: int = 0

    LAYOUT = struct.Struct(">BHBBBII")
    SIZE = LAYOUT.size

    def encode(self) -> bytes:
        return self.LAYOUT.pack(self.result, self.timeout_ms, self.action, int(self.tripped),
                                self.chips, self.silent_ms & 0xFFFFFFFF, self.at_ms & 0xFFFFFFFF)

    @classmethod
    def decode(cls, payload: bytes) -> FailsafeState:
        if len(payload) != cls.SIZE:
            raise FrameError(f"FAILSAFE_REPLY of {len(payload)} bytes, expected {cls.SIZE}")
        result, ms, action, tripped, chips, silent, at = cls.LAYOUT.unpack(payload)
        return cls(result, ms, action, bool(tripped), chips, silent, at)

    @property
    def stopped(self) -> list[int]:
        """The chip selects the trip stopped."""
        return [k for k in range(8) if self.chips >> k & 1]

    def describe(self, names: dict[int, str] | None = None) -> str:
        """One sentence on the latched trip (``names``: axis names by chip select)."""
        if not self.tripped:
            return "no failsafe trip latched"
        names = names or {}
        who = ", ".join(f"axis {names[k]} (cs {k})" if k in names else f"cs {k}"
                        for k in self.stopped) or "no chip (none answered)"
        try:
            how = FailsafeAction(self.action).name.lower()
        except ValueError:
            how = f"action {self.action}"
        return (f"the bridge stopped {who} ({how} stop) after the host was silent for "
                f"{self.silent_ms / 1e3:.2f} s (at bridge time {self.at_ms / 1e3:.1f} s)")


#: the one FAILSAFE frame a recording takes without ending: seq 0, empty payload, always the
#: same bytes, so that the bridge matches it byte by byte while it samples
FAILSAFE_FEED = encode_frame(FrameType.FAILSAFE, 0)
