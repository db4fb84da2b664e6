"""Shaped moves (AN-706 4.5.3): the planner's pieces, and an S-curve run on the simulator.

The plan is checked against the shape's own arithmetic (a jerk-limited move's seven segments
cover the distance in V/A + A/J + D/V seconds); the run against the chip's registers at every
sample (the model's sample loop observed, ``fast=0``): the move ends exactly on its target, the
chip's velocity is each piece's velocity by the end of that piece (the recorded velocity
follows the plan within one piece), and the pieces go out at least 10 ms apart (AN-706 4.6.2).
"""

from __future__ import annotations

import math

import pytest

import lm629_host
from lm629_host.errors import ArgumentError
from lm629_host.physics.pid import sample_period_s
from lm629_host.chip.shapes import Points, SCurve, ShapedMove, plan

from sim_urls import UNO, available, ready_chip

T = sample_period_s(8e6)
#: 20000 counts at up to 20000 counts/s, 150000 counts/s^2, 3e6 counts/s^3
D, V, A, J = 20000, 20000.0, 150000.0, 3e6


def test_s_curve_segments_cover_the_distance_in_the_jerk_limited_time():
    p = plan(SCurve(V, A, J), D, T)
    # reaches V: ramps of V/A + A/J each (mean velocity V/2), the rest at V
    assert p.duration == pytest.approx(D / V + V / A + A / J, rel=1e-9)
    assert p.position_at(p.duration) == pytest.approx(D, abs=1e-6)
    assert p.velocity_at(p.duration / 2) == pytest.approx(V)
    assert p.acceleration_at(A / J + 0.01) == pytest.approx(A, rel=1e-3)  # the constant part
    assert p.acceleration_at(A / J / 2) == pytest.approx(J * A / J / 2, rel=1e-3)  # the jerk
    # pieces 20 ms apart, each the mean velocity over its piece: their distance is the move's
    assert all(b.t - a.t == pytest.approx(0.02) for a, b in zip(p.pieces, p.pieces[1:]))
    covered = sum(piece.velocity / 65536 / T * 0.02 for piece in p.pieces[:-1])
    covered += p.pieces[-1].velocity / 65536 / T * (p.duration - p.pieces[-1].t)
    assert covered == pytest.approx(D, abs=len(p.pieces))  # rounding: < 1 count a piece
    # the acceleration word lets the chip reach the largest step within one piece, and is
    # the plan's peak acceleration (A, in 16.16 counts/sample^2) to within the rounding
    steps = [b.velocity - a.velocity for a, b in zip(p.pieces, p.pieces[1:])]
    assert p.acceleration * (math.floor(0.02 / T) - 1) >= max(abs(s) for s in steps)
    assert p.acceleration == pytest.approx(A * T * T * 65536, rel=0.03)


def test_a_short_s_curve_never_reaches_its_velocity_and_points_give_the_users_profile():
    p = plan(SCurve(V, A, J), 1000, T)
    assert p.position_at(p.duration) == pytest.approx(1000, abs=1e-6)
    assert max(p.velocity_at(k * 1e-3) for k in range(1000)) < V
    tri = plan(Points([(0, 0), (0.1, 10000), (0.2, 0)]), -1000, T)
    assert tri.duration == pytest.approx(0.2)
    assert tri.velocity_at(0.1) == pytest.approx(-10000)  # the target's sign is the direction
    with pytest.raises(ArgumentError, match="start at"):
        Points([(0.1, 0), (0.2, 0)])
    with pytest.raises(ArgumentError, match="piece_s=0.002"):
        plan(SCurve(V, A, J), D, T, piece_s=0.002)


def _observed(url: str):
    """A chip, and the list the model appends (tick, desired velocity word, position error)
    to at every sample."""
    chip = lm629_host.open(url)
    chip.reset()
    chip.load_filter(kp=20, kd=100)
    chip.update_filter()
    model = chip.transport.model
    log: list[tuple[int, int, int]] = []
    sample = model._sample

    def observed(motion):
        sample(motion)
        log.append((model.tick, motion.desired_velocity, motion.position_error()))

    model._sample = observed
    return chip, log


