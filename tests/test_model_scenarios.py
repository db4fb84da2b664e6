"""Motion scenarios on ``sim://``, through the public LM629 API only.

Numbers: 8 MHz -> one sample T = 256 us; 16.16 words, ONE = 65536 = 1 count/sample; the
default motor has a 500-line encoder (2000 counts/rev).  With 8-bit output the filter's
output is the top byte of u = kp e, so at kp = 20 the drive is 0 for 0 <= e < 256/20 = 12.8
counts (AN-706 5.2.4): the dead band within which a P-only loop leaves the shaft.
"""

from __future__ import annotations

import pytest

from lm629_host import CommandError, Signals, Status

ONE = 65536
T = 2048 / 8e6


def open_move(open_chip, params: str = "", **filt):
    chip = open_chip(f"sim://?strict=1{'&' + params if params else ''}")
    chip.reset()
    if filt:
        chip.load_filter(**filt)
        chip.update_filter()
    return chip


def test_an706_bringup_1000_counts_settles_on_target(open_chip):
    """AN-706 2.12: kp = 20, acceleration = velocity = 100, a 1000-count move.

    At 100/65536 counts/sample the cruise takes 1000 * 65536 / 100 = 655,360 samples
    = 167.77 s; the one-sample ramps add half a sample each.
    """
    chip = open_move(open_chip, kp=20)
    t0 = chip.clock.now()
    chip.load_trajectory(acceleration=100, velocity=100, position=1000, start=True)
    assert not chip.read_status() & Status.TRAJECTORY_COMPLETE
    status = chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=200, poll=0.25)
    elapsed = chip.clock.now() - t0
    assert 655_360 * T - 0.01 < elapsed < 655_360 * T + 0.26
    assert not status & Status.MOTOR_OFF
    chip.clock.sleep(0.5)  # let the shaft settle
    assert chip.read_desired_position() == 1000
    real = chip.read_real_position()
    assert 1000 - 13 < real <= 1000  # inside the kp = 20 dead band, never past the target
    assert chip.read_real_velocity() == 0
    assert chip.read_signals() & Signals.ON_TARGET


def test_reversed_leads_at_kp1_run_away(open_chip):
    """AN-706 2.12's phasing check.  At kp = 1 one output step needs e = 256 counts; a move at
    2 counts/sample gets there in about 130 samples.  Correct leads follow; reversed leads
    drive the shaft the other way and the following error grows without bound."""
    results = {}
    for params in ("", "reversed=1"):
        chip = open_move(open_chip, params, kp=1)
        chip.load_trajectory(acceleration=ONE // 8, velocity=2 * ONE, position=4000, start=True)
        chip.clock.sleep(0.3)
        results[params] = (chip.read_desired_position(), chip.read_real_position())
    desired, real = results[""]
    assert 0 < real < desired
    desired, real = results["reversed=1"]
    assert real < -500  # ran the wrong way within 0.3 s
    assert desired - real > 2000


def test_velocity_mode_direction_and_smooth_stop(open_chip):
    chip = open_move(open_chip, kp=400, kd=2000)
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE, velocity_mode=True, forward=True,
                         start=True)
    sig = chip.read_signals()
    assert sig & Signals.VELOCITY_MODE and sig & Signals.FORWARD
    chip.clock.sleep(0.5)  # ramp: 100 samples = 25.6 ms
    assert chip.read_desired_velocity() == ONE
    assert chip.read_real_velocity() in (0, 1, 2)
    assert abs(chip.read_desired_position() - chip.read_real_position()) < 50
    # reverse on the fly: ramps through zero to -1 count/sample
    chip.load_trajectory(velocity_mode=True, forward=False, start=True)
    assert not chip.read_signals() & Signals.FORWARD
    chip.clock.sleep(0.5)
    assert chip.read_desired_velocity() == -ONE
    assert chip.read_real_velocity() in (0, -1, -2)
    # on-the-fly velocity change, still backwards
    chip.load_trajectory(velocity=ONE // 2, velocity_mode=True, forward=False, start=True)
    chip.clock.sleep(0.2)
    assert chip.read_desired_velocity() == -ONE // 2
    chip.reset_interrupts()
    chip.load_trajectory(stop="smooth", start=True)
    # from 1/2 count/sample at 1/100 per sample: 50 samples
    chip.clock.sleep(49 * T)
    assert not chip.read_status() & Status.TRAJECTORY_COMPLETE
    chip.clock.sleep(3 * T)
    assert chip.read_status() & Status.TRAJECTORY_COMPLETE
    assert chip.read_desired_velocity() == 0
    held = chip.read_desired_position()
    chip.clock.sleep(0.2)
    assert chip.read_desired_position() == held


def test_abrupt_stop_holds_and_stt_resumes_to_the_original_target(open_chip):
    chip = open_move(open_chip, kp=400, kd=2000)
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE, position=3000, start=True)
    chip.clock.sleep(0.5)
    chip.load_trajectory(stop="abrupt", start=True)
    chip.clock.sleep(2 * T)
    assert chip.read_desired_velocity() == 0
    stopped = chip.read_desired_position()
    assert 0 < stopped < 3000
    assert chip.read_status() & Status.TRAJECTORY_COMPLETE
    chip.clock.sleep(0.3)
    assert chip.read_desired_position() == stopped
    chip.reset_interrupts()
    chip.start()  # AN-706 6.3.1: on toward the original target
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=5, poll=0.01)
    assert chip.read_desired_position() == 3000


