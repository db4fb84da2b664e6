"""``LM629.move_to`` / ``Move.wait`` on every simulated transport.

Numbers: 8 MHz, T = 256 us.  velocity 65536 = 1 count/sample, acceleration 655 = 0.01
count/sample^2: a 1000-count trapezoid is 100 samples of ramp each way (50 counts each) and
900 samples at speed: 1100 samples = 0.2816 s.  kp = 20 on the 8-bit output leaves a P-only
dead band of 256 / 20 = 12.8 counts (AN-706 5.2.4), inside the default tolerance of 20.
"""

from __future__ import annotations

import pytest

import lm629_host

from lm629_host import Cmd, MotionError, MoveRules, Status
from lm629_host.errors import MotionFault
from lm629_host.chip.move import MOVE_FLAGS
from lm629_host.bus.opcodes import INTERRUPTS

from sim_urls import with_params

T = 2048 / 8e6
PROFILE_1000 = 1100 * T


def _ready(chip, kp: int = 20):
    chip.reset()
    chip.load_filter(kp=kp)
    chip.update_filter()
    return chip


def test_move_to_twice_then_relative(usb_transport_url, open_chip, recorder):
    chip = _ready(open_chip(usb_transport_url))
    first = chip.move_to(1000, velocity=65536, acceleration=655).wait()
    assert first.target == 1000 and abs(first.error) <= 13
    assert first.error == 1000 - first.position
    assert PROFILE_1000 <= first.duration <= PROFILE_1000 + MoveRules().settle_timeout
    # the second move starts with TRAJECTORY_COMPLETE still set by the first: it must not end
    # its wait (the trap of wait_for); it returns only once RDDP is the new target
    assert chip.read_status() & Status.TRAJECTORY_COMPLETE
    second = chip.move_to(5000, velocity=4 * 65536, acceleration=6553).wait()
    assert chip.read_desired_position() == 5000
    assert abs(second.error) <= 13 and abs(5000 - chip.read_real_position()) <= 13
    # 4000 counts at 4 counts/sample, 0.1 c/s^2: 40-sample ramps, 960 samples = 0.2458 s
    assert second.duration >= 960 * T
    third = chip.move_to(-3000, velocity=4 * 65536, relative=True).wait()
    assert third.target == 2000 and chip.read_desired_position() == 2000
    assert abs(2000 - chip.read_real_position()) <= 13


def test_flags_are_cleared_in_the_program_that_starts_the_move(usb_transport_url, open_chip,
                                                               recorder):
    chip = _ready(open_chip(usb_transport_url))
    chip.move_to(300, velocity=65536, acceleration=655).wait()
    recorder.clear()
    programs = chip.transport.stats.programs
    move = chip.move_to(600, velocity=65536, acceleration=655)
    # one program (one exchange on a bridge): the snapshot the move starts from,
    # then RSTI, LTRJ with its words, STT
    assert chip.transport.stats.programs - programs == 1
    data = recorder.data()
    assert data.index(("command", int(Cmd.RDSIGS))) < data.index(("command", int(Cmd.RSTI)))
    rsti = data.index(("command", int(Cmd.RSTI)))
    assert data[rsti + 1] == ("write", int(INTERRUPTS & ~MOVE_FLAGS))
    assert data[rsti + 2] == ("command", int(Cmd.LTRJ))
    assert data[-1] == ("command", int(Cmd.STT))
    assert not chip.read_status() & Status.TRAJECTORY_COMPLETE  # cleared, the move is running
    move.wait()


def test_stalled_motor_is_a_motion_fault_with_the_motor_stopped(usb_transport_url, open_chip):
    chip = _ready(open_chip(with_params(usb_transport_url, "stall=1")))
    with pytest.raises(MotionError) as e:
        chip.move_to(5000, velocity=65536, acceleration=655).wait()
    assert e.value.reason == MotionError.STALL
    assert e.value.reason is MotionFault.STALL and e.value.axis is None
    assert e.value.position == 0 and e.value.error == 5000
    assert "motor stopped" in e.value.detail
    assert str(e.value) == f"motion fault (stall): {e.value.detail}"
    snap = chip.snapshot()
    assert snap.status & Status.MOTOR_OFF and snap.desired_velocity == 0
    chip.clock.sleep(0.05)  # nothing moves any more
    assert chip.read_real_position() == 0 and chip.read_desired_velocity() == 0


def test_reversed_leads_are_a_runaway(open_chip):
    chip = _ready(open_chip("sim://?reversed=1"))
    with pytest.raises(MotionError) as e:
        chip.move_to(5000, velocity=65536, acceleration=655).wait()
    assert e.value.reason == MotionError.RUNAWAY
    assert e.value.position < 0  # the shaft went the other way
    assert chip.read_status() & Status.MOTOR_OFF


