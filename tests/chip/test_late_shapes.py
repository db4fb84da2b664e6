"""Shaped moves land whatever the host's timing (AN-706 4.5.3 pieces, timed from the host).

An S-curve of 30,000 or 100,000 counts at 20,000 counts/s, 150,000 counts/s^2 and 3e6
counts/s^3 is 85 or 260 pieces of 20 ms: more than a bridge holds (64), so the host times
them on every transport.  The host is late in the three ways a script is: ``wait()`` called
50 ms after the move started, a 0.3 s recording taken before ``wait()``, and a 0.2 s stall in
the middle of the move (on a simulator: its clock runs on while the host does nothing).  Each
move ends exactly on its target (the chip's own landing, read back) and at rest within the
20-count tolerance, where before it crawled on the last piece's cap and timed out.

What a late piece does to the shape is read at every sample of the simulated chip
(``sim://?fast=0``): during a stall the velocity holds the last cap; afterwards the profile
carries on from where the chip is, and its end comes no later than the plan's own end plus
the host's lateness plus a piece.
"""

from __future__ import annotations

import pytest

import lm629_host
from lm629_host.bus.opcodes import Status
from lm629_host.clock import ROUNDING_S
from lm629_host.chip.shapes import SCurve, ShapedMove
from lm629_host.transports.base import Transport

from sim_urls import UNO, ready_chip

CURVE = SCurve(20000.0, 150000.0, 3e6)
URLS = ["sim://", "sim+ftdi://", f"sim+avr://?{UNO}", f"sim+emu://?{UNO}"]
#: the ways a host is late: wait() 50 ms after the start, a 0.3 s recording before wait(), a
#: 0.2 s stall half-way through the move
LATE = ["wait 50 ms late", "0.3 s recording first", "0.2 s stall mid-move"]


def _chip(url: str) -> lm629_host.LM629:
    return ready_chip(url)


def _stall_at(chip: lm629_host.LM629, move: ShapedMove, at_s: float, stall_s: float,
              sleep=None):
    """A ``progress`` callback that stalls the host once, at the first snapshot ``at_s`` or
    more into the move: ``sleep`` (default: the transport's clock, which on a simulator runs
    the chip on while the host does nothing)."""
    stalled: list[float] = []

    def progress(s) -> None:
        if not stalled and s.time - move.t0 >= at_s:
            stalled.append(s.time - move.t0)
            (sleep or chip.clock.sleep)(stall_s)
    return progress, stalled


def _late_move(chip: lm629_host.LM629, distance: int | ShapedMove, how: str):
    """Start the shaped move (or take one started), be late ``how``, wait; return (move,
    result)."""
    move = distance if isinstance(distance, ShapedMove) else chip.move_profile(distance, CURVE)
    progress = None
    if how == "wait 50 ms late":
        chip.clock.sleep(0.05)
    elif how == "0.3 s recording first":
        trace = chip.record(1e-3, 0.3)
        assert len(trace) == 300
    else:
        progress, stalled = _stall_at(chip, move, move.plan.duration / 2, 0.2)
    result = move.wait(progress=progress)
    if progress is not None:
        assert stalled, "the stall never happened"
    return move, result


@pytest.mark.parametrize("how", LATE)
@pytest.mark.parametrize("distance", [30000, 100000])
@pytest.mark.parametrize("url", URLS)
def test_a_late_host_still_lands_a_host_timed_s_curve(url, distance, how):
    with _chip(url) as chip:
        move, result = _late_move(chip, distance, how)
        assert chip.read_desired_position() == distance  # the chip's own landing, exactly
        assert abs(result.error) <= 20 and result.target == distance
        if move.far:  # a bridge that takes a long move's pieces in refills times them itself
            assert move.far_state is not None and move.far_state.pending == 0
            return
        host_loop = type(chip.transport).record_rows is Transport.record_rows
        recorded_between = how == "0.3 s recording first" and host_loop
        if recorded_between:
            # polled row by row from the host: the pieces went out between the rows, on time
            assert move.resyncs == 0 and move.lag == 0
            assert max(move.jitter) < 2e-3
        else:  # the host found its place again from the chip's position, once
            assert move.resyncs == 1
        if how == "0.2 s stall mid-move":  # at full speed the chip went on as planned: the
            assert abs(move.lag) < 0.02       # pieces it passed were skipped
        elif not recorded_between:  # the chip was held near rest: the shape starts late
            assert move.lag > 0.02
        # the move took the plan, the host's lateness, and the settling: no crawl
        assert result.duration < move.plan.duration + max(0.0, move.lag) + 0.15


