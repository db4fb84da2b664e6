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
   (:meth:`.ftdi_busy.BusyWait.calibrate`: a read command, then status reads, at several
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
   :meth:`.ftdi_busy.BusyWait.learn`, brought back down by :meth:`.ftdi_busy.BusyWait.relax`), so
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
after the program's busy timeout, and :meth:`.ftdi_resync.Resync.after_stall` purges the FT232H, leaves
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
from typing import Any

from lm629_host.wiring import ft232h as pins
from lm629_host.clock import Clock, WallClock
from lm629_host.bus.opcodes import BUSY_BIT
from lm629_host.bus.program import BusCycle, Op, Program, ProgramResult, TraceCallback
from lm629_host.urls import Option, PortURL
from lm629_host.transports.base import Transport
from lm629_host.transports.reports import Check, PortInfo
from lm629_host.transports.ftdi_busy import BusyWait
from lm629_host.transports.ftdi_exchange import Stalled, StreamExchange
from lm629_host.transports.ftdi_open import (
    DEFAULT_LATENCY_MS,
    OPTIONS,
    SET_LOW,
    adapter_checks,
    busy_pin_of,
    find_adapters,
    open_mpsse,
    options_of,
    pyftdi_url,
)
from lm629_host.transports.ftdi_resync import Resync
from lm629_host.transports.keepalive import KeepAlive
from lm629_host.transports.mpsse import (DEFAULT_BUSY_US, DEFAULT_TCK_HZ, Stream, StreamCompiler,
                                        chips_of_units, streams_of)

log = logging.getLogger("lm629_host.ftdi")

_BUSY = BUSY_BIT  # a plain int (opcodes.BUSY_BIT)


