"""What the chip holds and what its sample loop may touch: the filter registers and the LTRJ
input buffer (plain data), and :class:`ChipState`, the part of the chip that the sample loop
(:mod:`.motion`, :mod:`.fastloop`) reads and writes.  :class:`~.chip.ChipModel` is a
``ChipState``; the sample loop never sees the host interface, so it imports this module and
not the chip's."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol


@dataclass
class FilterRegisters:
    """LFIL input buffer or working registers."""

    kp: int = 0
    ki: int = 0
    kd: int = 0
    il: int = 0
    ds: int = 1  #: derivative interval, samples (the LFIL word's high byte + 1)

    def copy(self) -> FilterRegisters:
        return FilterRegisters(self.kp, self.ki, self.kd, self.il, self.ds)


@dataclass
class TrajectoryBuffer:
    """LTRJ input buffer: mode, pending stop, and the parameters loaded since the last STT."""

    #: the last LTRJ control word as written (for inspection; the chip acts on the two below)
    control: int = 0
    #: bits 11/12 (velocity mode, forward) of the last LTRJ that carried no stop bit: the
    #: running trajectory's mode, which a plain STT after a stop resumes [model choice 27]
    mode: int = 0
    #: the stop bit (8, 9 or 10) of the last LTRJ, executed once by the next accepted STT
    stop: int = 0
    #: 16.16 unsigned word as loaded (absolute), or the signed sum of the relative words loaded
    #: since the last STT [model choice 29]
    acceleration: int = 0
    velocity: int = 0
    position: int = 0  #: signed counts (absolute, or the sum of relative words)
    #: which parameters were loaded (and how) since the last accepted STT
    loaded: int = 0


class ChipState(Protocol):
    """The chip as its sample loop sees it (:class:`~.chip.ChipModel` is one)."""

    clock_hz: int
    filter: FilterRegisters  #: the working filter registers
    motor_off: bool
    flags: int  #: latched status bits 1..6
    signals_extra: int  #: signals-register bits not derived from elsewhere
    breakpoint: int
    position_error_threshold: int
    motion: Any  #: the :class:`~.motion.Motion` this state belongs to

    @property
    def sample_clocks(self) -> int:
        """Chip clocks per sample (2048)."""

    def turn_motor_off(self) -> None: ...


__all__ = ["ChipState", "FilterRegisters", "TrajectoryBuffer"]