@pytest.mark.parametrize("how", LATE)
@pytest.mark.parametrize("url", [f"sim+emu://?{UNO}", f"sim+avr://?{UNO}"])
def test_the_bridge_timed_path_lands_whatever_the_host_does(url, how):
    """20000 counts: 60 pieces, which a PROFILE bridge holds: its timer issues them, the
    host's lateness does not reach the chip."""
    with _chip(url) as chip:
        move, result = _late_move(chip, 20000, how)
        assert move.far
        assert chip.read_desired_position() == 20000 and abs(result.error) <= 20
        state = move.far_state
        assert state is not None and state.issued == len(move.plan.pieces) - 1
        assert state.late_max_s < 1e-3


# ---------------------------------------------------------------------------------- the shape
def _observed() -> tuple[lm629_host.LM629, list[tuple[float, int]]]:
    """A chip on ``sim://?fast=0`` and the list the model appends (time s, desired velocity
    word) to at every sample."""
    chip = _chip("sim://?fast=0")
    model = chip.transport.model
    log: list[tuple[float, int]] = []
    sample = model._sample

    def observed(motion):
        sample(motion)
        log.append((model.tick / 8e6, abs(motion.desired_velocity)))

    model._sample = observed
    return chip, log


@pytest.mark.parametrize("phase", ["speeding up", "cruising", "slowing down"])
def test_a_stall_holds_the_last_cap_then_the_shape_carries_on_from_the_chip(phase):
    """A 0.2 s stall 0.1 s into the move, half-way, or 0.12 s before the plan's end."""
    chip, log = _observed()
    with chip:
        move = chip.move_profile(30000, CURVE)
        plan = move.plan
        at = {"speeding up": 0.1, "cruising": plan.duration / 2,
              "slowing down": plan.duration - 0.12}[phase]
        progress, stalled = _stall_at(chip, move, at, 0.2)
        result = move.wait(progress=progress)
        assert chip.read_desired_position() == 30000 and abs(result.error) <= 20
    t0 = move.t0
    begin, end = t0 + stalled[0], t0 + stalled[0] + 0.2
    held = move.words[max(k for k, t in enumerate(move.piece_times) if t0 + t <= begin)]
    during = [v for t, v in log if begin + 2 * plan.piece_s <= t <= end]
    after = [v for t, v in log if t > end + 2 * plan.piece_s]
    # during the stall the chip runs at the cap in force (it had a piece to reach it), or,
    # near the end, its own deceleration lands it: never faster than that cap
    assert during and all(v <= held for v in during)
    if phase != "slowing down":
        assert all(v == held for v in during)
    else:
        assert during[-1] < held / 2
    # never faster than the plan's fastest piece
    assert max(v for _, v in log) <= plan.peak_velocity
    if phase == "speeding up":  # the ramp goes on from the held velocity, up to the cruise
        top = after.index(max(after))
        assert after[0] >= held and all(b >= a for a, b in zip(after[:top], after[1:top + 1]))
    else:  # slowing to the end without a bump or a crawl: never up again once it slows
        since = [v for t, v in log if t >= begin]
        last_top = max(k for k, v in enumerate(since) if v == max(since))
        tail = since[last_top:]
        assert all(b <= a for a, b in zip(tail, tail[1:])) and tail[-1] == 0
    # the trajectory ends within a piece of the plan's end plus the host's lateness
    done = max(t for t, v in log if v) - t0
    assert done <= plan.duration + move.lag + plan.piece_s
    # the host found its place from the chip's position; near the end it found it landed
    assert move.resyncs == (0 if phase == "slowing down" else 1)


