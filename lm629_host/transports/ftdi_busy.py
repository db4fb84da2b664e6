"""The FT232H's wait after each transfer, fitted to the chip: measured before the first
program, raised when a check still sees busy, brought back to the measure when raising it
costs more than the repeats it saves (:mod:`.ftdi` has the busy discipline it serves).

An MPSSE stream cannot look at the busy bit before it writes, so it waits after every transfer
and checks afterwards.  The documented worst case (100 us) is safe and slow; the chip at hand
is usually four to six times faster, and only speed rests on the measure: a check that sees
busy repeats the command, so a measure too short costs a repeat, never a command.  What the
wait is now and what it was measured at is one :class:`BusyWait`; the stream compiler it sets
(:class:`.mpsse.StreamCompiler`'s ``busy_s`` and ``command_s``) is what every stream reads.

With the busy pin wired there is no timed wait: what is checked before the first program is
then that the pin follows D0 during a held status read (:meth:`BusyWait.check_pin`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

from lm629_host.bus.opcodes import BUSY_BIT
from lm629_host.bus.pinout import pin_of
from lm629_host.errors import TransportError
from lm629_host.transports.ftdi_exchange import StreamExchange
from lm629_host.transports.mpsse import DEFAULT_BUSY_US, StreamCompiler
from lm629_host.wiring import ft232h as pins

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
#: more tell the chip's busy time and what a command costs apart (:func:`busy_bounds`);
#: 0 first, so that a chip that shows no busy is found in one stream
CALIBRATION_PADS = (0.0, 1e-6, 2e-6, 3e-6)
#: ... and one stream more that idles this share of the least busy time those allow before
#: its status reads (short of it: its first read must still see busy)
CALIBRATION_IDLE_SHARE = 0.8
#: the wait is the busy time measured times this.  The measure is already an upper bound (the
#: first status read that saw busy clear, up to one read period late); a chip whose busy time
#: differs between commands (the datasheet gives 15-25 us typical) shows it at a check, which
#: repeats the command and lengthens the wait (:meth:`BusyWait.learn`)
CALIBRATION_MARGIN = 1.0
#: what one busy repeat costs, about: a poll exchange and the repeat's exchange, each a USB
#: write and read (at least one 125 us high-speed microframe each way).  A wait raised after a
#: repeat comes back down (halved, never below the calibrated wait) once the extra waiting it
#: has cost since the last repeat adds up to this: a chip that really needs the longer wait
#: then costs one repeat per this much waiting, never more than staying raised would
REPEAT_COST_S = 4 * 125e-6
#: the step at which :func:`busy_bounds` tries the cost of an MPSSE command, s
COMMAND_STEP_S = 1e-9


class BusyWait:
    """The wait after each transfer on one FT232H: what the compiler waits now, what the chip
    was measured at, and the checks that saw busy.  ``measure``: run :meth:`calibrate` before
    the first program (no ``busy_us`` given, no busy pin); ``pin``: the line D0 is wired to
    (:meth:`check_pin` runs instead)."""

    def __init__(self, compiler: StreamCompiler, exchange: StreamExchange, *, measure: bool,
                 pin: str | None) -> None:
        self.compiler = compiler
        self.exchange = exchange
        self.url = exchange.url
        self.pin = pin
        self.hits = 0  #: status reads before a transfer that showed busy (all time)
        #: the chip's busy time measured at open (None: not measured, the fixed wait is used)
        self.calibrated_s: float | None = None
        #: what an MPSSE command is counted at when a wait is shortened by the commands run
        #: before its check: the most it is taken to cost until the calibration finds the least
        #: this adapter's can be (:func:`busy_bounds`)
        self.command_s = COMMAND_S
        self.exchanges = 0  #: USB write+read pairs the calibration took
        #: what the last calibration found, or why there is none (``lm629 doctor`` shows it)
        self.note = ("not measured yet: it runs before the first program" if measure else
                     "not measured: " + ("waiting on the busy pin" if pin
                                         else f"busy_us={self.wait_s * 1e6:g} fixed"))
        #: True while :meth:`calibrate` or :meth:`check_pin` is still to run before a program
        self.due = measure or pin is not None
        self._extra_s = 0.0  # waiting above the calibrated wait since the last repeat

    @property
    def wait_s(self) -> float:
        """The wait after each transfer now (what the compiler puts in every stream)."""
        return self.compiler.busy_s

    @property
    def floor_s(self) -> float | None:
        """The wait the calibration set (None: not calibrated): the floor of :meth:`relax`."""
        if self.calibrated_s is None:
            return None
        return min(self.calibrated_s * CALIBRATION_MARGIN, DEFAULT_BUSY_US * 1e-6)

    def before_program(self) -> None:
        """What is due before a program: the calibration, or the check of the busy pin."""
        self.due = False
        if self.pin is None:
            self.calibrate()
        else:
            self.check_pin()

    def _set(self, busy_s: float) -> None:
        self.compiler.busy_s = busy_s
        self.compiler.command_s = self.command_s

    # ------------------------------------------------------------------ the measure at open
    def calibrate(self) -> float | None:
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
        only the streams together tell (:func:`busy_bounds`: pyftdi's virtual FT232H
        runs commands in no time, an FT2232H takes about 0.5 us).  The wait is the longest
        busy time they allow, shortened before each check by the commands run since the
        transfer, counted at the lowest cost they allow; one stream more, idle for most of
        the least busy time they allow before its reads, narrows the cost.  Nothing of the busy discipline
        changes: every transfer still has its check, and a check that sees busy still repeats
        the command (and lengthens the wait, :meth:`learn`).
        Returns the busy time measured, or None (the fixed wait kept)."""
        ex = self.exchange
        c = StreamCompiler(self.compiler.tck_hz, self.wait_s, COMMAND_S)
        first = c.status_stream(0, "status", 0)
        self.exchanges = 1
        if ex.run(first)[0] & _BUSY:
            self.note = (f"not measured: the chip was busy at open; waiting the "
                         f"documented {self.wait_s * 1e6:g} us")
            log.info("%s: the chip is busy at open: keeping the documented %g us busy wait",
                     self.url, self.wait_s * 1e6)
            return None
        seen: list[tuple[list[tuple[float, int]], int | None]] = []
        for pad in CALIBRATION_PADS:
            s, times = c.calibration_stream(CALIBRATION_POLLS, pad, ex.lead().get(0, 0.0))
            answer = ex.run(s)
            self.exchanges += 1
            ex.owed = {0: self.wait_s}  # after RDSIGS's word
            if answer[0] & _BUSY:  # busy before RDSIGS: its command byte was ignored
                break
            polls = answer[1:1 + CALIBRATION_POLLS]
            clear = next((j for j, b in enumerate(polls) if not b & _BUSY), None)
            if clear == 0:
                # no read saw busy: the chip took no command (in reset, unclocked, D0 stuck
                # low), so nothing was measured; the first read's time is not a busy time.
                # Measured again before the next program, as check_pin does
                self.due = True
                self.note = (f"not measured: no status read after RDSIGS showed "
                             f"busy (a chip that took no command, or D0 stuck low); "
                             f"waiting the documented {self.wait_s * 1e6:g} us, "
                             "measured again before the next program")
                log.info("%s: the chip showed no busy after RDSIGS: keeping the documented %g "
                         "us wait, measured again before the next program", self.url,
                         self.wait_s * 1e6)
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
                s, times = c.calibration_stream(CALIBRATION_POLLS, 0.0, ex.lead().get(0, 0.0),
                                                CALIBRATION_IDLE_SHARE * bounds[2])
                answer = ex.run(s)
                self.exchanges += 1
                ex.owed = {0: self.wait_s}
                polls = answer[1:1 + CALIBRATION_POLLS]
                clear = next((j for j, b in enumerate(polls) if not b & _BUSY), None)
                if not answer[0] & _BUSY and clear:
                    bounds = busy_bounds([*seen, (times, clear)], COMMAND_S) or bounds
        if bounds is None:
            self.note = (f"not measured: {why}; waiting the documented "
                         f"{self.wait_s * 1e6:g} us")
            log.info("%s: no busy time measured at open (%s): keeping the documented %g us wait",
                     self.url, why, self.wait_s * 1e6)
            return None
        measured, self.command_s, _least = bounds
        busy = min(measured * CALIBRATION_MARGIN, DEFAULT_BUSY_US * 1e-6)
        self.calibrated_s = measured
        self._set(busy)
        ex.owed = {0: busy}
        self.note = (f"measured: the chip holds busy <= {measured * 1e6:.1f} us "
                     f"(an MPSSE command here takes >= {self.command_s * 1e9:.0f} "
                     f"ns); waiting {busy * 1e6:.1f} us after each transfer")
        log.info("%s: the chip holds busy <= %.1f us, a command takes >= %.0f ns: waiting "
                 "%.1f us after each transfer", self.url, measured * 1e6, self.command_s * 1e9,
                 busy * 1e6)
        return measured

    def check_pin(self) -> bool:
        """Before the first program with ``busy_pin``: see on the chip what waiting on the pin
        relies on (docs/ftdi.md, "What must be measured"), in two exchanges (a status read,
        then :meth:`.mpsse.StreamCompiler.pin_check_stream`): right after RDSIGS's command byte a
        held status read must show busy on D0 and the same level on GPIOL1, and 100 us later,
        /RD still low, busy clear on both.  So a chip that latches its status at /RD falling,
        or a missing or misplaced wire, is a TransportError here, not a stream that waits for
        ever later.  A chip busy at open is left alone; one that shows no busy after the
        command (in reset, unpowered) is checked again before the next program.  True when the
        pin was seen to work, False when not checked."""
        ex = self.exchange
        if ex.run(self.compiler.status_stream(0, "status", 0))[0] & _BUSY:
            log.info("%s: the chip is busy at open: the busy pin is not checked", self.url)
            return False
        answer = ex.run(self.compiler.pin_check_stream())
        check, d_on, p_on, d_off, p_off = answer[:5]
        if check & _BUSY:  # busy again since the first read: RDSIGS was ignored, no harm
            self.hits += 1
            log.info("%s: the chip turned busy at open: the busy pin is not checked", self.url)
            return False
        seen = [(d & _BUSY, bool(p & pins.BUSY_PINS[self.pin or ""]))
                for d, p in ((d_on, p_on), (d_off, p_off))]
        where = (f"the wire from D0 (C0, LM629 pin {pin_of('D0')}) to ADBUS5 (D5), and that HI is "
                 "off ADBUS5")
        if any(bool(d) != p for d, p in seen):
            raise TransportError(
                f"busy_pin={self.pin}: GPIOL1 does not follow D0 during a status read "
                f"(D0/GPIOL1 read {seen[0][0]}/{int(seen[0][1])} with busy on, {seen[1][0]}/"
                f"{int(seen[1][1])} 100 us later): check {where}; or open the port without "
                "busy_pin", port=self.url)
        if not seen[0][0]:
            # the chip took no command (in its /RST window, never out of reset, not powered):
            # nothing learnt about the pin; checked again before the next program
            log.info("%s: the chip showed no busy after RDSIGS: the busy pin is checked again "
                     "before the next program", self.url)
            self.due = True
            return False
        if seen[1][0]:
            raise TransportError(
                f"busy_pin={self.pin}: D0 still showed busy 100 us later with /RD held low, "
                "so this chip does not show busy on D0 for as long as a status read is held (it "
                "may latch its status when /RD falls): waiting on the pin would never end. Open "
                "the port without busy_pin (the timed wait works on any chip)", port=self.url)
        log.info("%s: busy pin checked: D0 and GPIOL1 showed busy and then clear during one "
                 "held status read", self.url)
        return True

    # ------------------------------------------------------------------ after a repeat
    def learn(self) -> None:
        """A check saw busy after a calibrated wait: wait twice as long from now on, at most
        the documented worst case.  What the chip showed is that one status read, run on the
        MPSSE clock the wait after its transfer, still saw busy: its busy time exceeded the
        wait, by an unknown amount.  The host's time around the exchange says nothing about
        it (a USB transfer alone is longer than the chip's busy time), so it is not used."""
        self._extra_s = 0.0
        if self.calibrated_s is None or self.wait_s >= DEFAULT_BUSY_US * 1e-6:
            return
        busy = min(DEFAULT_BUSY_US * 1e-6, 2 * self.wait_s)
        log.warning("%s: the chip held busy longer than measured at open: waiting %.1f us "
                    "after each transfer from now on (was %.1f us)", self.url, busy * 1e6,
                    self.wait_s * 1e6)
        self._set(busy)

    def relax(self, checks: int) -> None:
        """``checks`` transfers passed their busy check: once the waiting above the calibrated
        wait since the last repeat adds up to :data:`REPEAT_COST_S`, halve the wait (never
        below the calibrated one)."""
        floor = self.floor_s
        if floor is None or self.wait_s <= floor:
            return
        self._extra_s += checks * (self.wait_s - floor)
        if self._extra_s < REPEAT_COST_S:
            return
        busy = max(floor, self.wait_s / 2)
        log.info("%s: no busy repeat for %.0f us of extra waiting: waiting %.1f us after each "
                 "transfer (was %.1f us)", self.url, self._extra_s * 1e6, busy * 1e6,
                 self.wait_s * 1e6)
        self._extra_s = 0.0
        self._set(busy)


