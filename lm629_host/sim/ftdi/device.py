"""An emulated FT232H in MPSSE mode with its pins wired to the chip model, in emulated time.

The device side of the USB link: what the FTDI chip does with the vendor control requests
pyftdi sends, with the bytes of a bulk OUT transfer (the MPSSE command stream), and what it
answers on bulk IN (two modem-status bytes, then the bytes the read commands produced).  The
pyusb side of it (descriptors, endpoints) is :mod:`.backend`.

Pins.  ADBUS and ACBUS are wired to an LM628/LM629 :class:`~lm629_host.sim.model.ChipModel` with the
pin map of :mod:`lm629_host.wiring.ft232h`; every edge that matters is turned into one model call,
strobe by strobe, as the chip's pins would see it: /WR rising with /CS low latches D0-D7 into
``write_command`` or ``write_data`` (by /PS); /RD falling with /CS low makes the chip drive the
bus with ``read_status`` or ``read_data``; /RST rising is ``reset_pulse``.  The emulator also
checks the chip's timing minimums (spec "Bus cycles") at each edge and records every miss in
``timing_violations``, and records bus contention (both sides driving D0-D7) there too.

Time.  The device owns the emulated time (integer nanoseconds) and runs the model's clock with
it (``model.advance_to``) before every edge.  What things cost (emulation choices, with why):

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

A status read held low.  Whether D0-D7 follow the status while /RD stays low is not in the
data sheet (it gives the access time from /RD falling, no hold-low maximum; AN-706 3.6 calls
the status a hardware register); the emulation choice is that they do (the status
byte is the register's current value whenever it is sampled), which is what a held read on
a busy pin relies on and what a bench must measure (docs/ftdi.md).  It is on with the busy
pin wired (``live_status``, default ``busy_pin``); in the default wiring the byte stays the
one latched at /RD falling, the behaviour the transport's busy calibration and every figure
of the timed-wait streams were measured with (a status read there lasts 0.8 us, so the two
choices differ by at most one calibration poll).  Data reads stay latched at /RD falling, as
the chip's I/O buffer is.

A test hook, :meth:`EmulatedFT232H.stretch_busy`, makes the chip hold busy far longer than its
documented 100 us after the next N transfers, to prove that the transport detects it.
"""

from __future__ import annotations

from dataclasses import dataclass

from lm629_host.wiring import ft232h as pins
from lm629_host.sim.wiring import Miswiring
from lm629_host.sim.model import ChipBus, ChipModel, chips_of
from lm629_host.sim.vcd import BusVcd, cs_name

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