def test_the_pieces_go_out_during_the_users_next_calls():
    """No wait() at all: the script records, then reads the status every 5 ms; every cap goes
    out before one of those programs, within a row (1 ms) or a poll (5 ms) of its time."""
    chip = _chip("sim://")
    with chip:
        move = chip.move_profile(30000, CURVE)
        chip.record(1e-3, 0.3)
        assert len(move.words) >= 15 and max(move.jitter) < 1.1e-3
        while not chip.read_status() & Status.TRAJECTORY_COMPLETE:
            chip.clock.sleep(0.005)
        assert move.resyncs == 0 and len(move.plan.pieces) - 1 <= len(move.words)
        assert max(move.jitter) < 5.1e-3
        chip.clock.sleep(0.02)
        chip.read_status()  # the next cap's time: the move sees the end, lets the chip go
        assert not move.issuing and chip.before_program is None
        assert chip.read_desired_position() == 30000


def test_a_stop_or_a_new_move_takes_the_chip_from_the_pieces():
    """The user's own trajectory command ends the shaped move's caps: after an emergency stop
    no later call restarts the motor; a move_to started over a shaped move lands on its own
    target, untouched by the shaped move's pieces."""
    from lm629_host import emergency_stop
    chip = _chip("sim://")
    with chip:
        move = chip.move_profile(30000, CURVE)
        chip.clock.sleep(0.5)  # the host stalls; the chip runs on the first cap
        emergency_stop(chip)
        assert move.dropped and not move.issuing
        issued = len(move.words)
        for _ in range(10):
            chip.clock.sleep(0.05)
            s = chip.snapshot()
            assert s.desired_velocity == 0
        assert len(move.words) == issued
    chip = _chip("sim://")
    with chip:
        shaped = chip.move_profile(30000, CURVE)
        chip.clock.sleep(0.3)
        move = chip.move_to(1000, velocity=200000)  # the acceleration loaded: it is moving
        assert shaped.dropped
        # a cap falling due may still go out before the new move's own start read: not after
        caps = len(shaped.words)
        assert caps <= 2
        result = move.wait()
        assert result.target == 1000 and chip.read_desired_position() == 1000
        assert len(shaped.words) == caps


# ---------------------------------------------------------------------------------- a real stall
@pytest.mark.under_load
@pytest.mark.parametrize("far_end", ["python", "firmware"])
def test_a_wall_clock_stall_on_a_served_bench(tmp_path, far_end):
    """``lm629 sim serve`` in its own process, in real time (the bridge keeps its own clock
    while the host sleeps): the host sleeps 0.2 s 0.1 s into a host-timed S-curve's ramp, its
    cap held low the while; the move carries on from the chip's position and lands.  Then a
    move the bridge times, the host asleep 0.2 s from its start: it lands too."""
    import time

    from served import serve

    with serve(tmp_path, far_end) as bench:
        with lm629_host.open(f"serial://{bench.link}") as chip:
            chip.reset()
            chip.load_filter(kp=20, kd=100)
            chip.update_filter()
            chip.transport.far_profiles = False  # the pieces timed from the host
            move = chip.move_profile(30000, CURVE)
            assert not move.far
            progress, stalled = _stall_at(chip, move, 0.1, 0.2, sleep=time.sleep)
            result = move.wait(progress=progress)
            # held below the plan's velocity, the chip fell behind it (on a busy machine the
            # host is late more often, and the shape later still)
            assert stalled and move.resyncs >= 1 and move.lag > 0.02
            assert chip.read_desired_position() == 30000 and abs(result.error) <= 20
            # 60 pieces: the bridge holds them and times them; the host sleeps 0.2 s at once
            chip.transport.far_profiles = True
            move = chip.move_profile(-20000, CURVE, relative=True)
            assert move.far
            time.sleep(0.2)
            result = move.wait()
            assert chip.read_desired_position() == 10000 and abs(result.error) <= 20
            state = move.far_state
            assert state is not None and state.issued == len(move.plan.pieces) - 1


def test_the_timeout_counts_without_the_hosts_own_lateness():
    """wait() called 3 s after a 1.68 s S-curve started: the chip crept on its first cap (200
    counts/s) the while, then the shape ran.  It ends 3 s after the plan's end, past the
    default timeout (1.5 x 1.68 s + 2 s = 4.5 s from the start), and lands: the timeout
    counts from the start plus the time the host's lateness added (``lag``)."""
    chip = _chip("sim://")
    with chip:
        move = chip.move_profile(30000, CURVE)
        chip.clock.sleep(3.0)
        result = move.wait()
        assert move.lag > 2.5 and result.duration > 4.5
        assert chip.read_desired_position() == 30000 and abs(result.error) <= 20


