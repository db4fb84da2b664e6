"""The FT232H transport through the real pyftdi on the emulated FT232H (``sim+ftdi://``).

Figures: the emulator charges ``usb_us`` (125 us) per bulk transfer; the stream waits 100 us
(the chip's documented worst-case busy) after each transfer before the next busy check.
"""

from __future__ import annotations

import logging

import pytest

import lm629_host
from lm629_host import BusyTimeout, Cmd, Status
from lm629_host.transports.ftdi_busy import COMMAND_S

LTRJ_WORDS = (0x002A, 0x0000, 0x1234, 0x0005, 0x6789, 0xFFFF, 0xFC18)  # acc, vel, pos -1000


def load_ltrj(chip, start=False):
    chip.load_trajectory(acceleration=0x1234, velocity=0x56789, position=-1000, start=start)


@pytest.fixture
def chip(open_chip):
    c = open_chip("sim+ftdi://?record=1")
    c.reset()
    return c


def usb(chip):
    d = chip.transport.device.counters
    return d.bulk_out, d.bulk_in


@pytest.mark.parametrize("name, call", [
    ("RDRP", lambda c: c.read_real_position()),
    ("LTRJ six words", load_ltrj),
    ("STT", lambda c: c.start()),
    ("LFIL four coefficients", lambda c: c.load_filter(kp=1, ki=2, kd=3, il=4)),
    ("MSKI", lambda c: c.mask_interrupts(Status.BREAKPOINT)),
    ("snapshot", lambda c: c.snapshot()),
])
def test_one_usb_write_and_one_usb_read_per_typed_command(chip, name, call):
    if name == "STT":
        load_ltrj(chip)
    t = chip.transport
    t.stats.reset()
    out0, in0 = usb(chip)
    call(chip)
    # counted by the transport and, independently, by the emulated device's endpoints
    assert t.stats.round_trips == 1
    assert usb(chip) == (out0 + 1, in0 + 1)
    assert t.stats.retries == 0


def test_ltrj_counts(chip):
    t = chip.transport
    t.stats.reset()
    load_ltrj(chip)
    s = t.stats
    # 8 transfers (command + 7 words), each after a status read: 8 busy polls, 1 + 7 x 2 write
    # strobes + 8 status strobes = 23 bus cycles; bytes in: 8 status bytes + the HI sample
    assert (s.busy_polls, s.bus_cycles, s.bytes_in) == (8, 23, 9)
    assert chip.transport.model.history[-1] == (Cmd.LTRJ, LTRJ_WORDS)


def test_rdrp_emulated_time_holds_the_two_busy_waits(open_chip):
    """RDRP with ``busy_us=100`` (the documented worst case, fixed): command, word, word.  Two
    100 us waits inside the stream (after the command and the first word), two 125 us USB
    transfers, plus a few microseconds of strobes."""
    chip = open_chip("sim+ftdi://?busy_us=100")
    chip.reset()
    t0 = chip.clock.now()
    chip.read_real_position()
    dt = chip.clock.now() - t0
    assert 2 * 125e-6 + 2 * 100e-6 <= dt < 2 * 125e-6 + 2 * 100e-6 + 60e-6


