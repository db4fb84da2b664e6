"""The chip model's host interface, driven strobe by strobe as the pins would drive it.

Numbers: busy 20 us (the model's choice inside the datasheet's 15-25 us typical) = 160 clocks at
8 MHz; reset completes 1.0 ms after /RST (inside the promised 1.5 ms); sample = 2048 clocks.
"""

from __future__ import annotations


import pytest

import lm629_host
from lm629_host import ProtocolViolation, Signals, Status
from lm629_host.sim.model import ChipModel, ChipParams
from lm629_host.bus.opcodes import Cmd
from lm629_host.transports.sim import SimTransport
from lm629_host.sim.build import build_model

BUSY = 160  # clocks at 8 MHz


def model(**kw) -> ChipModel:
    kw.setdefault("strict", False)
    m = ChipModel(ChipParams(**kw))
    m.advance(2e-3)
    return m


def write_word(m: ChipModel, word: int) -> None:
    m.write_data(word >> 8)
    m.write_data(word & 0xFF)


def settle(m: ChipModel) -> None:
    m.advance_to(m.tick + BUSY)


def test_busy_after_command_byte_and_after_second_byte_of_a_word():
    m = model()
    m.write_command(Cmd.LPEI)
    assert m.read_status() & Status.BUSY
    m.advance_to(m.tick + BUSY - 1)
    assert m.read_status() & Status.BUSY
    m.advance_to(m.tick + 1)
    assert not m.read_status() & Status.BUSY
    m.write_data(0x01)  # first byte: no busy
    assert not m.read_status() & Status.BUSY
    m.write_data(0x23)  # second byte: busy
    assert m.read_status() & Status.BUSY
    settle(m)
    assert m.position_error_threshold == 0x0123


def test_write_while_busy_is_ignored_without_command_error():
    m = model()
    m.write_command(Cmd.LPEI)
    write_word(m, 0x0456)  # while busy: both bytes lost, as on silicon
    settle(m)
    assert m.position_error_threshold == 0x7FFF
    assert not m.read_status() & Status.COMMAND_ERROR
    assert len(m.violations) == 2


def test_strict_raises_on_a_write_while_busy():
    m = model(strict=True)
    m.write_command(Cmd.LPEI)
    with pytest.raises(ProtocolViolation, match="while busy"):
        m.write_data(0x04)


def test_read_while_busy_returns_stale_data():
    m = model()
    m.write_command(Cmd.LPEI)
    settle(m)
    write_word(m, 0x1234)  # the I/O register now holds 1234
    settle(m)
    m.write_command(Cmd.RDSIGS)  # busy for 20 us
    stale = m.read_data()
    assert stale == 0x12  # the high byte of the previous word, not the signals register
    settle(m)
    hi, lo = m.read_data(), m.read_data()
    assert (hi << 8 | lo) == m.signals


def test_data_without_a_command_and_wrong_direction_set_command_error():
    m = model()
    m.write_command(Cmd.STT)
    settle(m)
    m.write_data(0x00)  # STT takes no data
    assert m.read_status() & Status.COMMAND_ERROR
    m.flags = 0
    m.write_command(Cmd.LFIL)
    settle(m)
    m.read_data()  # a read where a write was expected
    assert m.read_status() & Status.COMMAND_ERROR
    m.flags = 0
    m.write_command(Cmd.RDRP)
    settle(m)
    m.write_data(0)  # a write where a read was expected
    assert m.read_status() & Status.COMMAND_ERROR


def test_new_command_aborts_an_unfinished_one():
    m = model()
    m.write_command(Cmd.LFIL)
    settle(m)
    write_word(m, 0x0008)  # kp follows...
    settle(m)
    m.write_command(Cmd.UDF)  # ...but never comes
    settle(m)
    m.advance(1e-3)
    assert m.filter.kp == 0
    assert any("aborts" in v for v in m.violations)


def test_lfil_is_double_buffered_until_udf_at_the_next_sample():
    m = model()
    m.write_command(Cmd.LFIL)
    settle(m)
    write_word(m, 0x0308)
    settle(m)
    write_word(m, 25)
    settle(m)
    assert m.filter_buffer.kp == 25 and m.filter_buffer.ds == 4  # high byte 3: 4 samples
    assert m.filter.kp == 0
    m.write_command(Cmd.UDF)
    assert m.filter.kp == 0  # not before the sample boundary
    m.advance_to(m.next_sample)
    assert m.filter.kp == 25 and m.filter.ds == 4
    assert m.signals & Signals.FILTER_UPDATED  # for one sample
    m.advance_to(m.next_sample)
    assert not m.signals & Signals.FILTER_UPDATED


def test_ltrj_is_buffered_until_stt():
    m = model()
    m.write_command(Cmd.LTRJ)
    settle(m)
    for w in (0x0002, 0x0000, 0x03E8):  # position 1000
        write_word(m, w)
        settle(m)
    assert m.trajectory.position == 1000
    assert m.motion.target_position == 0
    m.write_command(Cmd.STT)
    settle(m)
    assert m.motion.target_position == 1000
    assert not m.read_status() & Status.MOTOR_OFF  # STT turns the drive on


