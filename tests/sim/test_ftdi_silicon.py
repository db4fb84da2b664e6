"""What the FT232H silicon does that the transport must respect, on the emulated FT232H that
models it (``lm629_host.sim.ftdi.device``): the bit-mode mask at open, the 1 KiB buffers,
clock modes left on by another tool, and the purge requests as libftdi and pyftdi define them.

The emulator's models are checked first (pyftdi's plain calls show each behaviour), then the
transport against them.
"""

from __future__ import annotations

import pytest
import usb.core

import lm629_host
from lm629_host.wiring import ft232h as pins
from lm629_host.sim.ftdi import EmulatedBackend, EmulatedFT232H
from lm629_host.sim.model import ChipModel
from lm629_host.bus.opcodes import Cmd
from lm629_host.bus.program import Program
from lm629_host.transports.ftdi import FtdiTransport
from lm629_host.transports.ftdi_open import FT232H_PID, FTDI_VID, open_mpsse
from lm629_host.transports.simftdi import EmulatedClock

BUS_LINES = {"/CS": pins.CS, "/RD": pins.RD, "/WR": pins.WR, "/PS": pins.PS, "/RST": pins.RST}


def usb_device(device: EmulatedFT232H):
    return usb.core.find(backend=EmulatedBackend([device]), idVendor=FTDI_VID,
                         idProduct=FT232H_PID)


def falls(device: EmulatedFT232H) -> list[tuple[str, int]]:
    """(line, ns) for every time a bus control line was low."""
    return [(name, ns) for ns, level in device.chip_pins.ctrl_log for name, bit in BUS_LINES.items()
            if not level & bit]


# ------------------------------------------------------------------ open: the bit-mode mask
def test_emulator_models_the_bitmode_mask():
    """pyftdi's open with the direction as the bit-mode mask: on the FT232H the masked lines
    become outputs driving the latch (0) until the first 0x80; /RST falls and the chip resets."""
    from pyftdi.ftdi import Ftdi

    model = ChipModel()
    device = EmulatedFT232H(model)
    ftdi = Ftdi()
    ftdi.open_mpsse_from_device(usb_device(device), 1, direction=pins.CTRL_DIRECTION,
                                initial=pins.CTRL_IDLE)
    lines = {name for name, _ in falls(device)}
    assert lines == set(BUS_LINES)
    ftdi.close()


def test_transport_open_drives_no_bus_line_low():
    """The transport's open: /CS, /RD, /WR, /PS and /RST never fall, and the chip is not reset
    (a register a reset would clear keeps its value), until a program asks for it."""
    model = ChipModel()
    model.reset_pulse()
    model.advance_to(model.tick + 100_000)
    model.position_error_threshold = 1234  # LPEI's register: /RST sets it back to 7FFF
    device = EmulatedFT232H(model)
    ftdi = open_mpsse("ftdi://emulated", device=usb_device(device))
    assert falls(device) == []
    # the lines do end up driven high (not left floating on the pull-ups)
    assert device.chip_pins.low_dir == pins.CTRL_DIRECTION
    assert device.chip_pins.ctrl & pins.CTRL_IDLE == pins.CTRL_IDLE
    t = FtdiTransport(ftdi, "ftdi://emulated", clock=EmulatedClock(device))
    chip = lm629_host.LM629(t)
    chip.read_status()
    assert {name for name, _ in falls(device)} == {"/CS", "/PS", "/RD"}  # the status read
    assert model.position_error_threshold == 1234
    chip.close()


def test_sim_ftdi_open_drives_no_bus_line_low():
    with lm629_host.open("sim+ftdi://") as chip:
        assert falls(chip.transport.device) == []


def test_close_returns_the_ft232h_to_uart_mode():
    """pyftdi's close is a bit-mode reset: the FT232H goes back to UART mode, where TXD, RTS#
    and DTR# (ADBUS0, 2, 4: TCK, /RD, /PS here) are outputs driven high and every other line
    is an input.  No bus line falls on the way (so /RST does not reset the chip)."""
    from lm629_host.sim.ftdi.device import UART_OUTPUTS
    chip = lm629_host.open("sim+ftdi://")
    chip.read_status()
    device = chip.transport.device
    n = len(device.chip_pins.ctrl_log)
    chip.close()
    assert UART_OUTPUTS == pins.TCK | pins.RD | pins.PS
    assert device.chip_pins.low_dir == UART_OUTPUTS and device.chip_pins.high_dir == 0
    assert device.chip_pins.ctrl == 0xFF  # /RD, /PS driven high; /CS, /WR, /RST pulled up
    assert all(level & pins.CTRL_IDLE == pins.CTRL_IDLE for _, level in device.chip_pins.ctrl_log[n:])


