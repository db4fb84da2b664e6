"""FT232H with D0 wired to GPIOL1 (``busy_pin=gpiol1``): each busy check is a status read held
low while the MPSSE engine waits on the pin (0x88 until high, 0x89 until low; FTDI AN_108), so
LTRJ + STT is one exchange, and a chip slower than any timed wait costs time, not a repeat.

Expected bytes come from the pin map (ftdi_pins: /CS ADBUS1, /RD ADBUS2, /WR ADBUS3, /PS ADBUS4;
GPIOL1 is ADBUS5) and AN_108's opcodes, as in test_ftdi_stream.py.  Timing on the emulated
FT232H: 125 us per USB transfer, 0.5 us per MPSSE command, the model's busy 20 us per transfer.
"""

from __future__ import annotations

import logging

import pytest

import lm629_host
from lm629_host import BusyTimeout, Cmd, Program
from lm629_host.wiring import ft232h as pins
from lm629_host.transports.mpsse import StreamCompiler, streams_of

pytest.importorskip("pyftdi")

WIRED = "sim+ftdi://?busy_pin=gpiol1&record=1"
LTRJ_WORDS = (0x002A, 0x0000, 0x1234, 0x0005, 0x6789, 0xFFFF, 0xFC18)  # acc, vel, pos -1000
DIR = 0xDF
SEL_CMD = 0xCC  # /CS and /PS low


def ltrj_stt() -> Program:
    return (Program().command(Cmd.LTRJ).write(0x2A).write32(0x1234).write32(0x56789)
            .write32(-1000 & 0xFFFFFFFF).command(Cmd.STT))


def load_ltrj(chip, start=False):
    chip.load_trajectory(acceleration=0x1234, velocity=0x56789, position=-1000, start=start)


# ------------------------------------------------------------------------- the stream
def test_wired_ltrj_stt_is_one_stream_of_held_checks_without_timed_waits():
    ops = ltrj_stt().ops
    assert len(streams_of(ops, cut_actions=False)) == 1
    assert len(streams_of(ops)) == 2  # unwired: two streams, cut before the STT
    s = StreamCompiler(6e6, 100e-6, busy_pin=True).compile(ops)
    data = bytes(s.data)
    assert pins.CLK_BYTES not in data  # no 100 us idle-clock waits
    # the first check: nothing sent before it in this stream, so only "wait until low"
    first = bytes([0x80, SEL_CMD & ~0x04, DIR, 0x8E, 0x01, 0x89, 0x83, 0x80, SEL_CMD, DIR,
                   0x8E, 0x00])
    assert data.startswith(bytes([0x80, SEL_CMD, DIR, 0x8E, 0x00]) + first)
    # every later check follows a transfer on the same chip: busy seen high, then low
    assert data.count(bytes([0x8E, 0x01, 0x88, 0x89, 0x83])) == 8  # 7 words + STT
    assert data.count(bytes([0x8E, 0x01, 0x89, 0x83])) == 1 and s.waits == 9
    assert [sl.kind for sl in s.slots].count("check") == 9


def test_a_wait_or_another_chip_between_drops_the_wait_for_busy_high():
    """0x88 would wait for ever once the transfer's busy is over: after WAIT, after another
    chip's operations and after /RST only 0x89 is sent."""
    c = StreamCompiler(6e6, busy_pin=True)
    after_wait = bytes(c.compile(Program().command(Cmd.RDSIGS).read().wait(200)
                                 .command(Cmd.UDF).ops).data)
    assert after_wait.count(0x88) == 1  # before RDSIGS's word, not after the WAIT
    two = (Program().command(Cmd.STT).select(1).command(Cmd.STT).select(0).command(Cmd.UDF))
    data = bytes(c.compile(two.ops).data)
    assert data.count(0x88) == 0 and data.count(0x89) == 3


# ------------------------------------------------------------------------- emulated
def test_wired_ltrj_stt_is_one_exchange_and_lands_once(open_chip):
    chip = open_chip(WIRED)
    chip.reset()
    t, model = chip.transport, chip.transport.model
    model.record_clear()
    before = t.stats.round_trips
    t0 = chip.clock.now()
    load_ltrj(chip, start=True)
    took = chip.clock.now() - t0
    assert t.stats.round_trips - before == 1 and t.stats.retries == 0
    assert model.history == [(Cmd.LTRJ, LTRJ_WORDS), (Cmd.STT, ())]
    assert not model.violations
    # two 125 us transfers, 8 transfers x 20 us of busy (waited on the pin), the commands;
    # the unwired transport needs two exchanges (> 750 us); this one stays under 1.5 x 478 us
    assert 250e-6 + 8 * 20e-6 < took < 1.5 * 478e-6
    assert t.device.wait_ns >= 8 * 20_000 - 8 * 3_000  # the engine stood still on busy