def test_motor_off_desired_follows_real_and_stt_resumes(open_chip):
    chip = open_move(open_chip, "coulomb=0.002", kp=400, kd=2000)
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE, position=3000, start=True)
    chip.clock.sleep(0.3)
    chip.reset_interrupts()
    chip.load_trajectory(stop="off", start=True)
    status = chip.read_status()
    assert status & Status.MOTOR_OFF and status & Status.TRAJECTORY_COMPLETE
    chip.clock.sleep(0.3)  # the shaft coasts to a stop
    assert chip.read_desired_position() == chip.read_real_position()
    assert chip.read_desired_velocity() == 0
    chip.reset_interrupts()
    chip.start()  # AN-706 6.3.3: loop closed, on to the target from where the shaft is
    assert not chip.read_status() & Status.MOTOR_OFF
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=5, poll=0.01)
    assert chip.read_desired_position() == 3000


def test_breakpoint_absolute_and_relative(open_chip):
    """Desired position reaches the breakpoint: status bit 6 (and HI when unmasked)."""
    chip = open_move(open_chip, "stall=1")  # no filter: only the generator matters here
    chip.set_breakpoint(500)
    chip.reset_interrupts()
    chip.mask_interrupts(Status.BREAKPOINT)
    chip.load_trajectory(acceleration=ONE, velocity=ONE, position=1000, start=True)
    # 1 count/sample from the first sample: 500 is reached at sample 500
    chip.clock.sleep(495 * T)
    assert not chip.read_status() & Status.BREAKPOINT
    chip.clock.sleep(10 * T)
    assert chip.read_status() & Status.BREAKPOINT
    assert chip.read_signals() & Signals.HOST_INTERRUPT
    assert 500 <= chip.read_desired_position() <= 510
    # relative to the target: 1000 - 100 = 900
    chip.set_breakpoint(-100, relative=True)
    chip.reset_interrupts()
    chip.clock.sleep(380 * T)  # desired about 890
    assert not chip.read_status() & Status.BREAKPOINT
    chip.clock.sleep(20 * T)
    assert chip.read_status() & Status.BREAKPOINT


