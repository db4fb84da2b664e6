"""The PID filter and output stage (:mod:`lm629_host.physics.pid`) against numbers worked out from
AN-706 5.2.3-5.2.5, and the chip model's two flattened sample loops (``fastloop.py_loop`` and
``_fastloop.c``) against it, bit for bit; the integration limit in every loop the model runs."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lm629_host import Status

from lm629_host.physics.pid import (
    U_FULL_SCALE,
    PIDState,
    derivative_term,
    filter_sum,
    full_scale,
    holds,
    lm628_dac_code,
    lm629_pwm,
    output_code,
    output_shift,
    pid_step,
    sat16,
    skip_held,
)

from filter_helpers import LOOPS, loop_filter


def run(errors, kp=0, ki=0, kd=0, il=0, ds=1):
    s = PIDState()
    return s, [pid_step(s, e, kp, ki, kd, il, ds) for e in errors]


def test_proportional_term_and_8_bit_output_is_the_top_byte():
    # kp = 20 (AN-706 2.12): e = 13 -> u = 260 = 0104h -> output 01; e = 12 -> 240 -> 00
    s, us = run([13, 12], kp=20)
    assert us == [260, 240]
    assert [output_code(u, False) for u in us] == [1, 0]
    # negative: e = -1 -> u = -20 = FFECh -> top byte FF = -1 (arithmetic shift)
    assert output_code(pid_step(s, -1, 20, 0, 0, 0, 1), False) == -1
    # 12-bit mode (LM628 PORT12): top 12 bits, 260 -> 0010h
    assert output_code(260, True) == 16


def test_error_saturates_to_16_bits_before_the_products():
    # e = 100000 -> 7FFF; kp = 1: u = 32767
    assert run([100_000], kp=1)[1] == [32767]
    assert run([-100_000], kp=1)[1] == [-32768]


def test_product_overflow_saturates_the_output():
    # kp = 7FFF, e = 2: 65534 overflows 16 bits -> 7FFF (AN-706 5.2.5), output 127 (PWM 127/128)
    u = run([2], kp=0x7FFF)[1][0]
    assert u == 0x7FFF and output_code(u, False) == 127
    u = run([-2], kp=0x7FFF)[1][0]
    assert u == -0x8000 and output_code(u, False) == -128
    # the sum of three terms saturates too: 20000 + 20000 -> 7FFF
    s, us = run([0, 1], kp=20000, kd=20000)
    assert us == [0, 32767]


def test_integral_uses_top_16_of_24_bits_and_the_limit():
    # e = 100 for 5 samples: sum 500 -> top 16 bits 500 >> 8 = 1 -> ki = 4 gives 4
    s, us = run([100] * 5, ki=4, il=1000)
    assert s.error_sum == 500 and us[-1] == 4 and s.integral == 4
    assert us[:2] == [0, 0] and us[2] == 4  # 300 >> 8 = 1 from the third sample
    # limit: ki = 7FFF, il = 1000: 7FFF * (256 >> 8) = 32767 -> limited to 1000
    s, us = run([256], ki=0x7FFF, il=1000)
    assert us == [1000] and s.integral == 1000
    # once at the limit, further errors of the same sign are not summed ...
    pid_step(s, 256, 0, 0x7FFF, 0, 1000, 1)
    assert s.error_sum == 256
    # ... but errors of the other sign are
    pid_step(s, -100, 0, 0x7FFF, 0, 1000, 1)
    assert s.error_sum == 156 and s.integral == 0


def test_negative_integral_reads_as_a_signed_16_bit_word():
    s, us = run([-256] * 2, ki=3, il=0x7FFF)
    assert s.error_sum == -512 and s.integral == -6 and us[-1] == -6
    assert s.integral & 0xFFFF == 0xFFFA  # what RDSUM puts on the bus


def test_error_sum_is_24_bits():
    s, _ = run([32767] * 300, ki=0, il=0x7FFF)
    assert s.error_sum == (1 << 23) - 1


def test_derivative_sampled_every_ds_samples_and_held():
    # ds = 3 (an interval of 3 samples, LFIL byte 2): derivative samples at n = 0, 3, 6;
    # e = 0, 1, 2, ... kd = 10
    s, us = run([0, 1, 2, 3, 4, 5, 6], kd=10, ds=3)
    # n=0: 10*(0-0) = 0; n=3: 10*(3-0) = 30 held for n=3..5; n=6: 10*(6-3) = 30
    assert us == [0, 0, 0, 30, 30, 30, 30]
    s, us = run([0, 5, 5, 5], kd=100, ds=1)
    assert us == [0, 500, 0, 0]


def test_output_pins():
    assert lm628_dac_code(0, False) == 0x80 and lm628_dac_code(-128, False) == 0x00
    assert lm628_dac_code(127, False) == 0xFF and lm628_dac_code(0, True) == 0x800
    assert lm629_pwm(127) == (0, 127)  # 127/128 max positive
    assert lm629_pwm(-128) == (1, 128)  # 128/128 max negative
    assert lm629_pwm(0) == (0, 0)
    assert sat16(40000) == 32767 and sat16(-40000) == -32768


def test_full_scale_is_u_at_full_drive_in_both_widths():
    # u = 8000h is full drive: -128 of 128 (8-bit), -2048 of 2048 (12-bit)
    assert full_scale(False) == 128 and full_scale(True) == 2048
    assert output_code(-U_FULL_SCALE, False) == -full_scale(False)
    assert output_code(-U_FULL_SCALE, True) == -full_scale(True)
    assert output_shift(False) == 8 and output_shift(True) == 4


def test_filter_sum_and_derivative_term_saturate_like_the_filter():
    # kd x difference: the difference is saturated first (40000 -> 7FFF), then the product
    assert derivative_term(1, 40000) == 32767 and derivative_term(2, -20000) == -32768
    # kp x e saturates before the ki and kd terms are added: 7FFF - 1000 + 0 = 31767
    assert filter_sum(2, 20000, -1000, 0) == 31767
    assert filter_sum(1, 30000, 2000, 1000) == 32767


def test_holds_and_skip_held_match_stepping_sample_by_sample():
    # ki = 0, il = 500, e = 7 held: the sum grows by 7 a sample, nothing else changes but the
    # derivative's countdown (ds = 4)
    s = PIDState()
    pid_step(s, 7, 40, 0, 0, 500, 4)
    assert holds(s, 7, 0, 500)
    stepped = PIDState(s.error_sum, s.last_error, s.derivative, s.countdown, s.integral, s.output)
    for _ in range(10):
        pid_step(stepped, 7, 40, 0, 0, 500, 4)
    skip_held(s, 10, 7, 500, 4)
    assert s == stepped and s.error_sum == 77
    # a held derivative term, a last error that differs or integral action: not held
    assert not holds(PIDState(derivative=5), 0, 0, 0)
    assert not holds(PIDState(last_error=3), 7, 0, 0)
    assert not holds(PIDState(last_error=7), 7, 1, 100)
    # il = 0: a sum of the other sign unwinds towards 0 (model choice 21)
    assert not holds(PIDState(last_error=7, error_sum=-300), 7, 0, 0)


# ---------------------------------------------------------------------------------- cross-check
GAIN = st.integers(0, 0x7FFF)


@settings(max_examples=300, deadline=None)
@given(kp=GAIN, ki=GAIN, kd=GAIN, il=GAIN, ds=st.integers(1, 256), twelve=st.booleans(),
       errors=st.lists(st.one_of(st.integers(-300, 300), st.integers(-40000, 40000),
                                 st.integers(-(1 << 30), (1 << 30) - 1)),
                       min_size=1, max_size=40))
def test_model_loops_compute_this_filter_bit_for_bit(kp, ki, kd, il, ds, twelve, errors):
    """The model's flattened loops (Python and C) and :func:`pid_step` give the same u(n),
    output code and filter memory at every sample, for any gains and errors: small errors
    (the dead band, the integral's top 16 bits), large ones (16-bit saturation of e, of the
    products and of the sum) and very large ones (the 24-bit sum's saturation)."""
    s = PIDState()
    expected = []
    for e in errors:
        u = pid_step(s, e, kp, ki, kd, il, ds)
        expected.append((u, output_code(u, twelve),
                         dict(esum=s.error_sum, elast=s.last_error, dterm=s.derivative,
                              countdown=s.countdown, iterm=s.integral, u=s.output)))
    for name, loop in LOOPS.items():
        assert loop_filter(loop, errors, kp, ki, kd, il, ds, twelve) == expected, name


@pytest.mark.parametrize("loop", ["0", "py", "c"])
@pytest.mark.parametrize("target,ki,il", [(-1000, 300, 500), (1000, 300, 500),
                                          (-3000, 100, 12345)])
def test_integration_term_is_limited_to_il_both_signs(open_chip, loop, target, ki, il):
    """Shaft locked (stall=1), kp = kd = 0: the desired position runs to ``target`` and stays
    there, so the error ends at e = target and the 24-bit sum keeps growing by e until the
    term ki x (sum >> 8) passes il; from then on RDSUM reads exactly sign(e) x il.  ki and il
    are chosen so that no multiple of ki equals il (300 x k never is 500, 100 x k never is
    12345): an unlimited term would read the first multiple past il (-600, -12400...)."""
    if loop == "c" and "c" not in LOOPS:
        pytest.skip("the C sample loop is not built here (pip install -e . builds it)")
    chip = open_chip(f"sim://?stall=1&fast={loop}")
    chip.reset()
    chip.load_filter(kp=0, ki=ki, kd=0, il=il)
    chip.update_filter()
    chip.load_trajectory(position=target, start=True, acceleration=65536 * 2, velocity=65536 * 20)
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=1.0)
    chip.clock.sleep(0.05)  # ~200 more samples at the limit
    expected = il if target > 0 else -il
    assert chip.read_integration_sum() == expected
    assert chip.read_real_position() == 0  # the shaft did not move: e stayed = target