@pytest.mark.parametrize("skip", [0, 3, 7])
def test_a_slow_chip_is_waited_for_not_repeated(open_chip, caplog, skip):
    """The chip holds busy 300 us (3x its documented worst case) after LTRJ's transfer number
    ``skip``: the held check waits for it in the adapter.  No write lands in busy, no repeat,
    one exchange, one LTRJ and one STT."""
    chip = open_chip(WIRED + "&strict=1")
    chip.reset()
    t, model, device = chip.transport, chip.transport.model, chip.transport.device
    model.record_clear()
    device.chip_pins.stretch_busy(1, 300e-6, skip=skip)
    before, w0 = t.stats.round_trips, device.wait_ns
    with caplog.at_level(logging.WARNING, logger="lm629_host.ftdi"):
        load_ltrj(chip, start=True)
    assert device.chip_pins.busy_stretched == 1
    assert model.history == [(Cmd.LTRJ, LTRJ_WORDS), (Cmd.STT, ())]
    assert not model.violations and t.stats.retries == 0 and not caplog.text
    assert t.stats.round_trips - before == 1
    assert device.wait_ns - w0 >= 300_000  # the stretched busy was waited out on the pin
    buf = model.trajectory
    assert (buf.control, buf.acceleration, buf.velocity, buf.position) == \
        (0x2A, 0x1234, 0x56789, -1000)


def test_busy_that_never_clears_stops_the_stream_which_the_transport_purges(open_chip):
    """fault=busy: the engine waits on the pin for ever (MPSSE has no timeout).  The read
    gives up after the program's busy timeout; the transport purges the FT232H, re-enters
    MPSSE with the lines idle and raises BusyTimeout for the operation not taken."""
    chip = open_chip("sim+ftdi://?busy_pin=gpiol1&fault=busy")
    t, device = chip.transport, chip.transport.device
    t0 = chip.clock.now()
    with pytest.raises(BusyTimeout) as err:
        chip.read_real_position()
    waited = chip.clock.now() - t0
    assert err.value.operation.startswith("command 0A") and err.value.index == 0
    assert err.value.status is not None and err.value.status & 0x01
    assert t.resync.stalls == 1
    # the read's patience: 3 + 5 ms / 1 ms latency periods, then the purge and one poll
    assert 5e-3 < waited < 12e-3
    assert device.waiting is None and not device._pending
    assert device.chip_pins.ctrl & pins.CTRL_IDLE == pins.CTRL_IDLE  # /CS, /RD, /WR, /RST high again
    assert chip.read_status() & 0x01  # the adapter answers again


def test_a_stall_before_stt_leaves_stt_untaken(open_chip):
    """Busy held 50 ms (past the 5 ms busy timeout) after LTRJ's third transfer: the stream
    stops at the next check, the read gives up, and nothing after it (STT included) reaches
    the chip.  Once busy clears, the same call lands once."""
    chip = open_chip(WIRED + "&strict=0")
    chip.reset()
    t, model, device = chip.transport, chip.transport.model, chip.transport.device
    model.record_clear()
    device.chip_pins.stretch_busy(1, 50e-3, skip=2)
    with pytest.raises(BusyTimeout) as err:
        load_ltrj(chip, start=True)
    assert err.value.index == 3 and t.resync.stalls == 1  # the check of the third data word
    # LTRJ never completed (its command byte and two words only), STT never written
    assert (Cmd.LTRJ, LTRJ_WORDS) not in model.history
    assert [c for c, _ in model.history].count(Cmd.STT) == 0
    chip.clock.sleep(50e-3)
    load_ltrj(chip, start=True)
    assert model.history[-2:] == [(Cmd.LTRJ, LTRJ_WORDS), (Cmd.STT, ())]
    assert [c for c, _ in model.history].count(Cmd.STT) == 1


def test_unwired_still_cuts_before_stt_and_reads_hi(open_chip):
    chip = open_chip("sim+ftdi://?record=1")
    chip.reset()
    t = chip.transport
    before = t.stats.round_trips
    load_ltrj(chip, start=True)
    assert t.stats.round_trips - before == 2
    assert chip.transport.execute(Program().status()).hi is not None
    wired = open_chip(WIRED)
    assert wired.transport.execute(Program().status()).hi is None  # ADBUS5 is D0 now


def test_busy_pin_option_is_checked():
    with pytest.raises(ValueError, match="busy_pin"):
        lm629_host.open("sim+ftdi://?busy_pin=gpiol2")
    with pytest.raises(ValueError, match="busy_us=50 and busy_pin=gpiol1"):
        lm629_host.open("sim+ftdi://?busy_pin=gpiol1&busy_us=50")
    lm629_host.open("sim+ftdi://?busy_pin=none&busy_us=50").close()  # unwired: busy_us is taken


