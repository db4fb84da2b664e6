"""The program-code cache of a link (PROTOCOL.md, RUN_STORE and RUN_CODE): short programs the
bridge keeps under a one-byte code, so that a polling loop sends one byte of program instead of
its operations.  The host's copy of what the bridge keeps lives here, least recently used
first; a HELLO empties both.
"""

from __future__ import annotations

from collections import OrderedDict

from lm629_host.bridge.protocol.constants import CODE_SLOTS, FrameType


class ProgramCodes:
    """What the bridge keeps under which code, as far as the host knows."""

    def __init__(self) -> None:
        #: short programs the bridge keeps, by code (RUN_CODE), least recently used first
        self.codes: OrderedDict[bytes, int] = OrderedDict()
        #: short programs sent lately (the second time, one gets a code)
        self._recent: OrderedDict[bytes, None] = OrderedDict()

    def choose(self, program: bytes) -> tuple[FrameType, bytes, tuple[bytes, int] | None]:
        """How to send a short program to a bridge that keeps programs under codes: by its
        code (RUN_CODE, 1 byte) when the bridge keeps it; the second time it is seen, with a
        code for it (RUN_STORE: the least recently used code is reused); the first time, as
        it is (RUN_SHORT: programs that carry changing data are not worth a code).  Returns
        the frame type, its payload, and (program, code) to remember once it ran."""
        codes = self.codes
        code = codes.get(program)
        if code is not None:
            codes.move_to_end(program)
            return FrameType.RUN_CODE, bytes((code,)), None
        if program not in self._recent:
            self._recent[program] = None
            if len(self._recent) > 2 * CODE_SLOTS:
                self._recent.popitem(last=False)
            return FrameType.RUN_SHORT, program, None
        used = set(codes.values())
        free = [c for c in range(CODE_SLOTS) if c not in used]
        if free:
            code = free[0]
        else:
            _, code = codes.popitem(last=False)  # the least recently used
        # until it ran, the bridge may hold either program under this code: forget both
        for p, c in list(codes.items()):
            if c == code:
                del codes[p]
        return FrameType.RUN_STORE, bytes((code,)) + program, (program, code)

    def forget(self) -> None:
        """The bridge forgot its programs (HELLO) or may hold others than we think."""
        self.codes.clear()

    def remember(self, program: bytes, code: int) -> None:
        """``program`` ran under ``code`` (a RUN_STORE was answered OK)."""
        self.codes[program] = code


__all__ = ["ProgramCodes"]
