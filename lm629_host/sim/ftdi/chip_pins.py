"""The emulated FT232H's pins and the LM628/LM629 on them, in emulated time.

ADBUS and ACBUS are wired to a :class:`~lm629_host.sim.model.ChipModel` (or a
:class:`~lm629_host.sim.model.ChipBus` of them) with the pin map of
:mod:`lm629_host.wiring.ft232h`; every edge that matters is turned into one model call, strobe
by strobe, as the chip's pins would see it: /WR rising with /CS low latches D0-D7 into
``write_command`` or ``write_data`` (by /PS); /RD falling with /CS low makes the chip drive the
bus with ``read_status`` or ``read_data``; /RST rising is ``reset_pulse``.  Each edge is also
checked against the chip's timing minimums (spec "Bus cycles"), every miss recorded in
``timing_violations``, and so is bus contention (both sides driving D0-D7).

This is the chip's side of the adapter; what drives the pins (the MPSSE engine behind USB) is
:class:`~lm629_host.sim.ftdi.device.EmulatedFT232H`, which charges what its commands and
transfers cost by :meth:`ChipPins.advance_ns`.  The time is kept here, in integer
nanoseconds, because the chip runs on it: ``model.advance_to`` before every edge.

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

A test hook, :meth:`ChipPins.stretch_busy`, makes the chip hold busy far longer than its
documented 100 us after the next N transfers, to prove that the transport detects it.
"""

from __future__ import annotations

from lm629_host.wiring import ft232h as pins
from lm629_host.sim.wiring import Miswiring
from lm629_host.sim.model import ChipBus, ChipModel, chips_of
from lm629_host.sim.vcd import BusVcd, cs_name

#: timing minimums of the chip's host interface (spec "Bus cycles", 6 MHz table), ns
WR_PULSE_NS = 100
WR_SETUP_NS = 50
WR_HOLD_NS = 120
RD_ACCESS_NS = 180
RECOVERY_NS = 120
PS_SETUP_NS = 30


