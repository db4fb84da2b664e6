"""The link failsafe on the simulated far ends, in simulated time (no wall-clock sleeps).

A host "dies" here by sending nothing more: the test reads the raw pipe, which runs the far
end (and its timer) forward without a byte from the host.  Numbers: the failsafe is 0.5 s by
default; the feeder sends after FEED_FRACTION (a quarter) of it idle.  The shaft runs at
2 counts/sample (velocity word 131072) after a 0.01 counts/sample^2 ramp (word 655); "the
stop's deceleration" is measured on the same model with the host's own stop of the same kind
at the same speed (tools/bench_failsafe.py, reference_stop_s), so the bound is failsafe + that
+ 20 ms.
"""

from __future__ import annotations

import os
import pty
import sys
import termios
from pathlib import Path

import pytest

import lm629_host
from lm629_host import TransportError
from lm629_host.motion.board import Board
from lm629_host.bridge.protocol import FAILSAFE_FEED, FailsafeAction, Result
from lm629_host.bus.opcodes import Status
from lm629_host.errors import FailsafeTripped
from lm629_host.transports.link import LinkTransport
from lm629_host.transports.simemu import EmuLinkTransport, open_emulated

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
from bench_failsafe import ACC, SPEED, reference_stop_s


def _board(url: str = "sim+emu://?axes=2") -> tuple[Board, EmuLinkTransport]:
    t = open_emulated(url)
    b = Board(t, axes=2)
    b.reset()
    for ax in b.axes:
        ax.load_filter(kp=20, kd=100)
        ax.update_filter()
    return b, t


def _run(b: Board) -> None:
    for ax in b.axes:
        ax.load_trajectory(acceleration=ACC, velocity=SPEED, velocity_mode=True, start=True)
    b.clock.sleep(0.3)  # at speed (the ramp is 200 samples, 51 ms)
    assert all(ax.read_real_velocity() == 2 for ax in b.axes)


def _silent_until_rest(t: EmuLinkTransport, span: float = 2.0) -> list[float]:
    """Send nothing for ``span`` s (the far end runs on); returns, per chip, when its shaft
    last moved (model seconds)."""
    models = t.models
    pos = [c.motion.real_position for c in models]
    moved = [t.model.now()] * len(models)
    end = t.model.now() + span
    while t.model.now() < end:
        t.pipe.read(0.001)
        for k, c in enumerate(models):
            if c.motion.real_position != pos[k]:
                pos[k], moved[k] = c.motion.real_position, c.now()
    return moved


@pytest.mark.parametrize("action, stop", [("abrupt", "abrupt"), ("smooth", "smooth"),
                                          ("off", "off")])
def test_a_silent_host_has_every_axis_at_rest_within_failsafe_plus_the_stop(action, stop):
    b, t = _board(f"sim+emu://?axes=2&failsafe_action={action}")
    _run(b)
    last = t._last_tx
    moved = _silent_until_rest(t)
    fs = t.emulator.failsafe
    assert fs.tripped and fs.chips == 0b11 and fs.action == FailsafeAction[action.upper()]
    assert fs.silent_ms == 500 and abs(fs.at_ms / 1e3 - (last + 0.5)) < 2e-3
    bound = 0.5 + reference_stop_s(stop) + 0.020
    assert all(m - last <= bound for m in moved), (moved, last, bound)
    assert all(m - last >= 0.5 for m in moved)  # nothing stopped it before the timeout
    for c in t.models:
        assert bool(c.read_status() & Status.MOTOR_OFF) == (action == "off")


def test_after_a_trip_motion_is_refused_until_acknowledged_and_a_new_open_is_told(caplog):
    b, t = _board()
    _run(b)
    _silent_until_rest(t, 1.0)
    with pytest.raises(FailsafeTripped, match=r"stopped cs 0, cs 1 \(abrupt stop\) after the "
                       r"host was silent for 0\.50 s.*lm629 clear") as e:
        b.axes[0].load_trajectory(acceleration=ACC, velocity=SPEED, velocity_mode=True,
                                  start=True)
    assert e.value.state is not None and e.value.state.chips == 0b11
    t.pipe.read(0.3)  # the ramp to 2 counts/sample would take 51 ms: well past it
    assert b.axes[0].read_real_velocity() == 0  # nothing of it ran
    assert t.models[0].motion.desired_velocity == 0
    # a new open on the same bridge reports the trip (a warning) and acknowledges it
    t2 = LinkTransport(t.pipe, "sim+emu://", baud=115200)
    assert t2.failsafe_report is not None and t2.failsafe_report.chips == 0b11
    assert "the bridge stopped cs 0, cs 1" in caplog.text
    assert not t.emulator.failsafe.tripped
    assert t2.failsafe_state().timeout_ms == 500  # armed again
    assert t2.clear_failsafe() is not None  # the one this open acknowledged
    assert t2.clear_failsafe() is None