@pytest.mark.parametrize("busy_us", [20, 45])
def test_the_busy_wait_is_the_chips_own_measured_before_the_first_program(open_chip, busy_us):
    """By default the wait after a transfer is the chip's busy time, measured before the first
    program: never shorter than the chip's (the model's ``busy_s``), at most about one status
    read (3 us) longer.  RDRP's two waits then hold just that: two 125 us USB transfers + two busy
    times + about 27 us of MPSSE commands, within 1.3 x the limit of two microframes + chip."""
    chip = open_chip(f"sim+ftdi://?busy_s={busy_us}e-6")
    t = chip.transport
    assert t.busy.calibrated_s is None  # opening touched nothing
    chip.reset()
    assert busy_us * 1e-6 <= t.busy.calibrated_s <= busy_us * 1e-6 + 3.5e-6
    assert t.busy.wait_s == pytest.approx(t.busy.calibrated_s)
    t.stats.reset()
    chip.load_trajectory(stop="off", start=True)
    t0 = chip.clock.now()
    chip.read_real_position()
    dt = chip.clock.now() - t0
    # each wait is shortened by the commands before its check (about 6) counted at the least
    # cost the calibration allows, not at the emulator's 0.5 us: that much longer at most
    slack = 2 * 8 * (COMMAND_S - t.busy.command_s)
    assert 2 * 125e-6 + 2 * busy_us * 1e-6 <= dt <= 2 * 125e-6 + 2 * t.busy.wait_s + 30e-6 + slack
    if busy_us == 20:
        assert dt <= 1.3 * 253e-6
    assert t.stats.retries == 0 and t.busy.hits == 0


def test_a_chip_slower_than_measured_is_repeated_and_the_wait_learns(open_chip, caplog):
    """A chip that holds busy 35 us after one transfer (measured: 20): the check sees busy, the
    command is repeated (never lost, never doubled), and the wait grows so that it is not
    seen again."""
    chip = _long_busy_chip(open_chip)
    model, device, t = chip.transport.model, chip.transport.device, chip.transport
    assert t.busy.wait_s < 25e-6
    device.chip_pins.stretch_busy(1, 35e-6, skip=2)
    with caplog.at_level(logging.WARNING, logger="lm629_host.ftdi"):
        load_ltrj(chip)
    assert model.history.count((Cmd.LTRJ, LTRJ_WORDS)) == 1 and model.history[-1] == \
        (Cmd.LTRJ, LTRJ_WORDS)
    assert t.stats.retries == 1 and "longer than measured" in caplog.text
    assert 35e-6 <= t.busy.wait_s <= 2 * t.busy.floor_s  # doubled: 22.2 -> 44.3 us, not the cap
    hits = t.busy.hits
    for _ in range(3):
        load_ltrj(chip)
    assert t.busy.hits == hits and t.stats.retries == 1


def test_one_retry_at_most_doubles_the_wait_and_retry_free_commands_bring_it_back(open_chip):
    """Busy held 10 us (the model's ``busy_s``): the calibration measures it within one status
    read (3.5 us).  One transfer held 25 us is repeated, and the wait doubles: at most twice
    the wait before, never the 100 us cap (the host's time around the USB exchange, >= 250
    us, plays no part).  Each later transfer whose check passes adds (wait - calibrated wait)
    of extra waiting; once that reaches REPEAT_COST_S (500 us) the wait halves back to the
    calibrated one.  One LTRJ is 8 checks (command byte and 7 words), about 81 us of extra
    waiting each at a doubled 21.3 us (calibrated 10.7 us: 10 us from the /WR strobe, the
    calibration's status reads being 3 us apart): the repeated LTRJ and the next 4 keep the
    doubled wait (5 x 85 = 427 us), the 6th brings it back."""
    import math

    from lm629_host.transports.ftdi_busy import REPEAT_COST_S
    chip = open_chip("sim+ftdi://?busy_s=10e-6&record=1&strict=0")
    chip.reset()
    t, device = chip.transport, chip.transport.device
    before = t.busy.wait_s
    assert 10e-6 <= t.busy.calibrated_s <= 13.5e-6 and before == pytest.approx(t.busy.floor_s)
    device.chip_pins.stretch_busy(1, 25e-6, skip=2)
    load_ltrj(chip)
    assert t.stats.retries == 1
    assert t.busy.wait_s == pytest.approx(2 * before) and t.busy.wait_s < 100e-6
    back_at = math.ceil(REPEAT_COST_S / (8 * before))  # loads, the repeated one included
    assert back_at == 6
    for n in range(2, back_at + 1):
        load_ltrj(chip)
        assert t.busy.wait_s == pytest.approx(before if n == back_at else 2 * before), n
    assert t.stats.retries == 1
    hist = t.model.history
    assert hist[-1] == (Cmd.LTRJ, LTRJ_WORDS) and hist.count((Cmd.LTRJ, LTRJ_WORDS)) == back_at


