"""Motion scenarios through the public LM629 API only: first on ``sim://``, then (from
"restarts after stops") on every simulated transport.

The scenarios on every transport (restarts after stops and motor off, RSTI, the plant
through reset, the index at start, violations with their time, buffered and relative
parameters, the RESET command's duration, out-of-range words, the P-only rest position) run on
``sim://`` (the model strobed directly) and through real far-end code: ``sim+emu://`` (the
Python bridge far end), ``sim+avr://`` (the compiled bridge firmware in simavr) and
``sim+ftdi://`` (pyftdi on the emulated FT232H): the ``transport_url`` fixture.  The model
choices cited are items of the list in ``lm629_host/sim/model/__init__.py``.

Numbers: 8 MHz -> one sample T = 256 us; 16.16 words, ONE = 65536 = 1 count/sample; the
default motor has a 500-line encoder (2000 counts/rev).  With 8-bit output the filter's
output is the top byte of u = kp e, so at kp = 20 the drive is 0 for 0 <= e < 256/20 = 12.8
counts (AN-706 5.2.4): the dead band within which a P-only loop leaves the shaft.
"""

from __future__ import annotations

import pytest

from lm629_host import CommandError, ProtocolViolation, Signals, Status
from lm629_host.bus.opcodes import Cmd, s32
from lm629_host.sim.model import ChipModel, ChipParams
from lm629_host.sim.model.motor import Motor

from sim_urls import with_params

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
    passes 3FFFFFFF at sample ceil(2^46 / 3FFFFFFF) = 65537 (16.777 s), RDDP then negative
    (the register itself, read raw: the driver's reads are extended past the wrap)."""
    def rddp() -> int:
        hi, lo = chip.raw(Cmd.RDDP, read=2)
        return s32((hi << 16) | lo)

    chip = open_move(open_chip, "stall=1")
    chip.set_breakpoint(100)
    chip.load_trajectory(acceleration=0x3FFFFFFF, velocity=0x3FFFFFFF, velocity_mode=True,
                         start=True)
    chip.clock.sleep(65530 * T)
    assert chip.read_status() & Status.BREAKPOINT  # passed 100 at the first sample
    chip.reset_interrupts()
    assert not chip.read_status() & Status.WRAPAROUND
    assert rddp() > 0x3FF00000
    chip.clock.sleep(10 * T)
    status = chip.read_status()
    assert status & Status.WRAPAROUND
    assert not status & Status.BREAKPOINT  # the jump from 3FFFFFFF to C0000000 is one count
    assert rddp() < -0x3FF00000
    chip.reset_interrupts()
    chip.load_trajectory(velocity_mode=True, forward=False, start=True)  # back across
    chip.clock.sleep(20 * T)
    assert chip.read_status() & Status.WRAPAROUND
    assert rddp() > 0x3FF00000


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


# ================================================================ on every simulated transport
def ready(open_chip, url: str, params: str = "", **filt):
    chip = open_chip(with_params(url, params))
    chip.reset()
    if filt:
        chip.load_filter(**filt)
        chip.update_filter()
    return chip


def model(chip) -> ChipModel:
    return chip.transport.model


# ---------------------------------------------------------------- 1. velocity mode restarts
@pytest.mark.parametrize("stop,forward", [("off", True), ("smooth", False), ("abrupt", True)])
def test_plain_stt_after_a_stop_resumes_velocity_mode(transport_url, open_chip, stop, forward):
    """AN-706 6.3.1 (smooth/abrupt: "STT will cause the motor to restart the trajectory") and
    6.3.3 (motor off: "resume movement in velocity mode"): a plain STT after LTRJ(stop) + STT
    runs on at the running trajectory's velocity (2 counts/sample), mode and direction, not at
    the stop-only LTRJ's (position mode towards the target 0 left from reset) [model choice 27].
    """
    chip = ready(open_chip, transport_url, kp=400, kd=2000)
    sign = 1 if forward else -1
    chip.load_trajectory(acceleration=ONE // 100, velocity=2 * ONE, velocity_mode=True,
                         forward=forward, start=True)
    chip.clock.sleep(0.2)  # 200 samples of ramp (51 ms), then cruise
    assert chip.read_desired_velocity() == sign * 2 * ONE
    chip.load_trajectory(stop=stop, start=True)
    chip.clock.sleep(0.15)
    assert chip.read_desired_velocity() == 0
    stopped = chip.read_desired_position()
    chip.reset_interrupts()
    chip.start()
    sig = chip.read_signals()
    assert sig & Signals.VELOCITY_MODE
    assert bool(sig & Signals.FORWARD) == forward
    assert not chip.read_status() & Status.MOTOR_OFF
    chip.clock.sleep(0.2)
    assert chip.read_desired_velocity() == sign * 2 * ONE
    moved = chip.read_desired_position() - stopped
    # 0.2 s = 781 samples, 200 of them ramping: about 2 * (781 - 100) counts on
    assert 1200 < sign * moved < 1600


# ---------------------------------------------------------------- 2. hold after completion
def _drift(chip, torque: float) -> int:
    """With the motor off, a load turns the shaft, then stops pulling; the shaft comes to rest."""
    m = model(chip)
    m.set_motor_params(load_torque=torque)
    chip.clock.sleep(0.15)
    m.set_motor_params(load_torque=0.0)
    chip.clock.sleep(0.3)
    real = chip.read_real_position()
    assert chip.read_desired_position() == real  # AN-706 6.3.2: desired follows while off
    assert chip.read_real_velocity() == 0
    return real


def test_stt_after_a_completed_move_and_motor_off_holds_where_the_shaft_is(transport_url, open_chip):
    """AN-706 6.3.3: "If any previous trajectory has completed then the motor will be held in
    the current position."  A move to 1000 completes, motor off, a load drifts the shaft back
    some hundreds of counts; a plain STT holds it there instead of driving it back to 1000; the
    same as after a reset with the same drift [model choice 27]."""
    chip = ready(open_chip, transport_url, kp=400, kd=2000)
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE, position=1000, start=True)
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=3, poll=0.01)
    chip.load_trajectory(stop="off", start=True)
    held = _drift(chip, 0.001)
    assert held < 900
    chip.reset_interrupts()
    chip.start()
    assert not chip.read_status() & Status.MOTOR_OFF
    chip.clock.sleep(0.3)
    assert chip.read_desired_position() == held
    assert abs(chip.read_real_position() - held) <= 2
    assert chip.read_status() & Status.TRAJECTORY_COMPLETE
    assert chip.read_signals() & Signals.ON_TARGET
    # after a reset, with a drift the same way: the same hold
    chip.reset()
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE)  # a move would be possible
    held = _drift(chip, 0.001)
    assert held < -100
    chip.start()
    chip.clock.sleep(0.3)
    assert chip.read_desired_position() == held
    assert abs(chip.read_real_position() - held) <= 2


