"""The motor step (lm629_host.physics.plant) against the closed-form solution, and the chip model's
flattened sample loops (Python and C), which write the step inline for speed, against it bit
for bit.

Worked numbers (rate 1, dt 1): dw/dt = drive - coulomb sign(w) - w.
* From rest, drive 3 against coulomb 1: w = 2 (1 - e^-t), x = 2 (t - 1 + e^-t); at t = 1
  w = 1.26424, x = 0.73576.
* Coasting from w = 1 with no drive, coulomb 1: w = 2 e^-t - 1 reaches 0 at t = ln 2, having
  gone 1 - ln 2 = 0.30685 counts, and sticks there.
"""

from __future__ import annotations

import math
import random

import pytest

from lm629_host.physics.plant import decay_and_gain, motor_step
from lm629_host.sim.model import fastloop

from filter_helpers import LOOPS


def _step(x, w, drive, coulomb, rate=1.0, dt=1.0):
    decay, gain = decay_and_gain(rate, dt)
    return motor_step(x, w, drive, coulomb, rate, decay, gain, dt)


def test_breakaway_from_rest():
    x, w = _step(0.0, 0.0, 3.0, 1.0)
    assert w == pytest.approx(2 * (1 - math.exp(-1)))  # 1.26424
    assert x == pytest.approx(2 * math.exp(-1))  # 0.73576
    x, w = _step(0.0, 0.0, -3.0, 1.0)  # the other way, the same
    assert w == pytest.approx(-2 * (1 - math.exp(-1))) and x == pytest.approx(-2 * math.exp(-1))


def test_stuck_while_the_drive_does_not_break_the_friction():
    assert _step(5.25, 0.0, 1.0, 1.0) == (5.25, 0.0)  # exactly at the friction: stuck
    assert _step(5.25, 0.0, -0.999, 1.0) == (5.25, 0.0)
    assert _step(5.25, 0.0, 1.001, 1.0)[1] > 0  # just past it: moves


def test_the_friction_stops_a_coasting_shaft_within_the_sample():
    x, w = _step(0.0, 1.0, 0.0, 1.0)
    assert w == 0.0 and x == pytest.approx(1 - math.log(2))  # 0.30685
    # without friction the speed only decays: w = e^-1, x = 1 - e^-1
    x, w = _step(0.0, 1.0, 0.0, 0.0)
    assert w == pytest.approx(math.exp(-1)) and x == pytest.approx(1 - math.exp(-1))


def test_the_sample_time_scales_as_the_units_do():
    """The chip model steps in seconds (dt = 256 us), the tuner in samples (dt = 1): the same
    shaft in either unit moves the same counts."""
    ts = 256e-6
    rate, coulomb, drive = 40.0, 3000.0, 90000.0  # 1/s, counts/s^2, counts/s^2
    x_s, w_s = _step(0.0, 200.0, drive, coulomb, rate, ts)
    x_n, w_n = _step(0.0, 200.0 * ts, drive * ts * ts, coulomb * ts * ts, rate * ts, 1.0)
    assert x_s == pytest.approx(x_n, rel=1e-12) and w_s * ts == pytest.approx(w_n, rel=1e-12)


def _loop_motor(loop, out, angle, speed, volts_per_code, apv, load, coul, rate, decay, gain, ts):
    """One sample of a flattened loop with the filter and trajectory idle: only its motor step
    acts on the held output code ``out``.  Returns (angle, speed) after it."""
    ints = dict(n=1, kp=0, ki=0, kd=0, il=0, ds=1, shift=8, stall=0, cpr=2000, index_k=0,
                count=math.floor(angle), home=0, out=out, p=0, v=0, a=0, vmax=0, target=0, done=1,
                vmode=0, fwd=1, stopping=0, esum=0, elast=0, dterm=0, countdown=0, iterm=0, u=0,
                motor_off=1, bp=1 << 30, threshold=0x7FFF, stop_on_error=0, flags=0, armed=0,
                rp=0, rv=0)
    floats = dict(volts_per_code=volts_per_code, apv=apv, load=load, coul=coul, rate=rate,
                  decay=decay, gain=gain, ts=ts, angle=angle, speed=speed)
    r = dict(zip(fastloop.RESULTS, loop(tuple(ints[k] for k in fastloop.INT_ARGS),
                                        tuple(floats[k] for k in fastloop.FLOAT_ARGS))))
    assert r["ran"] == 1
    return r["angle"], r["speed"]


@pytest.mark.parametrize("name", sorted(LOOPS))
def test_the_model_fast_loops_take_this_step_bit_for_bit(name):
    """Random shafts: at rest (stuck, the drive exactly at the friction among them, or
    breaking away), moving with the drive, against it (turned round by the friction within
    the sample, or not), with and without a load."""
    rnd = random.Random(7)
    loop = LOOPS[name]
    ts = 2048 / rnd.choice([6e6, 8e6])
    for _ in range(3000):
        rate = rnd.choice([0.5, 12.0, 80.0, 400.0])
        decay, gain = decay_and_gain(rate, ts)
        apv = rnd.choice([-1, 1]) * rnd.uniform(1e3, 5e5)  # counts/s^2 per volt
        volts_per_code = rnd.choice([24 / 128, 12 / 2048])
        coul = rnd.choice([0.0, rnd.uniform(0, 2e5)])
        load = rnd.choice([0.0, rnd.uniform(-1e5, 1e5)])
        out = rnd.randint(-128, 127)
        speed = rnd.choice([0.0, rnd.uniform(-3e4, 3e4), rnd.uniform(-50, 50)])
        angle = rnd.uniform(-1e6, 1e6)
        if rnd.random() < 0.1:  # at rest with the drive exactly at the friction: stuck
            speed, coul = 0.0, abs(out * volts_per_code * apv - load)
        got = _loop_motor(loop, out, angle, speed, volts_per_code, apv, load, coul, rate, decay,
                          gain, ts)
        want = motor_step(angle, speed, out * volts_per_code * apv - load, coul, rate, decay,
                          gain, ts)
        assert got == want, (out, angle, speed, rate, coul, load)
