"""Typed commands whose effect needs the motion model: STT refusals, signed reads, snapshot."""

from __future__ import annotations

import pytest

from lm629_host import CommandError, Status


def test_every_refused_stt_raises_even_with_a_stale_command_error_flag(open_chip, recorder):
    """AN-706 6.5.1: a relative velocity that would go negative is a command error.  The second
    refusal must be reported too, although the flag is still set from the first."""
    chip = open_chip("sim://")
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=100, velocity=65536, velocity_mode=True)
    chip.start()
    for _ in range(2):
        chip.load_trajectory(velocity=-2 * 65536, velocity_relative=True)
        with pytest.raises(CommandError, match="STT"):
            chip.start()
        assert Status.COMMAND_ERROR in chip.read_status()
    recorder.clear()
    chip.load_trajectory(stop="smooth")
    chip.start()  # accepted: clears the stale flag first (RSTI keeping all but bit 1)
    assert recorder.data() == [("command", 0x1F), ("write", 0x0400),  # LTRJ stop smoothly
                               ("command", 0x1D), ("write", 0x007C), ("command", 0x01)]
    assert Status.COMMAND_ERROR not in chip.read_status()


def test_clean_start_sends_no_rsti(open_chip, recorder):
    chip = open_chip("sim://")
    chip.reset()
    recorder.clear()
    chip.start()
    assert recorder.data() == [("command", 0x01)]


def test_negative_positions_and_velocities_read_back_signed(open_chip):
    chip = open_chip("sim://")
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=200, velocity=3 * 65536, position=-1500, start=True)
    chip.clock.sleep(0.05)
    snap = chip.snapshot()
    assert snap.desired_velocity < 0 and snap.desired_position < 0
    assert snap.desired_position == chip.read_desired_position() or snap.desired_position > -1500
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=5)
    assert chip.read_desired_position() == -1500
    assert abs(chip.read_real_position() + 1500) <= 13  # kp = 20 dead band: 256/20 counts
