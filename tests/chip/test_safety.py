"""The emergency stop: abrupt stop, then motor off, and what it reports.

AN-706 3.3: an acceleration change while moving with the drive on is refused ("ignored") and
stays buffered until the trajectory completes (model choices 13 and 28); a stop loaded while it
is pending is refused with it, but motor off is always taken (AN-706 6.3.3).  The emergency
stop must then still leave the motor off and say so, not report that it could not stop.
"""

from __future__ import annotations

import os
import signal
import threading

import pytest

import lm629_host
from lm629_host import CommandError, Status
from lm629_host.chip.safety import StopSignals, Terminated, emergency_stop


def _moving_chip(url: str):
    chip = lm629_host.open(url)
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=100, velocity=65536, position=200000, start=True)
    chip.clock.sleep(0.05)
    return chip


@pytest.mark.parametrize("url", ["sim://", "sim+emu://"])
def test_stop_with_a_refused_acceleration_pending_still_turns_the_motor_off(url):
    with _moving_chip(url) as chip:
        with pytest.raises(CommandError):  # acceleration change while moving: refused
            chip.load_trajectory(acceleration=200, start=True)
        stopped, note = emergency_stop(chip)
        assert stopped, note
        assert note.startswith("motor off (abrupt stop failed")
        assert chip.read_status() & Status.MOTOR_OFF


def test_a_plain_emergency_stop_says_abrupt_then_off():
    with _moving_chip("sim://") as chip:
        assert emergency_stop(chip) == (True, "motor stopped (abrupt stop, then motor off)")
        assert chip.read_status() & Status.MOTOR_OFF


# ------------------------------------------------------------------------------ stop signals
def _signal_during_snapshot(signum: int, cycle: int = 5):
    """A chip whose trace sends ``signum`` to this process at the ``cycle``-th bus cycle of
    its next program, as a user's kill arrives mid-program; returns (chip, cycles seen)."""
    seen: list = []

    def trace(c):
        seen.append(c)
        if len(seen) == cycle:
            os.kill(os.getpid(), signum)
    chip = lm629_host.open("sim://", trace=trace)
    return chip, seen


@pytest.mark.parametrize(("signum", "kind"), [(signal.SIGTERM, Terminated),
                                              (signal.SIGHUP, Terminated),
                                              (signal.SIGINT, KeyboardInterrupt)])
def test_a_stop_signal_during_a_program_is_raised_when_the_program_has_ended(signum, kind):
    before = signal.getsignal(signum)
    guard = StopSignals()
    chip, seen = _signal_during_snapshot(signum)
    with chip:
        guard.install()
        try:
            guard.guard(chip.transport)
            with pytest.raises(KeyboardInterrupt) as info:
                chip.snapshot()
        finally:
            guard.restore()
        assert type(info.value) is kind
        assert getattr(info.value, "signum", signal.SIGINT) == signum  # the CLI's 128 + N
        # the whole snapshot ran (busy polls apart): 6 command bytes and their 9 words, the
        # signal sent at its 5th cycle
        data = [c.kind for c in seen if c.kind != "status"]
        words = (1, 2, 2, 2, 1, 1)  # RDSIGS, RDDP, RDRP, RDDV, RDRV, RDSUM
        assert data == [k for n in words for k in ["command"] + ["read"] * n]
        assert not chip.transport.model.violations  # no program cut in half
        assert Status.MOTOR_OFF in chip.read_status()  # the bus is usable for the stop
    assert signal.getsignal(signum) is before


def test_a_stop_signal_between_programs_is_raised_at_once():
    guard = StopSignals()
    chip, _seen = _signal_during_snapshot(signal.SIGTERM, cycle=10**9)
    with chip:
        guard.install()
        try:
            guard.guard(chip.transport)
            with pytest.raises(Terminated):
                os.kill(os.getpid(), signal.SIGTERM)
                chip.clock.sleep(1.0)  # not reached: the handler raises first
            assert guard.pending is None
        finally:
            guard.restore()


def test_installing_outside_the_main_thread_changes_no_handler():
    before = signal.getsignal(signal.SIGTERM)
    guard = StopSignals()
    t = threading.Thread(target=guard.install)
    t.start()
    t.join()
    assert not guard.installed and signal.getsignal(signal.SIGTERM) is before


@pytest.mark.parametrize("url", ["sim://", "sim+emu://?usb=uno"])
def test_a_refused_value_leaves_a_holding_axis_holding_and_stops_a_moving_one(url):
    """Bad input touches nothing: a move refused (an S-curve of 400 s, more pieces than a plan
    holds) on an axis holding at rest leaves it holding, motor on, with no note of a stop (it
    turned the motor off and said "motor stopped (abrupt stop, then motor off)"); the same
    refusal after an earlier step of the block left the axis moving stops it, the PID
    holding, and says so."""
    from lm629_host import SCurve
    from lm629_host.chip.safety import STOP_NOTE, stop_on_error
    from lm629_host.errors import ArgumentError

    with lm629_host.open(url) as chip:
        chip.reset()
        chip.load_filter(kp=20, kd=100)
        chip.update_filter()
        chip.move_to(1000, velocity=1 << 17, acceleration=1 << 9).wait()
        with pytest.raises(ArgumentError) as e, stop_on_error(chip):
            chip.move_profile(6000 * 2000, SCurve(velocity=30000, acceleration=400, jerk=8000))
        assert getattr(e.value, STOP_NOTE, None) is None
        s = chip.snapshot()
        assert not s.status & Status.MOTOR_OFF and s.desired_position == 1000
    with _moving_chip(url) as chip:
        with pytest.raises(ArgumentError) as e, stop_on_error(chip):
            chip.move_profile(6000 * 2000, SCurve(velocity=30000, acceleration=400, jerk=8000))
        assert getattr(e.value, STOP_NOTE, None) == "motor stopped (abrupt stop, holding)"
        chip.clock.sleep(0.01)
        s = chip.snapshot()
        assert not s.status & Status.MOTOR_OFF and s.desired_velocity == 0