def test_busy_pin_wiring_moves_hi_off_gpiol1_and_puts_d0_there():
    """The wiring that busy_pin=gpiol1 needs, from the one pin map (docs/ftdi.md's second
    table is generated from it; tests/wiring/test_wiring.py checks it is current)."""
    from lm629_host.wiring.connections import connections
    plain = {(c.adapter_pin, c.chip_line) for c in connections("ft232h", 2)}
    wired = {(c.adapter_pin, c.chip_line) for c in connections("ft232h", 2, busy_pin=True)}
    assert plain - wired == {("ADBUS5", "HI")}
    assert wired - plain == {("ADBUS5", "D0")}
    assert ("ACBUS0", "D0") in wired  # D0 keeps its data wire
    assert pins.BUSY_PINS["gpiol1"] == 1 << 5 == pins.HI  # ADBUS5: the line 0x88/0x89 watch
    with pytest.raises(ValueError, match="only the FT232H"):
        connections("uno", 1, busy_pin=True)


# ------------------------------------------------------------------------- the pin check
def test_the_first_program_checks_that_d0_and_gpiol1_show_busy_during_a_held_read(open_chip):
    """Before the first program: a status read, then RDSIGS and one status read held 100 us
    (the documented worst case), sampled at once and at the end: D0 and GPIOL1 read busy, then
    both clear.  Two exchanges, counted apart from the program's."""
    chip = open_chip(WIRED)
    t = chip.transport
    programs, trips = t.stats.programs, t.stats.round_trips
    chip.read_status()
    assert not t.busy.due  # done before that first program
    assert (t.stats.programs - programs, t.stats.round_trips - trips) == (1, 1)
    assert t.busy.check_pin() is True  # and again by hand: D0 and GPIOL1 busy, then clear


def test_a_chip_that_latches_its_status_at_rd_falling_is_refused(open_chip):
    """The emulated chip made to keep the status byte of /RD's falling edge (live_status=0):
    D0 still shows busy 100 us later, so waiting on the pin would never end: a TransportError
    at the first program that says to open the port without busy_pin, and no stream waits."""
    chip = open_chip("sim+ftdi://?busy_pin=gpiol1&live_status=0")
    with pytest.raises(lm629_host.TransportError, match="without busy_pin") as err:
        chip.read_status()
    assert "still showed busy 100 us later" in str(err.value)
    assert chip.transport.resync.stalls == 0


@pytest.fixture
def usb_bus(monkeypatch):
    """pyftdi's USB lookup sees one emulated FT232H (serial FT5LM629) on a chip model; the
    test wires it (``usb_bus(busy_pin=...)``) and opens it by its ``ftdi://`` URL."""
    from pyftdi.usbtools import UsbTools

    from lm629_host.sim.ftdi import EmulatedFT232H
    from lm629_host.sim.ftdi.backend import SHARED
    from lm629_host.sim.model import ChipModel

    monkeypatch.setattr(UsbTools, "BACKENDS", ("lm629_host.sim.ftdi.backend",))
    UsbTools.flush_cache()
    UsbTools.release_all_devices()
    monkeypatch.setattr(SHARED, "libusb_present", True)

    def wire(busy_pin: bool) -> EmulatedFT232H:
        device = EmulatedFT232H(ChipModel(), serial="FT5LM629", busy_pin=busy_pin,
                                live_status=True)
        monkeypatch.setattr(SHARED, "devices", [device])
        return device

    yield wire
    UsbTools.release_all_devices()
    UsbTools.flush_cache()


def test_ftdi_url_with_busy_pin_on_an_adapter_wired_for_it(usb_bus):
    device = usb_bus(busy_pin=True)
    with lm629_host.open("ftdi://ftdi:232h:FT5LM629/1?busy_pin=gpiol1") as chip:
        assert chip.transport.busy_pin == "gpiol1"
        chip.reset()
        trips = device.counters.bulk_out
        load_ltrj(chip, start=True)
        assert device.counters.bulk_out - trips == 1
        assert device.model.trajectory.position == -1000


def test_gpiol1_wired_to_hi_as_by_default_is_refused(usb_bus):
    """The adapter still wired as by default (HI on ADBUS5) but opened with busy_pin: the
    check before the first program sees GPIOL1 not follow D0, and no stream waits on it."""
    usb_bus(busy_pin=False)
    with lm629_host.open("ftdi://ftdi:232h:FT5LM629/1?busy_pin=gpiol1") as chip:
        with pytest.raises(lm629_host.TransportError, match="GPIOL1 does not follow D0"):
            chip.read_status()
        assert chip.transport.resync.stalls == 0