def test_stt_after_motor_off_mid_move_still_resumes_to_the_target(transport_url, open_chip):
    """AN-706 6.3.3, the other half: "If a trajectory was in progress when the motor-off
    command was issued then the motor will restart and move to the target position"."""
    chip = ready(open_chip, transport_url, kp=400, kd=2000)
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE, position=3000, start=True)
    chip.clock.sleep(0.3)
    chip.load_trajectory(stop="off", start=True)
    _drift(chip, 0.001)
    chip.reset_interrupts()
    chip.start()
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=5, poll=0.01)
    assert chip.read_desired_position() == 3000


# ---------------------------------------------------------------- 3. status right after RSTI
def test_status_right_after_rsti_following_reset_reads_c0_at_every_phase(transport_url, open_chip):
    """Real LM629s read C0 right after RSTI 0000 following a reset (three reads of three, ~78 us
    after RSTI): the breakpoint condition (breakpoint 0, desired 0) shows again at once, not at
    the next 256 us sample [model choice 19].  Tried at 16 phases across one sample."""
    chip = open_chip(transport_url)
    assert chip.reset() == 0xC0
    for k in range(16):
        chip.clock.sleep(T / 16)
        chip.reset_interrupts()
        assert chip.sync() == 0xC0, f"phase {k}/16 of a sample"  # once busy clears
    # level-held only while the desired position sits on the breakpoint: moved on, RSTI clears
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=ONE, velocity=ONE, position=200, start=True)
    chip.clock.sleep(10 * T)
    chip.reset_interrupts()
    assert not chip.read_status() & Status.BREAKPOINT
    chip.clock.sleep(2 * T)
    assert not chip.read_status() & Status.BREAKPOINT


