"""The core issue's acceptance scenarios, run unchanged on every simulated transport.

``sim://`` drives the chip model directly; ``sim+emu://`` goes through LinkTransport's frames
to the Python bridge far end; ``sim+avr://`` through the real bridge firmware in simavr;
``sim+ftdi://`` through the real FT232H transport and pyftdi on an emulated FT232H (also wired
with ``busy_pin=gpiol1``): the ``transport_url`` fixture of tests/conftest.py.
Every figure below comes from the application notes (AN-693 table 4, AN-706 3.7 / 4.4.1) or
the datasheet's command table.
"""

from __future__ import annotations

import time

import pytest

from lm629_host import BusyTimeout, ResetError, Signals, Status, WaitTimeout

from sim_urls import with_params


def test_an693_filter_module_puts_exactly_its_bytes_on_the_bus(transport_url, open_chip, recorder):
    """AN-693 table 4: LFIL, control word 0008 (ds = 0, kp only), kp = 000A, UDF."""
    chip = open_chip(transport_url)
    recorder.clear()
    chip.load_filter(kp=10)
    chip.update_filter()
    assert recorder.data() == [("command", 0x1E), ("write", 0x0008), ("write", 0x000A),
                               ("command", 0x04)]
    # each transfer is preceded by a status read showing busy clear (on transports that report
    # their busy checks; the bridge polls on its far side and reports none)
    cycles = recorder.cycles
    for i, c in enumerate(cycles):
        if c.kind != "status" and any(x.kind == "status" for x in cycles):
            assert i > 0 and cycles[i - 1].kind == "status", f"{c} without a busy check"
            assert not cycles[i - 1].value & Status.BUSY


def test_an706_initialisation_through_reset(transport_url, open_chip, recorder):
    """AN-706 4.4.1 / 3.7: /RST, status 00, 84 or C4 within 1.5 ms, MSKI 0, RSTI 0, 80 or C0."""
    chip = open_chip(transport_url)
    recorder.clear()
    t0 = chip.clock.now()
    status = chip.reset()
    assert status in (0x80, 0xC0)
    assert chip.clock.now() - t0 >= 1.5e-3  # the reset wait ran on the transport's clock
    assert recorder.data() == [("reset", 0), ("command", 0x1C), ("write", 0), ("command", 0x1D),
                               ("write", 0)]
    statuses = [c.value for c in recorder.cycles if c.kind == "status"]
    assert statuses[0] == 0x00
    assert any(s in (0x84, 0xC4) for s in statuses[1:])
    assert statuses[-1] in (0x80, 0xC0)
    signals = chip.read_signals()
    # 8-bit output and motor off after reset; no interrupt is enabled after MSKI 0
    assert Signals.EIGHT_BIT_OUTPUT in signals and Signals.MOTOR_OFF in signals
    assert Signals.HOST_INTERRUPT not in signals


def test_reset_error_when_the_chip_never_leaves_reset(transport_url, open_chip):
    chip = open_chip(with_params(transport_url, "fault=reset"))
    with pytest.raises(ResetError) as info:
        chip.reset()
    assert set(info.value.statuses) == {0x00}
    assert info.value.attempts == 2
    assert "00" in str(info.value) and "84 or C4" in str(info.value)


def test_busy_timeout_when_busy_is_stuck(transport_url, open_chip):
    chip = open_chip(with_params(transport_url, "fault=busy"))
    t0 = chip.clock.now()
    with pytest.raises(BusyTimeout) as info:
        chip.read_real_position()
    assert "0A (RDRP)" in str(info.value)
    assert info.value.status is not None and info.value.status & Status.BUSY
    assert chip.clock.now() - t0 >= 5e-3  # the default busy timeout, on the transport's clock


def test_ltrj_stt_words_msb_first_with_signed_position(transport_url, open_chip, recorder):
    chip = open_chip(transport_url)
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    recorder.clear()
    chip.load_trajectory(acceleration=0x1234, velocity=0x56789, position=-1000)
    chip.start()
    assert recorder.data() == [
        ("command", 0x1F), ("write", 0x002A),
        ("write", 0x0000), ("write", 0x1234),  # acceleration, MS word first
        ("write", 0x0005), ("write", 0x6789),  # velocity
        ("write", 0xFFFF), ("write", 0xFC18),  # -1000, two's complement
        ("command", 0x01)]


