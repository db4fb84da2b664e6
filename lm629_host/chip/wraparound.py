"""Positions that survive the position register's wraparound (AN-706 6.5.2).

The chip's position registers hold C0000000..3FFFFFFF: one count past 3FFFFFFF the register
reads C0000000 (and one count below C0000000 it reads 3FFFFFFF), and the chip sets status bit 4
(WRAPAROUND).  "The host has to manage wraparound by noting its occurrence and resetting the
Status byte wraparound bit using the RSTI command ... With management there is no reason why
absolute position should be lost."

:class:`PositionTracker` is that management for one chip.  It keeps, per register (desired,
real), the last value read and its extended value, a Python int of any size (64 bits and
beyond).  A new read extends by the register's change since the last one taken the short way
round the 2^31-count circle: the direction of travel between the two reads.  That is exact
while the shaft moves less than 2^30 counts (half the register) between two reads: 8.4 s at the
chip's top velocity of 32767 counts per sample at 8 MHz, years at any bench speed.  The
wraparound bit says that the circle was crossed; the tracker counts the crossings it saw
(``wraps``) and the chip's owner clears the bit with RSTI (:meth:`LM629.positions
<lm629_host.LM629>`), so that the next crossing sets it again.

A reset or DFH makes both registers 0 again: :meth:`restart` forgets the history, so the
extended positions restart from the register's values.
"""

from __future__ import annotations

import contextlib
import copy
from collections.abc import Iterator
from dataclasses import replace

from lm629_host.errors import ArgumentError
# the status byte's wraparound bit as a plain int: every position read tests it, and an
# IntFlag operation costs a Python-level call each time
from lm629_host.bus.bits import STATUS_WRAPAROUND as _WRAP_BIT
from lm629_host.bus.opcodes import POSITION_MAX, POSITION_MIN, wrap_counts
from lm629_host.bus.snapshot import Snapshot

#: counts round the register's circle (C0000000..3FFFFFFF)
REGISTER_SPAN = POSITION_MAX - POSITION_MIN + 1


#: a register difference taken the short way round the circle, in [-2^30, 2^30)
short_way = wrap_counts


def check_register_position(name: str, value: object) -> int:
    """``value`` when it is a whole number of counts the position register holds, else an
    :class:`ArgumentError` naming the register's range: a target lies within one register
    range; extended positions are for reading (docs/python.md, "Long runs")."""
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or \
            not POSITION_MIN <= value <= POSITION_MAX:
        raise ArgumentError(
            name, value, f"{name}={value!r} is outside the position register's range "
            f"{POSITION_MIN}..{POSITION_MAX} (0xC0000000..0x3FFFFFFF): a target lies within one "
            "register range, reached the short way round it; extended positions are for "
            "reading (a long run: docs/python.md, \"Long runs\")", lo=POSITION_MIN,
            hi=POSITION_MAX)
    return value


class PositionTracker:
    """The extended desired and real positions of one chip (see the module docstring)."""

    def __init__(self) -> None:
        #: register name -> (last register value, its extended value)
        self._last: dict[str, tuple[int, int]] = {}
        #: register crossings seen through the status byte's WRAPAROUND bit
        self.wraps = 0
        #: a position has been extended: the tracker's origin.  A bit seen before (or with)
        #: the first position read was latched by a crossing before it (a script that ended
        #: mid-move across the wrap, leaving the bit set for the next process): the extended
        #: positions start from the register's values after that crossing, so it is not one
        #: of this tracker's; it is still cleared, so that the next crossing shows
        self._origin = False
        #: the bit was seen set and not cleared since: the owner's next read clears it (RSTI)
        self.pending = False
        #: :meth:`holding` blocks open, and a bit seen inside them (pending once they end)
        self._holds = 0
        self._held = False

    def restart(self) -> None:
        """The registers were zeroed (reset, DFH): extend from their new values."""
        self._last.clear()

    def extend(self, name: str, raw: int, near: str | None = None) -> int:
        """The extended value of register ``name`` read as ``raw``.  A register never read
        before starts the short way from register ``near`` (the real position next to the
        desired one: their difference is the following error, never half the circle)."""
        value = self.near_register(raw, name if name in self._last or near is None else near)
        self._last[name] = (raw, value)
        self._origin = True
        return value

    def knows(self, name: str) -> bool:
        """True when register ``name`` was read since the last restart: the next read of it
        extends from there (without, a read after a crossing starts on the far side)."""
        return name in self._last

    def to_register(self, position: int) -> int:
        """The register value an extended position reads as."""
        return short_way(position)

    def near_register(self, raw: int, name: str = "desired") -> int:
        """The extended position a register value ``raw`` stands for now: the one the short
        way from the last extended value of ``name`` (the chip goes the short way round to a
        target, model choice 9 and AN-706 6.5.2), or ``raw`` with no history."""
        last = self._last.get(name)
        return raw if last is None else last[1] + short_way(raw - last[0])

    def saw(self, status: int) -> None:
        """Note a status byte: a WRAPAROUND bit not seen since it was last cleared is a new
        crossing (``wraps``), and ``pending`` until the owner clears it with RSTI (a
        recording's rows all show the bit until then: one crossing, not one per row).
        Inside :meth:`holding` it becomes pending only when the block ends.  A bit seen
        before the tracker's first position read is a crossing before its origin: cleared,
        not counted."""
        if int(status) & _WRAP_BIT and not self.pending and not self._held:
            if self._origin:
                self.wraps += 1
            if self._holds:
                self._held = True
            else:
                self.pending = True

    @contextlib.contextmanager
    def holding(self) -> Iterator[None]:
        """A bit seen inside the block is counted but made ``pending`` (so cleared by the
        next read) only when the block ends.  A batch decodes its calls inside one: the
        programs it sent were built before any of their results were known, so none of them
        can carry an RSTI that a result inside the batch asks for (its calls would come out
        otherwise than the programs sent)."""
        self._holds += 1
        try:
            yield
        finally:
            self._holds -= 1
            if not self._holds and self._held:
                self._held = False
                self.pending = True

    def copy(self) -> PositionTracker:
        """An independent tracker with this one's history (a batch's shadow chip builds on
        one, so that the dummy answers it is given never reach this one)."""
        twin = copy.copy(self)
        twin._last = dict(self._last)
        return twin

    def snapshot(self, s: Snapshot) -> Snapshot:
        """``s`` with its positions extended (the desired one first)."""
        desired = self.extend("desired", s.desired_position)
        real = self.extend("real", s.real_position, near="desired")
        return replace(s, desired_position=desired, real_position=real)


__all__ = ["REGISTER_SPAN", "PositionTracker", "check_register_position", "short_way"]