# ---------------------------------------------------------------------------- transport
class FtdiTransport(Transport):
    """Bus programs as MPSSE streams on an opened pyftdi ``Ftdi`` (see the module docstring).

    Composed of the parts that share a stream's state: the compiler (``compiler``: the
    stream's bytes, with the wait and the heartbeat's level in them), the exchange (``wire``:
    a stream out, its answer back, the wait owed from one stream to the next), the busy wait
    fitted to the chip (``busy``: measured at open, raised after a repeat, brought back) and
    the short exchanges after a check that saw busy or a stall (``resync``).  What stays here
    is the loop that runs a program's streams and judges their checks, and the heartbeat."""

    scheme = "ftdi"
    options: tuple[Option, ...] = OPTIONS  #: its URL options, one table (parsed once, and listed by a message)
    has_reset_line = True
    #: a WAIT is idle clocks (1/6 us each at the default clock); the status read behind it
    #: sets the lines up in about five MPSSE commands (ftdi_busy.COMMAND_S, 0.5 us, each)
    busy_probe_us = 3.0
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
        program (:meth:`.ftdi_busy.BusyWait.calibrate`; opening itself never touches the bus), the documented
        100 us when it cannot be.  ``busy_pin``: "gpiol1" when D0 is wired to ADBUS5
        (``connections("ft232h", busy_pin=True)``): every busy check then waits in the adapter on the pin
        (no timed wait, nothing to calibrate, no cut before STT), and HI is not seen."""
        super().__init__(url, trace=trace)
        self.clock = clock or WallClock()
        if busy_pin is not None and busy_pin not in pins.BUSY_PINS:
            raise ValueError(f"busy_pin={busy_pin!r}: expected one of "
                             f"{', '.join(pins.BUSY_PINS)} (or none)")
        self.busy_pin = busy_pin
        self.compiler = StreamCompiler(tck_hz, DEFAULT_BUSY_US * 1e-6 if busy_s is None else busy_s,
                                       busy_pin=busy_pin is not None)
        self.wire = StreamExchange(ftdi, self.url, self.clock, self.stats, latency_ms)
        # before the first program; with a busy pin there is no timed wait to measure, but
        # what the pin relies on is checked instead (BusyWait.check_pin)
        self.busy = BusyWait(self.compiler, self.wire, pin=busy_pin,
                             measure=busy_s is None and busy_pin is None)
        self.resync = Resync(self.wire, self.compiler, self._emit, busy_pin)
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
            # the keep-alive's protocol (when, skipped while a program holds the lock, which
            # clock); the heartbeat says only what to send: a toggle
            self.keepalive = KeepAlive(self.feed_period_s, self._toggle, f"heartbeat {url}",
                                       last_heard=lambda: self._last_toggle, clock=self.clock,
                                       busy=self.lock)
            self.keepalive.start(self)

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
        return adapter_checks()

    # ------------------------------------------------------------------ the heartbeat
    def _toggle(self) -> None:
        """What the keep-alive sends: the heartbeat line toggled (the lines are idle between
        programs: one set-low-byte command)."""
        ftdi = self.wire.ftdi
        if not self.feed_period_s or ftdi is None:
            return
        c = self.compiler
        c.keep_level ^= c.keep
        self._last_toggle = self.clock.now()
        ftdi.write_data(bytes((SET_LOW, c.low_byte(pins.CTRL_IDLE), pins.CTRL_DIRECTION)))

    def close(self) -> None:
        self.feed_period_s = 0.0
        if self.keepalive is not None:
            self.keepalive.stop()
        ftdi, self.wire.ftdi = self.wire.ftdi, None
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
        busy = self.busy
        never_busy = busy.due and busy.exchanges > 0
        return [Check("busy wait", not never_busy, f"{busy.note}; now "
                                                   f"{busy.wait_s * 1e6:.1f} us")]

    # ------------------------------------------------------------------ one program
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

    def _execute(self, program: Program) -> ProgramResult:
        ops = program.ops
        if self.busy.due:
            saved = self.stats.as_dict()
            try:
                self.busy.before_program()
            finally:  # its exchanges are not the program's: counted apart
                for name, value in saved.items():
                    setattr(self.stats, name, value)
        chip_at = chips_of_units(ops)
        statuses: dict[int, int] = {}
        reads: dict[int, int] = {}
        last_status: int | None = None
        hi: bool | None = None
        wired = self.busy_pin is not None
        wire = self.wire
        for units in streams_of(ops, cut_actions=not wired):
            unit_of = {k: a for a, b in units for k in range(a, b)}
            end = units[-1][1]
            first_try: dict[int, float] = {}
            pos = units[0][0]
            skip: set[int] = set()
            while pos < end:
                # as much as fits the FT232H's buffers; a long unit (a command reading many
                # words) may span streams: a repeat still starts at its command byte
                stream = self.compiler.compile(ops[pos:end], pos, wire.lead(),
                                               max_bytes=pins.FIFO_BYTES,
                                               chip=chip_at[pos - 1] if pos else 0, skip=skip)
                stop = self.compiler.end
                owed_after = self.compiler.owed_after
                t0 = self.clock.now()
                try:
                    answer = wire.run(stream, program.busy_timeout_s)
                except Stalled as stall:
                    raise self.resync.after_stall(program, stream, stall.answer, reads) from None
                wire.owed = owed_after
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
                    raise self.resync.unwired(ops[failed[1]].describe())
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
                        statuses[slot.op] = last_status = self.resync.poll_until_clear(
                            program, slot.op, t0 + program.busy_timeout_s, words)
                if failed is None:
                    self.busy.relax(sum(1 for sl in stream.slots if sl.kind == "check"))
                    pos = stop
                    continue
                skip |= {k for a, b in units if a in taken for k in range(a, b)}
                unit_start, op_index = failed
                # what earlier streams read for this unit is read again
                for k in [k for k in reads if k >= unit_start and unit_of.get(k) not in taken]:
                    del reads[k]
                self.busy.hits += 1
                self.stats.retries += 1
                first = first_try.setdefault(unit_start, t0)
                log.warning("%s: busy was still set before %s (the chip held busy past the "
                            "stream's %g us wait); repeating from %s%s", self.url,
                            ops[op_index].describe(), self.busy.wait_s * 1e6,
                            ops[unit_start].describe(),
                            f" (leaving out {len(taken)} unit(s) other chips took)" if taken
                            else "")
                words = [reads[j] for j in sorted(reads) if j < unit_start]
                last_status = self.resync.poll_until_clear(program, op_index,
                                                     first + program.busy_timeout_s, words)
                self.busy.learn()
                pos = unit_start
        return ProgramResult(tuple(reads[k] for k in sorted(reads)),
                             tuple(statuses[k] for k in sorted(statuses)), last_status, hi)

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


# ---------------------------------------------------------------------------- list, doctor
#: module-level names of the class methods (``ftdi.list_ports()``)
list_ports = FtdiTransport.list_ports
doctor = FtdiTransport.doctor


__all__ = ["FtdiTransport", "doctor", "list_ports"]
