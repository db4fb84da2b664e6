"""The USB adapter models between the host and a simulated bridge (``usb=`` on ``sim+emu://``
and ``sim+avr://``; :mod:`lm629_host.sim.usb`).

Numbers from the sources in docs/usb.md: the Uno R3's 16U2 (Arduino-usbserial on LUFA) flushes
its UART buffer when Timer0 overflows, clk/256 from 16 MHz over 8 bits = 256 x 256 / 16e6 =
4.096 ms, or when more than 96 of its 128 bytes wait; an FT232R sends a 64-byte packet (62
data bytes) when full, else when its latency timer (16 ms default, 1 ms low latency) runs
out; full-speed USB moves data in 1 ms frames.  At 1 Mbaud the bridge's RDRP takes 0.23 ms
on the line (sim+emu://) and 0.29 ms (firmware), so it fits inside one frame and one tick.
"""

from __future__ import annotations

import math
import statistics

import pytest

import lm629_host
from lm629_host.sim.build import sim_options
from lm629_host.transports import simemu
from lm629_host.sim.usb import (
    FRAME_S,
    FTDI_PACKET_DATA,
    UNO_NEARLY_FULL,
    Cdc,
    Ftdi,
    Uno,
    adapter_of,
)
from sim_urls import available

LINKS = ["sim+emu://", "sim+avr://"]

#: the 16U2's flush tick, from the datasheet facts in the notes (not from the model):
#: Timer0 at clk/256 from 16 MHz overflows every 256 x 16 us
UNO_TICK_S = 4.096e-3


@pytest.fixture(params=LINKS)
def link(request) -> str:
    if not available(request.param):
        pytest.skip(f"{request.param} not available here")
    return request.param


def _rdrp_times(url: str, n: int = 20, before_s: float = 0.0) -> list[float]:
    chip = lm629_host.open(url)
    try:
        chip.reset()
        clock = chip.clock
        clock.sleep(before_s)
        out = []
        for _ in range(n):
            t0 = clock.now()
            chip.read_real_position()
            out.append(clock.now() - t0)
        return out
    finally:
        chip.close()


def test_uno_rdrp_takes_one_flush_tick(link):
    """In a request/reply loop each exchange waits for the next Timer0 overflow: one RDRP
    takes one flush tick (0.75-1.5 x 4.096 ms: 3.072-6.144 ms), against 0.23-0.36 ms without
    USB."""
    bare = _rdrp_times(f"{link}?fast_baud=1000000")
    assert max(bare) < 0.4e-3  # under a tenth of a tick
    for seed in (0, 1, 2):
        times = _rdrp_times(f"{link}?fast_baud=1000000&usb=uno&usb_seed={seed}")
        assert 3.072e-3 <= statistics.mean(times) <= 6.144e-3, times
        # each one ends on a frame, at most a tick and the two frames after the request:
        # 4.096 + 2 x 1 ms
        assert all(t <= 6.096e-3 + 1e-6 for t in times), times


def _frame(t: float) -> float:
    """The first full-speed frame start at or after ``t`` (frames at whole milliseconds)."""
    return math.ceil(t / FRAME_S - 1e-9) * FRAME_S


def _overflow(phase: float, t: float) -> float:
    """The 16U2's first Timer0 overflow after ``t``: at phase + n x 4.096 ms."""
    return phase + math.ceil((t - phase) / UNO_TICK_S + 1e-12) * UNO_TICK_S


def test_uno_reply_comes_at_the_first_frame_after_a_flush_tick():
    """One RDRP from several phases: the request goes out at the next frame start F, the
    reply is in the 16U2 0.2-0.3 ms later (the line at 1 Mbaud), waits for the next Timer0
    overflow, and the host has it at the first frame start after that."""
    for k in range(6):
        chip = lm629_host.open("sim+emu://?fast_baud=1000000&usb=uno&usb_seed=7")
        uno = chip.transport.pipe.adapter
        chip.clock.sleep(k * 0.7e-3)  # a different phase of the request against the tick
        t0 = chip.clock.now()
        chip.read_real_position()
        t1 = chip.clock.now()
        out = _frame(t0)
        expected = {round(_frame(_overflow(uno.phase, out + d)), 9) for d in (0.2e-3, 0.3e-3)}
        assert round(t1, 9) in expected, (t0, t1, expected)
        chip.close()


def test_uno_flushes_at_once_above_96_bytes():
    """Arduino-usbserial: more than BUFFER_NEARLY_FULL (96) bytes waiting are sent without
    waiting for the timer; 96 wait for it."""
    uno = Uno(seed=3)
    t = uno.phase + 0.5e-3  # just after an overflow: the next is 3.596 ms away
    assert uno.receive(t, bytes(UNO_NEARLY_FULL)) == []
    assert uno.next_timer(t) == pytest.approx(t + 3.596e-3)
    [(at, data)] = uno.receive(t + 1e-4, b"\x01")
    assert at == t + 1e-4 and len(data) == UNO_NEARLY_FULL + 1
    assert uno.next_timer(t) is None  # nothing held