def test_derivative_interval_is_remembered_between_lfils(transport_url, open_chip, recorder):
    chip = open_chip(transport_url)
    chip.load_filter(kp=5, derivative_interval=4)
    recorder.clear()
    chip.load_filter(ki=7, il=100)
    assert recorder.data() == [("command", 0x1E), ("write", 0x0305), ("write", 7), ("write", 100)]


def test_breakpoint_interrupt_drives_hi_and_rsti_clears_it(transport_url, open_chip):
    chip = open_chip(transport_url)
    chip.reset()
    chip.mask_interrupts(Status.BREAKPOINT)
    # after reset the breakpoint and the desired position are both 0: the flag sets at the
    # next sample (spec, observed C4/C0)
    status = chip.wait_for(Status.BREAKPOINT, timeout=0.01)
    assert Status.BREAKPOINT in status
    assert Signals.HOST_INTERRUPT in chip.read_signals()
    chip.set_breakpoint(5000)
    chip.reset_interrupts(Status.BREAKPOINT)
    signals = chip.read_signals()
    assert Signals.BREAKPOINT not in signals and Signals.HOST_INTERRUPT not in signals


def test_wait_for_times_out_on_the_transport_clock(transport_url, open_chip):
    chip = open_chip(transport_url)
    chip.reset()
    t0 = chip.clock.now()
    with pytest.raises(WaitTimeout):
        chip.wait_for(Status.INDEX_PULSE, timeout=0.02)
    assert 0.02 <= chip.clock.now() - t0 < 0.03


def test_bad_arguments_touch_nothing(transport_url, open_chip, recorder):
    chip = open_chip(transport_url)
    before = chip.transport.stats.as_dict()
    recorder.clear()
    with pytest.raises(ValueError, match="kp=32768"):
        chip.load_filter(kp=0x8000)
    with pytest.raises(ValueError, match="position"):
        chip.load_trajectory(position=0x40000000)
    assert recorder.cycles == []
    assert chip.transport.stats.as_dict() == before


def test_signed_reads_of_a_move_below_minus_65536(transport_url, open_chip):
    """Reads come back signed: RDDP/RDRP/RDDV as 32-bit two's complement (high word FFFE
    for -70000), RDRV 16-bit.  A fast move far below zero: the desired position ends exactly on
    -70000 (0xFFFEEE90), the motor lags behind but runs backwards."""
    chip = open_chip(transport_url)
    chip.reset()
    chip.define_home()
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=10 << 16, velocity=1000 << 16, position=-70000, start=True)
    chip.clock.sleep(0.02)  # 78 samples: still accelerating at 10 counts/sample^2
    assert chip.read_desired_velocity() < -(100 << 16)
    assert chip.read_real_velocity() < 0
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=1)
    assert chip.read_desired_position() == -70000
    assert chip.read_desired_velocity() == 0
    assert chip.read_real_position() < 0
    assert chip.read_integration_sum() == 0  # ki = 0


def test_lm628_port12_and_port8_switch_the_output_mode(transport_url, open_chip):
    chip = open_chip(with_params(transport_url, "chip=lm628"))
    chip.reset()
    chip.port12()
    assert Signals.EIGHT_BIT_OUTPUT not in chip.read_signals()
    chip.reset()  # a reset returns the port to 8 bits; reset() re-issues PORT12
    assert Signals.EIGHT_BIT_OUTPUT not in chip.read_signals()
    chip.port8()
    assert Signals.EIGHT_BIT_OUTPUT in chip.read_signals()


def test_nothing_sleeps_on_the_wall_clock(transport_url, open_chip, monkeypatch):
    """Every simulated transport waits on its own clock: a reset (1.5 ms), 0.2 s of sleep and
    a 0.05 s wait_for timeout run with time.sleep forbidden."""
    def forbidden(seconds):
        raise AssertionError(f"time.sleep({seconds}) on {transport_url}")

    monkeypatch.setattr(time, "sleep", forbidden)
    chip = open_chip(transport_url)
    chip.reset()
    t0 = chip.clock.now()
    chip.clock.sleep(0.2)
    with pytest.raises(WaitTimeout):
        chip.wait_for(Status.INDEX_PULSE, timeout=0.05)
    assert chip.clock.now() - t0 >= 0.25
