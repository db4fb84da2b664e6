"""Motion supervision in the library (lm629_host.chip.supervise): a velocity-mode run watched like
a move (runaway, stall, smooth stop to rest), the index search, waiting until still.

Numbers: at 8 MHz a sample is 256 us; 65536 = 1 count/sample, reached in 100 samples at the
acceleration word 655 (0.01 count/sample^2), 50 counts of ramp; 0.3 s is 1172 samples."""

from __future__ import annotations

import pytest

from lm629_host import MotionError, MotionFault, Status
from lm629_host.chip.supervise import run_velocity, search_index, wait_still


def _ready(chip):
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    return chip


def test_a_velocity_run_turns_at_the_speed_then_stops_smoothly_to_rest(open_chip):
    chip = _ready(open_chip("sim://"))
    run = run_velocity(chip, 65536, 655)
    chip.clock.sleep(0.3)
    s = run.check()
    assert s.desired_velocity == 65536 and s.real_velocity == 1
    # 1172 samples: 50 counts of ramp, then ~1072 at 1 count/sample; a P-only loop (kp = 20)
    # follows a moving target some tens of counts behind
    assert 1120 <= s.desired_position <= 1124
    assert 0 < s.following_error < 100
    rest = run.stop()
    assert rest.real_velocity == 0 and rest.desired_velocity == 0
    assert chip.read_status() & Status.TRAJECTORY_COMPLETE
    # the smooth stop runs 100 samples and 50 counts further; then the loop settles
    assert s.real_position + 40 <= rest.real_position <= s.real_position + 50 + 60
    assert not chip.read_status() & Status.MOTOR_OFF  # a smooth stop holds the position


@pytest.mark.parametrize("url, reason", [("sim://?reversed=1", MotionFault.RUNAWAY),
                                         ("sim://?stall=1", MotionFault.STALL)])
def test_a_velocity_run_that_does_not_turn_as_asked_is_a_fault_with_the_motor_off(
        open_chip, url, reason):
    chip = _ready(open_chip(url))
    run = run_velocity(chip, 65536, 655)
    chip.clock.sleep(0.3)
    with pytest.raises(MotionError) as info:
        run.check()
    assert info.value.reason is reason and "motor stopped" in info.value.detail
    assert chip.read_status() & Status.MOTOR_OFF
    if reason is MotionFault.RUNAWAY:
        assert info.value.position < 0  # it went backwards


def test_below_one_count_per_sample_the_check_cannot_tell_and_says_nothing(open_chip):
    chip = _ready(open_chip("sim://?stall=1"))
    run = run_velocity(chip, 30000, 655)  # 0.46 count/sample: the real velocity reads 0 or 1
    chip.clock.sleep(0.3)
    assert run.check().real_position == 0


def test_the_index_search_returns_the_latched_position_and_leaves_the_shaft_at_rest(open_chip):
    chip = _ready(open_chip("sim://?index_offset=500"))
    assert search_index(chip, 65536, timeout=2.0) == 500
    s = chip.snapshot()
    assert s.real_velocity == 0 and s.desired_velocity == 0 and s.real_position > 500


def test_wait_still_is_timed_on_the_clock_not_counted_in_polls(open_chip):
    """The same 50 ms of stillness with a 2 ms poll and a 20 ms poll."""
    for poll in (0.002, 0.02):
        chip = _ready(open_chip("sim://"))
        chip.move_to(300, velocity=65536, acceleration=655)
        start = chip.clock.now()
        s = wait_still(chip, 2.0, poll=poll)
        assert s.real_velocity == 0 and abs(s.real_position - 300) <= 14
        # the move's profile alone is 400 samples (0.1 s); then at least 50 ms still
        assert s.time - start >= 0.1 + 0.05