def test_hardware_reset_status_sequence_in_time():
    m = model()
    m.reset_pulse()
    t0 = m.tick
    assert m.read_status() == 0x00
    m.advance_to(t0 + 7_999)  # 1.0 ms at 8 MHz, minus one clock
    assert m.read_status() == 0x00
    m.advance_to(t0 + 12_000)  # 1.5 ms
    assert m.read_status() in (0x84, 0xC4)


def test_software_reset_holds_busy_and_keeps_the_error_threshold():
    m = model()
    m.write_command(Cmd.LPEI)
    settle(m)
    write_word(m, 100)
    settle(m)
    m.write_command(Cmd.RESET)
    assert m.read_status() & Status.BUSY
    m.advance(0.9e-3)
    assert m.read_status() & Status.BUSY
    m.advance(0.2e-3)
    assert m.read_status() in (0x84, 0xC4)
    assert m.position_error_threshold == 100  # RESET keeps it...
    m.reset_pulse()
    m.advance(1.5e-3)
    assert m.position_error_threshold == 0x7FFF  # ...a hardware reset sets 7FFF


def test_mski_rsti_and_hi():
    m = model()
    assert m.hi  # after reset: trajectory complete is set and enabled (mask 003E-equivalent)
    m.write_command(Cmd.MSKI)
    settle(m)
    write_word(m, 0x0000)
    settle(m)
    assert not m.hi
    m.write_command(Cmd.MSKI)
    settle(m)
    write_word(m, Status.TRAJECTORY_COMPLETE | Status.BREAKPOINT)
    settle(m)
    assert m.hi and m.signals & Signals.HOST_INTERRUPT
    m.write_command(Cmd.RSTI)
    settle(m)
    write_word(m, 0x00FF & ~Status.TRAJECTORY_COMPLETE)  # 0 clears: only trajectory complete
    settle(m)
    assert not m.read_status() & Status.TRAJECTORY_COMPLETE
    assert m.read_status() & Status.BREAKPOINT  # untouched (set since reset: bp 0 = position 0)
    assert m.hi


@pytest.mark.parametrize("variant,eight_bit_after_port12,error", [("lm628", False, False),
                                                                   ("lm629", True, True)])
def test_port12_per_variant(variant, eight_bit_after_port12, error):
    m = model(variant=variant)
    assert m.signals & Signals.EIGHT_BIT_OUTPUT
    m.write_command(Cmd.PORT12)
    settle(m)
    assert bool(m.signals & Signals.EIGHT_BIT_OUTPUT) == eight_bit_after_port12
    assert bool(m.read_status() & Status.COMMAND_ERROR) == error
    m.write_command(Cmd.PORT8)
    settle(m)
    assert m.signals & Signals.EIGHT_BIT_OUTPUT


def test_unknown_simulator_parameter_is_refused():
    with pytest.raises(ValueError, match="unknown simulator parameter"):
        build_model("sim://?clok=6000000")
    with pytest.raises(ValueError, match="fault='power'"):
        build_model("sim://?fault=power")


def test_reset_without_a_reset_line_uses_the_reset_command(recorder):
    class NoResetLine(SimTransport):
        has_reset_line = False

    transport = NoResetLine(build_model("sim://"), trace=recorder)
    chip = lm629_host.LM629(transport)
    assert chip.reset() in (0x80, 0xC0)
    assert recorder.data()[:1] == [("command", Cmd.RESET)]
    assert ("reset", 0) not in recorder.data()


def test_retried_reset_is_reported_with_every_status(open_chip):
    chip = open_chip("sim://?fault=reset")
    chip.reset_attempts = 3
    with pytest.raises(lm629_host.ResetError) as info:
        chip.reset()
    assert info.value.statuses == (0,) * 6 and info.value.attempts == 3  # 00 at once, 00 at 1.5 ms


def test_reset_error_when_rst_is_not_connected(open_chip):
    """A chip that does not read 00 right after /RST never saw the pulse (AN-706 4.4.1)."""
    chip = open_chip("sim://?fault=rst")
    with pytest.raises(lm629_host.ResetError) as info:
        chip.reset()
    assert info.value.statuses[0] != 0x00
    assert info.value.statuses[1] in (0x84, 0xC4, 0x80, 0xC0)


def test_reset_writes_nothing_into_a_chip_still_in_reset(open_chip, recorder):
    """A reset slower than the promised 1.5 ms: the check fails and MSKI/RSTI are never sent
    into the /RST window (the strict model would raise if they were)."""
    chip = open_chip("sim://?reset_s=0.0016")
    with pytest.raises(lm629_host.ResetError):
        chip.reset()
    assert ("command", 0x1C) not in recorder.data()


def test_busy_timeout_is_configurable(open_chip):
    chip = lm629_host.open("sim://?fault=busy", busy_timeout=0.02)
    t0 = chip.clock.now()
    with pytest.raises(lm629_host.BusyTimeout, match="20 ms"):
        chip.read_signals()  # RDSIGS: its busy check times out
    assert chip.clock.now() - t0 >= 0.02
    with pytest.raises(ValueError, match="busy_timeout=5e-05"):
        chip.busy_timeout = 50e-6
