"""Tests of rig.py: on the simulator by default (`python -m pytest`), on the bench with
`python -m pytest --lm629-port /dev/ttyACM0 --lm629-allow-motion` (docs/testing.md).

Figures: the chip samples every 2048 clocks, 256 us at 8 MHz (datasheet); rig.VELOCITY is 4
counts/sample = 15625 counts/s; rig.ACCELERATION 0.05 counts/sample^2 ramps to it in 80
samples (20.5 ms).
"""

import pytest

from lm629_host import Status

import rig

SAMPLE_S = 2048 / 8e6


def test_reset_leaves_the_motor_off(lm629):
    # AN-706 4.4.1: after reset and MSKI/RSTI 0000 the status reads 80 or C0 (motor off)
    assert lm629.read_status() & Status.MOTOR_OFF
    rig.prepare(lm629)
    assert lm629.read_real_position() == 0


@pytest.mark.lm629_motion
def test_a_long_move_takes_the_time_of_its_trapezoid(lm629):
    rig.prepare(lm629)
    result = lm629.move_to(60000, velocity=rig.VELOCITY, acceleration=rig.ACCELERATION).wait()
    ramp = 4 / 0.05 * SAMPLE_S  # 80 samples up, 80 down
    cruise = (60000 - 4 * 80) / 4 * SAMPLE_S  # the rest at 4 counts/sample
    expected = 2 * ramp + cruise  # 3.86 s of motion
    time_base = "simulated" if lm629.transport.simulated else "wall"
    print(f"60000 counts in {result.duration:.3f} s of {time_base} time (trapezoid {expected:.3f} s)")
    assert abs(result.error) <= 20
    assert expected <= result.duration <= expected + 0.3  # + settling (20 ms at rest)


@pytest.mark.lm629_motion
def test_shuttle_ends_every_move_on_target(lm629):
    rig.prepare(lm629)
    results = rig.shuttle(lm629, travel=2000, cycles=2)
    assert [r.target for r in results] == [2000, 0, 2000, 0]
    assert max(abs(r.error) for r in results) <= 20


def test_a_free_shaft_stays_put(lm629):
    lm629.clock.sleep(1.0)  # motor off after reset, no load: nothing turns it
    assert lm629.read_real_position() == 0


@pytest.mark.lm629_sim("inertia=4e-5&load_torque=0.002")
def test_a_hanging_load_pulls_the_free_shaft(lm629):
    # motor off, shorted winding (the model's drive off): the load torque less the Coulomb
    # friction, 0.0018 N m, against viscous friction plus back-EMF braking Kt^2/R:
    # b = 2e-6 + 0.025**2 / 4 = 1.5825e-4 N m s/rad; terminal speed 11.37 rad/s, time constant
    # J / b = 0.253 s; after 1 s: 11.37 * (1 - 0.253 * (1 - e^-3.95)) = 8.63 rad = 2747 counts
    lm629.clock.sleep(1.0)
    assert lm629.read_real_position() == pytest.approx(-2747, rel=0.03)


@pytest.mark.lm629_sim(axes=2)
@pytest.mark.lm629_motion
def test_both_axes_of_a_two_axis_board(lm629_board):
    assert len(lm629_board.axes) == 2
    for axis in lm629_board.axes:
        rig.prepare(axis)
    lm629_board.move_linear({0: 3000, 1: 1500}, velocity=rig.VELOCITY,
                           acceleration=rig.ACCELERATION).wait()
    assert [a.read_real_position() for a in lm629_board.axes] == [
        pytest.approx(3000, abs=20), pytest.approx(1500, abs=20)]


@pytest.mark.lm629_hardware
def test_the_bench_answers(lm629):
    assert not lm629.transport.simulated
    assert lm629.read_status() & Status.MOTOR_OFF
