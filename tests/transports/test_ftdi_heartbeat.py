"""The FT232H's heartbeat pin (``?heartbeat=adbus7``) on the emulated FT232H.

The FT232H has no timer of its own, so a dead host cannot be noticed on its side; instead the
transport toggles a line the one-chip wiring leaves free (ADBUS7, the second chip's /CS) while
the process lives, for an external monostable on the amplifier's enable.  Numbers: at
``heartbeat_hz=50`` the line changes every 10 ms (half a period) of idle link; each toggle is
one set-low-byte command, so its USB write (125 us per emulated microframe) comes on top.
"""

from __future__ import annotations

import pytest

import lm629_host
from lm629_host.wiring.ft232h import CS1
from lm629_host.bus.opcodes import Status


def _edges(device, since_ns: int) -> list[int]:
    """When ADBUS7 changed level, from ``since_ns`` on (the device's control-line log)."""
    out, prev = [], None
    for ns, level in device.chip_pins.ctrl_log:
        bit = bool(level & CS1)
        if prev is not None and bit != prev and ns >= since_ns:
            out.append(ns)
        prev = bit
    return out


def test_the_heartbeat_toggles_at_its_rate_while_the_host_lives_and_stops_with_it():
    chip = lm629_host.open("sim+ftdi://?heartbeat=adbus7&heartbeat_hz=50")
    t, dev = chip.transport, chip.transport.device
    assert t.chip_selects == 1  # ADBUS7 is no /CS now
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    t0 = dev.ns
    chip.clock.sleep(1.0)  # the host idles: the feeder toggles every 10 ms
    edges = _edges(dev, t0)
    assert 95 <= len(edges) <= 100
    gaps = [(b - a) / 1e6 for a, b in zip(edges, edges[1:])]
    assert all(10.0 <= g <= 10.5 for g in gaps), gaps  # 10 ms + the write's USB time
    # programs keep the line where it is: a move runs with the chip's timing checked
    chip.load_trajectory(acceleration=655, velocity=65536, position=200, start=True)
    assert chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=2) & Status.TRAJECTORY_COMPLETE
    # the host stops (a dead process runs no feeder): the adapter's time goes on, the line
    # stays where it was
    t1 = dev.ns
    dev.advance_ns(1_000_000_000)
    assert _edges(dev, t1) == []
    chip.close()


@pytest.mark.parametrize("pin, words", [("adbus1", "ADBUS1 carries /CS"),
                                        ("adbus0", "ADBUS0 carries the MPSSE clock TCK"),
                                        ("adbus5", "ADBUS5 carries HI (GPIOL1)"),
                                        ("acbus2", "ACBUS2 carries data line D2"),
                                        ("pin9", "expected adbus7 or none")])
def test_a_pin_the_bus_uses_is_refused_before_any_traffic(pin, words):
    with pytest.raises(ValueError, match=words.replace("(", r"\(").replace(")", r"\)")):
        lm629_host.open(f"sim+ftdi://?heartbeat={pin}")


def test_without_the_option_adbus7_is_the_second_chips_select():
    chip = lm629_host.open("sim+ftdi://")
    assert chip.transport.chip_selects == 2 and chip.transport.feed_period_s == 0
    chip.close()
