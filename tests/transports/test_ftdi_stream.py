"""FT232H stream compilation: exact MPSSE bytes, delays, stream cuts, and bus timing at the pins.

Expected bytes come from the pin map (lm629_host.wiring.ft232h: /CS ADBUS1, /RD ADBUS2, /WR ADBUS3,
/PS ADBUS4, /RST ADBUS6, D0-D7 on ACBUS) and FTDI AN_108's opcodes (0x80 set low byte, value,
direction; 0x82 set high byte; 0x81/0x83 read low/high byte; 0x8E n: n+1 idle clock bits;
0x8F lo hi: (n+1) x 8 idle clocks; 0x87 send immediate).
"""

from __future__ import annotations

import pytest

import lm629_host
from lm629_host import Cmd, Program
from lm629_host.transports.mpsse import StreamCompiler, streams_of, units_of

IDLE = 0xDE  # /CS /RD /WR /PS /RST and /CS of chip 1 (ADBUS7) high, TCK low
DIR = 0xDF  # TCK, /CS, /RD, /WR, /PS, /RST, ADBUS7 driven; HI (ADBUS5) the one input
SEL_CMD = 0xCC  # /CS and /PS low (chip 1 deselected)
SEL_DATA = 0xDC  # /CS low, /PS high


def status_read(sel: int) -> list[int]:
    """/RD low, two idle bits (333 ns >= 180 ns access), sample ACBUS, /RD high, one bit."""
    return [0x80, sel & ~0x04, DIR, 0x8E, 0x01, 0x83, 0x80, sel, DIR, 0x8E, 0x00]


def write_byte(sel: int, byte: int) -> list[int]:
    """Drive ACBUS, /WR low one bit (167 ns >= 100 ns), /WR high, one bit (hold, recovery)."""
    return [0x82, byte, 0xFF, 0x80, sel & ~0x08, DIR, 0x8E, 0x00, 0x80, sel, DIR, 0x8E, 0x00]


def test_udf_compiles_to_exactly_these_bytes():
    stream = StreamCompiler(tck_hz=6e6, busy_s=100e-6).compile(Program().command(Cmd.UDF).ops)
    expected = ([0x80, SEL_CMD, DIR, 0x8E, 0x00]  # select, /PS setup one bit
                + status_read(SEL_CMD)  # busy check
                + write_byte(SEL_CMD, 0x04)  # UDF
                + [0x80, IDLE, DIR, 0x82, 0x00, 0x00, 0x81, 0x87])  # idle, release, HI, flush
    assert list(stream.data) == expected
    assert [s.kind for s in stream.slots] == ["check", "pins"]
    assert stream.events == [("status", 0), ("command", 0x04)]


def test_mski_word_waits_the_documented_100us_before_its_busy_check():
    stream = StreamCompiler(tck_hz=6e6, busy_s=100e-6).compile(
        Program().command(Cmd.MSKI).write(0x1234).ops)
    data = list(stream.data)
    # 100 us at 6 MHz = 600 clocks = 75 idle bytes: 0x8F 0x4A 0x00 (n + 1 = 75)
    wait = [0x8F, 0x4A, 0x00]
    i = next(k for k in range(len(data)) if data[k:k + 3] == wait)
    after = data[i + 3:]
    # then D0-D7 released, the busy check of the word (with /PS still low from the command),
    # /PS high, both bytes, high first
    assert after[:3] == [0x82, 0x00, 0x00]
    assert after[3:14] == status_read(SEL_CMD)
    assert after[14:19] == [0x80, SEL_DATA, DIR, 0x8E, 0x00]
    assert after[19:32] == write_byte(SEL_DATA, 0x12)
    assert after[32:45] == write_byte(SEL_DATA, 0x34)
    assert data.count(0x8F) == 1  # no wait after the last transfer: the next stream owes it
    # idle bits: 2 /PS setups, 2 status reads x 3, 3 written bytes x 2 = 14, plus the 600
    assert stream.delay_s == pytest.approx((600 + 14) / 6e6)


def test_wait_and_reset_pulse_lengths():
    c = StreamCompiler(tck_hz=6e6)
    stream = c.compile(Program().reset().status().wait(1500).status().ops)
    data = bytes(stream.data)
    # /RST low for 64 clocks (10.7 us >= 8 clocks of a 1 MHz chip): 0x8F 0x07 0x00
    assert data.startswith(bytes([0x80, IDLE & ~0x40, DIR, 0x8F, 0x07, 0x00, 0x80, IDLE, DIR]))
    # 1500 us at 6 MHz = 9000 clocks = 1125 bytes: n = 1124 = 0x0464
    assert bytes([0x8F, 0x64, 0x04]) in data


def test_units_and_stream_cuts():
    p = (Program().command(Cmd.LTRJ).write(0x2A).write32(1).write32(2).write32(3)
         .status().command(Cmd.STT).sync())
    assert units_of(p.ops) == [(0, 8), (8, 9), (9, 10), (10, 11)]
    # STT acts on what LTRJ loaded: it goes in a second stream, after LTRJ's checks came back
    assert streams_of(p.ops) == [[(0, 8), (8, 9)], [(9, 10), (10, 11)]]
    # reads and loads share one stream
    snap = Program().status()
    for cmd in (Cmd.RDSIGS, Cmd.RDDP, Cmd.RDRP):
        snap.command(cmd).read(2)
    assert len(streams_of(snap.ops)) == 1
    # an action first in its program needs no cut
    assert len(streams_of(Program().status().command(Cmd.STT).sync().ops)) == 1


def test_bus_timing_is_met_by_idle_clocks_alone(open_chip):
    """command_ns=0: MPSSE commands take no time in the emulator; only the idle clocks do.
    The emulator checks every minimum of the spec's 6 MHz table at the pins."""
    chip = open_chip("sim+ftdi://?command_ns=0")
    chip.reset()
    chip.load_filter(kp=20, ki=1, kd=100, il=500)
    chip.update_filter()
    chip.load_trajectory(acceleration=0x1234, velocity=0x56789, position=-1000, start=True)
    chip.snapshot()
    assert chip.transport.device.chip_pins.timing_violations == []


def test_the_timing_checker_catches_a_too_fast_tck():
    """The same with TCK at 30 MHz (one idle bit = 33 ns): /WR pulses too short, data sampled
    too early: strict sim+ftdi:// refuses the stream."""
    with pytest.raises(lm629_host.ProtocolViolation, match="/WR pulse 33 ns"):
        with lm629_host.open("sim+ftdi://?command_ns=0&frequency=30000000") as chip:
            chip.update_filter()
