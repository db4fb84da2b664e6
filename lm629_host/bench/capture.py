"""Step and move responses for tuning: desired and actual position over time, CSV and PNG.

The picture of AN-706 figure 11 from the user's own motor: load a filter, start a move (a
"step" is a move with acceleration and velocity so large that the desired position jumps), and
take a :meth:`LM629.snapshot` every ``interval_s`` of the chip's clock for ``duration_s``.
Times in the capture are the transport clock's (simulated time on ``sim://``), relative to the
STT.  matplotlib is optional (``pip install 'lm629-host[plot]'``); without it the CSV is still
written and :class:`PlotUnavailable` says how to get the picture.
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from lm629_host.errors import MotionError
from lm629_host.chip.lm629 import LM629
from lm629_host.bus.snapshot import Snapshot
from lm629_host.errors import check_int
from lm629_host.chip.move import MoveResult
from lm629_host.physics.pid import STEP_ACCELERATION, STEP_VELOCITY
from lm629_host.chip.recording import far_snapshots
from lm629_host.chip.safety import stop_on_error
from lm629_host.physics.units import FIXED_ONE

CSV_COLUMNS = ("t_s", "desired_position", "real_position", "following_error",
               "desired_velocity", "real_velocity", "integration_sum", "status")


class PlotUnavailable(RuntimeError):
    """matplotlib is not installed: the CSV was written, the PNG was not."""


@dataclass
class Capture:
    """A recorded response: snapshots with times relative to the STT."""

    target: int
    filter: dict[str, int]
    velocity: int
    acceleration: int
    rows: list[Snapshot] = field(default_factory=list)
    t0: float = 0.0
    #: after the recording: where the shaft came to rest (``check=True``), or the fault
    result: MoveResult | None = None
    fault: MotionError | None = None
    #: True when the rows were recorded on the far side (:mod:`lm629_host.chip.recording`)
    recorded: bool = False

    def times(self) -> list[float]:
        return [s.time - self.t0 for s in self.rows]

    @property
    def max_following_error(self) -> int:
        return max((s.following_error for s in self.rows), key=abs, default=0)

    @property
    def overshoot(self) -> int:
        """Counts the shaft went past the target (in the direction of the move), >= 0."""
        if not self.rows:
            return 0
        start = self.rows[0].real_position
        sign = 1 if self.target >= start else -1
        return max(0, max(sign * (s.real_position - self.target) for s in self.rows))

    @property
    def final_error(self) -> int:
        return self.target - self.rows[-1].real_position if self.rows else 0


def capture_move(chip: LM629, distance: int, *, duration_s: float = 0.5,
                 interval_s: float = 0.001, velocity: int = STEP_VELOCITY,
                 acceleration: int = STEP_ACCELERATION, filter: dict[str, int] | None = None,
                 progress: Callable[[Snapshot], None] | None = None, check: bool = True,
                 tolerance: int | None = None) -> Capture:
    """Load ``filter`` (kp/ki/kd/il/derivative_interval; UDF), move ``distance`` counts from
    the current desired position (:meth:`LM629.move_to`: the move's flags cleared as it
    starts), and record snapshots every ``interval_s`` for ``duration_s`` seconds of the
    chip's clock: on the far side where the transport records there
    (:func:`lm629_host.chip.recording.far_snapshots`: timed by the bridge, from one interval after
    the STT), else polled from the host.  With ``check`` (default) then wait until the shaft rests within
    ``tolerance`` of the target (``Move.wait``): ``cap.result``, or ``cap.fault`` (a
    :class:`MotionError`, motor stopped) so that the caller can still save the recording.
    Any other exception stops the motor first."""
    if not (isinstance(duration_s, (int, float)) and duration_s > 0 and duration_s < 1e6):
        raise ValueError(f"duration_s={duration_s} must be > 0 seconds")
    if not (isinstance(interval_s, (int, float)) and 0 < interval_s <= duration_s):
        raise ValueError(f"interval_s={interval_s} must be > 0 and at most duration_s={duration_s}")
    check_int("distance", distance, -(1 << 30), (1 << 30) - 1)
    check_int("velocity", velocity, 1, STEP_VELOCITY)
    check_int("acceleration", acceleration, 1, STEP_ACCELERATION)
    filt = dict(filter or {})
    program = chip.filter_program(**filt) if filt else None  # validate before any traffic
    chip.trajectory_program(acceleration=acceleration, velocity=velocity, position=0)
    if chip.is_moving():
        raise ValueError("the motor is moving: a step response starts from rest (and the chip "
                         "refuses a new acceleration during a move); `lm629 stop --smooth` first")
    # the target (from the desired position: a read, which moves nothing) checked against the
    # soft limits before anything is sent: a refused step leaves the axis as it was, holding
    # (checked inside stop_on_error it turned the motor off, after loading the filter)
    first = chip.snapshot()
    target = first.desired_position + distance
    chip.trajectory_program(position=target)
    with stop_on_error(chip):
        if program is not None:
            chip.load_filter(**filt)
            chip.update_filter()
        cap = Capture(target, filt, velocity, acceleration)
        move = chip.move_to(target, velocity=velocity, acceleration=acceleration)
        cap.t0 = move.t0
        cap.rows.append(first)
        end = cap.t0 + duration_s
        clock = chip.clock
        # recorded on the far side where the transport can (the bridge's timer, the
        # simulator's clock: lm629_host.chip.recording), from one interval after the STT
        clock.sleep(max(0.0, cap.t0 + interval_s - clock.now()))
        recorded = far_snapshots(chip, interval_s, max(1, round(duration_s / interval_s)))
        if recorded is not None:
            cap.recorded = True
            for s in recorded:
                cap.rows.append(s)
                if progress is not None:
                    progress(s)
        next_t = cap.t0
        while recorded is None:  # host polling, as on a transport that cannot record
            next_t += interval_s
            wait = next_t - clock.now()
            if wait > 0:
                clock.sleep(wait)
            s = chip.snapshot()
            cap.rows.append(s)
            if progress is not None:
                progress(s)
            if s.time >= end:
                break
        if check:
            profile = move.profile_s(move.clock_hz_for(chip.move_rules)) or 0.0
            try:
                cap.result = move.wait(timeout=duration_s + 1.5 * profile
                                       + chip.move_rules.settle_timeout + 1.0,
                                       tolerance=tolerance)
            except MotionError as exc:
                cap.fault = exc
    return cap


def write_csv(cap: Capture, path: str | Path) -> Path:
    """One row per snapshot; velocities in counts/sample (desired: 16.16 converted)."""
    path = Path(path)
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(CSV_COLUMNS)
        for t, s in zip(cap.times(), cap.rows):
            w.writerow([f"{t:.6f}", s.desired_position, s.real_position, s.following_error,
                        f"{s.desired_velocity / FIXED_ONE:.5f}", s.real_velocity,
                        s.integration_sum, f"{int(s.status):02X}"])
    return path


def read_csv(path: str | Path) -> list[dict[str, str]]:
    with Path(path).open(newline="") as f:
        return list(csv.DictReader(f))


def summary(cap: Capture) -> Sequence[str]:
    """The figures a tuner looks at, one per line."""
    lines = [f"target {cap.target} counts, {len(cap.rows)} samples over "
             f"{cap.times()[-1] * 1e3:.1f} ms",
             f"largest following error {cap.max_following_error:+d} counts, overshoot "
             f"{cap.overshoot} counts, final error {cap.final_error:+d} counts"]
    if cap.result is not None:
        lines.append(f"at rest {cap.result.error:+d} counts from the target, "
                     f"{cap.result.duration:.3f} s after the start")
    return lines


__all__ = ["Capture", "capture_move", "write_csv", "read_csv", "summary",
           "PlotUnavailable", "CSV_COLUMNS"]
