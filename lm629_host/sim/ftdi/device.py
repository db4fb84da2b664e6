"""An emulated FT232H in MPSSE mode with its pins wired to the chip model, in emulated time.

The device side of the USB link: what the FTDI chip does with the vendor control requests
pyftdi sends, with the bytes of a bulk OUT transfer (the MPSSE command stream), and what it
answers on bulk IN (two modem-status bytes, then the bytes the read commands produced).  The
pyusb side of it (descriptors, endpoints) is :mod:`.backend`.

The pins.  ADBUS and ACBUS, and the LM628/LM629 wired to them, are :mod:`.chip_pins`
(:attr:`EmulatedFT232H.chip_pins`): the chip's strobes, its timing checks, the VCD of its bus
lines and the busy-stretch test hook.  This module is the adapter's side: USB, its buffers and
the MPSSE engine that drives those pins.

Time.  The emulated time (integer nanoseconds) is the pins' (the chip runs on it); the device
charges what its work costs there (emulation choices, with why):

* each MPSSE command costs ``command_ns`` to fetch and execute, default 500 ns: pyftdi's own
  figure for the delay between two SET_BITS commands (``Ftdi.mpsse_bit_delay``, measured on an
  FT2232H); clock commands cost that plus their clocks;
* idle clocks (0x8E: n+1 bits, 0x8F: (n+1) x 8 bits) cost their periods at the configured TCK:
  60 MHz / ((1 + divisor) x 2), or 12 MHz / ((1 + divisor) x 2) with the divide-by-5 on;
* each bulk transfer costs ``usb_ns``, default 125 us: one USB 2.0 high-speed micro-frame, the
  granularity at which the host controller schedules a bulk transfer;
* bytes produced by read commands are sent at once after 0x87 (send immediate); otherwise,
  like the real chip, only when the latency timer expires: a bulk IN then costs the latency
  timer, and so does a bulk IN with nothing to send (the chip answers the two modem-status
  bytes alone when the timer expires).

What the silicon does that a careless host gets wrong, modelled so that tests can see it:

* the bit-mode mask: SET_BITMODE to MPSSE with a non-zero mask makes those ADBUS lines outputs
  at once, driving the MPSSE low-byte latch, which entering MPSSE leaves at 0: a host that
  passes its direction there (pyftdi's ``open_mpsse`` does) pulls /CS, /RD, /WR and /RST low
  until its first 0x80 (``ctrl_log`` records every level of the control lines, with its time);
* the 1 KiB buffers each way (:data:`~lm629_host.wiring.ft232h.FIFO_BYTES`): the engine stops at a
  read command while its answer buffer is full and takes no more command bytes once its
  command buffer is full; a bulk OUT that then cannot be taken times out (USB NAKs it);
* clock modes that survive a change of bit mode: adaptive clocking (0x96) makes idle clocks
  wait for RTCK on GPIOL3, which nothing drives here, so a stream stalls; 3-phase clocking
  (0x8C) makes each clock 1.5 periods.  A device "left so by another tool" starts with them on
  (``adaptive=True``, ``three_phase=True``);
* purge: request 0 value 1 empties the host->chip buffer, value 2 the chip->host buffer (FTDI's
  "purge RX/TX" from the chip's side, libftdi's and pyftdi's ``SIO_RESET_PURGE_RX/TX``).

Wait on I/O (0x88 / 0x89: until GPIOL1, ADBUS5, is high / low; FTDI AN_108).  GPIOL1 is HI
in the default wiring; with ``busy_pin=True`` it is wired to D0 instead (``connections.
connections("ft232h", busy_pin=True)``) and HI to nothing.  The engine then really stops on the emulated clock: a
condition already met costs the command; one the model says will be met at a known time (busy
clearing at ``busy_deadline()``) resumes the engine at that time; one that never comes
(``fault=busy``, or 0x88 with busy already over) stalls it, and the device answers the host's
bulk IN requests with empty packets at its latency timer, as the chip does, until the host
gives up and purges (a purge of the host->chip buffer, or leaving MPSSE, drops the waiting
command).  The engine runs no further ahead than the host's clock allows: waits are resolved
while a bulk IN is pending, up to that request's latency timer, so a host whose read times
out sees exactly what it would see on the real chip.
"""

from __future__ import annotations

from dataclasses import dataclass

from lm629_host.wiring import ft232h as pins
from lm629_host.sim.ftdi.chip_pins import ChipPins
from lm629_host.sim.wiring import Miswiring
from lm629_host.sim.model import ChipBus, ChipModel

