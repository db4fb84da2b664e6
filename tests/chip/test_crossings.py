"""Where two capabilities meet: wraparound and batches, batches and threads, moves and their
length, and every transport after close.  Each case was a short sequence the stateful test
(tests/crossings/) or a user found; the numbers come from the register's range and the
trajectory's arithmetic, and the oracle is the chip model behind the transport.

The register holds C0000000..3FFFFFFF (2^31 counts); ``reset_position=0x3FFFF000`` starts it
4096 counts below the top, so that a run crosses in simulated milliseconds.
"""

from __future__ import annotations

import threading

import pytest

import lm629_host
from lm629_host.chip.move import MoveTooLong
from lm629_host.config.profile import ensure_applied, parse_profile
from lm629_host.errors import TransportError
from lm629_host.bus.opcodes import Cmd, Status
from lm629_host.chip.lm629 import LM629
from lm629_host.physics.plan import plan

from sim_urls import SIM_URLS, available, ready_chip

#: 4096 counts below the top of the register
NEAR_TOP = 0x3FFFF000
TOP = 1 << 30  #: the first count past 3FFFFFFF, extended
#: the three kinds of link: the model strobed directly, the bridge in Python, the firmware
LINKS = ("sim://", "sim+emu://?baud=1000000", "sim+avr://?baud=1000000")
#: one sample at 8 MHz
T = 2048 / 8e6


def _open(url: str) -> lm629_host.LM629:
    """``url`` near the top, reset, kp=20 kd=200; the model records the commands it gets."""
    return ready_chip(url, f"reset_position={NEAR_TOP}&record=1", kd=200)


def true_real(chip: lm629_host.LM629) -> int:
    """The model's own real position, unwrapped: encoder counts since the reset, from where
    the reset put the register (the simulator's truth, not the driver's)."""
    motion = chip.transport.models[chip.chip_select].motion
    return motion.motor.count - motion.home_count


@pytest.mark.parametrize("url", LINKS)
@pytest.mark.parametrize("reads", [1, 2])
def test_batched_reads_across_the_wrap_extend_like_direct_ones(url, reads):
    """20 counts/sample forward, a batch every 2 ms of simulated time (7.8 samples: ~160
    counts): the crossing at 3FFFFFFF is one crossing, every batched value moves on by less
    than 2 ms of travel, and the last agrees with the model's unwrapped position.  (c351da8:
    a jump of -2^31 and a crossing counted per batch; with two reads, RuntimeError.)"""
    chip = _open(url)
    try:
        chip.run_velocity(20 * 65536, 6553)
        seen: list[tuple[int, int]] = []
        for _ in range(60):
            with chip.batch() as b:
                real = b.read_real_position()
                desired = b.read_desired_position() if reads == 2 else None
            seen.append((real.value, desired.value if desired is not None else real.value))
            chip.clock.sleep(0.002)
        steps = [b[0] - a[0] for a, b in zip(seen, seen[1:])]
        # never back, never more than 2.5 ms at 20 counts/sample and its overshoot (kp=20)
        assert all(0 <= d <= 20 * 16 for d in steps), steps
        assert all(abs(d - r) < 2000 for r, d in seen)  # the following error, never 2^31
        assert seen[0][0] < TOP < seen[-1][0]
        assert chip.positions.wraps == 1
        assert abs(chip.read_real_position() - true_real(chip)) <= 40
    finally:
        chip.load_trajectory(stop="abrupt", start=True)
        chip.close()


@pytest.mark.parametrize("url", LINKS)
def test_one_script_counts_the_same_crossings_on_every_link(url):
    """Across the wrap with a move to a register value past it, back across, then forward
    again in velocity mode for 0.5 s at 4 counts/sample (7800 counts: past the top from
    4096 below it): three crossings, on every link (c351da8: 3 on sim://, 2 on the bridges,
    whose far-side move waits never cleared the wraparound bit)."""
    chip = _open(url)
    try:
        chip.move_to(-TOP + 8000, velocity=4 * 65536, acceleration=6553).wait()
        assert chip.positions.wraps == 1
        assert chip.read_real_position() == pytest.approx(TOP + 8000, abs=20)
        chip.move_to(NEAR_TOP, velocity=4 * 65536, acceleration=6553).wait()
        assert chip.positions.wraps == 2
        run = chip.run_velocity(4 * 65536, 6553)
        chip.clock.sleep(0.5)
        run.stop()
        chip.read_real_position()
        assert chip.positions.wraps == 3
        assert abs(chip.read_real_position() - true_real(chip)) <= 40
    finally:
        chip.close()


