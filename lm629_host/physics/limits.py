"""Soft limits of one axis: the travel a rig allows and the fastest it may be driven.

Why here, in the library: every trajectory the host sends to a chip is built by one method,
:meth:`LM629.trajectory_program <lm629_host.LM629.trajectory_program>` (``move_to``,
``load_trajectory``, a board's synchronized moves, the tuner's and ``capture_move``'s steps,
the CLI's index search all go through it).  An axis with ``chip.limits`` set has every one of
them checked there, so a lab script that opens the board with its profile is held to the
limits as the command line is; :meth:`LM629.move_to` and the board's moves check their targets
before their first read too, so that a refused move costs no bus exchange at all.

The limits are counts (``min``/``max``) and counts per second (``max_velocity``,
``max_acceleration``, per second squared), the units of a profile; they are compared with the
chip's 16.16 trajectory words at the chip's sample period (2048 / clock).  A stop (the LTRJ
stop bits) is never refused: stopping must always work.  What cannot be checked before the
chip runs it is refused on an axis with travel limits: a relative position (the chip adds it
to a target the host would have to read first: ``move_to(..., relative=True)`` does that and is
checked) and velocity mode (it runs until stopped, past any limit); a relative velocity or
acceleration likewise on an axis with a cap.
"""

from __future__ import annotations

from dataclasses import dataclass

from lm629_host.bus.opcodes import FIXED_ONE, NOMINAL_CLOCK_HZ
from lm629_host.physics.pid import sample_period_s


@dataclass(frozen=True)
class SoftLimits:
    """One axis's limits; ``None`` for a limit not set.  ``where`` names their source in every
    message (``bench.toml [axis.x]``); ``lines`` maps a limit's name to its line there."""

    min: int | None = None  #: counts
    max: int | None = None  #: counts
    max_velocity: float | None = None  #: counts/s
    max_acceleration: float | None = None  #: counts/s^2
    clock_hz: float = NOMINAL_CLOCK_HZ
    where: str = "the soft limits"  #: the file they come from
    table: str = ""  #: the table in it (``axis.x``)
    lines: tuple[tuple[str, int], ...] = ()

    def __post_init__(self) -> None:
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError(f"{self._at('min')} = {self.min} is above max = {self.max}")

    # ------------------------------------------------------------------ the words
    @property
    def sample_s(self) -> float:
        return sample_period_s(self.clock_hz)

    @property
    def velocity_word(self) -> int | None:
        """The largest velocity word allowed (16.16 counts/sample)."""
        if self.max_velocity is None:
            return None
        return int(self.max_velocity * self.sample_s * FIXED_ONE)

    @property
    def acceleration_word(self) -> int | None:
        """The largest acceleration word allowed (16.16 counts/sample^2)."""
        if self.max_acceleration is None:
            return None
        return int(self.max_acceleration * self.sample_s ** 2 * FIXED_ONE)

    @property
    def has_travel(self) -> bool:
        return self.min is not None or self.max is not None

    def _at(self, key: str) -> str:
        """``bench.toml:14: [axis.x] max``: where the limit ``key`` is set."""
        line = dict(self.lines).get(key)
        table = f"[{self.table}] " if self.table else ""
        return f"{self.where}{f':{line}' if line else ''}: {table}{key}"

    def _fail(self, key: str, text: str) -> ValueError:
        return ValueError(f"{text} ({self._at(key)})")

    # ------------------------------------------------------------------ the checks
    def check_position(self, target: int, what: str = "target") -> None:
        """ValueError when ``target`` (counts) is outside min..max."""
        if self.min is not None and target < self.min:
            raise self._fail("min", f"{what} {target} is below the soft limit min = {self.min} "
                                    "counts")
        if self.max is not None and target > self.max:
            raise self._fail("max", f"{what} {target} is above the soft limit max = {self.max} "
                                    "counts")

    def check_velocity(self, word: int) -> None:
        cap = self.velocity_word
        if cap is not None and word > cap:
            raise self._fail("max_velocity",
                             f"velocity word {word} is {word / FIXED_ONE / self.sample_s:.0f} "
                             f"counts/s, above max_velocity = {self.max_velocity:g} counts/s "
                             f"(word {cap})")

    def check_acceleration(self, word: int) -> None:
        cap = self.acceleration_word
        if cap is not None and word > cap:
            raise self._fail("max_acceleration",
                             f"acceleration word {word} is "
                             f"{word / FIXED_ONE / self.sample_s ** 2:.0f} counts/s^2, above "
                             f"max_acceleration = {self.max_acceleration:g} counts/s^2 "
                             f"(word {cap})")

    def check_trajectory(self, acceleration: int | None, velocity: int | None,
                         position: int | None, *, acceleration_relative: bool = False,
                         velocity_relative: bool = False, position_relative: bool = False,
                         velocity_mode: bool = False) -> None:
        """The check of every LTRJ that may move the motor (see the module docstring)."""
        if velocity_mode and self.has_travel:
            key = "min" if self.min is not None else "max"
            raise self._fail(key, "velocity mode runs until it is stopped, past any soft limit: "
                                  "move to a target instead")
        if position is not None:
            if position_relative and self.has_travel:
                raise self._fail("min" if self.min is not None else "max",
                                 "a relative position cannot be checked against the soft "
                                 "limits before the chip adds it: use move_to(..., "
                                 "relative=True), which reads the target first")
            if not position_relative:
                self.check_position(position)
        if velocity is not None:
            if velocity_relative and self.max_velocity is not None:
                raise self._fail("max_velocity", "a relative velocity cannot be checked "
                                                 "against max_velocity: give the velocity")
            self.check_velocity(velocity)
        if acceleration is not None:
            if acceleration_relative and self.max_acceleration is not None:
                raise self._fail("max_acceleration", "a relative acceleration cannot be "
                                 "checked against max_acceleration: give the acceleration")
            self.check_acceleration(acceleration)

    def clip_step(self, velocity: int, acceleration: int) -> tuple[int, int]:
        """A step's words (the chip's largest, so that the desired position jumps) brought
        down to the caps: on a capped axis a "step" is the fastest trapezoid allowed."""
        v, a = self.velocity_word, self.acceleration_word
        return (velocity if v is None else max(1, min(velocity, v)),
                acceleration if a is None else max(1, min(acceleration, a)))

    def describe(self) -> str:
        parts = []
        if self.has_travel:
            lo = "-inf" if self.min is None else str(self.min)
            hi = "+inf" if self.max is None else str(self.max)
            parts.append(f"travel {lo}..{hi} counts")
        if self.max_velocity is not None:
            parts.append(f"max_velocity {self.max_velocity:g} counts/s (word {self.velocity_word})")
        if self.max_acceleration is not None:
            parts.append(f"max_acceleration {self.max_acceleration:g} counts/s^2 "
                         f"(word {self.acceleration_word})")
        return ", ".join(parts) or "no limits"


def clip_step(chip: object, velocity: int, acceleration: int) -> tuple[int, int]:
    """``chip.limits.clip_step`` when the chip has limits, else the words as given."""
    limits = getattr(chip, "limits", None)
    return limits.clip_step(velocity, acceleration) if limits is not None else (velocity,
                                                                                acceleration)


__all__ = ["SoftLimits", "clip_step"]