#: timing minimums of the chip's host interface (spec "Bus cycles", 6 MHz table), ns
WR_PULSE_NS = 100
WR_SETUP_NS = 50
WR_HOLD_NS = 120
RD_ACCESS_NS = 180
RECOVERY_NS = 120
PS_SETUP_NS = 30


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
    """One FT232H, its MPSSE engine and the chip on its pins."""

    vendor_id = 0x0403
    product_id = 0x6014
    bcd_device = 0x0900  #: FT232H (pyftdi recognises the part by this)

    def __init__(self, model: ChipModel | ChipBus, *, serial: str = "LM629EMU", usb_ns: int = 125_000,
                 command_ns: int = 500, bus: int = 1, address: int = 7,
                 adaptive: bool = False, three_phase: bool = False,
                 busy_pin: bool = False, live_status: bool | None = None,
                 wiring: Miswiring | None = None) -> None:
        self.model = model
        #: the /CS lines wired (a heartbeat on ADBUS7 leaves the first alone)
        self.chip_select_lines: tuple[int, ...] = pins.CHIP_SELECTS
        #: ``wiring=``: the wires between ACBUS0-7 and the chip's D0-D7 (None: correct); a
        #: byte is bent where the chip latches it and where it drives the bus
        self.wiring = wiring
        self.serial = serial
        self.manufacturer = "FTDI"
        self.product = "Single RS232-HS"
        self.bus = bus
        self.address = address
        self.usb_ns = usb_ns
        self.command_ns = command_ns
        self.ns = 0  #: emulated time, nanoseconds since the device was created
        self._sync_model_epoch()
        self.counters = Counters()
        self.latency_ms = 16
        self.bitmode = BITMODE_RESET
        self.tck_divisor = 0
        self.div5 = True
        self.adaptive = adaptive  #: adaptive clocking on (0x96): idle clocks wait for RTCK
        self.three_phase = three_phase  #: 3-phase clocking on (0x8C): 1.5 periods a clock
        self.stalled = False  #: the engine waits (answer buffer full, or RTCK never comes)
        #: D0 wired to GPIOL1 (ADBUS5) and HI to nothing (``busy_pin=gpiol1``)
        self.busy_pin = busy_pin
        #: a status read held low shows the status as it is now, not as at /RD falling
        self.live_status = busy_pin if live_status is None else live_status
        #: the wait-on-I/O command the engine is stopped at (0x88/0x89), or None
        self.waiting: int | None = None
        self.wait_ns = 0  #: total time the engine spent in wait-on-I/O commands
        #: (ns, level of the ADBUS control lines) at every change, from power-on
        self.ctrl_log: list[tuple[int, int]] = [(0, 0xFF)]
        self.timing_violations: list[str] = []
        self.unknown_commands: list[int] = []
        self._rx = bytearray()  #: bytes waiting for the host (bulk IN)
        self._flushed = 0  #: how many of them a send-immediate released
        self._pending = bytearray()  #: an incomplete command at the end of a bulk OUT
        # pin state: values and directions of both bytes; inputs float high (pull-ups)
        self._low_val, self._low_dir = 0xFF, 0x00
        self._high_val, self._high_dir = 0xFF, 0x00
        self._ctrl = 0xFF  #: the level on the ADBUS control lines (as the chip sees them)
        self._drive: int | None = None  #: the byte the chip drives on D0-D7 while /RD is low
        self._edge_ns: dict[str, int] = {}  #: time of the last edge of each line
        self._data_changed_ns = 0
        self._stretch_left = 0
        self._stretch_skip = 0
        self._stretch_clocks = 0
        self.busy_stretched = 0  #: transfers whose busy the hook stretched
        #: the VCD the pins go to (:meth:`write_vcd`); None: no pin is logged
        self.vcd: BusVcd | None = None

    # ------------------------------------------------------------------ time
    def _sync_model_epoch(self) -> None:
        """The device's time zero is the model's current tick."""
        self._epoch_tick = self.model.tick

    def now(self) -> float:
        return self.ns * 1e-9

    def advance_ns(self, ns: int) -> None:
        if ns > 0:
            self.ns += ns
            self._run_model()

    def _run_model(self) -> None:
        m = self.model
        m.advance_to(self._epoch_tick + self.ns * m.clock_hz // 1_000_000_000)

    @property
    def tck_hz(self) -> float:
        base = 12e6 if self.div5 else 60e6
        return base / ((1 + self.tck_divisor) * 2)

    def _clocks_ns(self, clocks: int) -> int:
        return round(clocks * (1.5 if self.three_phase else 1.0) * 1e9 / self.tck_hz)

    # ------------------------------------------------------------------ the pins as a VCD
    def write_vcd(self, path: str, timescale_ns: int = 10) -> None:
        """From now on, every level the chip's bus lines take goes to the VCD ``path`` on the
        emulated clock: D0-D7 (ACBUS as driven, the chip's byte while it answers a read, else
        the pull-ups), /CS of each chip, /RD, /WR, /PS, /RST and HI (ADBUS)."""
        chips = len(chips_of(self.model))
        self.vcd = BusVcd(path, chips=chips, his=1, timescale_ns=timescale_ns,
                          comment="lm629-host: the emulated FT232H's pins")
        self._log_pins()

    def _log_pins(self) -> None:
        vcd = self.vcd
        if vcd is None:
            return
        out = self._high_dir
        chip = self._drive if self._drive is not None else 0xFF
        data = (self._high_val & out) | (chip & ~out & 0xFF)
        ctrl = self._ctrl
        lines = {"rd": int(bool(ctrl & pins.RD)), "wr": int(bool(ctrl & pins.WR)),
                 "ps": int(bool(ctrl & pins.PS)), "rst": int(bool(ctrl & pins.RST)),
                 "hi": int(chips_of(self.model)[0].hi)}
        for k in range(len(chips_of(self.model))):
            lines[cs_name(k)] = int(bool(ctrl & pins.CHIP_SELECTS[k]))
        vcd.data(self.ns, data)
        vcd.set(self.ns, lines)

    def close_vcd(self) -> None:
        if self.vcd is not None:
            self._log_pins()
            self.vcd.close(self.ns)

    # ------------------------------------------------------------------ test hook
    def stretch_busy(self, transfers: int, seconds: float, skip: int = 0) -> None:
        """Hold busy for ``seconds`` (instead of the model's ``busy_s``) after each of the
        ``transfers`` transfers the chip accepts after the next ``skip`` ones: a chip out of
        its documented 100 us."""
        self._stretch_skip = skip
        self._stretch_left = transfers
        self._stretch_clocks = max(1, round(seconds * self.model.clock_hz))

    def _strobe(self, fn, *args):
        m = self.model
        if not self._stretch_left:
            return fn(*args)
        skipping = self._stretch_skip > 0
        saved, was_busy = m.busy_clocks, m.busy
        if not skipping:
            m.busy_clocks = self._stretch_clocks
        try:
            return fn(*args)
        finally:
            m.busy_clocks = saved
            if not was_busy and m.busy:  # the chip accepted a transfer
                if skipping:
                    self._stretch_skip -= 1
                else:
                    self._stretch_left -= 1
                    self.busy_stretched += 1

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
            return bytes((self._read_low(),))[:length]
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
            self._set_low(0xFF, UART_OUTPUTS)
            self._set_high(0xFF, 0x00)
        elif mode != BITMODE_MPSSE:
            # another bit-bang mode (not used here): every line released, pulled up
            self._set_low(0xFF, 0x00)
            self._set_high(0xFF, 0x00)
        else:
            # entering MPSSE: the mask's lines become outputs at once, driving the low-byte
            # latch, which starts at 0; the high byte stays input until a 0x82
            self._set_low(0x00, mask)
            self._set_high(0x00, 0x00)

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
    def _gpiol1(self) -> bool:
        """The level on ADBUS5 as the engine's wait-on-I/O sees it."""
        return bool(self._read_low() & pins.GPIOL1)

    def _gpiol1_at(self, want: bool) -> int | None:
        """When (ns) GPIOL1 will read ``want`` with nothing else changing, or None: never.
        Only D0 of a held status read changes by itself (busy clears, ``busy_deadline``);
        nothing sets busy without a strobe, and HI and undriven lines do not change here."""
        if self._gpiol1() == want:
            return self.ns
        if not self.busy_pin or want or not self._status_held():
            return None
        chip = self._selected_chip()
        deadline = None if chip is None else chip.busy_deadline()
        if deadline is None:
            return None
        clock = self.model.clock_hz
        return max(self.ns, -(-(deadline - self._epoch_tick) * 1_000_000_000 // clock))

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
                at = self._gpiol1_at(op == pins.WAIT_HIGH)
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
                self._set_low(arg[0], arg[1])
            elif op == pins.SET_HIGH:
                self._set_high(arg[0], arg[1])
            elif op == pins.GET_LOW or op == pins.GET_HIGH:
                self._rx.append(self._read_low() if op == pins.GET_LOW else self._read_high())
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

    # ------------------------------------------------------------------ pins
    def _read_low(self) -> int:
        value = (self._low_val & self._low_dir) | (~self._low_dir & 0xFF & ~pins.GPIOL1)
        if self.busy_pin:  # ADBUS5 wired to D0
            if self._read_high(check=False) & 0x01:
                value |= pins.GPIOL1
        elif chips_of(self.model)[0].hi:  # HI is chip 0's line (chip 1 has none)
            value |= pins.HI
        return value & 0xFF

    def _selected_chip(self) -> ChipModel | None:
        """The chip whose /CS is low (one only), or None."""
        low = [k for k, cs in enumerate(self.chip_select_lines) if not self._ctrl & cs]
        chips = chips_of(self.model)
        if len(low) != 1 or low[0] >= len(chips) or (len(chips) == 1 and low[0] != 0):
            return None
        return chips[low[0]]

    def _status_held(self) -> bool:
        """A status read is going on: /CS of one chip, /PS and /RD low."""
        return (self._drive is not None and not self._ctrl & (pins.PS | pins.RD)
                and self._selected_chip() is not None)

    def _read_high(self, check: bool = True) -> int:
        if self._drive is not None:
            if self.live_status and self._status_held():
                # [emulation choice] the status register drives D0-D7 with its current
                # value for as long as /RD is low (see the module docstring)
                self._run_model()
                self._drive = self.model.read_status()
                if self.wiring is not None:
                    self._drive = self.wiring.to_host(self._drive)
                if self.vcd is not None:
                    self._log_pins()
            if not check:
                return self._drive
            rd_fell = self._edge_ns.get("RD_fall", 0)
            if self.ns - rd_fell < RD_ACCESS_NS:
                self._timing(f"data sampled {self.ns - rd_fell} ns after /RD fell "
                             f"(access time {RD_ACCESS_NS} ns)")
            if self._high_dir:
                self._timing("D0-D7 read while the adapter drives them (contention)")
            return self._drive
        return (self._high_val & self._high_dir) | (~self._high_dir & 0xFF)

    def _timing(self, what: str) -> None:
        self.timing_violations.append(f"at {self.ns / 1000:.3f} us: {what}")

    def _set_high(self, value: int, direction: int) -> None:
        before = (self._high_val & self._high_dir, self._high_dir)
        self._high_val, self._high_dir = value & 0xFF, direction & 0xFF
        if (self._high_val & self._high_dir, self._high_dir) != before:
            self._data_changed_ns = self.ns
            if self._high_dir and self._drive is not None:
                self._timing("adapter drives D0-D7 while the chip drives them (contention)")
            wr_rose = self._edge_ns.get("WR_rise")
            if wr_rose is not None and self.ns - wr_rose < WR_HOLD_NS and before[1]:
                self._timing(f"data changed {self.ns - wr_rose} ns after /WR rose "
                             f"(hold {WR_HOLD_NS} ns)")
            if self.vcd is not None:
                self._log_pins()

    def _set_low(self, value: int, direction: int) -> None:
        try:
            self._set_low_lines(value, direction)
        finally:
            if self.vcd is not None:
                self._log_pins()

    def _set_low_lines(self, value: int, direction: int) -> None:
        self._low_val, self._low_dir = value & 0xFF, direction & 0xFF
        level = (self._low_val & self._low_dir) | (~self._low_dir & 0xFF)  # inputs pulled up
        old, self._ctrl = self._ctrl, level
        changed = old ^ level
        if changed:
            self.ctrl_log.append((self.ns, level))
        if not changed & (pins.CS_ALL | pins.RD | pins.WR | pins.PS | pins.RST):
            return
        self._run_model()
        now = self.ns
        for name, bit in (("CS", pins.CS), ("RD", pins.RD), ("WR", pins.WR), ("PS", pins.PS),
                          ("RST", pins.RST), ("CS1", pins.CS1)):
            if changed & bit:
                self._edge_ns[name + ("_rise" if level & bit else "_fall")] = now
        low = [k for k, cs in enumerate(self.chip_select_lines) if not level & cs]
        selected = len(low) == 1
        if len(low) > 1 and changed & (pins.RD | pins.WR) and not level & (pins.RD | pins.WR):
            self._timing("two chips selected during a strobe")
        if selected and isinstance(self.model, ChipBus):
            if low[0] >= len(self.model.chips):
                selected = False  # a /CS line with no chip on it
            else:
                self.model.select(low[0])
        elif selected and low[0] != 0:
            selected = False  # one chip, wired to /CS of chip 0
        # /RST
        if changed & pins.RST:
            if level & pins.RST:
                low_ns = now - self._edge_ns.get("RST_fall", 0)
                need = 8 * 1e9 / self.model.clock_hz
                if low_ns < need:
                    self._timing(f"/RST low for {low_ns} ns (8 chip clocks = {need:.0f} ns)")
                self.model.reset_pulse()
            return
        # strobes: check recovery and /PS setup at each falling edge
        for strobe in (pins.RD, pins.WR):
            if changed & strobe and not level & strobe and selected:
                last = max(self._edge_ns.get("RD_rise", -10**9), self._edge_ns.get("WR_rise", -10**9))
                if now - last < RECOVERY_NS:
                    self._timing(f"strobe {now - last} ns after the previous one "
                                 f"(recovery {RECOVERY_NS} ns)")
                ps_edge = max(self._edge_ns.get("PS_rise", -10**9),
                              self._edge_ns.get("PS_fall", -10**9))
                if now - ps_edge < PS_SETUP_NS:
                    self._timing(f"/PS changed {now - ps_edge} ns before a strobe "
                                 f"(setup {PS_SETUP_NS} ns)")
        if changed & pins.RD:
            if not level & pins.RD and selected:
                # /RD fell: the chip puts the status byte or a data byte on D0-D7
                m = self.model
                self._drive = (m.read_status() if not level & pins.PS
                               else self._strobe(m.read_data))
                if self.wiring is not None:
                    self._drive = self.wiring.to_host(self._drive)
                if self._high_dir:
                    self._timing("/RD low while the adapter drives D0-D7 (contention)")
            elif level & pins.RD:
                self._drive = None
        if changed & pins.WR and level & pins.WR and not old & pins.WR and selected:
            # /WR rose: the chip latches D0-D7
            width = now - self._edge_ns.get("WR_fall", 0)
            if width < WR_PULSE_NS:
                self._timing(f"/WR pulse {width} ns (minimum {WR_PULSE_NS} ns)")
            if now - self._data_changed_ns < WR_SETUP_NS:
                self._timing(f"data set up {now - self._data_changed_ns} ns before /WR rose "
                             f"(setup {WR_SETUP_NS} ns)")
            if self._high_dir != 0xFF:
                self._timing("/WR strobed with D0-D7 not driven by the adapter")
            byte = self._high_val
            if self.wiring is not None:
                byte = self.wiring.to_chip(byte)
            m = self.model
            if level & pins.PS:
                self._strobe(m.write_data, byte)
            else:
                self._strobe(m.write_command, byte)