@pytest.mark.parametrize("url", LINKS)
def test_a_crossing_a_script_left_latched_is_not_the_next_drivers(url):
    """Found by the machine's long run on sim:// (a script ended mid-move across the wrap,
    the next process on the same far end): the first driver starts 8000 counts forward from
    4096 below the top and reads nothing after; the chip latches the wraparound bit at the
    crossing.  The next driver's positions start from the register's values (3904 past the
    bottom: it cannot know the turn before it), so that crossing is not one of its own: it
    counts 0, clears the bit, and counts the next crossing (back under the top) as its 1st.
    (It counted the latched bit: 1 wrap at its first read, 2 after one crossing of its own.)"""
    chip = _open(url)
    try:
        chip.move_to(8000, velocity=4 * 65536, acceleration=6553, relative=True)
        chip.clock.sleep(1.0)  # the move (2000 samples at 4 counts/sample: 0.5 s) has ended
        assert chip.transport.models[0].status & Status.WRAPAROUND
        nxt = LM629(chip.transport)  # the next process's driver on the same chip
        assert nxt.read_real_position() == pytest.approx(-TOP + 3904, abs=20)
        assert nxt.positions.wraps == 0
        nxt.move_to(-8000, velocity=4 * 65536, acceleration=6553, relative=True).wait()
        assert nxt.positions.wraps == 1
        assert nxt.read_real_position() == pytest.approx(-TOP - 4096, abs=20)
    finally:
        chip.close()


@pytest.mark.parametrize("url", LINKS)
def test_a_board_powered_up_behind_the_driver_counts_from_its_reset_once_the_profile_is_back(url):
    """Found by the machine's long run on sim://: a driver whose positions began past the top
    (the next process after a script that crossed: 3904 counts past the bottom, no turn), the
    board's power off and on behind it (every register as from power-on: 4096 below the top
    again), the profile applied again where it was lost (``ensure_applied``, as ``lm629
    --profile`` does).  Its message says positions count from the reset, yet the driver took
    the reset's register value the short way from its old one: one turn down, 2^31 counts
    off (-TOP - 4096 for NEAR_TOP; 1073745920 for -1073737728 on the bottom in the machine)."""
    chip = _open(url)
    try:
        chip.move_to(8000, velocity=4 * 65536, acceleration=6553, relative=True).wait()
        nxt = LM629(chip.transport)  # the next process's driver on the same chip
        assert nxt.read_real_position() == pytest.approx(-TOP + 3904, abs=20)
        with chip.transport.lock:  # the supply off and on (lm629 sim serve's SIGUSR1)
            chip.transport.models[0].reset_pulse()
        nxt.clock.sleep(0.002)
        profile = parse_profile("[board]\n[axis.x]\ncs = 0\nkp = 20\nkd = 200\n", "bench.toml")
        said: list[str] = []
        assert ensure_applied({"x": nxt}, profile, said.append) == ["x"]
        assert "positions count from where the shaft was at the reset" in said[0]
        assert nxt.read_desired_position() == NEAR_TOP
        assert nxt.read_real_position() == pytest.approx(NEAR_TOP, abs=2)
        assert nxt.positions.wraps == 0
    finally:
        chip.close()


@pytest.mark.parametrize("url", LINKS)
def test_a_velocity_run_whose_first_read_is_past_the_wrap(url):
    """Found by the machine: reset 4096 counts below the top, 4 counts/sample for 0.3 s (1170
    samples, ~4500 counts): the run crosses before anything reads a position.  The run's start
    reads where it starts (in its own program), so the reads after the crossing extend past
    2^30 (c351da8: the first read took the register's value, 2^31 off)."""
    chip = _open(url)
    try:
        run = chip.run_velocity(4 * 65536, 6553)
        chip.clock.sleep(0.3)
        rest = run.stop()
        assert rest.desired_position > TOP and rest.real_position > TOP
        assert abs(rest.real_position - true_real(chip)) <= 2
        assert chip.positions.wraps == 1
    finally:
        chip.close()