# FTDI vendor requests (the ones pyftdi sends; FTDI AN_232B-series numbering)
REQ_RESET = 0x00
REQ_SET_MODEM_CTRL = 0x01
REQ_SET_FLOW_CTRL = 0x02
REQ_SET_BAUDRATE = 0x03
REQ_SET_DATA = 0x04
REQ_POLL_MODEM_STATUS = 0x05
REQ_SET_EVENT_CHAR = 0x06
REQ_SET_ERROR_CHAR = 0x07
REQ_SET_LATENCY_TIMER = 0x09
REQ_GET_LATENCY_TIMER = 0x0A
REQ_SET_BITMODE = 0x0B
REQ_READ_PINS = 0x0C
REQ_READ_EEPROM = 0x90

BITMODE_RESET = 0x00
#: the ADBUS lines the UART drives once a bit-mode reset has returned the FT232H to UART mode:
#: TXD (ADBUS0), RTS# (ADBUS2), DTR# (ADBUS4) (FT232H datasheet FT_000288, UART pin table;
#: pyftdi's pinout table gives ADBUS0/2/4 the same UART functions)
UART_OUTPUTS = 0x01 | 0x04 | 0x10
BITMODE_MPSSE = 0x02

PURGE_HOST_TO_CHIP = 1  #: SIO_RESET_PURGE_RX: commands not yet executed
PURGE_CHIP_TO_HOST = 2  #: SIO_RESET_PURGE_TX: answers not yet read


class BufferFull(Exception):
    """A bulk OUT the device cannot take: its command buffer is full while the engine waits
    for the host to read answers (libusb reports a timeout)."""

#: the two status bytes at the head of every bulk IN packet: modem status (CTS, DSR, and the
#: reserved bit 0 the chip always sets), then line status with the transmitter-empty bits set
MODEM_STATUS = bytes((0x31, 0x60))
PACKET_SIZE = 512  #: high-speed bulk packet size of the FT232H


@dataclass
class Counters:
    """What crossed the emulated USB link."""

    bulk_out: int = 0  #: bulk OUT transfers (MPSSE streams, or parts of them)
    bulk_in: int = 0  #: bulk IN transfers, empty ones included
    bytes_out: int = 0
    bytes_in: int = 0  #: payload bytes sent in bulk IN packets, modem-status bytes excluded
    control: int = 0  #: vendor control requests
    most_unread: int = 0  #: the most answer bytes ever waiting for the host (limit: 1 KiB)