def test_uno_phase_is_deterministic_for_a_seed():
    phases = {Uno(seed).phase for seed in range(5)}
    assert len(phases) == 5 and all(0 <= p < UNO_TICK_S for p in phases)
    assert Uno(4).phase == Uno(4).phase
    a = _rdrp_times("sim+emu://?fast_baud=1000000&usb=uno&usb_seed=11", n=5, before_s=1.3e-3)
    b = _rdrp_times("sim+emu://?fast_baud=1000000&usb=uno&usb_seed=11", n=5, before_s=1.3e-3)
    assert a == b


def test_ftdi_latency_timer_and_full_packets(link):
    """An FT232R holds a short reply for its latency timer: 16 ms by default, about 1-2 ms
    with 1 ms; a full 62-byte packet goes at once."""
    slow = _rdrp_times(f"{link}?fast_baud=1000000&usb=ftdi", n=6)
    assert all(15e-3 <= t <= 16e-3 + 2 * FRAME_S for t in slow), slow
    fast = _rdrp_times(f"{link}?fast_baud=1000000&usb=ftdi&latency_ms=1", n=6)
    assert all(FRAME_S - 1e-6 <= t <= 3 * FRAME_S + 1e-6 for t in fast), fast
    f = Ftdi(latency_ms=16, seed=0)
    [(at, data)] = f.receive(0.004, bytes(FTDI_PACKET_DATA + 5))
    assert at == 0.004 and len(data) == FTDI_PACKET_DATA and len(f.held) == 5
    assert f.next_timer(0.004) == pytest.approx(0.004 + 0.016)  # the packet restarted it


def test_cdc_is_one_frame_per_exchange(link):
    """A native device releases the reply at once: with the request out at a frame start and
    the reply back within the frame, each RDRP is one 1 ms frame."""
    times = _rdrp_times(f"{link}?fast_baud=1000000&usb=cdc", n=10)
    assert all(t == pytest.approx(FRAME_S, abs=1e-6) for t in times), times
    assert Cdc().receive(0.5e-3, b"ab") == [(0.5e-3, b"ab")]


def test_usb_none_is_no_adapter(link):
    """usb=none is the bridge's line alone: each RDRP takes exactly as long as with no usb=
    at all (0.23-0.36 ms at 1 Mbaud), less than one 1 ms frame."""
    none = _rdrp_times(f"{link}?fast_baud=1000000&usb=none", n=10)
    # the same to a few microseconds (the firmware's loop catches a byte a little earlier or
    # later); an adapter would add a 1 ms frame at least
    assert none == pytest.approx(_rdrp_times(f"{link}?fast_baud=1000000", n=10), abs=5e-6)
    assert all(0.2e-3 <= t < 0.4e-3 for t in none), none
    for url in ("sim+emu://?usb=none", "sim+emu://"):  # the URL as its transport parses it
        assert adapter_of(url, sim_options(url, simemu.OPTIONS, defaults=True)) is None


@pytest.mark.parametrize("url, message", [
    ("sim+emu://?usb=ch340", "usb"),
    ("sim+emu://?usb=uno&latency_ms=1", "latency_ms= is the FTDI latency timer"),
    ("sim+emu://?usb=ftdi&latency_ms=0", "latency_ms"),
    ("sim+avr://?usb=uno&usb_seed=-1", "usb_seed"),
])
def test_bad_usb_options_are_refused_before_anything_opens(url, message):
    with pytest.raises(ValueError, match=message):
        lm629_host.open(url)


def test_uno_move_costs_at_most_two_flush_ticks():
    """A 4000-count move_to(...).wait() behind the Uno, mean of 16 moves at timer phases
    spread evenly over one tick, takes at most 2 flush ticks longer than without USB (move_to
    is one exchange and Move.wait sees the end on the bridge).  Sixteen phases, not three: the
    mean of three swung from 1.74 to 2.16 ticks when an earlier exchange of the open moved the
    phase (16 read 1.88 before and after)."""
    phases = 16

    def mean_move(usb: str) -> float:
        out = []
        for i in range(phases):
            chip = lm629_host.open(f"sim+emu://?fast_baud=1000000&usb={usb}&usb_seed={i}")
            chip.reset()
            chip.load_filter(kp=20)
            chip.update_filter()
            chip.clock.sleep(i * UNO_TICK_S / phases)
            t0 = chip.clock.now()
            chip.move_to(4000, velocity=4 * 65536, acceleration=2048).wait()
            out.append(chip.clock.now() - t0)
            chip.close()
        return statistics.mean(out)

    assert mean_move("uno") - mean_move("none") <= 2 * 4.096e-3