# ---------------------------------------------------------------- 4. the plant through reset
@pytest.mark.parametrize("how", ["rst", "command"])
def test_the_shaft_coasts_through_reset_with_zero_drive(transport_url, open_chip, how):
    """The motor and encoder do not stop for the chip's reset [model choice 31].  A shaft at
    10 counts/sample (39,062 counts/s) is let go (motor off: zero drive) and the chip is reset
    while it coasts.  Zero drive before, during and after the reset window alike, so the shaft
    must be exactly where the same motor, coasting with zero drive for every sample that
    passed, would be (not frozen for the ~4 samples of the window), and still
    turning: the back-EMF decay is 39.6 /s (kt^2/(R J) + b/J), tau = 25 ms."""
    chip = ready(open_chip, transport_url, kp=400, kd=2000)
    chip.load_trajectory(acceleration=ONE // 4, velocity=10 * ONE, velocity_mode=True,
                         start=True)
    chip.clock.sleep(0.4)
    m = model(chip)
    motor = m.motion.motor
    assert 38_000 < motor.speed < 40_500  # counts/s
    chip.load_trajectory(stop="off", start=True)
    coast = Motor(m.motor_params, motor.sample_s)
    coast.angle, coast.speed = motor.angle, motor.speed
    n0, t0 = m.samples, chip.clock.now()
    if how == "rst":
        chip.reset()  # /RST, 1.5 ms wait, MSKI, RSTI
    else:
        chip.raw(Cmd.RESET)
        chip.clock.sleep(1.6e-3)
        assert chip.read_status() in (0x84, 0xC4)
    n = m.samples - n0
    assert n >= (chip.clock.now() - t0) / T - 1 and n >= 4  # the window's samples included
    for _ in range(n):
        coast.run(0.0)
    assert (motor.angle, motor.speed) == (coast.angle, coast.speed)
    assert motor.speed > 20_000  # e^(-39.6 x 12 ms) = 0.62 after the longest link round trips
    # after the reset the encoder counts on, from real position 0 where the reset completed;
    # the speed keeps decaying (a few ms of link time on the bridges: e^-0.2 = 0.82)
    chip.clock.sleep(4 * T)
    assert 5 <= chip.read_real_velocity() <= 10
    assert chip.read_real_position() > 20


# ---------------------------------------------------------------- 5. the index at start
@pytest.mark.parametrize("forward,expected", [(True, 1000), (False, -1000)])
def test_default_index_is_half_a_turn_away_and_reachable(transport_url, open_chip, forward, expected):
    """[model choice 20]: by default the index is 2 x lines = 1000 counts from where the shaft
    starts.  A SIP at rest latches nothing (the shaft does not sit on the index);
    a slow search either way finds it within half a revolution: +1000 forward, -1000 back."""
    chip = ready(open_chip, transport_url, kp=400, kd=2000)
    chip.set_index_position()
    chip.clock.sleep(0.2)
    assert not chip.read_status() & Status.INDEX_PULSE
    assert chip.read_signals() & Signals.ACQUIRE_INDEX
    chip.load_trajectory(acceleration=ONE // 10, velocity=2 * ONE, velocity_mode=True,
                         forward=forward, start=True)
    chip.wait_for(Status.INDEX_PULSE, timeout=1.5, poll=0.01)
    assert chip.read_index_position() == expected
    assert not chip.read_signals() & Signals.ACQUIRE_INDEX


# ---------------------------------------------------------------- 6. violations with their time
def test_lenient_violations_carry_their_simulated_time(transport_url, open_chip):
    """A harness driving the model needs to know when: every recorded violation has ``time``
    (simulated seconds) and ``tick``.  A read from LPES (a write command) is one."""
    chip = open_chip(with_params(transport_url, "strict=0"))
    chip.reset()
    m = model(chip)
    times = []
    for _ in range(2):
        chip.clock.sleep(0.01)
        before = chip.clock.now()
        n = len(m.violations)
        chip.raw(Cmd.LPES, read=1)
        after = chip.clock.now()
        new = m.violations[n:]
        assert any("data read with a write command" in v for v in new)
        for v in new:
            assert before <= v.time <= after
            assert v.tick == round(v.time * 8e6)
        times.append(new[-1].time)
    assert times[1] - times[0] >= 0.01


def test_violation_time_on_the_bare_model():
    m = ChipModel(ChipParams(strict=False))
    m.advance(0.5e-3)
    m.write_command(Cmd.LPEI)
    m.write_data(0x12)
    m.write_data(0x34)  # second byte while busy: ignored, a violation, at 0.5 ms
    assert m.violations[-1].time == pytest.approx(0.5e-3) and m.violations[-1].tick == 4000
    assert "while busy" in m.violations[-1]


