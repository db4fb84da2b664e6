"""The fast paths against the slow ones they stand for: each must give the same result.

* ``sim://`` skips the busy polls whose answer the model's busy deadline already gives: every
  counter, the simulated clock and the chip's state must be those of the full poll loop (a
  trace callback forces the full loop: a trace shows every poll).
* ``Op.WAIT_STATUS``: the wait happens on the far side in one exchange; ``sim://`` goes
  straight to the status change, and the tick it lands on must be the first sample at which a
  copy of the model stepped one sample at a time shows the bit.
* A bridge without the WAIT_STATUS capability still works: the host polls, at a rate set by
  the wait, not every millisecond.
* ``record=1`` keeps a bounded window.
"""

from __future__ import annotations

import copy
import math

import pytest

import lm629_host
from lm629_host import Status
from lm629_host.sim.bridge import BridgeEmulator, EmuPipe
from lm629_host.transports.simemu import EmuLinkTransport
from lm629_host.errors import BusyTimeout, WaitTimeout
from lm629_host.bridge.protocol import Capability, HelloInfo
from lm629_host.chip.waiting import POLL_MAX_S, poll_interval
from lm629_host.bus.opcodes import Cmd
from lm629_host.bus.program import WAIT_STATUS_POLL_US, Program
from lm629_host.sim.clock import SimClock
from lm629_host.sim.build import build_model



def _scenario(chip) -> list:
    """A bit of everything that checks busy: reset, filter, a move and an on-the-fly change,
    reads while moving, the software RESET (busy 1 ms), a snapshot."""
    out: list = []
    chip.reset()
    chip.load_filter(kp=20, kd=100)
    chip.update_filter()
    chip.load_trajectory(acceleration=200, velocity=0x30000, position=3000)
    chip.start()
    for _ in range(20):
        out.append(chip.read_real_position())
        out.append(chip.read_desired_position())
        chip.clock.sleep(3e-3)
    chip.load_trajectory(velocity=0x10000)
    chip.start()
    out.append(int(chip.sync()))
    out.append(chip.run(Program().command(Cmd.RESET).sync()).statuses)
    out.append(chip.snapshot().real_position)
    return out


def _run(url: str, *, trace: bool, skip: bool = True):
    cycles: list = []
    chip = lm629_host.open(url, trace=cycles.append if trace else None)
    chip.transport.skip_known_busy = skip
    results = _scenario(chip)
    m = chip.transport.model
    state = (m.tick, m.samples, m.status, m.motion.real_position, m.motion.desired_position,
             m.motor_off, m.flags)
    return results, chip.transport.stats.as_dict(), state, cycles


@pytest.mark.parametrize("url", ["sim://", "sim://?chip=lm628&clock=6000000"])
def test_busy_skip_is_bit_identical_to_the_full_poll_loop(url):
    fast = _run(url, trace=False)
    full = _run(url, trace=True)
    noskip = _run(url, trace=False, skip=False)
    assert fast[0] == full[0] == noskip[0]  # every word and status read
    assert fast[1] == full[1] == noskip[1]  # programs, bus cycles, busy polls
    assert fast[2] == full[2] == noskip[2]  # simulated clock, samples, the chip's registers
    # the skip did happen: most of the busy polls were counted, not made
    polls = sum(1 for c in full[3] if c.kind == "status")
    assert fast[1]["busy_polls"] > 1000 and polls >= fast[1]["busy_polls"]


def _run_emu(url: str, *, skip: bool):
    chip = lm629_host.open(url)
    emu = chip.transport.emulator
    emu.skip_known_busy = skip
    results = _scenario(chip)
    m = emu.model
    state = (m.tick, m.samples, m.status, m.motion.real_position, m.motion.desired_position,
             m.motor_off, m.flags)
    stats = (emu.stats.runs, emu.stats.bus_cycles, emu.stats.busy_polls)
    chip.close()
    return results, stats, state