def busy_bounds(observations: Sequence[tuple[Sequence[tuple[float, int]], int | None]],
                command_max_s: float) -> tuple[float, float, float] | None:
    """What calibration polls tell of the chip's busy time and of the adapter's MPSSE command
    cost, neither known alone: ``observations`` holds, for each calibration stream, its
    polls' (idle seconds, commands) (:meth:`.mpsse.StreamCompiler.calibration_stream`) and the
    index of the first poll that saw busy clear (None: none did; at least 1: the one before saw
    it set).  For a command cost ``c`` a poll's /RD falls ``idle + commands * c`` after the
    transfer, so each stream bounds the busy time from below (the last poll that saw busy)
    and above (the first that saw it clear).  Streams with different idle paddings agree
    only for some costs: those are the costs the adapter may have, from 0 up to
    ``command_max_s`` (the most a command is taken to cost; a slower adapter shows up as a
    check that sees busy, which the transport repeats and learns from).

    Returns (the longest busy time any such cost allows, the lowest such cost, the shortest
    busy time any allows), or None when
    no cost makes the streams agree (the chip's busy time changed between them).  A wait of
    the first, shortened by the commands run before a check counted at the second, lasts at
    least the busy time on any adapter the polls allow: a command costs at least that."""
    busy_hi: float | None = None
    busy_lo = math.inf
    lowest: float | None = None
    for k in range(int(round(command_max_s / COMMAND_STEP_S)) + 1):
        c = k * COMMAND_STEP_S
        lo, hi = 0.0, math.inf
        for times, clear in observations:
            if clear is None:  # busy through the last poll
                idle, n = times[-1]
                lo = max(lo, idle + n * c)
                continue
            idle, n = times[clear - 1]
            lo = max(lo, idle + n * c)
            idle, n = times[clear]
            hi = min(hi, idle + n * c)
        if lo < hi:
            lowest = c if lowest is None else lowest
            busy_hi = hi if busy_hi is None else max(busy_hi, hi)
            busy_lo = min(busy_lo, lo)
    if busy_hi is None or lowest is None or math.isinf(busy_hi):
        return None
    return busy_hi, lowest, busy_lo


__all__ = ["BusyWait", "busy_bounds", "COMMAND_S", "CALIBRATION_POLLS", "CALIBRATION_PADS",
           "CALIBRATION_IDLE_SHARE", "CALIBRATION_MARGIN", "REPEAT_COST_S"]