def test_an_adapter_whose_commands_take_no_time_waits_the_busy_seen_plus_a_poll(open_chip):
    """pyftdi's own virtual FT232H runs MPSSE commands in no time (its engine has no clock):
    ``command_ns=0`` here.  Counted at 0.5 us a command, the calibration's status reads (5
    commands and 3 bits each) were taken to be 3 us apart where they are 0.5 us apart, and
    busy held 10 us came out as a 61.2 us wait, six times.  The calibration's streams at
    four paddings find what a command costs here (nothing): the wait is the busy time and
    about a status read (10-12.5 us), one forced repeat at most doubles it (under 25 us), and
    no check sees busy in the commands after (strict model: a transfer while busy raises)."""
    chip = open_chip("sim+ftdi://?busy_s=10e-6&command_ns=0&record=1")
    chip.reset()
    t, device = chip.transport, chip.transport.device
    assert t.busy.command_s < 50e-9
    assert 10e-6 <= t.busy.calibrated_s < 12.5e-6 and t.busy.wait_s == pytest.approx(t.busy.calibrated_s)
    for _ in range(5):
        load_ltrj(chip)
        chip.read_real_position()
    assert t.stats.retries == 0 and t.busy.hits == 0
    device.chip_pins.stretch_busy(1, 15e-6, skip=2)
    load_ltrj(chip)
    assert t.stats.retries == 1 and t.busy.wait_s < 25e-6
    assert t.model.history[-1] == (Cmd.LTRJ, LTRJ_WORDS)


@pytest.mark.parametrize("command_ns", [0, 100, 250, 500])
@pytest.mark.parametrize("busy_us", [8, 20, 45])
def test_the_calibrated_wait_holds_whatever_a_command_costs(open_chip, command_ns, busy_us):
    """Whatever an MPSSE command costs on the adapter (up to the 0.5 us taken as the most),
    the measured wait is never shorter than the chip's busy time and a session of typed
    commands sees no busy check fail; the wait is at most a few status reads longer."""
    chip = open_chip(f"sim+ftdi://?busy_s={busy_us}e-6&command_ns={command_ns}&record=1")
    chip.reset()
    t = chip.transport
    assert busy_us * 1e-6 <= t.busy.calibrated_s <= busy_us * 1e-6 + 5e-6
    assert t.busy.command_s <= command_ns * 1e-9
    for _ in range(3):
        load_ltrj(chip)
        chip.read_real_position()
        chip.load_filter(kp=1, ki=2, kd=3, il=4)
    assert t.stats.retries == 0 and t.busy.hits == 0


def test_a_bus_that_never_shows_busy_keeps_the_default_and_says_why(open_chip):
    """D0 stuck low: no status read after the calibration's RDSIGS shows busy, which is no
    measure (the first read's 1.2 us is not a busy time).  The documented 100 us is kept, the
    calibration runs again before the next program, and doctor shows the reason."""
    from click.testing import CliRunner

    from lm629_host.cli import main
    chip = open_chip("sim+ftdi://?wiring=d0-low")
    t = chip.transport
    chip.read_status()
    assert t.busy.calibrated_s is None and t.busy.wait_s == pytest.approx(100e-6)
    assert "no status read after RDSIGS showed busy" in t.busy.note
    assert [c.ok for c in t.port_checks()] == [False]
    exchanges = t.stats.round_trips
    chip.read_status()  # measured again first: its exchanges are counted apart
    assert t.busy.exchanges == 2 and t.stats.round_trips == exchanges + 1
    assert t.busy.calibrated_s is None and t.busy.wait_s == pytest.approx(100e-6)
    r = CliRunner().invoke(main, ["--port", "sim+ftdi://?wiring=d0-low", "doctor"])
    assert r.exit_code == 1
    assert "busy wait: not measured: no status read after RDSIGS showed busy" in r.output
    r = CliRunner().invoke(main, ["--port", "sim+ftdi://", "doctor"])
    assert "busy wait: measured: the chip holds busy <= 20.2 us" in r.output


