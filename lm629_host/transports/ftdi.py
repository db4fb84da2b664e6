"""``ftdi://``: an FT232H in MPSSE mode, through pyftdi on pyusb, wired as in :mod:`..ftdi_pins`.

URL: pyftdi's own, ``ftdi://ftdi:232h[:SERIAL]/1``, plus options after ``?``:
``latency`` (USB latency timer, ms, default 1), ``busy_us`` (the wait after each transfer:
``auto``, the default, measures the chip's busy time before the first program; a number fixes
it, 100 being the documented worst case), ``frequency`` (MPSSE clock TCK in Hz, default 6 MHz),
``busy_pin`` (``gpiol1``: D0 is also wired to ADBUS5, see "Waiting on the busy pin" below).

How a bus program becomes USB traffic
=====================================

Each bus program is compiled into one MPSSE command stream: "set low byte" (0x80) drives the
control lines /CS, /RD, /WR, /PS, /RST; "set high byte" (0x82) drives D0-D7 or releases them;
"read high byte" (0x83) samples D0-D7; idle clocks (0x8E n: n+1 TCK periods, 0x8F n: 8(n+1)
periods) are the delays; a final "read low byte" (0x81) samples HI; "send immediate" (0x87)
ends the stream so that the FT232H returns every byte the stream read in one bulk IN, without
waiting for its latency timer.  So a typed command is one USB write and one USB read.

Timing minimums (spec "Bus cycles") are met by idle clocks alone, never by assuming how fast
the MPSSE engine executes a command: at the default TCK of 6 MHz one idle bit is 167 ns, so
/WR is low for one bit (>= 100 ns pulse, >= 50 ns data setup), data and /PS are held for one
bit after each strobe (>= 120 ns hold and recovery, >= 30 ns /PS hold), /PS and /CS settle one
bit before a strobe (>= 30 ns setup), and a read samples D0-D7 two bits (333 ns) after /RD
falls (<= 180 ns access).  /RST is held low at least 10 us: 8 clocks of the slowest (1 MHz)
chip, with margin (10.7 us at 6 MHz, rounded up to whole idle bytes).

The busy discipline, without looking at the answer in between
-------------------------------------------------------------

The busy bit can only be seen by a status read, and an MPSSE stream cannot branch on what it
reads.  So the stream does what a polling host would do, but open-loop, and checks afterwards:

1. Before every transfer (command byte, data word written or read) the stream reads the status
   byte, then makes the transfer.  After every transfer it waits before the next status read:
   by default as long as this chip holds busy, measured before the first program
   (:meth:`FtdiTransport.calibrate_busy`: a read command, then status reads, at several
   spacings, which also tell what an MPSSE command costs on this adapter; the datasheet says
   15-25 us typically, 100 us at worst), the wait shortened by the MPSSE commands the stream
   runs before its check (counted at the least cost the calibration allows, at most 0.5 us,
   ``COMMAND_S``); with
   ``busy_us=N`` a fixed N us of idle clocks (100: the documented worst case, the wait before
   this measure existed).  So every one of these status reads normally shows busy clear, and
   every transfer lands.  Between programs the same wait is kept: a stream starts with
   whatever is left of it since the previous stream ended.  After a RESET command byte the
   wait is 1.5 ms (busy stays set until the reset is done).  Only speed rests on the measure:
   a check that sees busy is the repeat below, which also doubles the wait (at most 100 us;
   :meth:`FtdiTransport._learn_busy`, brought back down by :meth:`FtdiTransport._relax`), so
   a chip slower than measured costs one repeat, not a lost command.
2. When the answer comes back, every status byte read before a transfer is checked.  If one
   shows busy, the chip ignored that transfer (a write while busy is ignored; a read while
   busy returns stale bytes) and nothing else tells.  The transport then polls the status in
   short exchanges until busy clears (at most ``program.busy_timeout_s``, then
   :class:`~lm629_host.errors.BusyTimeout`), and repeats the whole command from its command
   byte, and everything after it in that stream, in a new stream.  Each repeat is counted in
   ``stats.retries`` and logged as a warning: never silent.

What is safe to repeat, and why the stream is cut before some commands:

* a command with data written (LFIL, LTRJ, MSKI, RSTI, LPEI, LPES, SBPA, SBPR): repeated from
  its command byte.  Its partial or shifted words may have been taken; a new command byte
  aborts an unfinished command, and the repeat loads every word again.  Loads only fill input
  buffers and registers, so loading them again is harmless;
* a read command (RDxx): repeated from its command byte.  The words it read may be stale or
  shifted; reading again has no side effect; the words reported are the repeat's;
* a command that acts (STT, DFH, SIP, UDF, RESET): never repeated once taken.  It has no data
  words, so its only check is the status read before its command byte, and a busy there means
  the byte was ignored: repeating it is then what makes it happen once.  But an action must
  not act on loads that a later check will find corrupted (STT after a damaged LTRJ would start
  a wrong move; the repeated LTRJ would come too late).  So the stream is cut before an action
  that follows a transfer in the same program: e.g. ``load_trajectory(..., start=True)`` is two
  exchanges, load and check first, then STT.  Every stream therefore holds at most one action,
  first, and only repeatable commands after it: repeating "from the first busy to the end of
  the stream" never doubles an action.

Waiting on the busy pin (``busy_pin=gpiol1``, an option because it needs a wire and an
assumption): MPSSE "wait on I/O" (0x88/0x89) watches GPIOL1 (ADBUS5).  With D0 wired there
too, each busy check is a status read held low while the engine waits for busy to rise (right
after a transfer on the same chip) and to clear (:meth:`.mpsse.StreamCompiler.held_check`).
Every transfer then lands after the chip took the one before, whatever its busy time, so no
cut before actions is needed and LTRJ + STT is one exchange.  It rests on what the data sheet
does not say: that D0 follows busy while /RD stays low (docs/ftdi.md lists what to measure).
The wait has no timeout: a chip that never clears busy stops the engine; the read gives up
after the program's busy timeout, and :meth:`FtdiTransport._recover` purges the FT232H, leaves
and re-enters MPSSE with the lines idle, and raises BusyTimeout for the operation whose check
never came (nothing from it on reached the chip).  A check that shows busy after the wait
means the pin does not follow D0: a TransportError, never a repeat (an STT may follow in the
stream).  Polling each status read in its own USB exchange costs a round trip per transfer
(the problem this transport exists to avoid).

With the fixed wait of the documented worst case the repeat path is a fault detector: it runs
only on a chip out of its data sheet, a noisy bus, or the emulator's ``stretch_busy`` hook;
with the measured wait also on a chip slower for some command than for the one measured.

Why LTRJ + STT stays two exchanges without the busy pin: a single stream cannot make STT depend on the checks of
the loads before it.  A chip holding busy 300 us after one transfer makes every later transfer
of the stream (STT included) land in busy and be ignored, which a repeat would mend; but one
holding it a little longer than the wait (35 us) drops one word and lets the next words and
STT land: STT would start a move from shifted words, and the repeat would start it twice.

What the FT232H itself asks for
-------------------------------

* Opening must not glitch the bus: see :func:`open_mpsse` (bit-mode mask 0, clock modes off,
  levels and directions in one 0x80).
* Its buffers hold 1 KiB each way (:data:`~lm629_host.wiring.ft232h.FIFO_BYTES`).  A stream is
  written whole before its answer is read; if its answers fill the chip->host buffer while
  more than 1 KiB of it is still unwritten, the MPSSE engine stops and the write times out.
  So a program is cut into streams of at most 1 KiB (``StreamCompiler.compile(max_bytes=)``),
  between operations; a command with many words may span streams, and a busy repeat still
  starts at its command byte.
"""

