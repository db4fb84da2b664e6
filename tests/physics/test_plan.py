"""The trapezoid/triangle planner (lm629_host.physics.plan) against numbers worked from AN-706 5.3
and against the chip model's generator.

Worked numbers: velocity word 0x20000 is 2 counts/sample, acceleration word 0x400 is
1/64 count/sample^2.  The ramp to 2 counts/sample takes 2 / (1/64) = 128 samples and covers
v^2 / 2a = 128 counts; both ramps 256 counts.  So a move of 256 counts is the boundary
(v^2 = d a); longer ones cruise, shorter ones are triangles peaking at sqrt(d a).  At 8 MHz
a sample is 2048 / 8e6 = 256 us.
"""

from __future__ import annotations

import math

import pytest

from lm629_host.physics.plan import plan
from lm629_host.sim.model.trajectory import Trajectory

V, A = 0x20000, 0x400


def test_trapezoid_phases_in_samples_and_seconds():
    p = plan(12000, V, A)
    assert not p.triangle and p.peak == 2.0
    # 128 samples up, (12000 - 256) / 2 = 5872 cruising, 128 down
    assert (p.accel_samples, p.cruise_samples, p.decel_samples) == (128.0, 5872.0, 128.0)
    assert p.samples == 6128.0  # d/v + v/a = 6000 + 128
    assert p.seconds(8e6) == pytest.approx(6128 * 256e-6)  # 1.568768 s
    assert p.accel_seconds(8e6) == pytest.approx(0.032768)
    assert p.seconds(8e6, margin_samples=2) == pytest.approx(6130 * 256e-6)
    assert p.seconds(4e6) == pytest.approx(2 * p.seconds(8e6))  # 512 us samples
    # counts travelled: a k^2 / 2 on the ramp, half-way at half time, all of it at the end
    assert p.travelled(128) == pytest.approx(128.0)
    assert p.travelled(3064) == pytest.approx(6000.0)
    assert p.travelled(6128) == 12000.0 and p.travelled(7000) == 12000.0
    assert plan(-12000, V, A) == p  # either way: the size counts


def test_triangle_peaks_below_the_velocity():
    p = plan(200, V, A)
    assert p.triangle and p.cruise_samples == 0.0
    assert p.peak == pytest.approx(math.sqrt(200 / 64))  # 1.7678 counts/sample
    assert p.accel_samples == pytest.approx(math.sqrt(200 * 64))  # 113.137 samples
    assert p.samples == pytest.approx(2 * math.sqrt(200 * 64))  # 226.27, not 200/2 + 128
    assert p.travelled(p.accel_samples) == pytest.approx(100.0)  # half-way at the peak


def test_the_boundary_between_trapezoid_and_triangle():
    at = plan(256, V, A)  # v^2 = d a exactly: the ramps meet, no cruise
    assert not at.triangle and at.cruise_samples == 0.0 and at.samples == 256.0
    below = plan(255, V, A)
    assert below.triangle and below.samples == pytest.approx(2 * math.sqrt(255 * 64))  # 255.50
    above = plan(257, V, A)
    assert not above.triangle and above.cruise_samples == 0.5 and above.samples == 256.5


def test_a_zero_distance_takes_no_time_and_a_zero_word_never_arrives():
    assert plan(0, V, A).samples == 0.0
    assert plan(100, 0, A).samples == math.inf and plan(100, V, 0).samples == math.inf


def _model_samples(distance: int, velocity: int, acceleration: int) -> tuple[int, list[int]]:
    """Samples the chip model's generator takes to complete the move from rest at 0, and
    its desired position (whole counts) at each."""
    t = Trajectory()
    t.max_velocity, t.acceleration, t.target, t.done = velocity, acceleration, distance, False
    path = []
    while True:
        finished, _wrapped = t.step()
        path.append(t.position >> 16)
        if finished:
            return len(path), path


@pytest.mark.parametrize("distance, velocity, acceleration", [
    (12000, V, A), (200, V, A), (255, V, A), (256, V, A), (257, V, A),
    (1000, 0x10000, 655), (5000, 0x30000, 0x2000), (400, 0x40000, 655), (10, 0x10000, 0x10000),
    (2000, 0x40000, 0x200),
])
def test_the_model_completes_within_the_last_sample_of_the_plan(distance, velocity, acceleration):
    """The generator runs whole samples: it completes between one sample before the plan's
    continuous time and that time (so a margin is the caller's: the STT's wait for the next
    sample).  The plan's sample-by-sample path lands on the target and keeps within a count
    of the generator's; its braking rule is simpler than the chip's landing (it brakes on
    v^2 / 2a + v), so it reaches the last count up to 10 samples early here (the generator
    then crawls the last fraction of a count)."""
    p = plan(distance, velocity, acceleration)
    n, path = _model_samples(distance, velocity, acceleration)
    assert p.samples - 1 <= n <= p.samples
    ours = p.desired()
    assert ours[-1] == distance and n - 10 <= len(ours) <= n
    ours += [distance] * (n - len(ours))
    assert max(abs(a - b) for a, b in zip(ours, path)) <= 1


def test_a_triangle_is_not_timed_as_a_trapezoid():
    """d/v + v/a (+ 2) for a move that never reaches the velocity: 400 counts at 4
    counts/sample and 0.01 count/sample^2 would take 100 + 400 = 500 samples; the ramps meet
    at 2 counts/sample after 200 samples, 400 in all, as the model runs it."""
    p = plan(400, 0x40000, 655)
    n, _path = _model_samples(400, 0x40000, 655)
    assert p.triangle and n == 400 and p.samples == pytest.approx(400.1, abs=0.05)
