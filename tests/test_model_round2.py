"""Chip model, round 2 (issue 15): restarts after stops and motor off, RSTI, the plant through
reset, the index at start, violations with their time, buffered and relative parameters, the
RESET command's duration, out-of-range words, the P-only rest position.

Every scenario runs on ``sim://`` (the model strobed directly) and through real far-end code:
``sim+emu://`` (the Python bridge far end), ``sim+avr://`` (the compiled bridge firmware in
simavr) and ``sim+ftdi://`` (pyftdi on the emulated FT232H).  Numbers: 8 MHz, T = 256 us,
ONE = 65536 = 1 count/sample, the default motor (500 lines: 2000 counts/rev).  The model
choices cited are items of the list in ``lm629_host/sim/model/__init__.py``.
"""

from __future__ import annotations

import pytest

from lm629_host import CommandError, ProtocolViolation, Signals, Status
from lm629_host.sim.model import ChipModel, ChipParams
from lm629_host.sim.model.motor import Motor
from lm629_host.opcodes import Cmd
from test_acceptance import _available

ONE = 65536
T = 2048 / 8e6
URLS = ["sim://", "sim+emu://", "sim+avr://", "sim+ftdi://"]


@pytest.fixture(params=URLS)
def base(request) -> str:
    if not _available(request.param):
        pytest.skip(f"{request.param} is not available here")
    return request.param


def url(base: str, params: str = "") -> str:
    return f"{base}?{params}" if params else base


def ready(open_chip, base: str, params: str = "", **filt):
    chip = open_chip(url(base, params))
    chip.reset()
    if filt:
        chip.load_filter(**filt)
        chip.update_filter()
    return chip


def model(chip) -> ChipModel:
    return chip.transport.model


# ---------------------------------------------------------------- 1. velocity mode restarts
@pytest.mark.parametrize("stop,forward", [("off", True), ("smooth", False), ("abrupt", True)])
def test_plain_stt_after_a_stop_resumes_velocity_mode(base, open_chip, stop, forward):
    """AN-706 6.3.1 (smooth/abrupt: "STT will cause the motor to restart the trajectory") and
    6.3.3 (motor off: "resume movement in velocity mode"): a plain STT after LTRJ(stop) + STT
    runs on at the running trajectory's velocity (2 counts/sample), mode and direction, not at
    the stop-only LTRJ's (position mode towards the target 0 left from reset) [model choice 27].
    """
    chip = ready(open_chip, base, kp=400, kd=2000)
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


def test_stt_after_a_completed_move_and_motor_off_holds_where_the_shaft_is(base, open_chip):
    """AN-706 6.3.3: "If any previous trajectory has completed then the motor will be held in
    the current position."  A move to 1000 completes, motor off, a load drifts the shaft back
    some hundreds of counts; a plain STT holds it there instead of driving it back to 1000; the
    same as after a reset with the same drift [model choice 27]."""
    chip = ready(open_chip, base, kp=400, kd=2000)
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


def test_stt_after_motor_off_mid_move_still_resumes_to_the_target(base, open_chip):
    """AN-706 6.3.3, the other half: "If a trajectory was in progress when the motor-off
    command was issued then the motor will restart and move to the target position"."""
    chip = ready(open_chip, base, kp=400, kd=2000)
    chip.load_trajectory(acceleration=ONE // 100, velocity=ONE, position=3000, start=True)
    chip.clock.sleep(0.3)
    chip.load_trajectory(stop="off", start=True)
    _drift(chip, 0.001)
    chip.reset_interrupts()
    chip.start()
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=5, poll=0.01)
    assert chip.read_desired_position() == 3000