def test_position_error_flag_is_a_fault(open_chip):
    chip = _ready(open_chip("sim://"))
    chip.load_position_error(5)  # LPEI 5 counts: a fast move exceeds it at once
    with pytest.raises(MotionError) as e:
        chip.move_to(20000, velocity=20 * 65536, acceleration=65536).wait()
    assert e.value.reason == MotionError.POSITION_ERROR
    assert chip.read_status() & Status.MOTOR_OFF


def test_following_error_when_the_tolerance_is_below_the_dead_band(open_chip):
    """kp = 20 (8-bit output: code = 20 e / 256, floor) against a load of 0.0005 N m pulling
    towards negative counts.  Code c drives c x 12 V / 128 / 4 ohm x 0.025 N m/A = c x 5.86e-4
    N m; at rest the drive less the load is within the dry friction (2e-4 N m): 0.51 <= c <=
    1.19, so c = 1 and the shaft rests e = 13..25 counts short of the target (20 e / 256 >= 1,
    < 2).  A tolerance of 0 cannot be met: a following-error fault naming that error."""
    chip = _ready(open_chip("sim://?load_torque=0.0005"), kp=20)
    with pytest.raises(MotionError) as e:
        chip.move_to(1000, velocity=65536, acceleration=655).wait(tolerance=0)
    assert e.value.reason == MotionError.FOLLOWING_ERROR
    assert 13 <= e.value.error <= 25
    assert e.value.position == 1000 - e.value.error


def test_timeout_is_a_motion_fault(open_chip):
    chip = _ready(open_chip("sim://"))
    with pytest.raises(MotionError) as e:
        chip.move_to(20000, velocity=65536, acceleration=655).wait(timeout=0.1)
    assert e.value.reason == MotionError.TIMEOUT
    assert chip.read_status() & Status.MOTOR_OFF


@pytest.mark.parametrize("kw, name", [
    (dict(velocity=0), "velocity=0"),
    (dict(velocity=65536, acceleration=0), "acceleration=0"),
    (dict(velocity=float("inf")), "velocity=inf"),
    (dict(velocity=float("nan")), "velocity=nan"),
    (dict(velocity=1 << 31), "velocity=2147483648"),
])
def test_bad_move_arguments_touch_nothing(open_chip, recorder, kw, name):
    chip = _ready(open_chip("sim://"))
    recorder.clear()
    with pytest.raises(ValueError, match=name.replace("[", r"\[")):
        chip.move_to(1000, **kw)
    assert recorder.cycles == []


def test_a_settle_timeout_says_what_was_still_wrong(open_chip):
    """kp = 3000 with no kd rings round the target for longer than the 1 s settle timeout;
    with a tolerance of 40 the shaft is inside it, still moving: the message says so (it
    said "did not settle within 40 counts ... (error +23)", a contradiction), with how far
    the shaft moved in the last poll."""
    from dataclasses import replace
    chip = _ready(open_chip("sim://"), kp=3000)
    chip.move_rules = replace(chip.move_rules, tolerance=40)
    with pytest.raises(MotionError) as e:
        chip.move_to(1000, velocity=65536, acceleration=655).wait()
    assert e.value.reason == MotionError.FOLLOWING_ERROR
    message = str(e.value)
    assert "did not settle in the 1 s after the trajectory ended" in message
    assert f"{e.value.error:+d} counts from the target (inside the tolerance 40)" in message
    assert abs(e.value.error) <= 40 and "still moving (" in message and " counts/s)" in message
    assert chip.read_status() & Status.MOTOR_OFF


#: 600 s (the default max_duration) at one count a sample (velocity word 65536, the top
#: speed reached in one sample: acceleration word 65536) of 2048 / 8 MHz = 256 us: 2343750
#: samples, a trapezoid of d counts taking d / v + v / a = d + 1 of them
LIMIT_COUNTS = 600 * 8_000_000 // 2048 - 1


def test_max_duration_is_refused_at_its_boundary(open_chip, recorder):
    """The default MoveRules refuse a move planned one sample longer than 600 s before it
    starts (the chip's positions read, no LTRJ nor STT sent), and take one planned at
    exactly 600 s (a doubled max_duration would take both; a halved one refuse both)."""
    from lm629_host.chip.move import MoveTooLong, check_duration
    rules = MoveRules()
    assert rules.max_duration == 600.0
    assert check_duration(rules, LIMIT_COUNTS, 65536, 65536, 8e6) == pytest.approx(600.0)
    with pytest.raises(MoveTooLong) as e:
        check_duration(rules, LIMIT_COUNTS + 1, 65536, 65536, 8e6)
    assert e.value.distance == LIMIT_COUNTS + 1 and e.value.limit == 600.0
    chip = _ready(open_chip("sim://"))
    recorder.clear()
    with pytest.raises(MoveTooLong, match="longer than the limit max_duration=600 s"):
        chip.move_to(LIMIT_COUNTS + 1, velocity=65536, acceleration=65536)
    sent = {c.value for c in recorder.cycles if c.kind == "command"}
    assert sent and not sent & {Cmd.LTRJ, Cmd.STT}
    assert chip.read_desired_position() == 0


