"""The snapshot: one builder (:func:`add_snapshot`) and one decoder (:func:`snapshot_of`) for
every program that reads one (a chip's snapshot, a board's, a far-side wait's, a full recording
row).  The words are decoded as the chip's two's complement (the reference's data-reporting
commands: RDDP/RDRP/RDDV 32 bits high word first, RDRV/RDSUM 16 bits)."""

from __future__ import annotations

import pytest

import lm629_host
from lm629_host.bus.opcodes import Signals, Status, s32_words
from lm629_host.bus.program import Op, Program, ProgramResult
from lm629_host.bus.snapshot import SNAPSHOT_WORDS, add_snapshot, snapshot_at, snapshot_of


@pytest.mark.parametrize(("hi", "lo", "value"), [
    (0x0000, 0x0000, 0), (0x7FFF, 0xFFFF, 2**31 - 1), (0x8000, 0x0000, -2**31),
    (0xFFFF, 0xFFFF, -1), (0xFFFF, 0xFA24, -1500), (0x0001, 0x0000, 65536)])
def test_two_words_read_high_first_are_one_signed_32_bit_value(hi, lo, value):
    assert s32_words(hi, lo) == value


def test_the_program_reads_status_then_signals_positions_velocities_and_sum():
    ops = [(o.op, o.arg) for o in add_snapshot(Program()).ops if o.op is not Op.SYNC]
    assert ops[0][0] is Op.STATUS
    # RDSIGS 0Ch, RDDP 08h, RDRP 0Ah, RDDV 07h, RDRV 0Bh, RDSUM 0Dh: 1+2+2+2+1+1 words
    assert [a for o, a in ops if o is Op.COMMAND] == [0x0C, 0x08, 0x0A, 0x07, 0x0B, 0x0D]
    assert sum(1 for o, _ in ops if o is Op.READ) == SNAPSHOT_WORDS == 9


def test_words_decode_signed_into_their_fields():
    words = (0x0102, 0xFFFF, 0xFA24, 0x0000, 0x05DC, 0xFFFD, 0x8000, 0xFFFD, 0x8000)
    s = snapshot_of(0x84, words, 1.5)
    assert s.status == Status(0x84) and s.signals == Signals(0x0102)
    assert (s.desired_position, s.real_position) == (-1500, 1500)
    assert s.desired_velocity == -3 * 65536 + 0x8000  # -2.5 counts/sample in 16.16
    assert (s.real_velocity, s.integration_sum) == (-3, -32768)
    assert s.following_error == -3000 and s.time == 1.5


def test_the_kth_snapshot_of_a_longer_program_takes_its_own_words_and_status():
    a = (0, 0, 1, 0, 2, 0, 3, 4, 5)
    b = (0, 0xFFFF, 0xFFFF, 0xFFFF, 0xFFFE, 0, 0, 0, 0)
    r = ProgramResult(words=a + b, statuses=(0x80, 0x04, 0x00))
    assert snapshot_at(r, 0, 0.0).desired_position == 1
    second = snapshot_at(r, 1, 0.0)
    assert (second.status, second.desired_position, second.real_position) == (4, -1, -2)
    assert snapshot_at(r, 1, 0.0, status_at=2).status == 0


def test_a_board_reads_each_axis_with_its_own_snapshot():
    with lm629_host.open_board("sim://?axes=2") as board:
        for a in board.axes:
            a.load_filter(kp=20)
            a.update_filter()
            a.reset_interrupts()  # the flags a reset leaves set: trajectory complete among them
        board.axes[1].load_trajectory(acceleration=200, velocity=3 * 65536, position=-1500,
                                      start=True)
        board.axes[1].wait_for(Status.TRAJECTORY_COMPLETE, timeout=5)
        s0, s1 = board.snapshots()
        assert (s0.desired_position, s1.desired_position) == (0, -1500)
        assert s1.desired_position == board.axes[1].read_desired_position()
        assert Status.TRAJECTORY_COMPLETE in s1.status
        assert Status.TRAJECTORY_COMPLETE not in s0.status


def test_a_full_recording_row_decodes_as_the_snapshot_does():
    chip = lm629_host.open("sim://")
    with chip:
        chip.reset()
        chip.load_filter(kp=20)
        chip.update_filter()
        chip.load_trajectory(acceleration=200, velocity=3 * 65536, position=-1500, start=True)
        chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=5)
        chip.clock.sleep(0.1)  # at rest: every register holds still
        snap = chip.snapshot()
        row = chip.record(1e-3, 2e-3, full=True).rows[-1]
        assert snap.desired_position == row.desired == -1500
        assert (row.real, row.signals, row.real_velocity, row.integration_sum) == (
            snap.real_position, snap.signals, snap.real_velocity, snap.integration_sum)
        assert row.desired_velocity == snap.desired_velocity == 0
