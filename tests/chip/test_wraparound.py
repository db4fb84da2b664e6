"""Positions across the position register's wraparound (AN-706 6.5.2), end to end.

The register holds C0000000..3FFFFFFF; ``sim://?reset_position=`` (model choice 33) starts it
near 3FFFFFFF so that a run crosses in simulated milliseconds.  The run crosses the boundary
forward three times and backward twice (velocity mode, turning round on each side), and every
position read is checked against the travel: monotonic within a leg, and the recorded real
velocity integrated over a recording across the wrap matches the extended position.
"""

from __future__ import annotations

import pytest

import lm629_host
from lm629_host.errors import ArgumentError
from lm629_host.physics.limits import SoftLimits
from lm629_host.bus.opcodes import POSITION_MAX, POSITION_MIN, Status
from lm629_host.physics.pid import sample_period_s
from lm629_host.chip.wraparound import PositionTracker, short_way

from sim_urls import UNO, ready_chip

#: 2000 counts below the top of the register
NEAR_TOP = POSITION_MAX - 2000
#: the velocity word of the run: 12 counts/sample, ~47000 counts/s at 8 MHz
SPEED = 12 * 65536
ACCEL = 2000

WRAP_URLS = ("sim://", "sim+avr://?baud=1000000", f"sim+emu://?{UNO}")


def _open(url: str) -> lm629_host.LM629:
    return ready_chip(url, f"reset_position={NEAR_TOP}")


def _leg(chip: lm629_host.LM629, forward: bool, beyond: int, seen: list[int]) -> None:
    """Velocity mode one way until the extended real position is ``beyond`` counts past the
    boundary at 2^30 (``forward``) or ``beyond`` counts before it; every read monotonic."""
    chip.load_trajectory(velocity=SPEED, velocity_mode=True, forward=forward, start=True)
    goal = POSITION_MAX + 1 + (beyond if forward else -beyond)
    while True:
        chip.clock.sleep(0.01)
        p = chip.read_real_position()
        if len(seen) > 1:
            # monotonic with the travel once the turn-round (the deceleration) is over
            direction = 1 if forward else -1
            if (p - seen[-1]) * direction < 0:
                assert (seen[-1] - seen[-2]) * direction <= 0, \
                    f"position went back: {seen[-2]} {seen[-1]} {p}"
        seen.append(p)
        if (p - goal) * (1 if forward else -1) >= 0:
            return


@pytest.mark.parametrize("url", WRAP_URLS)
def test_velocity_run_crosses_the_wrap_both_ways_without_a_jump(url):
    chip = _open(url)
    with chip:
        assert chip.read_real_position() == NEAR_TOP  # the register near 3FFFFFFF
        chip.load_trajectory(acceleration=ACCEL)
        seen: list[int] = [chip.read_real_position()]
        crossings = []
        for forward in (True, False, True, False):
            before = chip.positions.wraps
            _leg(chip, forward, 3000, seen)
            crossings.append(chip.positions.wraps - before)
            # the host noted the wrap and cleared status bit 4 with RSTI: it reads clear now
            chip.read_real_position()
            assert not chip.read_status() & Status.WRAPAROUND
        # each leg crossed the boundary once (desired position: status bit 4)
        assert crossings == [1, 1, 1, 1]
        # the extended position went past 3FFFFFFF and back, by at most one leg's overshoot:
        # no jump of 2^31 anywhere
        steps = [b - a for a, b in zip(seen, seen[1:])]
        assert max(abs(s) for s in steps) < 20_000
        assert max(seen) > POSITION_MAX + 3000 and min(seen) < POSITION_MAX - 3000 + 1
        # the third forward crossing, recorded (the bridge's timer on a bridge): no jump, and
        # the extended position is the integral of the recorded velocity within 0.1 %
        before = chip.positions.wraps
        chip.load_trajectory(velocity=SPEED, velocity_mode=True, forward=True, start=True)
        trace = chip.record(1e-3, 2.0, full=True)
        chip.load_trajectory(stop="smooth", start=True)
        chip.read_real_position()
        assert chip.positions.wraps == before + 1
        assert not chip.read_status() & Status.WRAPAROUND
        real = trace.real
        assert real[0] <= POSITION_MAX < real[-1], "the recording did not cross the wrap"
        assert all(abs(b - a) < 100 for a, b in zip(real, real[1:]))  # ~47 counts a row
        sample_s = sample_period_s(chip.clock_hz)
        # the recorded velocities integrated over the rows' own times: the desired one
        # (16.16 counts/sample) gives the desired position's travel, the real one (whole
        # counts over the last sample) the real position's, each within 0.1 %
        rows = trace.rows
        for position, speed, scale in (("desired", "desired_velocity", 65536),
                                       ("real", "real_velocity", 1)):
            integral = sum((getattr(a, speed) + getattr(b, speed)) / 2 / scale * (b.t - a.t)
                           / sample_s for a, b in zip(rows, rows[1:]))
            travel = getattr(rows[-1], position) - getattr(rows[0], position)
            assert travel > 80_000
            assert abs(integral - travel) <= 1e-3 * travel, (position, integral, travel)


