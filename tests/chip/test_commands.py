"""Typed commands whose effect needs the motion model: STT refusals, signed reads, snapshot,
RSTI clearing exactly the flags asked for, and the derivative interval reset forgets."""

from __future__ import annotations

import pytest

from lm629_host import CommandError, Status
from lm629_host.bus.opcodes import INTERRUPTS, Cmd
from lm629_host.bus.program import Program

MOVE = dict(acceleration=65536 * 2, velocity=65536 * 20)
T = 2048 / 8e6  #: one sample at 8 MHz


def test_every_refused_stt_raises_even_with_a_stale_command_error_flag(open_chip, recorder):
    """AN-706 6.5.1: a relative velocity that would go negative is a command error.  The second
    refusal must be reported too, although the flag is still set from the first."""
    chip = open_chip("sim://")
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=100, velocity=65536, velocity_mode=True)
    chip.start()
    for _ in range(2):
        chip.load_trajectory(velocity=-2 * 65536, velocity_relative=True)
        with pytest.raises(CommandError, match="STT"):
            chip.start()
        assert Status.COMMAND_ERROR in chip.read_status()
    recorder.clear()
    chip.load_trajectory(stop="smooth")
    chip.start()  # accepted: clears the stale flag first (RSTI keeping all but bit 1)
    assert recorder.data() == [("command", 0x1F), ("write", 0x0400),  # LTRJ stop smoothly
                               ("command", 0x1D), ("write", 0x007C), ("command", 0x01)]
    assert Status.COMMAND_ERROR not in chip.read_status()


def test_clean_start_sends_no_rsti(open_chip, recorder):
    chip = open_chip("sim://")
    chip.reset()
    recorder.clear()
    chip.start()
    assert recorder.data() == [("command", 0x01)]


def test_negative_positions_and_velocities_read_back_signed(open_chip):
    chip = open_chip("sim://")
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=200, velocity=3 * 65536, position=-1500, start=True)
    t_stt = chip.clock.now()
    chip.clock.sleep(0.05)
    snap = chip.snapshot()
    # still accelerating (3 counts/sample is 3 x 65536 / 200 = 983 samples away): after n
    # samples the desired velocity is -200 n and the desired position -200 n (n + 1) / 2 in
    # 16.16, read as signed words (the integer part floors: -58.9 reads -59)
    n, rest = divmod(-snap.desired_velocity, 200)
    assert rest == 0 and 0 < n < 983
    assert abs(n - (snap.time - t_stt) / T) <= 2  # ~195 samples of 256 us in 0.05 s
    assert snap.desired_position in {(-200 * m * (m + 1) // 2) >> 16 for m in (n - 1, n)}
    assert snap.desired_position < -50 and snap.real_position < 0
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=5)
    assert chip.read_desired_position() == -1500
    assert abs(chip.read_real_position() + 1500) <= 13  # kp = 20 dead band: 256/20 counts


def test_reset_sets_the_remembered_derivative_interval_back_to_one_sample(open_chip, recorder):
    chip = open_chip("sim://")
    chip.reset()
    chip.load_filter(kp=5, derivative_interval=4)
    assert chip.derivative_interval == 4
    chip.reset()
    assert chip.derivative_interval == 1
    recorder.clear()
    chip.load_filter(kp=6)  # no interval given: the remembered one, 1 sample (ds byte 0)
    data = recorder.data()
    assert data[0] == ("command", int(Cmd.LFIL))
    assert data[1][0] == "write" and data[1][1] >> 8 == 0


def test_rsti_clears_only_the_flags_asked_for(open_chip, recorder):
    """Trajectory complete (a zero-length move) and command error (a data read after a write
    command) both set; RSTI for one leaves the other, and the word on the bus is
    INTERRUPTS & ~flags (0 bits clear)."""
    chip = open_chip("sim://?strict=0")
    chip.reset()
    chip.load_trajectory(position=0, start=True, **MOVE)
    chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=1.0)
    chip.run(Program().command(Cmd.SBPA).read(1))  # wrong direction: command error
    both = Status.TRAJECTORY_COMPLETE | Status.COMMAND_ERROR
    assert chip.read_status() & both == both
    recorder.clear()
    chip.reset_interrupts(Status.TRAJECTORY_COMPLETE)
    assert recorder.data() == [("command", int(Cmd.RSTI)),
                               ("write", int(INTERRUPTS) & ~int(Status.TRAJECTORY_COMPLETE))]
    st = chip.read_status()
    assert st & Status.COMMAND_ERROR and not st & Status.TRAJECTORY_COMPLETE
    chip.reset_interrupts(Status.COMMAND_ERROR)
    assert not chip.read_status() & both


def test_the_derivative_interval_is_ds_as_in_the_profile(open_chip):
    """``load_filter(ds=7)``: the profile's and the CLI's name; ds = 7 is the LFIL control
    word's high byte 7 - 1 = 06.  ``derivative_interval=`` stays the same setting; both at
    once, or a ds out of 1..256, is an ArgumentError naming ds before any bus cycle."""
    from lm629_host import ArgumentError
    chip = open_chip("sim://?record=1")
    chip.reset()
    chip.load_filter(kp=20, ds=7)
    assert chip.derivative_interval == 7
    assert chip.transport.model.history[-1] == (Cmd.LFIL, (0x0608, 20))
    chip.load_filter(kp=20, derivative_interval=3)
    assert chip.derivative_interval == 3
    cycles = chip.transport.stats.bus_cycles
    for kwargs in ({"ds": 0}, {"ds": 257}, {"ds": 2, "derivative_interval": 2}):
        with pytest.raises(ArgumentError) as info:
            chip.load_filter(kp=1, **kwargs)
        assert info.value.argument == "ds"
    assert chip.transport.stats.bus_cycles == cycles and chip.derivative_interval == 3