from __future__ import annotations

import logging
import os
from typing import Any

from lm629_host import data
from lm629_host.wiring import ft232h as pins
from lm629_host.clock import Clock, WallClock
from lm629_host.errors import BusyTimeout, TransportError
from lm629_host.bus.opcodes import BUSY_BIT
from lm629_host.bus.pinout import pin_of
from lm629_host.bus.program import BusCycle, Op, Program, ProgramResult, TraceCallback
from lm629_host.urls import PortURL
from lm629_host.transports.base import Check, PortInfo, Transport
from lm629_host.transports.ftdi_open import (  # noqa: F401 - the transport's open, re-exported
    ADVICE_ACCESS,
    ADVICE_BUSY,
    ADVICE_NO_BACKEND,
    DEFAULT_LATENCY_MS,
    DISABLE_CLK_3PHASE,
    DISABLE_CLK_ADAPTIVE,
    FT232H_PID,
    FTDI_VID,
    OPTIONS,
    SET_HIGH,
    SET_LOW,
    busy_pin_of,
    heartbeat_pin,
    open_mpsse,
    options_of,
    pyftdi_url,
    find_adapters,
    translate_open_error,
    usb_errno,
)
from lm629_host.transports.keepalive import KeepAlive
from lm629_host.transports.mpsse import (DEFAULT_BUSY_US, DEFAULT_TCK_HZ, Stream, StreamCompiler, busy_bounds,
                                        chips_of_units, streams_of)

log = logging.getLogger("lm629_host.ftdi")

_BUSY = BUSY_BIT  # a plain int (opcodes.BUSY_BIT)

#: the most one MPSSE command is taken to cost in the busy-wait estimate: pyftdi's figure for
#: two SET_BITS in a row (``Ftdi.mpsse_bit_delay``, measured on an FT2232H), the emulator's
#: default.  The calibration finds what it costs on the adapter at hand, at most this
#: (pyftdi's virtual FT232H: nothing)
COMMAND_S = 500e-9
#: status reads after each of the calibration's commands (3 bits of idle clocks and 5
#: commands each, back to back: 20 us with commands that take no time, 120 us at 0.5 us)
CALIBRATION_POLLS = 40
#: the idle clocks between the calibration's status reads, one stream each: two paddings or
#: more tell the chip's busy time and what a command costs apart (:func:`.mpsse.busy_bounds`);
#: 0 first, so that a chip that shows no busy is found in one stream
CALIBRATION_PADS = (0.0, 1e-6, 2e-6, 3e-6)
#: ... and one stream more that idles this share of the least busy time those allow before
#: its status reads (short of it: its first read must still see busy)
CALIBRATION_IDLE_SHARE = 0.8
#: the wait is the busy time measured times this.  The measure is already an upper bound (the
#: first status read that saw busy clear, up to one read period late); a chip whose busy time
#: differs between commands (the datasheet gives 15-25 us typical) shows it at a check, which
#: repeats the command and lengthens the wait (:meth:`FtdiTransport._learn_busy`)
CALIBRATION_MARGIN = 1.0
#: what one busy repeat costs, about: a poll exchange and the repeat's exchange, each a USB
#: write and read (at least one 125 us high-speed microframe each way).  A wait raised after a
#: repeat comes back down (halved, never below the calibrated wait) once the extra waiting it
#: has cost since the last repeat adds up to this: a chip that really needs the longer wait
#: then costs one repeat per this much waiting, never more than staying raised would
REPEAT_COST_S = 4 * 125e-6