# ---------------------------------------------------------------------- injected long busy
def _long_busy_chip(open_chip):
    chip = open_chip("sim+ftdi://?record=1&strict=0")
    chip.reset()
    chip.transport.model.record_clear()
    chip.transport.stats.reset()
    return chip


@pytest.mark.parametrize("skip", range(8))
def test_long_busy_on_any_ltrj_transfer_never_loses_or_doubles_a_write(open_chip, caplog, skip):
    """The chip holds busy 300 us (3x its documented worst case) after LTRJ's transfer number
    ``skip`` (0 = the command byte, 1 = the control word...).  The transport must see it in the
    status bytes, repeat LTRJ from its command byte, and run STT exactly once, after the good
    LTRJ."""
    chip = _long_busy_chip(open_chip)
    model, device = chip.transport.model, chip.transport.device
    device.chip_pins.stretch_busy(1, 300e-6, skip=skip)
    with caplog.at_level(logging.WARNING, logger="lm629_host.ftdi"):
        load_ltrj(chip, start=True)
    assert device.chip_pins.busy_stretched == 1
    history = model.history
    # exactly one complete, correct LTRJ, then exactly one STT, and nothing after it
    assert history.count((Cmd.LTRJ, LTRJ_WORDS)) == 1
    assert history[-2:] == [(Cmd.LTRJ, LTRJ_WORDS), (Cmd.STT, ())]
    assert [c for c, _ in history].count(Cmd.STT) == 1
    # what came before the good LTRJ is the damaged attempt, which the repeat replaced
    damaged = history[:-2]
    assert all(c == Cmd.LTRJ and w != LTRJ_WORDS for c, w in damaged)
    if skip < 7:  # a stretch after the last word only delays STT's check, which waits
        assert len(damaged) == 1
        assert chip.transport.stats.retries == 1
        assert "repeating from command 1F (LTRJ)" in caplog.text
        assert any("while busy" in v for v in model.violations)  # it did write into busy
    # the chip's trajectory buffer holds what was meant when STT took it
    buf = model.trajectory
    assert (buf.control, buf.acceleration, buf.velocity, buf.position) == \
        (0x2A, 0x1234, 0x56789, -1000)


def test_long_busy_for_several_transfers_still_lands_everything(open_chip):
    chip = _long_busy_chip(open_chip)
    model, device = chip.transport.model, chip.transport.device
    device.chip_pins.stretch_busy(4, 400e-6, skip=2)
    chip.load_filter(kp=10, ki=20, kd=30, il=40)
    chip.mask_interrupts(Status.BREAKPOINT)
    lfil = (Cmd.LFIL, (0x000F, 10, 20, 30, 40))
    assert model.history.count(lfil) == 1
    assert model.history[-1] == (Cmd.MSKI, (int(Status.BREAKPOINT),))
    assert [c for c, _ in model.history].count(Cmd.MSKI) == 1
    assert (model.filter_buffer.kp, model.filter_buffer.ki, model.filter_buffer.kd,
            model.filter_buffer.il) == (10, 20, 30, 40)
    assert model.mask == int(Status.BREAKPOINT)
    assert chip.transport.stats.retries >= 2


def test_long_busy_on_a_read_gives_the_fresh_word_not_the_stale_one(open_chip):
    chip = _long_busy_chip(open_chip)
    load_ltrj(chip)  # leaves FC18 in the chip's I/O register: what a stale read returns
    model, device = chip.transport.model, chip.transport.device
    device.chip_pins.stretch_busy(1, 300e-6)  # the RDSIGS command byte
    signals = chip.read_signals()
    assert int(signals) == model.signals
    assert int(signals) != 0xFC18
    assert chip.transport.stats.retries == 1