# ------------------------------------------------------------------ clock modes
def test_clock_modes_left_on_by_another_tool_are_switched_off_at_open():
    """Adaptive clocking on: the emulator's idle clocks wait for RTCK, so a stream never ends;
    3-phase on: delays last 1.5 x.  The transport switches both off when it opens."""
    device = EmulatedFT232H(ChipModel(), adaptive=True, three_phase=True)
    ftdi = open_mpsse("ftdi://emulated", device=usb_device(device))
    assert not device.adaptive and not device.three_phase
    assert device.tck_hz == pytest.approx(6e6)  # the divide-by-5 and divisor as asked
    t = FtdiTransport(ftdi, "ftdi://emulated", clock=EmulatedClock(device))
    chip = lm629_host.LM629(t)
    chip.reset()
    assert chip.read_real_position() == 0
    chip.close()


def test_emulator_adaptive_clocking_stalls_a_stream():
    from pyftdi.ftdi import Ftdi

    device = EmulatedFT232H(ChipModel(), adaptive=True)
    ftdi = Ftdi()
    ftdi.open_mpsse_from_device(usb_device(device), 1)
    ftdi.write_data(bytes((0x8E, 7, 0x81, 0x87)))  # 8 idle clocks, read the low byte
    assert ftdi.read_data_bytes(1, 4) == b""
    ftdi.close()


# ------------------------------------------------------------------ purge
def test_purge_values_as_libftdi_defines_them():
    """Value 1 (SIO_RESET_PURGE_RX, pyftdi ``purge_rx_buffer``) empties the host->chip buffer;
    value 2 (SIO_RESET_PURGE_TX, ``purge_tx_buffer``) the chip->host one."""
    from pyftdi.ftdi import Ftdi

    device = EmulatedFT232H(ChipModel())
    ftdi = Ftdi()
    ftdi.open_mpsse_from_device(usb_device(device), 1)
    # an incomplete command waits in the host->chip buffer: purge 1 drops it, so the next
    # bytes are commands again (else 0x81 0x87 would be taken as its arguments)
    ftdi.write_data(bytes((0x80,)))
    ftdi.purge_rx_buffer()
    ftdi.write_data(bytes((0x81, 0x87)))
    assert len(ftdi.read_data_bytes(1, 4)) == 1
    # an answer waits in the chip->host buffer: purge 2 drops it
    ftdi.write_data(bytes((0x81, 0x87)))
    ftdi.purge_tx_buffer()
    assert ftdi.read_data_bytes(1, 4) == b""
    ftdi.close()


# ------------------------------------------------------------------ the 1 KiB buffers
def test_emulator_stalls_a_stream_whose_answers_overflow_1k():
    """1100 reads in one stream: the engine stops at the 1025th (answer buffer full), the
    rest of the stream cannot be taken, and the USB write times out."""
    from pyftdi.ftdi import Ftdi, FtdiError

    device = EmulatedFT232H(ChipModel())
    ftdi = Ftdi()
    ftdi.open_mpsse_from_device(usb_device(device), 1)
    with pytest.raises(FtdiError, match="timed out"):
        ftdi.write_data(bytes((0x83,)) * 1100 + bytes((0x8E, 0)) * 600 + b"\x87")
    ftdi.close()


def test_an_1100_read_program_works():
    """550 RDRP (1100 READ operations) in one program: split into streams that fit the
    FT232H's buffers, every word right."""
    with lm629_host.open("sim+ftdi://") as chip:
        chip.reset()
        chip.transport.model.set_motor_params(load_torque=0.0)
        p = Program()
        for _ in range(550):
            p.command(Cmd.RDRP).read(2)
        r = chip.run(p)
        dev = chip.transport.device
        assert r.words == (0,) * 1100
        assert dev.counters.most_unread <= pins.FIFO_BYTES
        st = chip.transport.stats
        # every stream fitted: the bytes went out in at least bytes/1 KiB exchanges
        assert st.round_trips >= st.bytes_out / pins.FIFO_BYTES
        assert st.retries == 0


def test_a_busy_repeat_in_a_later_stream_starts_at_its_command():
    """550 RDRP split over many streams; a chip that holds busy too long after the 700th
    transfer makes the transport repeat from that RDRP's command byte in a new stream: every
    word is still right and nothing is read twice into the result."""
    with lm629_host.open("sim+ftdi://") as chip:
        chip.reset()
        dev = chip.transport.device
        dev.chip_pins.stretch_busy(1, 400e-6, skip=700)
        p = Program()
        for _ in range(550):
            p.command(Cmd.RDRP).read(2)
        r = chip.run(p)
        assert r.words == (0,) * 1100
        assert dev.chip_pins.busy_stretched == 1 and chip.transport.stats.retries == 1
