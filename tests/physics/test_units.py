"""units.Scale against the worked examples of the spec (AN-706 5.3, the datasheet, AN-868)."""

from __future__ import annotations

import math

import pytest

from lm629_host.physics.units import Scale, from_fixed, to_fixed


def test_sample_periods():
    assert Scale(500).sample_period == pytest.approx(256e-6)
    assert Scale(500, clock_hz=6_000_000).sample_period == pytest.approx(341.333e-6, rel=1e-5)
    assert Scale(500).counts_per_rev == 2000


def test_an706_5_3_trapezoid():
    """500 lines, 8 MHz, 500 rev in 60 s with 15 s ramps: position 1,000,000 (000F4240),
    acceleration 6.36 -> 00000006, velocity 5.69 counts/sample -> about 0005B0A3 (the note
    rounds the sample count to 58,600; exact sample counts give 372,827, 0.02 % lower)."""
    t = Scale(500).trapezoid(500, 60, 15)
    assert t.position == 0x000F4240
    assert t.acceleration == 0x00000006
    assert t.velocity == pytest.approx(0x0005B0A3, rel=3e-4)
    # with the truncated acceleration the real ramp is longer than asked: the object says so
    assert t.accel_time_s == pytest.approx(372827 / 6 * 256e-6, rel=1e-4)
    assert t.accel_time_s > 15


def test_datasheet_6mhz_example():
    """500 lines, 6 MHz: position 200,000 (00030D40), velocity 6.82 counts/sample (0006D1EC),
    acceleration 0000000F."""
    s = Scale(500, clock_hz=6_000_000)
    assert s.position(100) == 0x00030D40
    assert to_fixed(6.82) == 0x0006D1EC
    # 6.82 counts/sample at T = 341.33 us is 599.4 rpm
    rpm = 6.82 / s.sample_period / s.counts_per_rev * 60
    assert s.velocity(rpm) == pytest.approx(0x0006D1EC, abs=1)
    # 0000000F is 15/65536 counts/sample^2, i.e. about 0.98 rev/s^2; one rev/s^2 rounds to it
    assert s.acceleration(1.0) == 0x0000000F


def test_an868_formulas():
    """velocity word = lines x 4 x T x rpm / 60 x 65536; acceleration word = lines x 4 x T^2 x
    rev/s^2 x 65536; position = lines x 4 x revolutions."""
    s = Scale(1000)
    T = 256e-6
    assert s.velocity(3000) == round(1000 * 4 * T * 3000 / 60 * 65536)
    assert s.acceleration(50) == round(1000 * 4 * T * T * 50 * 65536)
    assert s.position(-2.5) == -10000


def test_inverses_report_what_the_chip_really_runs():
    s = Scale(500)
    assert s.rpm(s.velocity(1000)) == pytest.approx(1000, rel=1e-5)
    assert s.rev_per_s2(s.acceleration(20)) == pytest.approx(20, rel=1e-2)
    assert s.revolutions(s.position(3.25)) == 3.25
    assert from_fixed(to_fixed(1.5)) == 1.5


def test_triangle_profile_times():
    s = Scale(500)
    ramp, total = s.profile_times(1000, velocity=100 * 65536, acceleration=65536)
    # v = 100 counts/sample needs 100 samples and 5000 counts of ramp: 1000 counts is a triangle
    assert ramp == pytest.approx(math.sqrt(1000) * 256e-6)
    assert total == pytest.approx(2 * ramp)


def test_pid_scaling_an706_5_2():
    s = Scale(500)
    T = 256e-6
    words = s.pid_to_chip(Kp=0.5, Ki=10, Kd=0.001, derivative_interval=2)
    assert words == {"kp": 128, "ki": round(65536 * 10 * T), "kd": round(256 * 0.001 / (2 * T))}
    w12 = s.pid_to_chip(Kp=0.5, Ki=10, Kd=0.001, output_bits=12)
    assert w12 == {"kp": 8, "ki": round(4096 * 10 * T), "kd": round(16 * 0.001 / T)}
    back = s.pid_from_chip(**words, derivative_interval=2)
    assert back["Kp"] == 0.5 and back["Kd"] == pytest.approx(0.001, rel=0.01)


@pytest.mark.parametrize("call,match", [
    (lambda s: s.velocity(1e9), "velocity gives raw word"),
    (lambda s: s.position(1e6), "position gives raw word"),
    (lambda s: s.acceleration(-1), "acceleration gives raw word"),
    (lambda s: s.trapezoid(10, 1, 0.6), "more than half"),
    (lambda s: s.trapezoid(10, 0, 0.1), "duration_s=0"),
    (lambda s: s.trapezoid(0.001, 100, 40), "rounds to 0"),
    (lambda s: s.pid_to_chip(Kp=200), "kp gives raw word"),
    (lambda s: s.pid_to_chip(output_bits=10), "output_bits=10"),
])
def test_out_of_range_units_are_refused(call, match):
    with pytest.raises(ValueError, match=match):
        call(Scale(500))


def test_bad_scale():
    with pytest.raises(ValueError, match="encoder_lines=0"):
        Scale(0)
    with pytest.raises(ValueError, match="1-8 MHz"):
        Scale(500, clock_hz=10e6)