class EmulatedFT232H:
    """One FT232H: its USB side, its buffers and its MPSSE engine, driving :attr:`chip_pins`."""

    vendor_id = 0x0403
    product_id = 0x6014
    bcd_device = 0x0900  #: FT232H (pyftdi recognises the part by this)

    def __init__(self, model: ChipModel | ChipBus, *, serial: str = "LM629EMU", usb_ns: int = 125_000,
                 command_ns: int = 500, bus: int = 1, address: int = 7,
                 adaptive: bool = False, three_phase: bool = False,
                 busy_pin: bool = False, live_status: bool | None = None,
                 wiring: Miswiring | None = None) -> None:
        #: the pins and the chip on them; the emulated time is theirs (:meth:`advance_ns`)
        self.chip_pins = ChipPins(model, busy_pin=busy_pin, live_status=live_status,
                                  wiring=wiring)
        self.model = model
        self.serial = serial
        self.manufacturer = "FTDI"
        self.product = "Single RS232-HS"
        self.bus = bus
        self.address = address
        self.usb_ns = usb_ns
        self.command_ns = command_ns
        self.counters = Counters()
        self.latency_ms = 16
        self.bitmode = BITMODE_RESET
        self.tck_divisor = 0
        self.div5 = True
        self.adaptive = adaptive  #: adaptive clocking on (0x96): idle clocks wait for RTCK
        self.three_phase = three_phase  #: 3-phase clocking on (0x8C): 1.5 periods a clock
        self.stalled = False  #: the engine waits (answer buffer full, or RTCK never comes)
        #: the wait-on-I/O command the engine is stopped at (0x88/0x89), or None
        self.waiting: int | None = None
        self.wait_ns = 0  #: total time the engine spent in wait-on-I/O commands
        self.unknown_commands: list[int] = []
        self._rx = bytearray()  #: bytes waiting for the host (bulk IN)
        self._flushed = 0  #: how many of them a send-immediate released
        self._pending = bytearray()  #: an incomplete command at the end of a bulk OUT

    # ------------------------------------------------------------------ time
    @property
    def ns(self) -> int:
        """Emulated time, nanoseconds since the device was created."""
        return self.chip_pins.ns

    def now(self) -> float:
        return self.ns * 1e-9

    def advance_ns(self, ns: int) -> None:
        self.chip_pins.advance_ns(ns)

    @property
    def tck_hz(self) -> float:
        base = 12e6 if self.div5 else 60e6
        return base / ((1 + self.tck_divisor) * 2)

    def _clocks_ns(self, clocks: int) -> int:
        return round(clocks * (1.5 if self.three_phase else 1.0) * 1e9 / self.tck_hz)

    # ------------------------------------------------------------------ USB: control
    def control_out(self, request: int, value: int, index: int, data: bytes) -> int:
        self.counters.control += 1
        if request == REQ_RESET:
            if value == PURGE_HOST_TO_CHIP:
                self._pending.clear()
            elif value == PURGE_CHIP_TO_HOST:
                self._rx.clear()
                self._flushed = 0
            else:  # reset: both
                self._rx.clear()
                self._flushed = 0
                self._pending.clear()
            self.stalled = False
            if not self._pending:
                self.waiting = None
        elif request == REQ_SET_LATENCY_TIMER:
            self.latency_ms = value & 0xFF
        elif request == REQ_SET_BITMODE:
            self._set_bitmode(value >> 8, value & 0xFF)
        # baud rate, data format, flow control, modem lines, event/error characters: no
        # effect on the MPSSE engine
        return len(data)

    def control_in(self, request: int, value: int, index: int, length: int) -> bytes:
        self.counters.control += 1
        if request == REQ_POLL_MODEM_STATUS:
            return MODEM_STATUS[:length]
        if request == REQ_GET_LATENCY_TIMER:
            return bytes((self.latency_ms,))[:length]
        if request == REQ_READ_PINS:
            return bytes((self.chip_pins.read_low(),))[:length]
        if request == REQ_READ_EEPROM:
            return b"\xff\xff"[:length]  # a blank EEPROM
        return bytes(length)

    def _set_bitmode(self, mode: int, mask: int) -> None:
        self.bitmode = mode
        # a change of mode stops the engine: a command it was waiting at is dropped
        self._pending.clear()
        self.waiting = None
        self.stalled = False
        if mode == BITMODE_RESET:
            # back to the mode the EEPROM selects, UART on a blank one: TXD, RTS# and DTR#
            # (ADBUS0/2/4, which carry TCK, /RD and /PS here) are the UART's outputs, driven
            # high (idle, deasserted: nothing here asserts them); every other line an input,
            # pulled up.  So the chip sees /RD and /PS high, as when the lines were idle
            self.chip_pins.set_low(0xFF, UART_OUTPUTS)
            self.chip_pins.set_high(0xFF, 0x00)
        elif mode != BITMODE_MPSSE:
            # another bit-bang mode (not used here): every line released, pulled up
            self.chip_pins.set_low(0xFF, 0x00)
            self.chip_pins.set_high(0xFF, 0x00)
        else:
            # entering MPSSE: the mask's lines become outputs at once, driving the low-byte
            # latch, which starts at 0; the high byte stays input until a 0x82
            self.chip_pins.set_low(0x00, mask)
            self.chip_pins.set_high(0x00, 0x00)

    # ------------------------------------------------------------------ USB: bulk
    def bulk_out(self, data: bytes) -> int:
        """One bulk OUT transfer; :class:`BufferFull` when the command buffer cannot take all
        of it (the engine waits for answers the host has not read)."""
        self.counters.bulk_out += 1
        self.counters.bytes_out += len(data)
        self.advance_ns(self.usb_ns)
        if self.bitmode != BITMODE_MPSSE:
            return len(data)
        taken = 0
        while taken < len(data):
            room = pins.FIFO_BYTES - len(self._pending)
            if room <= 0:
                raise BufferFull(f"FT232H command buffer full ({pins.FIFO_BYTES} bytes) with "
                                 f"{len(self._rx)} answer bytes unread: took {taken} of "
                                 f"{len(data)} bytes")
            self._pending += data[taken:taken + room]
            taken += min(room, len(data) - taken)
            self._run_mpsse()
        return len(data)

    def bulk_in(self, size: int) -> bytes:
        """One bulk IN packet of at most ``size`` bytes (modem-status bytes included)."""
        self.counters.bulk_in += 1
        if self.waiting is not None:
            # the request is pending while the engine waits on GPIOL1: it goes on when the
            # pin comes right, if that is before this request's latency timer expires
            expiry = self.ns + max(1, self.latency_ms) * 1_000_000
            self._run_mpsse(until_ns=expiry)
            if self.waiting is not None or (self._rx and not self._flushed):
                self.advance_ns(expiry - self.ns)  # the timer sends what there is
                self._flushed = len(self._rx)
                if not self._rx:
                    return MODEM_STATUS
        if self._rx and not self._flushed:
            # no send-immediate: the chip holds the bytes until its latency timer expires
            self.advance_ns(self.latency_ms * 1_000_000)
            self._flushed = len(self._rx)
        elif not self._rx:
            self.advance_ns(max(1, self.latency_ms) * 1_000_000)
            return MODEM_STATUS
        else:
            self.advance_ns(self.usb_ns)
        n = min(size, PACKET_SIZE) - len(MODEM_STATUS)
        n = min(n, self._flushed, len(self._rx))
        payload = bytes(self._rx[:n])
        del self._rx[:n]
        self._flushed -= n
        self.counters.bytes_in += n
        if self._pending and not self.adaptive:
            self._run_mpsse()  # room in the answer buffer again: a stalled engine goes on
        return MODEM_STATUS + payload

    # ------------------------------------------------------------------ MPSSE engine
    def _run_mpsse(self, until_ns: int | None = None) -> None:
        """Run the pending commands.  A wait-on-I/O whose condition comes by ``until_ns`` (None:
        now; a bulk IN passes its latency timer's expiry) moves the emulated time to it, else
        the engine stops there (:attr:`waiting`)."""
        buf = self._pending
        i = 0
        self.stalled = False
        self.waiting = None
        while i < len(buf):
            op = buf[i]
            if op in (pins.WAIT_HIGH, pins.WAIT_LOW):
                at = self.chip_pins.gpiol1_at(op == pins.WAIT_HIGH)
                if at is None or at > (self.ns if until_ns is None else until_ns):
                    self.waiting = op
                    self.stalled = True
                    break
                start = self.ns
                self.advance_ns(at - self.ns)
                self.advance_ns(self.command_ns)
                self.wait_ns += self.ns - start
                i += 1
                continue
            need = (3 if op in (pins.SET_LOW, pins.SET_HIGH, pins.SET_DIVISOR, pins.CLK_BYTES)
                    else 2 if op == pins.CLK_BITS else 1)
            if i + need > len(buf):
                break  # the rest of this command comes with the next bulk OUT
            if op in (pins.GET_LOW, pins.GET_HIGH) and len(self._rx) >= pins.FIFO_BYTES:
                # the answer buffer is full: wait for the host to read (full packets go out
                # without waiting for the latency timer)
                self._flushed = len(self._rx)
                self.stalled = True
                break
            if op in (pins.CLK_BITS, pins.CLK_BYTES) and self.adaptive:
                self.stalled = True  # idle clocks wait for RTCK (GPIOL3), which never comes
                break
            arg = buf[i + 1:i + need]
            i += need
            self.advance_ns(self.command_ns)
            if op == pins.SET_LOW:
                self.chip_pins.set_low(arg[0], arg[1])
            elif op == pins.SET_HIGH:
                self.chip_pins.set_high(arg[0], arg[1])
            elif op == pins.GET_LOW or op == pins.GET_HIGH:
                self._rx.append(self.chip_pins.read_low() if op == pins.GET_LOW else self.chip_pins.read_high())
                self.counters.most_unread = max(self.counters.most_unread, len(self._rx))
            elif op == pins.SEND_IMMEDIATE:
                self._flushed = len(self._rx)
            elif op == pins.CLK_BITS:
                self.advance_ns(self._clocks_ns(arg[0] + 1))
            elif op == pins.CLK_BYTES:
                self.advance_ns(self._clocks_ns(((arg[0] | arg[1] << 8) + 1) * 8))
            elif op == pins.SET_DIVISOR:
                self.tck_divisor = arg[0] | arg[1] << 8
            elif op == pins.DISABLE_DIV5:
                self.div5 = False
            elif op == pins.ENABLE_DIV5:
                self.div5 = True
            elif op == pins.ENABLE_CLK_3PHASE:
                self.three_phase = True
            elif op == pins.DISABLE_CLK_3PHASE:
                self.three_phase = False
            elif op == pins.ENABLE_CLK_ADAPTIVE:
                self.adaptive = True
            elif op == pins.DISABLE_CLK_ADAPTIVE:
                self.adaptive = False
            elif op in (pins.LOOPBACK_ON, pins.LOOPBACK_OFF):
                pass  # loopback on / off: nothing on our pins
            else:
                # the real engine answers an unknown opcode with 0xFA and the opcode
                self.unknown_commands.append(op)
                self._rx += bytes((0xFA, op))
        del buf[:i]

