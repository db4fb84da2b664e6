"""The motor and encoder model against the DC-motor equations worked by hand.

Defaults: 12 V amplifier, R = 4 ohm, kt = ke = 0.025, J = 4e-6, b = 2e-6, Tc = 2e-4 N m,
500 lines -> 2000 counts/rev = 2000 / (2 pi) counts/rad.
"""

from __future__ import annotations

from math import pi

import pytest

import lm629_host
from lm629_host.sim.model.motor import Motor
from lm629_host.sim.model.params import MotorParams

T = 2048 / 8e6
COUNTS_PER_RAD = 2000 / (2 * pi)


def test_no_load_speed_at_full_drive():
    # w = (kt V / R - Tc) / (kt^2 / R + b) = (0.075 - 0.0002) / 1.5825e-4 = 472.67 rad/s
    m = Motor(MotorParams(), T)
    for _ in range(2000):  # 0.5 s = 20 mechanical time constants (J / 1.5825e-4 = 25 ms)
        m.run(12.0)
    assert m.speed == pytest.approx(472.669826 * COUNTS_PER_RAD, rel=1e-6)
    assert m.speed == pytest.approx(150_456, rel=1e-4)


def test_first_sample_from_rest_matches_the_exact_solution():
    # constant acceleration a0 = (kt V / R - Tc) / J, decay rate L = 1.5825e-4 / J = 39.5625 /s
    m = Motor(MotorParams(), T)
    angle0 = m.angle
    m.run(12.0)
    a0 = (0.075 - 0.0002) / 4e-6 * COUNTS_PER_RAD
    lam = 39.5625
    from math import exp
    w_inf = a0 / lam
    assert m.speed == pytest.approx(w_inf * (1 - exp(-lam * T)), rel=1e-9)
    assert m.angle - angle0 == pytest.approx(w_inf * (T - (1 - exp(-lam * T)) / lam), rel=1e-9)


def test_coulomb_friction_holds_below_breakaway_and_reversed_leads_flip_the_torque():
    # one 8-bit output step: 12/128 V -> 0.025 * 0.09375 / 4 = 5.86e-4 N m
    m = Motor(MotorParams(coulomb=1e-3), T)
    for _ in range(100):
        m.run(12 / 128)
    assert m.speed == 0.0 and m.angle == 0.5
    m = Motor(MotorParams(), T)
    m.run(12 / 128)
    assert m.speed > 0
    r = Motor(MotorParams(reversed=True), T)
    r.run(12 / 128)
    assert r.speed == pytest.approx(-m.speed)
    s = Motor(MotorParams(stall=True), T)
    s.run(12.0)
    assert s.speed == 0.0 and s.angle == 0.5


def test_coasting_shaft_stops_and_sticks():
    m = Motor(MotorParams(coulomb=0.002), T)
    for _ in range(50):
        m.run(12.0)
    for _ in range(400):  # 0 V: back-EMF braking plus dry friction
        m.run(0.0)
    assert m.speed == 0.0
    stopped = m.angle
    m.run(0.0)
    assert m.angle == stopped


@pytest.mark.parametrize("c0, c1, expected", [
    (0, 10, None), (0, 37, 37), (36, 38, 37), (37, 37, 37), (500, 437, 437),
    (100, 2037, 437), (-1000, -1963, -1163), (40, 436, None)])
def test_index_once_per_revolution(c0, c1, expected):
    """Index at counts 37 + 400 k; the first one met moving from c0 to c1 (both included)."""
    m = Motor(MotorParams(lines=100, index_offset=37), T)  # 400 counts/rev
    assert m.index_between(c0, c1) == expected


def test_bad_motor_parameters_are_refused_naming_the_value():
    with pytest.raises(ValueError, match="lines=0"):
        lm629_host.open("sim://?lines=0")
    with pytest.raises(ValueError, match="inertia=-1"):
        lm629_host.open("sim://?inertia=-1")
    with pytest.raises(ValueError, match="coulomb"):
        lm629_host.open("sim://?coulomb=-0.1")


def test_motor_parameters_change_mid_run_from_python():
    """A weight hung on a held shaft: 0.01 N m against kp = 400 -> the shaft gives way a few
    counts, the loop pushes back; locking the rotor stops it where it is."""
    chip = lm629_host.open("sim://?strict=1")
    try:
        chip.reset()
        chip.load_filter(kp=400, kd=2000)
        chip.update_filter()
        chip.start()
        chip.clock.sleep(0.1)
        assert chip.read_real_position() == 0
        model = chip.transport.model
        model.set_motor_params(load_torque=0.01)
        chip.clock.sleep(0.5)
        sag = chip.read_real_position()
        # 0.01 N m needs 0.01 * 4 / 0.025 = 1.6 V = 17 output steps of 12/128 V -> e ~ 17 * 256 / 400
        assert -14 <= sag <= -8
        model.set_motor_params(stall=True)
        chip.clock.sleep(0.1)
        assert chip.read_real_position() == sag
        with pytest.raises(ValueError, match="inertia=0"):
            model.set_motor_params(inertia=0)
        with pytest.raises(ValueError, match="'weight'"):
            model.set_motor_params(weight=1)
        assert model.motor_params.inertia == 4e-6
    finally:
        chip.close()