def test_tracker_extends_the_short_way_and_restarts():
    t = PositionTracker()
    assert t.extend("real", POSITION_MAX - 5) == POSITION_MAX - 5
    assert t.extend("real", POSITION_MIN + 4) == POSITION_MAX + 5  # 10 counts forward
    assert t.extend("real", POSITION_MAX) == POSITION_MAX  # back again
    assert t.extend("real", POSITION_MIN) == POSITION_MAX + 1
    # a first read of the desired position starts next to the real one
    assert t.extend("desired", POSITION_MAX) == POSITION_MAX  # the real one: one count ahead
    t.restart()
    assert t.extend("real", 7) == 7
    assert short_way(2 ** 31 + 3) == 3 and short_way(2 ** 30) == POSITION_MIN


def test_targets_beyond_the_register_are_refused_with_its_range():
    with lm629_host.open("sim://") as chip:
        chip.reset()
        before = chip.transport.stats.programs
        for bad in (POSITION_MAX + 1, POSITION_MIN - 1, 2 ** 40):
            with pytest.raises(ArgumentError, match=r"-1073741824\.\.1073741823 "
                                                    r"\(0xC0000000\.\.0x3FFFFFFF\)") as exc:
                chip.move_to(bad, velocity=65536, acceleration=100)
            assert exc.value.argument == "position"
        assert chip.transport.stats.programs == before  # nothing reached the bus


def test_move_across_the_wrap_ends_on_the_extended_target():
    """A relative move from just below 3FFFFFFF ends 3000 counts on: the target, the result
    and the soft limits all in extended counts."""
    with lm629_host.open(f"sim://?reset_position={NEAR_TOP}") as chip:
        chip.reset()
        chip.load_filter(kp=20, kd=100)
        chip.update_filter()
        chip.limits = SoftLimits(min=NEAR_TOP - 10, max=NEAR_TOP + 3100)
        move = chip.move_to(3000, velocity=4 * 65536, acceleration=200, relative=True)
        assert move.target == NEAR_TOP + 3000
        result = move.wait()
        assert result.target == NEAR_TOP + 3000
        assert abs(result.position - (NEAR_TOP + 3000)) <= 20
        assert chip.read_desired_position() == NEAR_TOP + 3000
        # the limit is extended counts: 200 more is past max = NEAR_TOP + 3100
        with pytest.raises(ValueError, match="above the soft limit max"):
            chip.move_to(200, velocity=4 * 65536, relative=True)
        # an absolute register value is reached the short way: 0x3FFFFFFF is 1001 back
        move = chip.move_to(POSITION_MAX, velocity=4 * 65536)
        assert move.target == POSITION_MAX
        move.wait()
        assert chip.read_desired_position() == POSITION_MAX


def test_a_boards_snapshots_cross_the_wrap_without_a_jump():
    """Two axes turning from just below 3FFFFFFF: the board's snapshots (one program for both
    chips) read extended positions past the boundary, each as that axis's own read does, and
    never step back across it."""
    with lm629_host.open_board(f"sim://?axes=2&reset_position={NEAR_TOP}") as board:
        board.reset()
        for ax in board.axes:
            ax.load_filter(kp=20, kd=100)
            ax.update_filter()
            ax.load_trajectory(acceleration=ACCEL, velocity=SPEED, velocity_mode=True,
                               start=True)
        last = [NEAR_TOP, NEAR_TOP]
        for _ in range(30):  # 0.3 s at 12 counts/sample: about 14000 counts, past the top
            board.clock.sleep(0.01)
            snaps = board.snapshots()
            for k, s in enumerate(snaps):
                assert s.real_position >= last[k] - 2, (k, last[k], s.real_position)
                last[k] = s.real_position
        assert all(p > POSITION_MAX + 5000 for p in last), last  # past 3FFFFFFF: no -2^31
        for ax, p in zip(board.axes, last):
            assert 0 <= ax.read_real_position() - p < 2000  # its own read agrees
            ax.load_trajectory(stop="abrupt", start=True)