UDEV_RULE = f"{data.UDEV_RULES_DIR}/{data.UDEV_RULE}"  #: where the installed rule lives


# ---------------------------------------------------------------------------- transport
class FtdiTransport(Transport):
    """Bus programs as MPSSE streams on an opened pyftdi ``Ftdi`` (see the module docstring)."""

    scheme = "ftdi"
    has_reset_line = True
    #: /CS lines of the wiring (ftdi_pins.CHIP_SELECTS): two axes
    chip_selects = len(pins.CHIP_SELECTS)

    def __init__(self, ftdi: Any, url: str | PortURL, *, trace: TraceCallback | None = None,
                 clock: Clock | None = None, busy_s: float | None = DEFAULT_BUSY_US * 1e-6,
                 tck_hz: float = DEFAULT_TCK_HZ, latency_ms: int = DEFAULT_LATENCY_MS,
                 busy_pin: str | None = None, heartbeat: str | None = None,
                 heartbeat_hz: float = 50.0) -> None:
        """``heartbeat``: a line the wiring leaves free (``ftdi_pins.HEARTBEAT_PINS``) that the
        transport toggles at ``heartbeat_hz`` while the process lives, whenever no program
        runs: the charge pump of an external monostable on the amplifier's enable, since the
        FT232H has no timer of its own.  ``busy_s``: the wait after each transfer; None: measured on the chip before the first
        program (:meth:`calibrate_busy`; opening itself never touches the bus), the documented
        100 us when it cannot be.  ``busy_pin``: "gpiol1" when D0 is wired to ADBUS5
        (``connections("ft232h", busy_pin=True)``): every busy check then waits in the adapter on the pin
        (no timed wait, nothing to calibrate, no cut before STT), and HI is not seen."""
        super().__init__(url, trace=trace)
        self.ftdi = ftdi
        self.clock = clock or WallClock()
        if busy_pin is not None and busy_pin not in pins.BUSY_PINS:
            raise ValueError(f"busy_pin={busy_pin!r}: expected one of "
                             f"{', '.join(pins.BUSY_PINS)} (or none)")
        self.busy_pin = busy_pin
        self.tck_hz = tck_hz
        self.compiler = StreamCompiler(tck_hz, DEFAULT_BUSY_US * 1e-6 if busy_s is None else busy_s,
                                       busy_pin=busy_pin is not None)
        self.busy_s = self.compiler.busy_s
        self.latency_ms = latency_ms
        self._last_end = -1.0  # clock time at which the last stream's answer came back
        self._owed: dict[int, float] = {}  # busy wait owed after each chip's last transfer
        self.busy_hits = 0  #: status reads before a transfer that showed busy (all time)
        #: the chip's busy time measured at open (None: not measured, the fixed wait is used)
        self.calibrated_busy_s: float | None = None
        #: what an MPSSE command is counted at when a wait is shortened by the commands run
        #: before its check: the most it is taken to cost until the calibration finds the least
        #: this adapter's can be (:func:`.mpsse.busy_bounds`)
        self.command_s = COMMAND_S
        self.calibration_exchanges = 0  #: USB write+read pairs the calibration took
        #: what the last calibration found, or why there is none (``lm629 doctor`` shows it)
        self.calibration_note = ("not measured yet: it runs before the first program"
                                 if busy_s is None and busy_pin is None else
                                 "not measured: " + ("waiting on the busy pin" if busy_pin
                                                     else f"busy_us={self.busy_s * 1e6:g} fixed"))
        self._extra_s = 0.0  # waiting above the calibrated wait since the last repeat
        # before the first program; with a busy pin there is no timed wait to measure, but
        # what the pin relies on is checked instead (check_busy_pin)
        self._calibrate = busy_s is None and busy_pin is None
        self._check_pin = busy_pin is not None
        self.stalls = 0  #: streams that stopped at a wait on the busy pin and were purged
        self.heartbeat = heartbeat
        #: the heartbeat's half period (0: none): the feeder toggles after this long idle
        self.feed_period_s = 0.0
        self.keepalive: KeepAlive | None = None  #: the heartbeat's, when there is one
        self._last_toggle = self.clock.now()
        if heartbeat is not None:
            line = pins.HEARTBEAT_PINS[heartbeat]
            self.chip_selects = 1  # its line is the second chip's /CS otherwise
            self.compiler.keep = self.compiler.keep_level = line
            self.feed_period_s = 0.5 / heartbeat_hz
            self.keepalive = KeepAlive(self.feed_period_s, self._beat, f"heartbeat {url}",
                                       lambda: self._last_toggle + self.feed_period_s)
            self.run_keep_alive(self.keepalive)

    # ------------------------------------------------------------------ opening
    @classmethod
    def from_url(cls, url: str | PortURL, *, trace: TraceCallback | None = None) -> FtdiTransport:
        opts = options_of(url)
        ftdi = open_mpsse(pyftdi_url(url), opts["latency"], opts["frequency"])
        busy = opts["busy_us"]
        return cls(ftdi, url, trace=trace, busy_s=None if busy is None else busy * 1e-6,
                   tck_hz=opts["frequency"], latency_ms=opts["latency"],
                   busy_pin=busy_pin_of(opts, url), heartbeat=opts["heartbeat"],
                   heartbeat_hz=opts["heartbeat_hz"])

    @classmethod
    def list_ports(cls) -> list[PortInfo]:
        """FT232H adapters on the USB bus (for ``lm629 list``); [] when pyftdi or libusb is
        missing (``doctor()`` says which)."""
        return find_adapters()

    @classmethod
    def doctor(cls, port: str | None = None) -> list[Check]:
        """What ``lm629 doctor`` reports about FT232H support on this machine."""
        checks: list[Check] = []
        try:
            import pyftdi
            checks.append(Check("pyftdi", True, f"pyftdi {pyftdi.__version__}"))
        except ImportError:
            # optional: only an FT232H needs it, so its absence is a note, not a problem
            return [Check("pyftdi", True, "not installed, optional: only ftdi:// needs it "
                                          "(pip install 'lm629-host[ftdi]')")]
        try:
            from pyftdi.usbtools import UsbTools
            UsbTools.find_backend()
            checks.append(Check("libusb", True, "pyusb found a libusb backend"))
        except ValueError:
            checks.append(Check("libusb", False, ADVICE_NO_BACKEND))
            return checks
        ports = cls.list_ports()
        usable = [p for p in ports if p.usable]
        if usable:
            checks.append(Check("FT232H", True, ", ".join(p.url for p in usable)))
        elif ports:
            checks.append(Check("FT232H", False, ports[0].problem))
        else:
            # like a serial bridge not found: nothing is wrong on a bench that uses another adapter
            checks.append(Check("FT232H", True, "none on the USB bus (0403:6014)"))
        rule = os.path.exists(UDEV_RULE)
        checks.append(Check("udev rule", rule or os.geteuid() == 0,
                            f"{UDEV_RULE} installed" if rule else
                            ("not installed (not needed as root)" if os.geteuid() == 0 else
                             "not installed: " + ADVICE_ACCESS.split("\n", 1)[1].strip())))
        if os.path.isdir("/sys/module/ftdi_sio"):
            checks.append(Check("ftdi_sio", True, "the ftdi_sio driver is loaded: pyftdi detaches it "
                                                  "from the adapter when it opens it; if that fails, "
                                                  "see the 'device busy' advice"))
        return checks

    # ------------------------------------------------------------------ the heartbeat
    def _feed_if_due(self) -> None:
        """Toggle the heartbeat line when no program has run for half its period (the lines
        are idle between programs: one set-low-byte command)."""
        if not self.feed_period_s or self.ftdi is None:
            return
        now = self.clock.now()
        if now - self._last_toggle < self.feed_period_s:
            return
        c = self.compiler
        c.keep_level ^= c.keep
        self._last_toggle = now
        self.ftdi.write_data(bytes((SET_LOW, c.low_byte(pins.CTRL_IDLE), pins.CTRL_DIRECTION)))

    def _beat(self) -> None:
        """The keep-alive's feed: toggle when due, only while no bus program holds the lock
        (a program under way keeps the line where it is)."""
        if self.ftdi is not None:
            self.keep_alive(self._feed_if_due, "heartbeat")

    def close(self) -> None:
        self.feed_period_s = 0.0
        if self.keepalive is not None:
            self.keepalive.stop()
        ftdi, self.ftdi = self.ftdi, None
        if ftdi is not None:
            try:
                ftdi.close()
            except Exception as exc:  # noqa: BLE001 - closing a vanished device must not raise
                log.warning("closing %s: %s", self.url, exc)

    def describe(self) -> str:
        return f"{self.url} (FT232H, MPSSE, TCK {self.compiler.tck_hz / 1e6:g} MHz)"

    def port_checks(self) -> list[Check]:
        """The busy wait: what the calibration found or why it has none, and the wait now.  A
        calibration that ran and is still pending saw no busy: a problem to show."""
        never_busy = self._calibrate and self.calibration_exchanges > 0
        return [Check("busy wait", not never_busy, f"{self.calibration_note}; now "
                                                   f"{self.busy_s * 1e6:.1f} us")]

    # ------------------------------------------------------------------ calibration
    def calibrate_busy(self) -> float | None:
        """Measure how long the chip holds busy after a transfer, and wait that long (not the
        documented worst case of 100 us) after each one from now on.  Run before the first
        program when the adapter was opened without ``busy_us`` (or ``busy_us=auto``).

        One status read first: a chip that is busy (or in reset, or not answering: D0 high) is
        left alone and the documented 100 us kept.  Then one stream per padding of
        :data:`CALIBRATION_PADS`: the status check, RDSIGS (a read command: it changes nothing
        on the chip), status reads that many idle clocks apart, a wait of the documented
        worst case, and RDSIGS's word (so that no command is left half done).  In each, the
        last read that saw busy and the first that saw it clear bound the busy time; what
        each read's time is depends on what an MPSSE command costs on this adapter, which
        only the streams together tell (:func:`.mpsse.busy_bounds`: pyftdi's virtual FT232H
        runs commands in no time, an FT2232H takes about 0.5 us).  The wait is the longest
        busy time they allow, shortened before each check by the commands run since the
        transfer, counted at the lowest cost they allow; one stream more, idle for most of
        the least busy time they allow before its reads, narrows the cost.  Nothing of the busy discipline
        changes: every transfer still has its check, and a check that sees busy still repeats
        the command (and lengthens the wait, :meth:`_learn_busy`).
        Returns the busy time measured, or None (the fixed wait kept)."""
        c = StreamCompiler(self.compiler.tck_hz, self.busy_s, COMMAND_S)
        first = c.status_stream(0, "status", 0)
        self.calibration_exchanges = 1
        if self._exchange(first)[0] & _BUSY:
            self.calibration_note = (f"not measured: the chip was busy at open; waiting the "
                                     f"documented {self.busy_s * 1e6:g} us")
            log.info("%s: the chip is busy at open: keeping the documented %g us busy wait",
                     self.url, self.busy_s * 1e6)
            return None
        seen: list[tuple[list[tuple[float, int]], int | None]] = []
        for pad in CALIBRATION_PADS:
            s, times = c.calibration_stream(CALIBRATION_POLLS, pad, self._lead().get(0, 0.0))
            answer = self._exchange(s)
            self.calibration_exchanges += 1
            self._owed = {0: self.busy_s}  # after RDSIGS's word
            if answer[0] & _BUSY:  # busy before RDSIGS: its command byte was ignored
                break
            polls = answer[1:1 + CALIBRATION_POLLS]
            clear = next((j for j, b in enumerate(polls) if not b & _BUSY), None)
            if clear == 0:
                # no read saw busy: the chip took no command (in reset, unclocked, D0 stuck
                # low), so nothing was measured; the first read's time is not a busy time.
                # Measured again before the next program, as check_busy_pin does
                self._calibrate = True
                self.calibration_note = (f"not measured: no status read after RDSIGS showed "
                                         f"busy (a chip that took no command, or D0 stuck low); "
                                         f"waiting the documented {self.busy_s * 1e6:g} us, "
                                         "measured again before the next program")
                log.info("%s: the chip showed no busy after RDSIGS: keeping the documented %g "
                         "us wait, measured again before the next program", self.url,
                         self.busy_s * 1e6)
                return None
            seen.append((times, clear))
        bounds = None
        if len(seen) < len(CALIBRATION_PADS):
            why = "the chip was busy before a calibration command"
        elif all(clear is None for _times, clear in seen):
            why = f"busy did not clear within {CALIBRATION_POLLS} status reads"
        else:
            why = "the chip's busy time changed between the calibration's commands"
            bounds = busy_bounds(seen, COMMAND_S)
            if bounds is not None:
                # one stream more, idle for most of the least busy time the others allow,
                # then status reads back to back: the reads around busy clearing then follow
                # few commands where the others followed many, which tells the cost closer
                s, times = c.calibration_stream(CALIBRATION_POLLS, 0.0, self._lead().get(0, 0.0),
                                                CALIBRATION_IDLE_SHARE * bounds[2])
                answer = self._exchange(s)
                self.calibration_exchanges += 1
                self._owed = {0: self.busy_s}
                polls = answer[1:1 + CALIBRATION_POLLS]
                clear = next((j for j, b in enumerate(polls) if not b & _BUSY), None)
                if not answer[0] & _BUSY and clear:
                    bounds = busy_bounds([*seen, (times, clear)], COMMAND_S) or bounds
        if bounds is None:
            self.calibration_note = (f"not measured: {why}; waiting the documented "
                                     f"{self.busy_s * 1e6:g} us")
            log.info("%s: no busy time measured at open (%s): keeping the documented %g us wait",
                     self.url, why, self.busy_s * 1e6)
            return None
        measured, self.command_s, _least = bounds
        busy = min(measured * CALIBRATION_MARGIN, DEFAULT_BUSY_US * 1e-6)
        self.calibrated_busy_s = measured
        self._set_busy(busy)
        self._owed = {0: busy}
        self.calibration_note = (f"measured: the chip holds busy <= {measured * 1e6:.1f} us "
                                 f"(an MPSSE command here takes >= {self.command_s * 1e9:.0f} "
                                 f"ns); waiting {busy * 1e6:.1f} us after each transfer")
        log.info("%s: the chip holds busy <= %.1f us, a command takes >= %.0f ns: waiting "
                 "%.1f us after each transfer", self.url, measured * 1e6, self.command_s * 1e9,
                 busy * 1e6)
        return measured

    def check_busy_pin(self) -> bool:
        """Before the first program with ``busy_pin``: see on the chip what waiting on the pin
        relies on (docs/ftdi.md, "What must be measured"), in two exchanges (a status read,
        then :meth:`.mpsse.StreamCompiler.pin_check_stream`): right after RDSIGS's command byte a
        held status read must show busy on D0 and the same level on GPIOL1, and 100 us later,
        /RD still low, busy clear on both.  So a chip that latches its status at /RD falling,
        or a missing or misplaced wire, is a TransportError here, not a stream that waits for
        ever later.  A chip busy at open is left alone; one that shows no busy after the
        command (in reset, unpowered) is checked again before the next program.  True when the
        pin was seen to work, False when not checked."""
        if self._exchange(self.compiler.status_stream(0, "status", 0))[0] & _BUSY:
            log.info("%s: the chip is busy at open: the busy pin is not checked", self.url)
            return False
        answer = self._exchange(self.compiler.pin_check_stream())
        check, d_on, p_on, d_off, p_off = answer[:5]
        if check & _BUSY:  # busy again since the first read: RDSIGS was ignored, no harm
            self.busy_hits += 1
            log.info("%s: the chip turned busy at open: the busy pin is not checked", self.url)
            return False
        seen = [(d & _BUSY, bool(p & pins.BUSY_PINS[self.busy_pin or ""]))
                for d, p in ((d_on, p_on), (d_off, p_off))]
        where = (f"the wire from D0 (C0, LM629 pin {pin_of('D0')}) to ADBUS5 (D5), and that HI is "
                 "off ADBUS5")
        if any(bool(d) != p for d, p in seen):
            raise TransportError(
                f"busy_pin={self.busy_pin}: GPIOL1 does not follow D0 during a status read "
                f"(D0/GPIOL1 read {seen[0][0]}/{int(seen[0][1])} with busy on, {seen[1][0]}/"
                f"{int(seen[1][1])} 100 us later): check {where}; or open the port without "
                "busy_pin", port=self.url)
        if not seen[0][0]:
            # the chip took no command (in its /RST window, never out of reset, not powered):
            # nothing learnt about the pin; checked again before the next program
            log.info("%s: the chip showed no busy after RDSIGS: the busy pin is checked again "
                     "before the next program", self.url)
            self._check_pin = True
            return False
        if seen[1][0]:
            raise TransportError(
                f"busy_pin={self.busy_pin}: D0 still showed busy 100 us later with /RD held low, "
                "so this chip does not show busy on D0 for as long as a status read is held (it "
                "may latch its status when /RD falls): waiting on the pin would never end. Open "
                "the port without busy_pin (the timed wait works on any chip)", port=self.url)
        log.info("%s: busy pin checked: D0 and GPIOL1 showed busy and then clear during one "
                 "held status read", self.url)
        return True

    def _set_busy(self, busy_s: float) -> None:
        self.busy_s = busy_s
        old = self.compiler
        self.compiler = StreamCompiler(self.compiler.tck_hz, busy_s, self.command_s,
                                       busy_pin=self.busy_pin is not None)
        self.compiler.keep, self.compiler.keep_level = old.keep, old.keep_level

    @property
    def calibrated_wait_s(self) -> float | None:
        """The wait the calibration set (None: not calibrated): the floor of :meth:`_relax`."""
        if self.calibrated_busy_s is None:
            return None
        return min(self.calibrated_busy_s * CALIBRATION_MARGIN, DEFAULT_BUSY_US * 1e-6)

    def _learn_busy(self) -> None:
        """A check saw busy after a calibrated wait: wait twice as long from now on, at most
        the documented worst case.  What the chip showed is that one status read, run on the
        MPSSE clock the wait after its transfer, still saw busy: its busy time exceeded the
        wait, by an unknown amount.  The host's time around the exchange says nothing about
        it (a USB transfer alone is longer than the chip's busy time), so it is not used."""
        self._extra_s = 0.0
        if self.calibrated_busy_s is None or self.busy_s >= DEFAULT_BUSY_US * 1e-6:
            return
        busy = min(DEFAULT_BUSY_US * 1e-6, 2 * self.busy_s)
        log.warning("%s: the chip held busy longer than measured at open: waiting %.1f us "
                    "after each transfer from now on (was %.1f us)", self.url, busy * 1e6,
                    self.busy_s * 1e6)
        self._set_busy(busy)

    def _relax(self, checks: int) -> None:
        """``checks`` transfers passed their busy check: once the waiting above the calibrated
        wait since the last repeat adds up to :data:`REPEAT_COST_S`, halve the wait (never
        below the calibrated one)."""
        floor = self.calibrated_wait_s
        if floor is None or self.busy_s <= floor:
            return
        self._extra_s += checks * (self.busy_s - floor)
        if self._extra_s < REPEAT_COST_S:
            return
        busy = max(floor, self.busy_s / 2)
        log.info("%s: no busy repeat for %.0f us of extra waiting: waiting %.1f us after each "
                 "transfer (was %.1f us)", self.url, self._extra_s * 1e6, busy * 1e6,
                 self.busy_s * 1e6)
        self._extra_s = 0.0
        self._set_busy(busy)

    # ------------------------------------------------------------------ one exchange
    def _exchange(self, stream: Stream, wait_s: float = 0.0) -> bytes:
        """Write ``stream``, read its answer.  ``wait_s``: how long its waits on the busy pin
        may take in all (they have no timeout of their own: the read gives up after that)."""
        ftdi = self.ftdi
        if ftdi is None:
            raise TransportError("the port is closed", port=self.url)
        need = len(stream.slots)
        # on hardware the answer can only come once the stream's delays have run: let pyftdi
        # wait that many latency periods for it, and a few more
        attempts = 3 + int((stream.delay_s + (wait_s if stream.waits else 0.0)) * 1000
                           / max(1, self.latency_ms))
        try:
            ftdi.write_data(stream.data)
            answer = bytes(ftdi.read_data_bytes(need, attempts))
        except TransportError:
            raise
        except Exception as exc:
            raise TransportError(
                f"USB transfer to the FT232H failed ({exc}). Check the USB cable and that the "
                "adapter is still plugged in; a command may or may not have reached the chip: "
                "read back what matters before going on", port=self.url) from exc
        st = self.stats
        st.round_trips += 1
        st.bytes_out += len(stream.data)
        st.bytes_in += len(answer)
        st.bus_cycles += stream.strobes
        if len(answer) != need and stream.waits:
            raise _Stalled(answer)
        if len(answer) != need:
            raise TransportError(
                f"the FT232H returned {len(answer)} of the {need} bytes the stream reads "
                f"(stream of {len(stream.data)} bytes). Check the USB cable and that no other "
                "program uses the adapter; the commands of this program may or may not have "
                "reached the chip", port=self.url)
        self._last_end = self.clock.now()
        return answer

    def _lead(self) -> dict[int, float]:
        """The busy wait still owed to each chip's last transfer of the previous streams."""
        if self._last_end < 0:
            return {}
        gone = self.clock.now() - self._last_end
        return {k: max(0.0, v - gone) for k, v in self._owed.items() if v > gone}

    def _emit_stream(self, stream: Stream, answer: bytes) -> None:
        if not self._tracing():
            return
        for kind, value in stream.events:
            if kind == "status":
                self._emit(BusCycle("status", answer[value]))
            elif kind == "read":
                self._emit(BusCycle("read", answer[value] << 8 | answer[value + 1]))
            else:
                self._emit(BusCycle(kind, value))

    def _poll_until_clear(self, program: Program, index: int, deadline: float,
                          words: list[int]) -> int:
        """Status reads, one short exchange each, until busy is clear; BusyTimeout at
        ``deadline``."""
        chip = chips_of_units(program.ops).get(index, 0)
        poll = self.compiler.status_stream(chip, "status", index)
        while True:
            status = self._exchange(poll)[0]
            self.stats.busy_polls += 1
            self._emit(BusCycle("status", status))
            if not status & _BUSY:
                self._owed = {k: v for k, v in self._owed.items() if k != chip}
                return status
            if self.clock.now() >= deadline:
                raise BusyTimeout(program.ops[index].describe(), program.busy_timeout_s, status,
                                  index, words)

    # ------------------------------------------------------------------ programs
    def _execute(self, program: Program) -> ProgramResult:
        ops = program.ops
        if self._calibrate or self._check_pin:
            opening = self.calibrate_busy if self._calibrate else self.check_busy_pin
            self._calibrate = self._check_pin = False
            saved = self.stats.as_dict()
            try:
                opening()
            finally:  # its exchanges are not the program's: counted apart
                for name, value in saved.items():
                    setattr(self.stats, name, value)
        chip_at = chips_of_units(ops)
        statuses: dict[int, int] = {}
        reads: dict[int, int] = {}
        last_status: int | None = None
        hi: bool | None = None
        wired = self.busy_pin is not None
        for units in streams_of(ops, cut_actions=not wired):
            unit_of = {k: a for a, b in units for k in range(a, b)}
            end = units[-1][1]
            first_try: dict[int, float] = {}
            pos = units[0][0]
            skip: set[int] = set()
            while pos < end:
                # as much as fits the FT232H's buffers; a long unit (a command reading many
                # words) may span streams: a repeat still starts at its command byte
                stream = self.compiler.compile(ops[pos:end], pos, self._lead(),
                                               max_bytes=pins.FIFO_BYTES,
                                               chip=chip_at[pos - 1] if pos else 0, skip=skip)
                stop = self.compiler.end
                owed_after = self.compiler.owed_after
                t0 = self.clock.now()
                try:
                    answer = self._exchange(stream, program.busy_timeout_s)
                except _Stalled as stall:
                    raise self._recover(program, stream, stall.answer, reads) from None
                self._owed = owed_after
                self._emit_stream(stream, answer)
                hi = None if wired else bool(answer[-1] & pins.HI)
                self.stats.busy_polls += sum(1 for sl in stream.slots if sl.kind in ("check", "sync"))
                # the first transfer whose busy check showed busy, and the start of its unit
                failed: tuple[int, int] | None = None
                busy_units: set[int] = set()
                for slot, byte in zip(stream.slots, answer):
                    if slot.kind in ("check", "sync") and byte & _BUSY and slot.op >= 0:
                        busy_units.add(unit_of[slot.op])
                        if failed is None and slot.kind == "check":
                            failed = (unit_of[slot.op], slot.op)
                if failed is not None and wired:
                    raise self._unwired(ops[failed[1]].describe())
                ok_end = failed[0] if failed else stop
                # on a multi-chip stream, the units after the failed one on other chips whose
                # every check passed were taken: they are recorded now and left out of the
                # repeat (an STT on chip 1 must not run twice because chip 0 was busy)
                taken: set[int] = set()
                if failed is not None:
                    fchip = chip_at[failed[1]]
                    taken = {a for a, b in units if ok_end < a and b <= stop
                             and a not in busy_units and ops[a].op is not Op.SELECT
                             and chip_at[a] != fchip and a not in skip}
                last_status = self._record(stream, answer, ok_end, taken, unit_of, statuses,
                                           reads, last_status)
                # a SYNC that saw busy waits here (not a failure: it is asked to wait)
                for slot, byte in zip(stream.slots, answer):
                    if slot.kind == "sync" and slot.op < ok_end and byte & _BUSY:
                        words = [reads[k] for k in sorted(reads)]
                        statuses[slot.op] = last_status = self._poll_until_clear(
                            program, slot.op, t0 + program.busy_timeout_s, words)
                if failed is None:
                    self._relax(sum(1 for sl in stream.slots if sl.kind == "check"))
                    pos = stop
                    continue
                skip |= {k for a, b in units if a in taken for k in range(a, b)}
                unit_start, op_index = failed
                # what earlier streams read for this unit is read again
                for k in [k for k in reads if k >= unit_start and unit_of.get(k) not in taken]:
                    del reads[k]
                self.busy_hits += 1
                self.stats.retries += 1
                first = first_try.setdefault(unit_start, t0)
                log.warning("%s: busy was still set before %s (the chip held busy past the "
                            "stream's %g us wait); repeating from %s%s", self.url,
                            ops[op_index].describe(), self.busy_s * 1e6,
                            ops[unit_start].describe(),
                            f" (leaving out {len(taken)} unit(s) other chips took)" if taken
                            else "")
                words = [reads[j] for j in sorted(reads) if j < unit_start]
                last_status = self._poll_until_clear(program, op_index,
                                                     first + program.busy_timeout_s, words)
                self._learn_busy()
                pos = unit_start
        return ProgramResult(tuple(reads[k] for k in sorted(reads)),
                             tuple(statuses[k] for k in sorted(statuses)), last_status, hi)

    def _recover(self, program: Program, stream: Stream, answer: bytes,
                 reads: dict[int, int]) -> BusyTimeout:
        """A stream stopped at a wait on the busy pin (MPSSE waits for ever; the read gave up):
        purge both buffers, leave MPSSE and enter it again (the engine drops the command it
        waits at; for that moment the FT232H is in UART mode: /RD and /PS driven high by RTS#
        and DTR#, the other lines inputs held high by the pull-ups, so the held status read
        ends, see :mod:`..ftdi_pins`), set the lines idle as at open, read the status once.  The
        operation whose check never came is the one the chip did not take; those before it
        were taken.  Returns the BusyTimeout to raise."""
        self.stalls += 1
        index = stream.slots[len(answer)].op if len(answer) < len(stream.slots) else -1
        ftdi = self.ftdi
        log.warning("%s: busy never cleared during the wait on %s before %s: purging the "
                    "FT232H and setting its lines idle again", self.url, self.busy_pin,
                    program.ops[index].describe() if index >= 0 else "the end")
        try:
            from pyftdi.ftdi import Ftdi
            ftdi.purge_buffers()
            ftdi.set_bitmode(0, Ftdi.BitMode.RESET)
            ftdi.set_bitmode(0, Ftdi.BitMode.MPSSE)
            ftdi.set_frequency(self.tck_hz)
            ftdi.write_data(bytes((DISABLE_CLK_ADAPTIVE, DISABLE_CLK_3PHASE,
                                   SET_LOW, pins.CTRL_IDLE, pins.CTRL_DIRECTION,
                                   SET_HIGH, 0, pins.DATA_IN)))
            chip = chips_of_units(program.ops).get(index, 0)
            status: int | None = self._exchange(
                self.compiler.status_stream(chip, "status", index))[0]
        except TransportError:
            raise
        except Exception as exc:  # pyftdi raises FtdiError, UsbToolsError, USBError...
            raise TransportError(
                f"the FT232H stalled on the busy pin and could not be reset ({exc}); unplug "
                "and replug it: a command may or may not have reached the chip",
                port=self.url) from exc
        self._last_end = self.clock.now()
        words = [reads[k] for k in sorted(reads)]
        return BusyTimeout(program.ops[index].describe() if index >= 0 else "the end of the "
                           "program", program.busy_timeout_s, status, index, words)

    def _unwired(self, what: str) -> TransportError:
        return TransportError(
            f"busy_pin={self.busy_pin}: the status read after the wait on the pin still showed "
            f"busy before {what}, so the pin did not follow D0: check the wire from D0 (C0) to "
            "ADBUS5 and that HI is no longer on ADBUS5 (docs/ftdi.md, 'Waiting on the busy "
            "bit'). The transfers after it in the same exchange may have been ignored by the "
            "chip: read back what matters (a move may have started) before going on, or open "
            "the port without busy_pin", port=self.url)

    @staticmethod
    def _record(stream: Stream, answer: bytes, ok_end: int, taken: set[int],
                unit_of: dict[int, int], statuses: dict[int, int], reads: dict[int, int],
                last_status: int | None) -> int | None:
        """Keep the bytes of the operations before ``ok_end`` and of the units ``taken``."""
        for slot, byte in zip(stream.slots, answer):
            if slot.op < 0 or (slot.op >= ok_end and unit_of.get(slot.op) not in taken):
                continue
            if slot.kind in ("status", "sync"):
                statuses[slot.op] = byte
                last_status = byte
            elif slot.kind == "check":
                last_status = byte
            elif slot.kind == "hi":
                reads[slot.op] = byte << 8
            elif slot.kind == "lo":
                reads[slot.op] |= byte
        return last_status


class _Stalled(Exception):
    """The answer of a stream that waits on the busy pin came back short: the engine is
    still waiting (``answer``: what it sent before)."""

    def __init__(self, answer: bytes) -> None:
        super().__init__(f"{len(answer)} answer bytes")
        self.answer = answer


# ---------------------------------------------------------------------------- list, doctor
#: module-level names of the class methods (``ftdi.list_ports()``)
list_ports = FtdiTransport.list_ports
doctor = FtdiTransport.doctor


__all__ = ["FtdiTransport", "open_mpsse", "list_ports", "doctor", "options_of", "pyftdi_url"]
