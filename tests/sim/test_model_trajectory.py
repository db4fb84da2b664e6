"""The trajectory generator against sequences worked out by hand in the chip's fixed point.

Units: positions in counts (the generator keeps 1/65536 count), velocity 16.16 counts/sample,
acceleration 16.16 counts/sample^2.  ONE = 65536 = 1 count (per sample, per sample^2).
"""

from __future__ import annotations

import pytest

from lm629_host.bus.opcodes import FIXED_ONE as ONE
from lm629_host.sim.model.trajectory import (
    Trajectory,
    landing_velocity,
    stop_distance,
    wrap_counts,
)


def move(target: int, a: int, v: int, position: int = 0, steps: int = 10_000) -> tuple[list, list, int]:
    """Run a position move; return desired positions (fixed point), velocities, finishing step."""
    t = Trajectory()
    t.position, t.acceleration, t.max_velocity, t.target, t.done = position << 16, a, v, target, False
    positions, velocities = [], []
    for n in range(1, steps + 1):
        finished, _ = t.step()
        positions.append(t.position)
        velocities.append(t.velocity)
        if finished:
            return positions, velocities, n
    raise AssertionError("move did not finish")


def test_stop_distance_is_the_sum_of_the_ramp_down():
    # from 3 counts/sample at 1: 2 + 1 = 3 counts; from 2.5 at 1: 1.5 + 0.5 = 2 counts
    assert stop_distance(3 * ONE, ONE) == 3 * ONE
    assert stop_distance(5 * ONE // 2, ONE) == 2 * ONE
    assert stop_distance(ONE, ONE) == 0
    assert stop_distance(0, ONE) == 0


def test_landing_velocity_solves_v_plus_ramp_equals_distance():
    # 5 counts at a = 1: v + (v-1) + (v-2) = 5 -> v = 8/3 (rounded down in 1/65536)
    assert landing_velocity(5 * ONE, ONE) == (8 * ONE) // 3 == 174762
    # 1 count left at a = 1: one step of exactly 1 count
    assert landing_velocity(ONE, ONE) == ONE
    for r in (1, 7, ONE, 3 * ONE + 5, 1000 * ONE):
        for a in (1, 100, ONE // 3, ONE):
            v = landing_velocity(r, a)
            assert v + stop_distance(v, a) <= r < (v + 1) + stop_distance(v + 1, a) + a


def test_trapezoid_sample_by_sample():
    """a = 1, v = 2, target 10: 1, 3, 5, 7, 9, 10 - accelerate, cruise, one step down, exact."""
    positions, velocities, n = move(10, ONE, 2 * ONE)
    assert [p >> 16 for p in positions] == [1, 3, 5, 7, 9, 10]
    assert positions[-1] == 10 * ONE  # exactly on target, no fraction left
    assert velocities == [ONE, 2 * ONE, 2 * ONE, 2 * ONE, 2 * ONE, 0]
    assert n == 6


def test_deceleration_point_and_exact_landing():
    """a = 1, v = 3, target 20.

    Cruise at 3 while the ramp down from 3 (2 + 1 = 3 counts) still fits after the step:
    1, 3, 6, 9, 12, 15.  At 15 (5 left) a step of 3 leaves 2 < 3: the deceleration point.
    The landing velocity solves v + (v-1) + (v-2) = 5: v = 8/3 = 174762/65536, then 109227
    (= (152918 + 65536) // 2 for the 152918/65536 left), then the last 43691 lands on 20.
    """
    positions, velocities, n = move(20, ONE, 3 * ONE)
    assert [p >> 16 for p in positions] == [1, 3, 6, 9, 12, 15, 17, 19, 20]
    assert velocities == [ONE, 2 * ONE, 3 * ONE, 3 * ONE, 3 * ONE, 3 * ONE, 174762, 109227, 0]
    assert positions[6] == 15 * ONE + 174762
    assert positions[-1] == 20 * ONE
    # never slows by more than the acceleration
    assert all(abs(b - a) <= ONE for a, b in zip(velocities, velocities[1:-1]))


@pytest.mark.parametrize("target, expected", [(4, [1, 3, 4]), (5, [1, 3, 4, 5]), (-4, [-1, -3, -4])])
def test_triangle_profiles(target, expected):
    """v = 10 is never reached: target 4 -> velocities 1, 2 then the last count; target 5 -> 1, 2,
    3/2 then 1/2 (4.5 -> 5); negative moves mirror."""
    positions, velocities, n = move(target, ONE, 10 * ONE)
    assert [p >> 16 for p in positions] == expected
    assert positions[-1] == target * ONE
    if target == 5:
        assert velocities == [ONE, 2 * ONE, 3 * ONE // 2, 0]


def test_small_acceleration_long_move_ends_exactly():
    """AN-706 2.12 values: a = v = 100 (0.0015 counts/sample), here over 100 counts."""
    positions, velocities, n = move(100, 100, 100, steps=200_000)
    assert positions[-1] == 100 * ONE
    assert max(velocities) == 100
    # 100 counts at 100/65536 counts/sample = 65,536 samples; the one-sample ramps at a = v
    # cost half a sample each way
    assert abs(n - 65_536) <= 2


def test_velocity_mode_ramps_both_ways_and_reverses():
    t = Trajectory()
    t.acceleration, t.max_velocity, t.velocity_mode, t.forward, t.done = ONE // 2, ONE, True, True, False
    for _ in range(2):
        t.step()
    assert t.velocity == ONE and t.position == ONE // 2 + ONE
    t.forward = False  # LTRJ + STT with bit 12 clear: ramp down through zero and back up
    seen = []
    for _ in range(4):
        t.step()
        seen.append(t.velocity)
    assert seen == [ONE // 2, 0, -ONE // 2, -ONE]


def test_smooth_stop_ramps_down_abrupt_stop_holds():
    t = Trajectory()
    t.acceleration, t.max_velocity, t.velocity_mode, t.forward, t.done = ONE, 3 * ONE, True, True, False
    for _ in range(3):
        t.step()
    assert t.velocity == 3 * ONE and t.position >> 16 == 6
    t.stop_smoothly()
    steps = [t.step() for _ in range(3)]
    assert [s[0] for s in steps] == [False, False, True]
    assert t.position >> 16 == 6 + 2 + 1 + 0 and t.done
    t2 = Trajectory()
    t2.acceleration, t2.max_velocity, t2.velocity_mode, t2.forward, t2.done = ONE, 3 * ONE, True, True, False
    for _ in range(3):
        t2.step()
    t2.stop_abruptly()
    assert t2.step() == (True, False)
    assert t2.position >> 16 == 6 and t2.velocity == 0


def test_wraparound_one_count_past_3fffffff_is_c0000000():
    t = Trajectory()
    t.position = (0x3FFFFFFF << 16)
    t.acceleration, t.max_velocity, t.velocity_mode, t.forward, t.done = ONE, ONE, True, True, False
    finished, wrapped = t.step()
    assert wrapped and t.position >> 16 == -0x40000000  # C0000000
    t.forward = False
    t.velocity = 0  # (as after a stop) one count back: below C0000000 is 3FFFFFFF
    finished, wrapped = t.step()
    assert wrapped and t.position >> 16 == 0x3FFFFFFF
    finished, wrapped = t.step()
    assert not wrapped and t.position >> 16 == 0x3FFFFFFE


def test_position_move_across_the_wraparound_goes_the_short_way():
    positions, _, n = move(wrap_counts(0x3FFFFFFF + 3), ONE, 2 * ONE, position=0x3FFFFFFF - 2)
    # 5 counts from 3FFFFFFD to C0000002: steps 1, 2, then 3/2 and 1/2 to land exactly
    assert [p >> 16 for p in positions] == [0x3FFFFFFE, -0x40000000, -0x40000000 + 1,
                                            -0x40000000 + 2]
    assert positions[-1] == (-0x40000000 + 2) * ONE
    assert n == 4


def test_target_moved_behind_is_overshot_then_approached():
    t = Trajectory()
    t.acceleration, t.max_velocity, t.target, t.done = ONE, 4 * ONE, 100, False
    for _ in range(4):
        t.step()
    assert t.velocity == 4 * ONE and t.position >> 16 == 10
    t.target = 12  # 2 counts ahead; the ramp from 4 needs 3 + 2 + 1 = 6
    trace = []
    for _ in range(40):
        finished, _ = t.step()
        trace.append(t.position >> 16)
        if finished:
            break
    assert finished and t.position == 12 * ONE
    assert max(trace) == 10 + 3 + 2 + 1  # ran on at the programmed deceleration
    assert all(abs(b - a) <= 4 for a, b in zip(trace, trace[1:]))


def test_define_home_shifts_target_with_position():
    t = Trajectory()
    t.position, t.target = (500 << 16) + 123, 800
    assert t.define_home() == 500
    assert t.position == 123 and t.target == 300
