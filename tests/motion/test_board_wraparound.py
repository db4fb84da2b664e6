"""A board's moves across the position register's wrap (AN-706 6.5.2): targets are register
values, reached the short way round as :meth:`LM629.move_to` reaches them.

Both axes start 4096 counts below 3FFFFFFF (``reset_position=0x3FFFF000``).  The register
values -1073725920 and -1073733920 are 2^30 - 1073725920 = 15904 and 7904 counts past the
wrap: travels of 20000 and 12000 counts, a line of sqrt(20000^2 + 12000^2) = 23324 counts.
c351da8 planned them as extended targets 2^31 away (37 hours) and its wait never returned.
"""

from __future__ import annotations

import math

import pytest

import lm629_host
from lm629_host.bus.opcodes import Cmd
from lm629_host.chip.move import MoveTooLong

from sim_urls import available, with_params

NEAR_TOP = 0x3FFFF000
TOP = 1 << 30
URLS = ("sim://", "sim+emu://?baud=1000000", "sim+avr://?baud=1000000")
T = 2048 / 8e6


def _board(url: str) -> lm629_host.Board:
    if not available(url):
        pytest.skip(f"{url}: not available here")
    board = lm629_host.open_board(with_params(url, f"axes=2&reset_position={NEAR_TOP}&record=1"))
    board.reset()
    for a in board.axes:
        a.load_filter(kp=20, kd=200)
        a.update_filter()
    return board


def _truth(board: lm629_host.Board) -> list[int]:
    """Each model's unwrapped real position (the simulator's, read beside the driver)."""
    return [m.motion.motor.count - m.motion.home_count for m in board.transport.models]


@pytest.mark.parametrize("url", URLS)
def test_a_line_to_register_values_past_the_wrap_is_short(url):
    board = _board(url)
    try:
        x, y = board.axes
        m = board.move_linear({x: -1073725920, y: -1073733920}, velocity=4 * 65536,
                              acceleration=6553)
        assert m.plan is not None
        assert [ap.target - ap.start for ap in m.plan.axes] == [20000, 12000]
        length = math.hypot(20000, 12000)
        # 4 counts/sample along the line, 0.1 counts/sample^2: d/v + v/a samples
        assert m.plan.samples == pytest.approx(length / 4 + 40, rel=1e-6)
        results = m.wait(timeout=10)
        assert [r.target for r in results] == [TOP + 15904, TOP + 7904]
        assert all(abs(r.error) <= 20 for r in results)
        for got, want in zip(_truth(board), (TOP + 15904, TOP + 7904)):
            assert abs(got - want) <= 20
        assert [a.read_real_position() - t for a, t in zip(board.axes, _truth(board))] == [0, 0]
        # and back across, to the values below the wrap
        back = board.move({x: NEAR_TOP, y: NEAR_TOP}, velocity=4 * 65536, acceleration=6553)
        assert [mv.target for mv in back.moves] == [NEAR_TOP, NEAR_TOP]
        back.wait(timeout=10)
        assert all(abs(t - NEAR_TOP) <= 20 for t in _truth(board))
    finally:
        board.close()


def test_a_board_move_planned_too_long_is_refused_before_anything_moves():
    """The register value 20000 from 4096 below the top: 1073717728 counts the short way."""
    board = _board("sim://")
    try:
        x, y = board.axes
        for m in board.transport.models:
            m.record_clear()
        with pytest.raises(MoveTooLong) as e:
            board.move({x: 20000, y: NEAR_TOP}, velocity=65536, acceleration=655)
        assert e.value.distance == 1073717728
        with pytest.raises(MoveTooLong):
            board.move_linear({x: 20000, y: NEAR_TOP + 10}, velocity=65536, acceleration=655)
        sent = [c for m in board.transport.models for c, _ in m.history]
        assert Cmd.RDSIGS in sent and not {Cmd.LTRJ, Cmd.STT} & set(sent)  # read, never moved
    finally:
        board.close()