def test_s_curve_move_ends_on_target_and_follows_its_pieces():
    chip, log = _observed("sim://?fast=0")
    with chip:
        move = chip.move_profile(D, SCurve(V, A, J))
        assert isinstance(move, ShapedMove) and move.target == D
        result = move.wait()
        assert chip.read_desired_position() == D  # exactly: the chip's own landing
        assert abs(result.error) <= chip.move_rules.tolerance
        pieces = move.plan.pieces
        # every piece went out as planned, 10 ms or more after the one before, on time on
        # sim://; the last may find the chip landed by its own deceleration, or be faster
        # than planned: it covers what the chip has left (a chip slowing behind its caps)
        n = len(move.words)
        assert len(pieces) - 1 <= n <= len(pieces)
        assert move.words[:-1] == [p.velocity for p in pieces[:n - 1]]
        assert move.words[-1] >= pieces[n - 1].velocity
        assert move.resyncs == 0 and move.lag == 0
        assert all(b - a >= 10e-3 for a, b in zip(move.piece_times, move.piece_times[1:]))
        assert max(abs(j) for j in move.jitter) < 1e-3
        # by the end of each piece the chip's velocity is that piece's, but in the last two:
        # there the chip's own deceleration takes over to land exactly on the target
        start_tick = round(move.t0 * 8e6)
        by_tick = {tick: v for tick, v, _ in log}
        ticks = sorted(by_tick)
        for k, piece in enumerate(pieces[:-2]):
            end = start_tick + round(move.piece_times[k + 1] * 8e6)  # the next piece's STT
            at = max(t for t in ticks if t < end)
            assert by_tick[at] == piece.velocity, (k, by_tick[at], piece.velocity)


# ---------------------------------------------------------------------------------- on a bridge
UNO_EMU = f"sim+emu://?{UNO}"


def _chip(url: str) -> lm629_host.LM629:
    return ready_chip(url)


@pytest.mark.parametrize("url", [UNO_EMU, f"sim+avr://?{UNO}"])
def test_behind_an_uno_the_bridge_times_the_pieces_not_usb(url):
    """PROFILE on the Python far end and on the firmware in simavr, behind an Uno's 16U2 (4.096
    ms flush tick): every piece goes out within a bus program of its time on the bridge's clock
    (< 1 ms); timed from the host instead, a piece is late by up to the USB tick."""
    if not available(url):
        pytest.skip(f"{url}: not available here")
    with _chip(url) as chip:
        move = chip.move_profile(D, SCurve(V, A, J))
        assert move.far and chip.transport.far_profiles
        result = move.wait()
        assert chip.read_desired_position() == D
        assert abs(result.error) <= chip.move_rules.tolerance
        state = move.far_state
        assert state is not None and not state.cancelled
        assert (state.issued, state.pending) == (len(move.plan.pieces) - 1, 0)
        far_late = state.late_max_s
    with _chip(url) as chip:
        chip.transport.far_profiles = False  # the same move, pieces timed from the host
        move = chip.move_profile(D, SCurve(V, A, J))
        move.wait()
        host_late = max(move.jitter)
    assert far_late < 1e-3
    assert host_late > 3e-3  # about one 4.096 ms flush tick


def test_a_stop_drops_the_pieces_still_pending():
    """An emergency stop (LTRJ) reaches the chip in the middle of the S-curve: the bridge drops
    what it still holds (PROFILE_CANCELLED), so no later piece restarts the stopped motor."""
    from lm629_host import emergency_stop
    with _chip(UNO_EMU) as chip:
        move = chip.move_profile(D, SCurve(V, A, J))
        chip.clock.sleep(0.3)
        emergency_stop(chip)
        chip.clock.sleep(move.plan.duration)  # past every piece's time
        state = chip.transport.profile(None, [], new=False)
        assert state.cancelled and state.pending == 0
        assert 0 < state.issued < len(move.plan.pieces) - 1
        assert chip.snapshot().desired_velocity == 0


def test_the_bridge_refuses_pieces_closer_than_10_ms():
    from lm629_host.errors import TransportError
    with _chip("sim+emu://?fast_baud=1000000") as chip:
        before = chip.transport.emulator.stats.pieces
        with pytest.raises(TransportError, match="BAD_PROFILE"):
            chip.transport.profile(None, [(0.02, 65536), (0.025, 65536)], new=True)
        state = chip.transport.profile(None, [], new=False)
        assert state.pending == 0
        chip.clock.sleep(0.05)
        assert chip.transport.emulator.stats.pieces == before
        assert chip.transport.profile(None, [], new=False).issued == 0