def test_position_error_lpei_flags_lpes_stops(open_chip):
    """Rotor locked; desired runs at 1 count/sample, so e(n) = n and e > 100 at sample 101."""
    chip = open_move(open_chip, "stall=1", kp=20)
    chip.load_position_error(100, stop=False)  # LPEI
    chip.load_trajectory(acceleration=ONE, velocity=ONE, position=1000, start=True)
    chip.clock.sleep(98 * T)
    assert not chip.read_status() & Status.POSITION_ERROR
    chip.clock.sleep(6 * T)
    status = chip.read_status()
    assert status & Status.POSITION_ERROR and not status & Status.MOTOR_OFF
    assert not chip.read_signals() & Signals.STOP_ON_ERROR
    # LPES: the same, and the motor goes off (desired then follows the locked rotor)
    chip = open_move(open_chip, "stall=1", kp=20)
    chip.load_position_error(100, stop=True)
    assert chip.read_signals() & Signals.STOP_ON_ERROR
    chip.load_trajectory(acceleration=ONE, velocity=ONE, position=1000, start=True)
    chip.clock.sleep(98 * T)
    assert not chip.read_status() & Status.MOTOR_OFF
    chip.clock.sleep(6 * T)
    status = chip.read_status()
    assert status & Status.POSITION_ERROR and status & Status.MOTOR_OFF
    assert status & Status.TRAJECTORY_COMPLETE
    chip.clock.sleep(2 * T)
    assert chip.read_desired_position() == chip.read_real_position() == 0


def test_wraparound_both_ways(open_chip):
    """Maximum velocity 3FFFFFFF (16384 - 1/65536 counts/sample) from 0: the desired position
    passes 3FFFFFFF at sample ceil(2^46 / 3FFFFFFF) = 65537 (16.777 s), RDDP then negative."""
    chip = open_move(open_chip, "stall=1")
    chip.set_breakpoint(100)
    chip.load_trajectory(acceleration=0x3FFFFFFF, velocity=0x3FFFFFFF, velocity_mode=True,
                         start=True)
    chip.clock.sleep(65530 * T)
    assert chip.read_status() & Status.BREAKPOINT  # passed 100 at the first sample
    chip.reset_interrupts()
    assert not chip.read_status() & Status.WRAPAROUND
    assert chip.read_desired_position() > 0x3FF00000
    chip.clock.sleep(10 * T)
    status = chip.read_status()
    assert status & Status.WRAPAROUND
    assert not status & Status.BREAKPOINT  # the jump from 3FFFFFFF to C0000000 is one count
    assert chip.read_desired_position() < -0x3FF00000
    chip.reset_interrupts()
    chip.load_trajectory(velocity_mode=True, forward=False, start=True)  # back across
    chip.clock.sleep(20 * T)
    assert chip.read_status() & Status.WRAPAROUND
    assert chip.read_desired_position() > 0x3FF00000


