"""The PID filter and output stage against numbers worked out from AN-706 5.2.3-5.2.5."""

from __future__ import annotations

from lm629_host.sim.model.pid import (
    PIDState,
    lm628_dac_code,
    lm629_pwm,
    output_code,
    pid_step,
    sat16,
)


def run(errors, kp=0, ki=0, kd=0, il=0, ds=0):
    s = PIDState()
    return s, [pid_step(s, e, kp, ki, kd, il, ds) for e in errors]


def test_proportional_term_and_8_bit_output_is_the_top_byte():
    # kp = 20 (AN-706 2.12): e = 13 -> u = 260 = 0104h -> output 01; e = 12 -> 240 -> 00
    s, us = run([13, 12], kp=20)
    assert us == [260, 240]
    assert [output_code(u, False) for u in us] == [1, 0]
    # negative: e = -1 -> u = -20 = FFECh -> top byte FF = -1 (arithmetic shift)
    assert output_code(pid_step(s, -1, 20, 0, 0, 0, 0), False) == -1
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
    pid_step(s, 256, 0, 0x7FFF, 0, 1000, 0)
    assert s.error_sum == 256
    # ... but errors of the other sign are
    pid_step(s, -100, 0, 0x7FFF, 0, 1000, 0)
    assert s.error_sum == 156 and s.integral == 0


def test_negative_integral_reads_as_a_signed_16_bit_word():
    s, us = run([-256] * 2, ki=3, il=0x7FFF)
    assert s.error_sum == -512 and s.integral == -6 and us[-1] == -6
    assert s.integral & 0xFFFF == 0xFFFA  # what RDSUM puts on the bus


def test_error_sum_is_24_bits():
    s, _ = run([32767] * 300, ki=0, il=0x7FFF)
    assert s.error_sum == (1 << 23) - 1


def test_derivative_sampled_every_ds_plus_1_samples_and_held():
    # ds = 2: derivative samples at n = 0, 3, 6; e = 0, 1, 2, ... kd = 10
    s, us = run([0, 1, 2, 3, 4, 5, 6], kd=10, ds=2)
    # n=0: 10*(0-0) = 0; n=3: 10*(3-0) = 30 held for n=3..5; n=6: 10*(6-3) = 30
    assert us == [0, 0, 0, 30, 30, 30, 30]
    s, us = run([0, 5, 5, 5], kd=100, ds=0)
    assert us == [0, 500, 0, 0]


def test_output_pins():
    assert lm628_dac_code(0, False) == 0x80 and lm628_dac_code(-128, False) == 0x00
    assert lm628_dac_code(127, False) == 0xFF and lm628_dac_code(0, True) == 0x800
    assert lm629_pwm(127) == (0, 127)  # 127/128 max positive
    assert lm629_pwm(-128) == (1, 128)  # 128/128 max negative
    assert lm629_pwm(0) == (0, 0)
    assert sat16(40000) == 32767 and sat16(-40000) == -32768