def test_trace_shows_the_busy_status_and_the_repeat(open_chip, recorder):
    chip = _long_busy_chip(open_chip)
    chip.transport.device.chip_pins.stretch_busy(1, 300e-6)  # the MSKI command byte
    recorder.clear()
    chip.mask_interrupts(Status.BREAKPOINT)
    kinds = [(c.kind, c.value) for c in recorder.cycles]
    busy_at = next(i for i, (k, v) in enumerate(kinds) if k == "status" and v & Status.BUSY)
    # the word strobed into busy, then polls until clear, then the whole command again
    assert kinds[busy_at + 1] == ("write", 0x0040)
    assert recorder.data() == [("command", 0x1C), ("write", 0x0040), ("command", 0x1C),
                               ("write", 0x0040)]


def test_stuck_busy_is_a_busy_timeout_on_the_emulated_clock(open_chip):
    chip = open_chip("sim+ftdi://?fault=busy")
    t0 = chip.clock.now()
    with pytest.raises(BusyTimeout, match="0A \\(RDRP\\)"):
        chip.read_real_position()
    elapsed = chip.clock.now() - t0
    # the default 5 ms busy timeout, polled in short exchanges of 2 x 125 us
    assert 5e-3 <= elapsed < 5e-3 + 1e-3


def test_strict_sim_ftdi_still_flags_a_violation_the_transport_did_not_see(open_chip):
    chip = open_chip("sim+ftdi://")
    with pytest.raises(lm629_host.ProtocolViolation, match="data byte"):
        chip.raw(Cmd.STT, write=[1])  # a data word after a command that takes none


def test_the_busy_wait_is_kept_across_streams_even_with_instant_usb(open_chip):
    """usb_us=0: the next stream would start right after the last transfer of the previous
    one; it must begin with what is left of the 100 us wait (the model's busy is 20 us), so no
    status read before a transfer ever shows busy and nothing is repeated (strict model)."""
    chip = open_chip("sim+ftdi://?usb_us=0&command_ns=0")
    chip.reset()
    for _ in range(3):
        load_ltrj(chip)
        chip.read_real_position()
        chip.mask_interrupts(0)
    assert chip.transport.stats.retries == 0
    assert chip.transport.busy.hits == 0


def test_program_result_reports_the_hi_line(open_chip):
    from lm629_host import Program

    chip = open_chip("sim+ftdi://")
    chip.reset()
    assert chip.run(Program().status()).hi is False
    chip.mask_interrupts(Status.BREAKPOINT)  # after reset the breakpoint flag sets at once
    chip.wait_for(Status.BREAKPOINT, timeout=0.01)
    assert chip.run(Program().status()).hi is True
    assert chip.transport.model.hi


def test_a_raised_wait_comes_back_to_the_calibrated_one_never_below(open_chip):
    """Busy held 55 us: the calibrated wait is about 57 us; a repeat doubles it to at most the
    documented 100 us cap (not 114 us), and once the extra waiting pays for a repeat the wait
    halves, to 50 us by the arithmetic, but never below the calibrated wait (a wait under the
    chip's busy time makes every check a repeat)."""
    import math

    from lm629_host.transports.ftdi_busy import REPEAT_COST_S
    chip = open_chip("sim+ftdi://?busy_s=55e-6&record=1&strict=0")
    chip.reset()
    t, device = chip.transport, chip.transport.device
    floor = t.busy.floor_s
    assert 55e-6 <= floor < 60e-6 and t.busy.wait_s == pytest.approx(floor)
    device.chip_pins.stretch_busy(1, 80e-6, skip=2)
    load_ltrj(chip)
    assert t.stats.retries == 1 and t.busy.wait_s == pytest.approx(100e-6)  # the cap, not 2 x floor
    for _ in range(math.ceil(REPEAT_COST_S / (8 * (100e-6 - floor))) + 1):
        load_ltrj(chip)
    assert t.busy.wait_s == pytest.approx(floor)  # halved from 100 us would be 50 us: the floor holds
    assert t.stats.retries == 1  # and no check saw busy after it