def test_explicit_acknowledge_lets_the_same_host_move_again():
    b, t = _board()
    _run(b)
    _silent_until_rest(t, 1.0)
    trip = b.clear_failsafe()
    assert trip is not None and trip.tripped
    b.axes[0].load_trajectory(acceleration=ACC, velocity=SPEED, velocity_mode=True, start=True)
    b.clock.sleep(0.3)
    assert b.axes[0].read_real_velocity() == 2
    assert t.emulator.failsafe.timeout_ms == 500


def test_an_idle_host_a_long_far_side_wait_and_a_recording_are_not_tripped():
    b, t = _board()
    _run(b)
    emu = t.emulator
    frames = emu.stats.frames
    b.clock.sleep(3.0)  # idle in Python: a feed after 0.375 s of silence (simulated clock)
    assert not emu.failsafe.tripped
    assert t.failsafe.feed_period_s == 0.375
    assert emu.stats.frames - frames == 3.0 // 0.375  # the feeds, exactly on time
    chip = b.axes[0]
    t0 = b.clock.now()
    with pytest.raises(Exception, match="waited 10 s"):
        chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=10.0)  # velocity mode: never
    assert b.clock.now() - t0 >= 10.0 and not emu.failsafe.tripped
    trace = chip.record(0.01, 5.0)
    assert len(trace.rows) == 500 and not trace.missing
    assert emu.stats.feeds >= 5.0 / 0.375 - 1  # FAILSAFE_FEED kept the recording alive
    assert not emu.failsafe.tripped and chip.read_real_velocity() == 2


def test_a_feed_during_a_recording_does_not_end_it_and_other_bytes_do():
    b, t = _board()
    emu = t.emulator
    stream = b.axes[0].record_stream(0.01)
    rows = iter(stream)
    next(rows)
    assert emu._rec is not None
    emu.receive(FAILSAFE_FEED)
    assert emu._rec is not None and emu.stats.feeds >= 1
    emu.receive(FAILSAFE_FEED[:3] + b"\x00")  # a damaged feed: ends it, as any byte does
    assert emu._rec is None
    stream.close()


def test_a_clean_close_disarms_and_leaves_the_axis_moving():
    b, t = _board()
    _run(b)
    emu, models = t.emulator, t.models
    pipe = t.pipe
    b.close()
    assert emu.failsafe.timeout_ms == 0
    pipe.read(2.0)
    assert not emu.failsafe.tripped and all(c.motion.real_velocity == 2 for c in models)


def test_a_with_block_left_by_an_exception_stops_a_moving_axis():
    b, t = _board()
    _run(b)
    models, pipe = t.models, t.pipe
    with pytest.raises(ZeroDivisionError):
        with b:
            b.clock.sleep(0.1)
            1 / 0  # noqa: B018 - the lab script's bug
    pipe.read(0.5)
    for c in models:
        assert c.motion.real_velocity == 0 and not c.read_status() & Status.MOTOR_OFF  # holds
    assert not t.emulator.failsafe.tripped  # it was the host


def test_a_with_block_left_normally_leaves_the_axis_moving():
    b, t = _board()
    _run(b)
    models, pipe = t.models, t.pipe
    with b:
        pass
    pipe.read(0.5)
    assert all(c.motion.real_velocity == 2 for c in models)


def test_failsafe_zero_disarms_and_bad_values_fail_before_any_traffic():
    b, t = _board("sim+emu://?axes=2&failsafe=0")
    _run(b)
    assert t.emulator.failsafe.timeout_ms == 0 and t.failsafe.feed_period_s == 0
    for bad, words in [("failsafe=0.01", "0 (off) or 0.05..10 s"),
                       ("failsafe=11", "outside 0 (off) or 0.05..10 s"),
                       ("failsafe_action=brake", "expected one of abrupt, smooth, off")]:
        with pytest.raises(ValueError, match=words.replace("(", r"\(").replace(")", r"\)")):
            open_emulated(f"sim+emu://?{bad}")


@pytest.mark.parametrize("bad", ["failsafe=0.01", "failsafe=11", "failsafe_feed=never"])
def test_a_bad_failsafe_option_is_refused_before_the_serial_port_opens(bad):
    """A timeout between 0 (off) and 0.05 s was refused only once the link was made, after
    the port had opened (an Uno resets when its port opens) and was never closed: the port's
    file descriptors stayed open.  Now every failsafe option is checked with the port's own,
    before it opens."""
    master, slave = pty.openpty()
    try:
        before = sorted(os.listdir("/proc/self/fd")), termios.tcgetattr(slave)
        with pytest.raises(ValueError, match=bad.split("=")[0]) as refused:
            lm629_host.open(f"serial://{os.ttyname(slave)}?{bad}")
        # no descriptor open while the error is held, and the line never set up (pyserial
        # puts it in raw mode at 115200 baud when it opens it)
        assert (sorted(os.listdir("/proc/self/fd")), termios.tcgetattr(slave)) == before
        assert "\n" not in str(refused.value)
    finally:
        os.close(master)
        os.close(slave)