@pytest.mark.parametrize("url", ["sim+emu://", "sim+emu://?chip=lm628&clock=6000000"])
def test_the_emulated_bridge_skips_busy_polls_bit_identically(url):
    """The emulated bridge's busy loop counts the polls the chip's busy deadline answers
    instead of strobing each (a strobe per microsecond: most of sim+emu://'s time went there):
    the same words and statuses, the same bus cycles and polls counted, the same simulated
    clock and chip state as strobing every one."""
    fast, full = _run_emu(url, skip=True), _run_emu(url, skip=False)
    assert fast[0] == full[0]
    assert fast[1] == full[1] and fast[1][2] > 1000  # busy 1 ms after RESET: 1000 polls alone
    assert fast[2] == full[2]


def test_busy_timeout_is_the_same_error_at_the_same_time():
    """A busy longer than the timeout (RESET holds busy reset_s = 1 ms, the timeout 0.5 ms): the
    skip must not jump past the timeout; the full loop raises, with its own message."""
    outs = []
    for trace in (False, True):
        chip = lm629_host.open("sim://", trace=(lambda c: None) if trace else None)
        chip.reset()
        with pytest.raises(BusyTimeout) as e:
            chip.run(Program(busy_timeout_s=0.5e-3).command(Cmd.RESET).command(Cmd.DFH))
        outs.append((str(e.value), chip.clock.now(), chip.transport.stats.as_dict()))
    assert outs[0] == outs[1]


def test_busy_stuck_high_still_times_out():
    chip = lm629_host.open("sim://?fault=busy")
    with pytest.raises(BusyTimeout):
        chip.run(Program(busy_timeout_s=1e-3).command(Cmd.DFH))
    assert chip.transport.stats.busy_polls > 100  # every poll made: busy has no known end


def _moving_model():
    chip = lm629_host.open("sim://")
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=100, velocity=0x20000, position=5000)
    chip.start()
    return chip


@pytest.mark.parametrize("mask", [int(Status.TRAJECTORY_COMPLETE), int(Status.BREAKPOINT)])
def test_advance_until_status_lands_on_the_first_sample_with_the_bit(mask):
    chip = _moving_model()
    chip.set_breakpoint(2500)
    m = chip.transport.model
    ref = copy.deepcopy(m)
    while not ref.status & mask:  # one sample at a time
        ref.advance_to(ref.next_sample)
    SimClock(m).advance_until_status(mask, 60.0)
    assert m.tick == ref.tick
    assert (m.status, m.motion.real_position, m.motion.desired_position, m.samples) == \
        (ref.status, ref.motion.real_position, ref.motion.desired_position, ref.samples)


def test_advance_until_status_stops_at_the_limit():
    chip = _moving_model()
    m = chip.transport.model
    t = chip.clock.now() + 0.1  # the move takes about 2.5 s
    SimClock(m).advance_until_status(int(Status.TRAJECTORY_COMPLETE), t)
    assert chip.clock.now() == pytest.approx(t, abs=1 / m.clock_hz)
    assert not m.status & Status.TRAJECTORY_COMPLETE


def test_wait_for_on_sim_is_one_program_and_returns_at_the_change():
    chip = _moving_model()
    m = chip.transport.model
    ref = copy.deepcopy(m)
    while not ref.status & Status.TRAJECTORY_COMPLETE:
        ref.advance_to(ref.next_sample)
    before = chip.transport.stats.programs
    status = chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=10)
    assert status & Status.TRAJECTORY_COMPLETE
    assert chip.transport.stats.programs - before == 1
    # the status read that saw it is one strobe after the sample that set it
    assert 0 < m.tick - ref.tick <= chip.transport._cycle_clocks


def test_wait_for_timeout_on_sim():
    chip = _moving_model()
    t0 = chip.clock.now()
    with pytest.raises(WaitTimeout):
        chip.wait_for(Status.INDEX_PULSE, timeout=0.5)
    assert 0.5 <= chip.clock.now() - t0 < 0.5 + 1e-5


def _emu(capabilities: int) -> EmuLinkTransport:
    model = build_model("sim://")
    emu = BridgeEmulator(model, info=HelloInfo(capabilities=capabilities))
    t = EmuLinkTransport(emu, model, EmuPipe(emu, baud=115200), "sim+emu://", baud=115200)
    return t