class ChipPins:
    """ADBUS and ACBUS of one FT232H, the chip(s) wired to them, and the emulated time."""

    def __init__(self, model: ChipModel | ChipBus, *, busy_pin: bool = False,
                 live_status: bool | None = None, wiring: Miswiring | None = None) -> None:
        self.model = model
        #: the /CS lines wired (a heartbeat on ADBUS7 leaves the first alone)
        self.chip_select_lines: tuple[int, ...] = pins.CHIP_SELECTS
        #: ``wiring=``: the wires between ACBUS0-7 and the chip's D0-D7 (None: correct); a
        #: byte is bent where the chip latches it and where it drives the bus
        self.wiring = wiring
        self.ns = 0  #: emulated time, nanoseconds since the device was created
        self._epoch_tick = model.tick  #: the model's tick at time zero
        #: D0 wired to GPIOL1 (ADBUS5) and HI to nothing (``busy_pin=gpiol1``)
        self.busy_pin = busy_pin
        #: a status read held low shows the status as it is now, not as at /RD falling
        self.live_status = busy_pin if live_status is None else live_status
        #: (ns, level of the ADBUS control lines) at every change, from power-on
        self.ctrl_log: list[tuple[int, int]] = [(0, 0xFF)]
        self.timing_violations: list[str] = []
        # pin state: values and directions of both bytes; inputs float high (pull-ups)
        self._low_val, self.low_dir = 0xFF, 0x00
        self._high_val, self.high_dir = 0xFF, 0x00
        self.ctrl = 0xFF  #: the level on the ADBUS control lines (as the chip sees them)
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
    def advance_ns(self, ns: int) -> None:
        if ns > 0:
            self.ns += ns
            self._run_model()

    def _run_model(self) -> None:
        m = self.model
        m.advance_to(self._epoch_tick + self.ns * m.clock_hz // 1_000_000_000)

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
        out = self.high_dir
        chip = self._drive if self._drive is not None else 0xFF
        data = (self._high_val & out) | (chip & ~out & 0xFF)
        ctrl = self.ctrl
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

    # ------------------------------------------------------------------ GPIOL1, for wait on I/O
    def _gpiol1(self) -> bool:
        """The level on ADBUS5 as the engine's wait-on-I/O sees it."""
        return bool(self.read_low() & pins.GPIOL1)

    def gpiol1_at(self, want: bool) -> int | None:
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

    # ------------------------------------------------------------------ pins
    def read_low(self) -> int:
        """ADBUS as the engine reads it (GET_LOW, the read-pins request)."""
        value = (self._low_val & self.low_dir) | (~self.low_dir & 0xFF & ~pins.GPIOL1)
        if self.busy_pin:  # ADBUS5 wired to D0
            if self.read_high(check=False) & 0x01:
                value |= pins.GPIOL1
        elif chips_of(self.model)[0].hi:  # HI is chip 0's line (chip 1 has none)
            value |= pins.HI
        return value & 0xFF

    def _selected_chip(self) -> ChipModel | None:
        """The chip whose /CS is low (one only), or None."""
        low = [k for k, cs in enumerate(self.chip_select_lines) if not self.ctrl & cs]
        chips = chips_of(self.model)
        if len(low) != 1 or low[0] >= len(chips) or (len(chips) == 1 and low[0] != 0):
            return None
        return chips[low[0]]

    def _status_held(self) -> bool:
        """A status read is going on: /CS of one chip, /PS and /RD low."""
        return (self._drive is not None and not self.ctrl & (pins.PS | pins.RD)
                and self._selected_chip() is not None)

    def read_high(self, check: bool = True) -> int:
        """ACBUS (D0-D7) as the engine reads it (GET_HIGH); ``check``: the read is a sample
        of the bus, held to the chip's access time."""
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
            if self.high_dir:
                self._timing("D0-D7 read while the adapter drives them (contention)")
            return self._drive
        return (self._high_val & self.high_dir) | (~self.high_dir & 0xFF)

    def _timing(self, what: str) -> None:
        self.timing_violations.append(f"at {self.ns / 1000:.3f} us: {what}")

    def set_high(self, value: int, direction: int) -> None:
        """ACBUS (D0-D7) set to ``value`` on the ``direction`` lines (SET_HIGH)."""
        before = (self._high_val & self.high_dir, self.high_dir)
        self._high_val, self.high_dir = value & 0xFF, direction & 0xFF
        if (self._high_val & self.high_dir, self.high_dir) != before:
            self._data_changed_ns = self.ns
            if self.high_dir and self._drive is not None:
                self._timing("adapter drives D0-D7 while the chip drives them (contention)")
            wr_rose = self._edge_ns.get("WR_rise")
            if wr_rose is not None and self.ns - wr_rose < WR_HOLD_NS and before[1]:
                self._timing(f"data changed {self.ns - wr_rose} ns after /WR rose "
                             f"(hold {WR_HOLD_NS} ns)")
            if self.vcd is not None:
                self._log_pins()

    def set_low(self, value: int, direction: int) -> None:
        """ADBUS (the control lines) set to ``value`` on the ``direction`` lines (SET_LOW):
        the chip sees each edge."""
        try:
            self._set_low_lines(value, direction)
        finally:
            if self.vcd is not None:
                self._log_pins()

    def _set_low_lines(self, value: int, direction: int) -> None:
        self._low_val, self.low_dir = value & 0xFF, direction & 0xFF
        level = (self._low_val & self.low_dir) | (~self.low_dir & 0xFF)  # inputs pulled up
        old, self.ctrl = self.ctrl, level
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
                if self.high_dir:
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
            if self.high_dir != 0xFF:
                self._timing("/WR strobed with D0-D7 not driven by the adapter")
            byte = self._high_val
            if self.wiring is not None:
                byte = self.wiring.to_chip(byte)
            m = self.model
            if level & pins.PS:
                self._strobe(m.write_data, byte)
            else:
                self._strobe(m.write_command, byte)