def _history(chip: lm629_host.LM629) -> list[int]:
    return [c for c, _ in chip.transport.models[chip.chip_select].history]


@pytest.mark.parametrize("url", LINKS[:2])
def test_a_target_past_the_wrap_as_typed_is_refused_before_anything_moves(url):
    """From 4096 counts below the top, the register value 20000 is 2^30 - 4096 - 20000 =
    1073717728 counts away the short way round: at 1 count/sample and 655/65536 per sample^2,
    d/v + v/a samples, 76 hours.  Refused with its length and duration, no LTRJ or STT sent;
    the same target given as a distance lands."""
    chip = _open(url)
    try:
        chip.transport.models[0].record_clear()
        with pytest.raises(MoveTooLong) as e:
            chip.move_to(20000, velocity=65536, acceleration=655)
        seconds = plan(1073717728, 65536, 655).seconds(8e6)
        assert seconds == pytest.approx((1073717728 + 65536 / 655) * T)
        assert e.value.distance == 1073717728 and e.value.seconds == pytest.approx(seconds)
        assert e.value.argument == "max_duration" and e.value.limit == 600
        assert "1073717728 counts" in str(e.value) and "max_duration" in str(e.value)
        assert not {Cmd.LTRJ, Cmd.STT} & set(_history(chip))
        assert Cmd.RDDP in _history(chip)  # the read that found where the move would start
        moved = chip.move_to(20000, velocity=65536, acceleration=655, relative=True).wait()
        assert moved.target == NEAR_TOP + 20000 and moved.target > TOP
        assert abs(true_real(chip) - moved.target) <= 20
    finally:
        chip.close()


def test_a_long_move_is_allowed_by_the_limit_and_a_shaped_one_checked_first():
    """max_duration raised past the plan lets the same move start; an S-curve across the
    same 2^30 counts is refused from its top speed before millions of pieces are planned."""
    from dataclasses import replace

    from lm629_host.chip.shapes import SCurve
    chip = _open("sim://")
    try:
        with pytest.raises(MoveTooLong) as e:
            chip.move_profile(20000, SCurve(velocity=4000, acceleration=40000, jerk=4e5))
        assert e.value.seconds == pytest.approx(1073717728 / 4000, rel=1e-5)  # its top speed
        chip.move_rules = replace(chip.move_rules, max_duration=3e5)
        move = chip.move_to(20000, velocity=65536, acceleration=655)
        chip.clock.sleep(0.05)
        assert chip.is_moving() and move.target == NEAR_TOP - 1073717728
    finally:
        chip.load_trajectory(stop="abrupt", start=True)
        chip.close()


@pytest.mark.parametrize("url", LINKS[:2])
def test_a_batch_used_from_a_second_thread_refuses_at_once_and_drops_nothing(url):
    """Another thread queuing on this thread's batch gets a RuntimeError that says whose the
    batch is (c351da8: a TypeError "ran 0/2 bus programs", and calls lost); the owner's
    calls all run."""
    chip = _open(url)
    try:
        errors: list[BaseException] = []
        with chip.batch() as b:
            mine = [b.read_status() for _ in range(3)]

            def other() -> None:
                try:
                    b.read_real_position()
                except BaseException as exc:  # noqa: BLE001 - the test looks at it
                    errors.append(exc)
            t = threading.Thread(target=other, name="worker")
            t.start()
            t.join()
            mine.append(b.read_desired_position())
        assert len(errors) == 1 and isinstance(errors[0], RuntimeError)
        assert "belongs to thread" in str(errors[0]) and "'worker'" in str(errors[0])
        assert all(h.value is not None for h in mine)
        assert mine[-1].value == NEAR_TOP
    finally:
        chip.close()


@pytest.mark.parametrize("url", SIM_URLS)
def test_every_call_on_a_closed_port_says_closed(url):
    """c351da8: on sim:// read_status() and record() answered after close(); on sim+avr://
    record() said the rate was too high."""
    if not available(url):
        pytest.skip(f"{url}: not available here")
    chip = lm629_host.open(url)
    chip.reset()
    chip.close()
    chip.close()  # idempotent
    for call in (chip.read_status, chip.snapshot, lambda: chip.record(1e-3, 0.01),
                 lambda: chip.move_to(100, velocity=65536, acceleration=655)):
        with pytest.raises(TransportError, match="closed"):
            call()
