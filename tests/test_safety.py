"""The emergency stop: abrupt stop, then motor off, and what it reports.

AN-706 3.3: an acceleration change while moving with the drive on is refused ("ignored") and
stays buffered until the trajectory completes (model choices 13 and 28); a stop loaded while it
is pending is refused with it, but motor off is always taken (AN-706 6.3.3).  The emergency
stop must then still leave the motor off and say so, not report that it could not stop.
"""

from __future__ import annotations

import pytest

import lm629_host
from lm629_host import CommandError, Status
from lm629_host.safety import emergency_stop


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