def test_bridge_with_wait_status_waits_in_one_round_trip():
    t = _emu(0x07 | Capability.WAIT_STATUS)
    assert t.has_wait_status
    chip = lm629_host.LM629(t)
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=100, velocity=0x20000, position=5000)
    chip.start()
    ref = copy.deepcopy(t.model)
    while not ref.status & Status.TRAJECTORY_COMPLETE:
        ref.advance_to(ref.next_sample)
    before = t.stats.round_trips
    assert chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=10) & Status.TRAJECTORY_COMPLETE
    assert t.stats.round_trips - before == 1
    # the bridge saw it at its next status read: within one poll period (and a strobe)
    late = (t.model.tick - ref.tick) / t.model.clock_hz
    assert 0 < late <= WAIT_STATUS_POLL_US * 1e-6 + 2e-6 + 30 * 10 / 115200


def test_old_bridge_without_wait_status_is_polled_at_a_rate_set_by_the_wait():
    t = _emu(0x07)
    assert not t.has_wait_status
    chip = lm629_host.LM629(t)
    chip.reset()
    before = t.stats.round_trips
    t0 = chip.clock.now()
    with pytest.raises(WaitTimeout):
        chip.wait_for(Status.INDEX_PULSE, timeout=10)
    assert chip.clock.now() - t0 >= 10
    # the most reads the poll rate allows (each read also costs its round trip, so fewer)
    waited, bound = 0.0, 1
    while waited < 10:
        waited += poll_interval(waited)
        bound += 1
    polls = t.stats.round_trips - before
    assert 10 / POLL_MAX_S <= bound and polls <= bound and polls < 10 / 1e-3 / 20


def test_record_keeps_a_bounded_window():
    chip = lm629_host.open("sim://?record=1&record_window=100")
    chip.reset()
    n0 = len(chip.transport.model.history) + chip.transport.model.history.dropped
    for i in range(1000):
        chip.set_breakpoint(i)
    h = chip.transport.model.history
    assert 100 <= len(h) <= 100 + 100 // 8
    assert len(h) + h.dropped == n0 + 1000
    assert h[-1] == (int(Cmd.SBPA), (0, 999)) and h[-100] == (int(Cmd.SBPA), (0, 900))


@pytest.mark.usefixtures("firmware_built")
def test_firmware_waits_on_the_bridge_in_one_round_trip():
    chip = lm629_host.open("sim+avr://?baud=1000000")
    assert chip.transport.has_wait_status
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    chip.load_trajectory(acceleration=400, velocity=0x40000, position=2000)
    chip.start()
    before = chip.transport.stats.round_trips
    t0 = chip.clock.now()
    assert chip.wait_for(Status.TRAJECTORY_COMPLETE, timeout=5) & Status.TRAJECTORY_COMPLETE
    # one exchange per half the failsafe's timeout at most (a wait is the host alive only
    # while it sends): the failsafe's 0.5 s default makes it 250 ms
    # (each wait lasts at least its 250 ms and up to a fifth longer: a status read and the
    # firmware's loop on top of every 125 us period)
    took = chip.clock.now() - t0
    chunks = math.ceil(took / 0.25)
    assert math.ceil(took / (0.25 * 1.2)) <= chip.transport.stats.round_trips - before <= chunks + 1
    assert abs(chip.read_real_position() - 2000) <= 13  # kp = 20: the 8-bit output's dead band
    t0 = chip.clock.now()
    with pytest.raises(WaitTimeout):  # never set: the bridge gives up after the timeout
        chip.wait_for(Status.INDEX_PULSE, timeout=0.02)
    assert chip.clock.now() - t0 >= 0.02


@pytest.mark.usefixtures("firmware_built")
def test_first_sim_avr_use_says_what_it_builds(tmp_path, monkeypatch, capsys):
    """A cold build takes seconds: the first use says so in one line on stderr; a warm one is
    silent."""
    import shutil

    from lm629_host.sim import harness

    fw = tmp_path / "firmware_bridge"
    shutil.copytree(harness.FIRMWARE_DIR, fw, ignore=shutil.ignore_patterns("build"))
    monkeypatch.setattr(harness, "FIRMWARE_DIR", fw)
    monkeypatch.setattr(harness, "_built", False)
    harness.ensure_built()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "building the bridge firmware" in err[0] and str(fw) in err[0]
    assert (fw / "build" / "lm629_bridge.hex").exists() and (fw / "build" / "libfitl.so").exists()
    monkeypatch.setattr(harness, "_built", False)
    harness.ensure_built()
    assert capsys.readouterr().err == ""