def test_the_bridge_refuses_a_timeout_outside_its_range():
    b, t = _board()
    with pytest.raises(TransportError, match=f"result {int(Result.BAD_FAILSAFE)}"):
        t.failsafe.request(bytes((1,)) + (49).to_bytes(2, "big") + b"\x00", "FAILSAFE (arm 49 ms)")
    assert t.emulator.failsafe.timeout_ms == 500  # unchanged


@pytest.mark.parametrize("url", ["sim+avr://?axes=2", "sim+avr://?axes=2&usb=uno"])
def test_the_firmware_is_not_tripped_by_an_idle_host_a_far_wait_or_a_recording(url):
    """The same three on the compiled firmware (in simavr, simulated time), then silence:
    the firmware trips 0.5 s after the host's last frame and stops both chips."""
    from sim_urls import available

    from lm629_host.transports import open_transport
    if not available("sim+avr://"):
        pytest.skip("sim+avr:// not available here")
    t = open_transport(url)
    b = Board(t, axes=2)
    b.reset()
    for ax in b.axes:
        ax.load_filter(kp=20, kd=100)
        ax.update_filter()
    _run(b)
    b.clock.sleep(3.0)
    chip = b.axes[0]
    with pytest.raises(Exception, match="waited 10 s"):
        chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=10.0)
    trace = chip.record(0.01, 5.0)
    assert len(trace.rows) == 500 and not trace.missing
    state = t.failsafe_state()
    assert state.timeout_ms == 500 and not state.tripped
    last = t._last_tx
    moved = _silent_until_rest(t, 1.5)  # type: ignore[arg-type]  # a sim+avr transport has the same models
    state = t.failsafe_state()
    assert state.tripped and state.chips == 0b11 and state.silent_ms == 500
    assert abs((state.at_ms - state.silent_ms) / 1e3 - last) < 2e-3
    assert all(m - last <= 0.5 + reference_stop_s("abrupt") + 0.020 for m in moved)


def test_a_trip_drops_a_shaped_moves_pending_pieces_so_none_restarts_the_axis():
    """A host that dies in the middle of a shaped move handed to the bridge (PROFILE): the trip
    drops the pieces still pending before it stops the chip, so the axis comes to rest and
    stays there while the rest of the pieces' times pass (none is issued after the trip); the
    schedule then says cancelled, and new pieces are refused until the trip is acknowledged."""
    import lm629_host
    from lm629_host.chip.shapes import SCurve
    chip = lm629_host.open("sim+emu://")
    t = chip.transport
    assert isinstance(t, EmuLinkTransport)
    chip.reset()
    chip.load_filter(kp=20, kd=100)
    chip.update_filter()
    # 20000 counts at up to 20000 counts/s: about 1.2 s of pieces 20 ms apart
    move = chip.move_profile(20000, SCurve(20000.0, 150000.0, 3e6))
    assert move.far
    chip.clock.sleep(0.05)
    sched = t.emulator._profile
    issued_before = sched.issued
    due = [sched.start + t_us * 1e-6 for t_us, _ in sched.pending]
    # the timer counts from the last good frame's arrival (the PROFILE frames take ~22 ms each
    # on the 115200 baud line): the far end's own record of it
    last = t.emulator._fs_last
    trip_at = last + 0.5
    assert sum(d > trip_at + 0.2 for d in due) >= 5  # pieces left well after the trip
    moved = _silent_until_rest(t, due[-1] - t.model.now() + 0.2)  # past the last piece's time
    fs = t.emulator.failsafe
    assert fs.tripped and fs.chips == 0b1 and abs(fs.at_ms / 1e3 - trip_at) < 2e-3
    # at rest after the trip's stop, and still at rest while the pieces it dropped fell due
    assert trip_at < moved[0] and sum(d > moved[0] for d in due) >= 5, (moved, trip_at, due)
    assert t.emulator.stats.pieces == issued_before + sum(d <= trip_at for d in due)
    state = t.profile(None, [], new=False)
    assert state.cancelled and state.pending == 0
    assert state.issued == issued_before + sum(d <= trip_at for d in due)
    with pytest.raises(FailsafeTripped, match="nothing of the shaped move was scheduled"):
        t.profile(None, [(0.02, 65536), (0.04, 65536)], new=True)
    assert t.profile(None, [], new=False).pending == 0
    assert chip.snapshot().desired_velocity == 0
    chip.close()