def test_move_rules_are_checked():
    with pytest.raises(ValueError, match="settle_time"):
        MoveRules(settle_time=float("nan"))
    with pytest.raises(ValueError, match="tolerance"):
        MoveRules(tolerance=-1)


def test_ctrl_c_while_waiting_stops_the_motor(open_chip):
    chip = _ready(open_chip("sim://"))
    move = chip.move_to(20000, velocity=65536, acceleration=655)
    seen = []

    def progress(snap):
        seen.append(snap)
        if len(seen) == 20:  # 0.1 s into the move: the motor is running
            assert snap.desired_velocity > 0
            raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt) as e:
        move.wait(progress=progress)
    assert e.value.lm629_stop_note == "motor stopped (abrupt stop, then motor off)"
    assert chip.read_status() & Status.MOTOR_OFF and chip.read_desired_velocity() == 0


def test_velocity_mode_is_a_method_with_a_signed_speed():
    """chip.run_velocity(v) like chip.move_to(...): -65536 turns backwards at 1 count/sample,
    so after 0.5 s (1953 samples at 256 us) the desired position is about -1953 + the ramp."""
    import lm629_host
    from lm629_host.bus.opcodes import Signals
    with lm629_host.open("sim://") as chip:
        chip.reset()
        chip.load_filter(kp=20, kd=100)
        chip.update_filter()
        run = chip.run_velocity(-65536, 655)
        chip.clock.sleep(0.5)
        run.check()
        assert not chip.read_signals() & Signals.FORWARD
        desired = chip.read_desired_position()
        assert -1953 <= desired <= -1953 + 110  # 100 samples of ramp lose at most 50 counts
        run.stop()
        with pytest.raises(ValueError):
            chip.run_velocity(2**30)


def test_rest_is_not_counted_across_far_checks_too_far_apart():
    """A far-side wait on a late link (ser2net beside two CPU hogs: CI saw it) reads its
    snapshots in checks too far apart to judge rest across them.  The shaft overshot 64 counts
    and read the same count twice at the top of the overshoot (RDRV 0: under a count a
    sample), then 48 ms later, in the next check, 55 counts over and coming back: that is not
    a shaft at rest, and no "came to rest -55 counts" fault.  A shaft that then stays at one
    count for the settle time is at rest, and the fault is the truth."""
    from lm629_host.bus.snapshot import Snapshot
    from lm629_host.chip.move import MoveWatch

    chip = lm629_host.open("sim://")
    with chip:
        chip.reset()
        chip.load_filter(kp=20, kd=100)
        chip.update_filter()
        move = chip.move_to(6000, velocity=1 << 16, acceleration=1 << 8)
        watch = MoveWatch(move, MoveRules(), timeout=10)
        done = Status.TRAJECTORY_COMPLETE | Status.BREAKPOINT

        def snap(t: float, rp: int, status: Status = Status.BREAKPOINT) -> Snapshot:
            """At ``t`` seconds on the transport's clock."""
            return Snapshot(status, chip.read_signals(), 6000 if status & done else 5999, rp,
                            0, 0, 0, t)

        # one check ends at the top of the overshoot, 64 over, read twice (0.0036 s apart)
        assert watch.check(snap(4.9481, 6064)) is None
        assert watch.check(snap(4.9517, 6064, done)) is None
        assert watch.quiet_since == 4.9481
        # the next check, 28 ms on: coming back; its five snapshots stamped as wait_far does,
        # a poll apart back from the reply's time, 5.0 (0.02 s in all but a float's rounding:
        # 5.0 - 0.02 rounds to more than 0.02 before 5.0); at rest for the settle time, 55
        # counts off: that fault is the truth
        assert 5.0 - (5.0 - 4 * 0.005) < 0.02
        checks = [snap(5.0 - (4 - k) * 0.005, 6055, done) for k in range(5)]
        watch.restart_rest(checks[0])
        assert watch.check(checks[0]) is None and watch.quiet_since == checks[0].time
        for s in checks[1:4]:
            assert watch.check(s) is None  # 5, 10, 15 ms at rest: not yet
        with pytest.raises(MotionError, match="came to rest -55 counts"):
            watch.check(checks[4])