@pytest.mark.parametrize("how", LATE)
def test_a_move_backwards_lands_late_too(how):
    """The host's place in the plan is counted along the move: backwards, from 5000 counts
    to -25000, the same three ways late."""
    chip = _chip("sim://")
    with chip:
        chip.move_to(5000, velocity=1 << 20, acceleration=1 << 10).wait()
        move = chip.move_profile(-30000, CURVE, relative=True)
        assert move.target == -25000 and move.plan.distance == -30000
        move, result = _late_move(chip, move, how)
        assert chip.read_desired_position() == -25000 and abs(result.error) <= 20
        assert move.resyncs == (0 if how == "0.3 s recording first" else 1)


def test_a_second_thread_reading_the_chip_issues_no_piece_twice():
    """A logger thread reads snapshots while wait() runs: the pieces go out from whichever
    thread gets there first, each once (``update_rule = "raise"``: two STTs closer than 10 ms
    would raise UpdateTooSoon), and the move lands."""
    import threading

    chip = _chip("sim://")
    with chip:
        chip.update_rule = "raise"
        move = chip.move_profile(30000, CURVE)
        errors: list[BaseException] = []
        done = threading.Event()

        def logger() -> None:
            try:
                while not done.is_set():
                    chip.snapshot()
            except BaseException as exc:  # noqa: BLE001 - handed to the test's thread
                errors.append(exc)

        thread = threading.Thread(target=logger)
        thread.start()
        try:
            result = move.wait()
        finally:
            done.set()
            thread.join()
        assert not errors
        assert chip.read_desired_position() == 30000 and abs(result.error) <= 20
        assert all(b - a >= 0.01 - ROUNDING_S for a, b in zip(move.piece_times, move.piece_times[1:]))
        # each cap due later than the one before: no piece of the plan went out twice (and
        # none closer than the update rule, or update_rule="raise" would have raised).  How
        # many went out is not this test's subject: the logger's reads take the simulated
        # bus's time too, so a host thread the OS held back is late on the chip's clock, and a
        # late host skips the pieces the chip has passed, raises the slowing caps to what the
        # chip has left, or adds caps past the plan's end for a chip still short of it (CI saw
        # 83 and 87 caps for a plan of 85 pieces)
        assert all(b > a for a, b in zip(move.dues, move.dues[1:]))


# ------------------------------------------------------------- a long move the bridge streams
@pytest.mark.parametrize("url, recording", [("sim+avr://", True), (f"sim+avr://?{UNO}", True),
                                            (f"sim+avr://?{UNO}", False), ("sim+emu://", True)])
def test_a_recording_in_a_long_streamed_move_lands_it_bridge_timed(url, recording):
    """100,000 counts: 260 pieces of 20 ms, streamed to a PROFILE bridge in top-ups, and a
    0.3 s recording at 5 ms in the middle.  At 115200 baud the NEW frame of 30
    pieces takes 22 ms on the wire, more than a piece: a host that counted the pieces from when
    it sent that frame topped the bridge up past the 64 it holds (BAD_PROFILE, the rest of the
    move dropped); and the last piece's cap (the S-curve's tail, a few counts/s) left a chip a
    few counts short crawling there for seconds.  Now: every piece issued by the bridge on its
    own timer, none refused, the chip on its target without a crawl."""
    with _chip(url) as chip:
        move = chip.move_profile(100000, CURVE)
        assert move.far and len(move.plan.pieces) == 260
        if recording:
            trace = chip.record(0.005, 0.3)
            assert len(trace) == 60
        result = move.wait()
        assert chip.read_desired_position() == 100000
        assert abs(result.error) <= 20 and result.target == 100000
        state = move.far_state
        assert state is not None and state.pending == 0 and state.queued == 0
        assert state.issued == len(move.plan.pieces) - 1 and not state.cancelled
        assert state.late_max_s < 5e-3  # the bridge's own lateness, on its clock
        # at most a landing cap a piece after the bridge's last piece, over the last counts
        assert result.duration < move.plan.duration + 0.15  # no crawl
        assert len(move.landings) <= 2
        assert all(t >= (move.far_end or 0.0) for t, _ in move.landings)