# ---------------------------------------------------------------- 7a. buffered acceleration
def test_refused_acceleration_stays_buffered_for_the_next_stt(transport_url, open_chip):
    """AN-706 3.3: new acceleration "can be loaded with LTRJ while the motor is moving, but
    cannot be executed by the STT command until the trajectory has completed"; the STT is
    "ignored" (command error).  The value stays in the input buffer (signals bit 14 stays
    set) and the first STT after completion executes it [model choice 13]: the move back
    ramps at 1/10 count/sample^2, not the 1/100 that was running."""
    chip = ready(open_chip, transport_url, kp=400, kd=2000)
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE, position=1500, start=True)
    chip.clock.sleep(0.1)
    chip.load_trajectory(acceleration=ONE // 10)
    with pytest.raises(CommandError):
        chip.start()
    assert chip.read_signals() & Signals.ACCELERATION_LOADED
    assert chip.read_desired_velocity() == ONE  # the move goes on as it was
    chip.reset_interrupts()
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=3, poll=0.01)
    assert chip.read_desired_position() == 1500
    assert chip.read_signals() & Signals.ACCELERATION_LOADED
    t0 = chip.clock.now()
    chip.load_trajectory(position=0, start=True)  # no acceleration in this LTRJ
    assert not chip.read_signals() & Signals.ACCELERATION_LOADED
    chip.clock.sleep(12 * T)
    # full speed within 10 samples at 1/10; at 1/100 it would take 100 samples (25.6 ms)
    assert chip.read_desired_velocity() == -ONE
    assert chip.clock.now() - t0 < 90 * T