def test_index_captured_once_per_sip(open_chip):
    """500 lines, index 1000 counts past zero: RDIP 1000; the next revolution (3000) only after
    another SIP; signals bit 0 shows an armed SIP until the index is seen."""
    chip = open_move(open_chip, "index_offset=1000", kp=400, kd=2000)
    chip.set_index_position()
    assert chip.read_signals() & Signals.ACQUIRE_INDEX
    chip.load_trajectory(acceleration=ONE // 10, velocity=ONE, velocity_mode=True, start=True)
    chip.clock.sleep(0.2)  # about 770 counts
    assert not chip.read_status() & Status.INDEX_PULSE
    chip.wait_for(Status.INDEX_PULSE, timeout=1, poll=0.01)
    assert not chip.read_signals() & Signals.ACQUIRE_INDEX
    assert chip.read_index_position() == 1000
    chip.clock.sleep(0.6)  # past 3000 without a SIP: nothing new latched
    assert chip.read_real_position() > 3000
    assert chip.read_index_position() == 1000
    chip.reset_interrupts()
    chip.set_index_position()
    chip.wait_for(Status.INDEX_PULSE, timeout=1, poll=0.01)
    assert chip.read_index_position() == 5000


def test_command_errors_acceleration_while_moving_and_negative_relative_velocity(open_chip):
    chip = open_move(open_chip, kp=400, kd=2000)
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE, position=5000, start=True)
    chip.clock.sleep(0.1)
    chip.load_trajectory(acceleration=ONE // 50)
    assert chip.read_signals() & Signals.ACCELERATION_LOADED
    with pytest.raises(CommandError):
        chip.start()
    # AN-706 3.3: ignored, and the acceleration stays loaded for later [model choice 13]
    assert chip.read_signals() & Signals.ACCELERATION_LOADED
    assert chip.read_desired_velocity() == ONE  # the move goes on unchanged
    chip.reset_interrupts()
    chip.load_trajectory(stop="off", start=True)  # executes it with the drive off [choice 28]
    assert not chip.read_signals() & Signals.ACCELERATION_LOADED
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE, position=5000, start=True)
    chip.clock.sleep(0.1)
    with pytest.raises(CommandError):
        chip.load_trajectory(velocity=-2 * ONE, velocity_relative=True, start=True)
    chip.reset_interrupts()
    # the refused relative word counts as never loaded [model choice 13]: a relative velocity
    # that stays positive is fine
    chip.load_trajectory(velocity=-ONE // 2, velocity_relative=True, start=True)
    chip.clock.sleep(0.1)
    assert chip.read_desired_velocity() == ONE // 2
    # with the motor off, the acceleration may change
    chip.load_trajectory(stop="off", start=True)
    chip.load_trajectory(acceleration=ONE // 50, start=True)
    assert not chip.read_status() & Status.COMMAND_ERROR


def test_define_home_during_a_move_keeps_the_physical_end(open_chip):
    chip = open_move(open_chip, kp=400, kd=2000)
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE // 4, position=2000, start=True)
    chip.clock.sleep(0.5)
    before = chip.read_desired_position()
    chip.define_home()
    assert chip.read_desired_position() in (0, 1)
    assert abs(chip.read_real_position()) <= 1
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=10, poll=0.01)
    final = chip.read_desired_position()
    assert final in (2000 - before, 2000 - before - 1)


def test_rdsum_sits_at_the_integration_limit_signed(open_chip):
    chip = open_move(open_chip, "stall=1", ki=100, il=500)
    chip.load_trajectory(acceleration=ONE, velocity=ONE, position=200, start=True)
    chip.clock.sleep(0.2)
    assert chip.read_integration_sum() == 500
    chip.load_trajectory(position=-200, start=True)  # acceleration unchanged: allowed
    chip.clock.sleep(1.0)
    assert chip.read_integration_sum() == -500


def test_lm628_12_bit_output_moves_the_motor(open_chip):
    """PORT12: the top 12 bits of u drive the DAC, so kp = 20 gives 16 x the drive of 8-bit."""
    chip = open_chip("sim://?strict=1&chip=lm628", chip="lm628")
    chip.reset()
    chip.port12()
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE // 2, position=2000, start=True)
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=10, poll=0.01)
    chip.clock.sleep(0.5)
    assert chip.read_desired_position() == 2000
    assert abs(chip.read_real_position() - 2000) <= 1  # dead band 16/20 < 1 count


def test_published_register_values_around_a_move(open_chip):
    """The spec's "Observed on real chips": signals 01C0 after reset (no on-target bit),
    status 40 / signals 0140 while moving, status 44 / signals 8544 when the move has ended
    (HI set: reset leaves every interrupt but the breakpoint enabled)."""
    chip = open_chip("sim://?strict=1")
    chip.reset()
    chip.mask_interrupts(Status.COMMAND_ERROR | Status.TRAJECTORY_COMPLETE | Status.INDEX_PULSE
                         | Status.WRAPAROUND | Status.POSITION_ERROR)  # the reset mask, 003E
    chip.clock.sleep(2 * T)
    assert chip.read_status() == 0xC0 and chip.read_signals() == 0x01C0
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=ONE, velocity=ONE, position=200, start=True)
    chip.clock.sleep(2 * T)
    assert chip.read_status() == 0x40 and chip.read_signals() == 0x0140
    chip.clock.sleep(0.5)
    assert chip.read_status() == 0x44 and chip.read_signals() == 0x8544