# ---------------------------------------------------------------- 3. status right after RSTI
def test_status_right_after_rsti_following_reset_reads_c0_at_every_phase(base, open_chip):
    """Real LM629s read C0 right after RSTI 0000 following a reset (three reads of three, ~78 us
    after RSTI): the breakpoint condition (breakpoint 0, desired 0) shows again at once, not at
    the next 256 us sample [model choice 19].  Tried at 16 phases across one sample."""
    chip = open_chip(base)
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
def test_the_shaft_coasts_through_reset_with_zero_drive(base, open_chip, how):
    """The motor and encoder do not stop for the chip's reset [model choice 31].  A shaft at
    10 counts/sample (39,062 counts/s) is let go (motor off: zero drive) and the chip is reset
    while it coasts.  Zero drive before, during and after the reset window alike, so the shaft
    must be exactly where the same motor, coasting with zero drive for every sample that
    passed, would be (the model used to freeze it for the ~4 samples of the window), and still
    turning: the back-EMF decay is 39.6 /s (kt^2/(R J) + b/J), tau = 25 ms."""
    chip = ready(open_chip, base, kp=400, kd=2000)
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
def test_default_index_is_half_a_turn_away_and_reachable(base, open_chip, forward, expected):
    """[model choice 20]: by default the index is 2 x lines = 1000 counts from where the shaft
    starts.  A SIP at rest latches nothing (it used to latch at once: the shaft sat on it);
    a slow search either way finds it within half a revolution: +1000 forward, -1000 back."""
    chip = ready(open_chip, base, kp=400, kd=2000)
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
def test_lenient_violations_carry_their_simulated_time(base, open_chip):
    """A harness driving the model needs to know when: every recorded violation has ``time``
    (simulated seconds) and ``tick``.  A read from LPES (a write command) is one."""
    chip = open_chip(url(base, "strict=0"))
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
def test_refused_acceleration_stays_buffered_for_the_next_stt(base, open_chip):
    """AN-706 3.3: new acceleration "can be loaded with LTRJ while the motor is moving, but
    cannot be executed by the STT command until the trajectory has completed"; the STT is
    "ignored" (command error).  The value stays in the input buffer (signals bit 14 stays
    set) and the first STT after completion executes it [model choice 13]: the move back
    ramps at 1/10 count/sample^2, not the 1/100 that was running."""
    chip = ready(open_chip, base, kp=400, kd=2000)
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
def test_two_relative_velocities_before_one_stt_add_up(base, open_chip):
    """AN-706 3.3: values "relative to those previously loaded": the second relative LTRJ is
    relative to the first one's (loaded, not yet started) value [model choice 29]:
    1 + 1/2 + 1/4 = 1.75 counts/sample (the model used to give 1.25); positions likewise."""
    chip = ready(open_chip, base, kp=400, kd=2000)
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
def test_reset_command_through_the_far_end_waits_out_both_durations(base, open_chip, reset_s):
    """The far end's busy wait is bounded by time (5 ms), not by a count, so the RESET command
    followed at once by MSKI/RSTI works at the default and at the 1.5 ms worst case: no write
    is lost into busy, the status is C0 after."""
    chip = open_chip(url(base, f"reset_s={reset_s}"))
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
def test_velocity_word_above_3fffffff_is_refused_and_reported(base, open_chip):
    """AN-706 2.7: velocity has 30 bits (bit 31 sign, bit 30 overflow); 6.5.1: a negative
    absolute velocity "is not allowed" (command error).  FDF0A3D8 (AN-868's overflowed clock
    scalar) is such a word: the STT is refused and ignored, the running velocity stays; the
    word is a recorded protocol violation with its time [model choice 30]."""
    chip = ready(open_chip, url(base, "strict=0"), kp=400, kd=2000)
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
def test_p_only_loop_rests_below_its_target_either_way(base, open_chip):
    """[model choice 22]: the 8-bit output is u >> 8 (floor), so at kp = 20 any e < 0 still
    drives (-1/128) and e = 0..12 does not (256/20 = 12.8): the shaft rests 0..12 counts below
    the target whichever way it came, short of 1000 going up, past 0 going down."""
    chip = ready(open_chip, base, kp=20)
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