# ---------------------------------------------------------------- 7b. relative after relative
def test_two_relative_velocities_before_one_stt_add_up(transport_url, open_chip):
    """AN-706 3.3: values "relative to those previously loaded": the second relative LTRJ is
    relative to the first one's (loaded, not yet started) value [model choice 29]:
    1 + 1/2 + 1/4 = 1.75 counts/sample (1.25 would be the second alone); positions likewise."""
    chip = ready(open_chip, transport_url, kp=400, kd=2000)
    chip.load_trajectory(acceleration=ONE // 50, velocity=ONE, velocity_mode=True, start=True)
    chip.clock.sleep(0.05)
    chip.load_trajectory(velocity=ONE // 2, velocity_relative=True, velocity_mode=True)
    chip.load_trajectory(velocity=ONE // 4, velocity_relative=True, velocity_mode=True)
    chip.start()
    chip.clock.sleep(0.1)
    assert chip.read_desired_velocity() == ONE + ONE // 2 + ONE // 4
    # absolute then relative: the absolute plus the relative
    chip.load_trajectory(velocity=3 * ONE, velocity_mode=True)
    chip.load_trajectory(velocity=-ONE, velocity_relative=True, velocity_mode=True, start=True)
    chip.clock.sleep(0.1)
    assert chip.read_desired_velocity() == 2 * ONE
    # positions the same way: absolute, then two relatives, one STT
    chip.load_trajectory(stop="abrupt", start=True)
    chip.clock.sleep(2 * T)
    chip.reset_interrupts()
    here = chip.read_desired_position()
    chip.load_trajectory(position=here)
    chip.load_trajectory(position=300, position_relative=True)
    chip.load_trajectory(position=-100, position_relative=True, start=True)
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=3, poll=0.01)
    assert chip.read_desired_position() == here + 200


# ---------------------------------------------------------------- 8. RESET command duration
def _count_limited_poll(m: ChipModel, reads: int = 5000, access_clocks: int = 2) -> int | None:
    """A production driver's busy poll: at most ``reads`` status reads, 250 ns each at 8 MHz;
    the read count at which busy was clear, or None when the count ran out."""
    for i in range(1, reads + 1):
        m.advance_to(m.tick + access_clocks)
        if not m.read_status() & Status.BUSY:
            return i
    return None


@pytest.mark.parametrize("reset_s,outcome", [(1.0e-3, "clear"), (1.5e-3, "runs out")])
def test_count_limited_busy_poll_after_reset_command(reset_s, outcome):
    """[model choices 3, 6] Busy holds for the whole RESET command.  5000 polls at 250 ns last
    1.25 ms: enough for the model's default 1 ms reset (busy clear at read 4000), not for the
    datasheet's 1.5 ms worst case, after which the driver's MSKI lands while busy, is ignored
    and recorded (at its time) as a violation."""
    m = ChipModel(ChipParams(strict=False, reset_s=reset_s))
    m.advance(1e-3)
    t0 = m.tick
    m.write_command(Cmd.RESET)
    got = _count_limited_poll(m)
    if outcome == "clear":
        assert got == 4000 and m.tick - t0 == 8000
        assert m.read_status() in (0x84, 0xC4)
        m.write_command(Cmd.MSKI)
        assert not m.violations
    else:
        assert got is None and m.tick - t0 == 10000  # 1.25 ms, still busy
        m.write_command(Cmd.MSKI)
        assert m.violations and "while busy" in m.violations[-1]
        assert m.violations[-1].time == pytest.approx((t0 + 10000) / 8e6)
        m.advance_to(t0 + 12000)
        assert m.read_status() in (0x84, 0xC4)


@pytest.mark.parametrize("reset_s", [1.0e-3, 1.5e-3])
def test_reset_command_through_the_far_end_waits_out_both_durations(transport_url, open_chip, reset_s):
    """The far end's busy wait is bounded by time (5 ms), not by a count, so the RESET command
    followed at once by MSKI/RSTI works at the default and at the 1.5 ms worst case: no write
    is lost into busy, the status is C0 after."""
    chip = open_chip(with_params(transport_url, f"reset_s={reset_s}"))
    chip.reset()
    t0 = chip.clock.now()
    chip.raw(Cmd.RESET)
    chip.mask_interrupts(Status.INDEX_PULSE)
    chip.reset_interrupts()
    assert chip.clock.now() - t0 >= reset_s
    assert chip.sync() == 0xC0
    assert model(chip).mask == Status.INDEX_PULSE
    assert not model(chip).violations


# ---------------------------------------------------------------- 9. velocity above 3FFFFFFF
def test_velocity_word_above_3fffffff_is_refused_and_reported(transport_url, open_chip):
    """AN-706 2.7: velocity has 30 bits (bit 31 sign, bit 30 overflow); 6.5.1: a negative
    absolute velocity "is not allowed" (command error).  FDF0A3D8 (AN-868's overflowed clock
    scalar) is such a word: the STT is refused and ignored, the running velocity stays; the
    word is a recorded protocol violation with its time [model choice 30]."""
    chip = ready(open_chip, with_params(transport_url, "strict=0"), kp=400, kd=2000)
    m = model(chip)
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE, velocity_mode=True, start=True)
    chip.clock.sleep(0.2)
    for word in (0xFDF0A3D8, 0x40000000):
        n = len(m.violations)
        before = chip.clock.now()
        chip.raw(Cmd.LTRJ, [0x1808, word >> 16, word & 0xFFFF])
        assert f"{word:08X}" in m.violations[n] and m.violations[n].time >= before
        with pytest.raises(CommandError):
            chip.start()
        chip.reset_interrupts()
        chip.clock.sleep(0.05)
        assert chip.read_desired_velocity() == ONE
        chip.load_trajectory(velocity=ONE, velocity_mode=True)  # replace the loaded word
    # 3FFFFFFF itself is in range
    chip.load_trajectory(velocity=0x3FFFFFFF, velocity_mode=True, start=True)


def test_strict_mode_reports_the_out_of_range_word():
    import lm629_host

    with lm629_host.open("sim://?strict=1") as chip:
        chip.reset()
        with pytest.raises(ProtocolViolation, match="FDF0A3D8 is above 3FFFFFFF"):
            chip.raw(Cmd.LTRJ, [0x0008, 0xFDF0, 0xA3D8])


# ---------------------------------------------------------------- 10. P-only rest position
def test_p_only_loop_rests_below_its_target_either_way(transport_url, open_chip):
    """[model choice 22]: the 8-bit output is u >> 8 (floor), so at kp = 20 any e < 0 still
    drives (-1/128) and e = 0..12 does not (256/20 = 12.8): the shaft rests 0..12 counts below
    the target whichever way it came, short of 1000 going up, past 0 going down."""
    chip = ready(open_chip, transport_url, kp=20)
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE // 2, position=1000, start=True)
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=5, poll=0.01)
    chip.clock.sleep(0.5)
    up = chip.read_real_position()
    assert 988 <= up <= 1000
    chip.reset_interrupts()
    chip.load_trajectory(position=0, start=True)
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=5, poll=0.01)
    chip.clock.sleep(0.5)
    down = chip.read_real_position()
    assert -12 <= down <= 0
    assert chip.read_real_velocity() == 0
