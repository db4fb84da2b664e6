"""Bus programs -> MPSSE command streams for the FT232H adapter: pure, no pyftdi, no USB.

The compiler turns bus operations into the bytes of one MPSSE stream with the pin map of
:mod:`lm629_host.wiring.ft232h`, and says what each answer byte will be (:class:`Slot`), the bus
events in order, and how long the stream's delays last.  It runs nothing: the transport
(:mod:`.ftdi`) sends the bytes, reads the answer and judges the busy checks.  Why the stream
looks as it does (timing minimums met by idle clocks alone, the busy discipline, the cuts
before actions and at 1 KiB) is written in the docstring of :mod:`.ftdi`.

Where the compiler is inside a stream (the levels it left on the control lines and on D0-D7,
the chip selected, the stream time counted so far, the busy waits owed per chip) is one
:class:`CompilerState`; a stream cut at 1 KiB rolls back to a :class:`Mark` (the stream's
lengths and a copy of that state) taken before the operation that did not fit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

from lm629_host.wiring import ft232h as pins
from lm629_host.bus.opcodes import RESET_WAIT_S, Cmd
from lm629_host.bus.program import BusOp, Op

# the MPSSE commands the streams use (FTDI AN_108; defined in ftdi_pins)
SET_LOW, GET_LOW, SET_HIGH, GET_HIGH = pins.SET_LOW, pins.GET_LOW, pins.SET_HIGH, pins.GET_HIGH
SEND_IMMEDIATE, CLK_BITS, CLK_BYTES = pins.SEND_IMMEDIATE, pins.CLK_BITS, pins.CLK_BYTES
WAIT_HIGH, WAIT_LOW = pins.WAIT_HIGH, pins.WAIT_LOW
#: bytes a stream may still need after its last operation: control lines idle (3), D0-D7
#: released (3), read HI (1), send immediate (1)
STREAM_TAIL = 8

DEFAULT_BUSY_US = 100  #: the chip's documented worst-case busy time
DEFAULT_TCK_HZ = 6e6
RST_LOW_S = 10e-6  #: >= 8 clocks of the slowest (1 MHz) chip, with margin
#: commands that act on the chip (not repeatable once taken): the stream is cut before them
ACTIONS = frozenset({Cmd.RESET, Cmd.STT, Cmd.DFH, Cmd.SIP, Cmd.UDF})


@dataclass(frozen=True)
class Slot:
    """One byte the stream reads: ``kind`` is "check" (status before a transfer), "status"
    (a STATUS op), "sync" (a SYNC op), "hi"/"lo" (bytes of a data word) or "pins" (HI)."""

    kind: str
    op: int  #: index of the program operation it belongs to (-1 for "pins")


@dataclass
class Stream:
    """A compiled MPSSE stream: the bytes to send, what each answer byte is, the bus events in
    order (for the trace) and how long its delays last."""

    data: bytearray = field(default_factory=bytearray)
    slots: list[Slot] = field(default_factory=list)
    #: ("status", slot), ("command", byte), ("write", word), ("read", slot of high byte),
    #: ("reset", 0), ("select", chip), in bus order
    events: list[tuple[str, int]] = field(default_factory=list)
    delay_s: float = 0.0
    strobes: int = 0
    #: status reads that wait on the busy pin (0x89, with 0x88 before it after a transfer):
    #: the stream lasts as long as the chip holds busy, which the compiler cannot know
    waits: int = 0

    def mark(self, state: CompilerState) -> Mark:
        """Where the stream and the compiler are now, to come back to."""
        return Mark(len(self.data), len(self.slots), len(self.events), self.delay_s,
                    self.strobes, self.waits, state.copy())

    def rollback(self, mark: Mark) -> CompilerState:
        """Drop everything compiled since ``mark``; the compiler state as it was then."""
        del self.data[mark.data:], self.slots[mark.slots:], self.events[mark.events:]
        self.delay_s, self.strobes, self.waits = mark.delay_s, mark.strobes, mark.waits
        return mark.state.copy()


@dataclass
class CompilerState:
    """Where the compiler is inside a stream."""

    ctrl: int = pins.CTRL_IDLE  #: the control lines (ADBUS) as the last 0x80 left them
    direction: int = pins.DATA_IN  #: the D0-D7 (ACBUS) direction the last 0x82 set
    cs: int = 0  #: the chip the operations address (``Op.SELECT`` changes it)
    t: float = 0.0  #: estimated stream time of what was compiled so far, s
    #: busy wait owed to each chip's last transfer before its next busy check, s ...
    owed: dict[int, float] = field(default_factory=dict)
    #: ... counted from this stream time (absent: the stream's start)
    owed_from: dict[int, float] = field(default_factory=dict)
    #: with a busy pin: the chip whose transfer the stream made last, nothing but status
    #: reads since (its busy is still to be seen rising), else None
    expect_busy: int | None = None

    def copy(self) -> CompilerState:
        return replace(self, owed=dict(self.owed), owed_from=dict(self.owed_from))


@dataclass(frozen=True)
class Mark:
    """A stream's lengths and the compiler state at one point (:meth:`Stream.mark`)."""

    data: int
    slots: int
    events: int
    delay_s: float
    strobes: int
    waits: int
    state: CompilerState


class StreamCompiler:
    """Bus operations -> MPSSE bytes, with the pin map of :mod:`lm629_host.wiring.ft232h`."""

    def __init__(self, tck_hz: float = DEFAULT_TCK_HZ, busy_s: float = DEFAULT_BUSY_US * 1e-6,
                 command_s: float = 0.0, busy_pin: bool = False):
        self.tck_hz = tck_hz
        self.busy_s = busy_s
        #: D0 is wired to GPIOL1 (``busy_pin=gpiol1``): each busy check is a status read held
        #: while the adapter waits on the pin (:meth:`held_check`), not a timed wait before it
        self.busy_pin = busy_pin
        #: what one MPSSE command is taken to cost when a busy wait is shortened by the
        #: commands run between the transfer and its check (0: not counted, the wait is idle
        #: clocks alone).  Only a busy wait uses it, never a timing minimum: a wrong figure
        #: makes a check see busy, which the transport repeats and learns from.
        self.command_s = command_s
        self.state = CompilerState()
        self.rd_fell_at = 0.0  #: stream time at which the last read's /RD fell
        self.end = 0  #: the index after the last operation :meth:`compile` compiled
        #: the busy wait still owed per chip when the last compiled stream ends
        self.owed_after: dict[int, float] = {}

    def begin(self, chip: int = 0) -> Stream:
        """A new stream: lines idle, D0-D7 released, ``chip`` selected, time 0."""
        self.state = CompilerState(cs=chip)
        return Stream()

    # primitives
    #: ADBUS lines the streams leave as they are (a heartbeat pin) and their level now
    keep: int = 0
    keep_level: int = 0

    def low_byte(self, value: int) -> int:
        """``value`` for the ADBUS latch, with the kept lines at their level."""
        return (value & ~self.keep) | self.keep_level

    def _low(self, s: Stream, value: int) -> None:
        s.data += bytes((SET_LOW, self.low_byte(value), pins.CTRL_DIRECTION))
        self.state.ctrl = value
        self.state.t += self.command_s

    def _high(self, s: Stream, value: int, direction: int) -> None:
        s.data += bytes((SET_HIGH, value, direction))
        self.state.direction = direction
        self.state.t += self.command_s

    def _bits(self, s: Stream, n: int) -> None:
        s.data += bytes((CLK_BITS, n - 1))
        s.delay_s += n / self.tck_hz
        self.state.t += self.command_s + n / self.tck_hz

    def delay(self, s: Stream, seconds: float) -> None:
        """Idle clocks lasting at least ``seconds``."""
        clocks = math.ceil(seconds * self.tck_hz - 1e-9)
        if clocks <= 0:
            return
        if clocks <= 8:
            self._bits(s, clocks)
            return
        units = math.ceil(clocks / 8)
        while units:
            n = min(units, 0x10000)
            s.data += bytes((CLK_BYTES, (n - 1) & 0xFF, (n - 1) >> 8))
            s.delay_s += n * 8 / self.tck_hz
            self.state.t += self.command_s + n * 8 / self.tck_hz
            units -= n

    def _selected(self, data_port: bool) -> int:
        """The control lines that address the current chip's status/command (``data_port``
        False) or data port, strobes high."""
        cs = pins.CHIP_SELECTS[self.state.cs]
        return (pins.CTRL_IDLE & ~cs & ~pins.PS) | (pins.PS if data_port else 0)

    def _select(self, s: Stream, data_port: bool) -> None:
        want = self._selected(data_port)
        if self.state.ctrl != want:
            self._low(s, want)
            self._bits(s, 1)  # /CS and /PS setup before the strobe

    def _check_lead(self, data_port: bool) -> int:
        """Commands a read of the status (``data_port`` False) or of data will run before
        /RD falls: a release of D0-D7, a change of /CS and /PS (with its setup bit), /RD."""
        n = 1 if self.state.direction != pins.DATA_IN else 0
        return n + (2 if self.state.ctrl != self._selected(data_port) else 0) + 1

    def read_byte(self, s: Stream, slot: Slot, data_port: bool, waits: bytes = b"") -> None:
        """One read strobe: /RD low, the access time, sample D0-D7, /RD high, recovery.
        ``waits``: wait-on-I/O commands run while /RD is held low, before the sample."""
        if self.state.direction != pins.DATA_IN:
            self._high(s, 0, pins.DATA_IN)
        self._select(s, data_port)
        self._low(s, self.state.ctrl & ~pins.RD)
        self.rd_fell_at = self.state.t  # when the byte is driven: what a status read reports
        self._bits(s, 2)  # read access time
        if waits:
            s.data += waits
            s.waits += 1
            self.state.t += len(waits) * self.command_s
        s.data.append(GET_HIGH)
        self.state.t += self.command_s
        s.slots.append(slot)
        self._low(s, self.state.ctrl | pins.RD)
        self._bits(s, 1)  # recovery, /PS hold
        s.strobes += 1

    def write_byte(self, s: Stream, byte: int, data_port: bool) -> None:
        """One write strobe: drive D0-D7, /WR low one bit, /WR high, hold."""
        self._select(s, data_port)
        self._high(s, byte, pins.DATA_OUT)
        self._low(s, self.state.ctrl & ~pins.WR)
        self._bits(s, 1)  # /WR pulse width, data setup
        self._low(s, self.state.ctrl | pins.WR)
        self._bits(s, 1)  # data hold, recovery
        s.strobes += 1

    def status(self, s: Stream, kind: str, op: int) -> None:
        """A status read (``kind`` "check", "status" or "sync" for program operation ``op``)."""
        s.events.append(("status", len(s.slots)))
        self.read_byte(s, Slot(kind, op), data_port=False)

    def held_check(self, s: Stream, kind: str, op: int) -> None:
        """A busy check that waits in the adapter (busy pin wired): /CS, /PS and /RD go low and
        stay low while the engine waits for GPIOL1 (D0, the busy bit) to be low, then the
        status byte is sampled (so the check still shows what the chip said) and /RD rises.

        Right after a transfer on the same chip the engine first waits for busy to be *seen
        high* (0x88): the data sheet says busy is set "after the rising edge" of the strobe
        without saying how soon, so a read that starts within a few hundred ns could see it
        still clear and let the next transfer land while the chip is busy.  Waiting for the
        rise proves the chip took the transfer; it is safe only while the transfer's busy is
        certainly still to come or on (15-25 us typical, AN-706 2.11, against the ~3 us of
        commands between the strobe and the 0x88), so it is left out after anything that
        takes time (WAIT, /RST, another chip's operations, a held wait already done)."""
        st = self.state
        waits = bytes((WAIT_HIGH, WAIT_LOW)) if st.expect_busy == st.cs else bytes((WAIT_LOW,))
        s.events.append(("status", len(s.slots)))
        self.read_byte(s, Slot(kind, op), data_port=False, waits=waits)
        st.expect_busy = None

    def finish(self, s: Stream, read_pins: bool = True) -> Stream:
        """Lines idle, D0-D7 released, HI sampled (``read_pins``), send immediate."""
        if self.state.ctrl != pins.CTRL_IDLE:
            self._low(s, pins.CTRL_IDLE)
        if self.state.direction != pins.DATA_IN:
            self._high(s, 0, pins.DATA_IN)
        if read_pins:
            s.data.append(GET_LOW)
            s.slots.append(Slot("pins", -1))
        s.data.append(SEND_IMMEDIATE)
        self.state.t += (2 if read_pins else 1) * self.command_s
        return s

    def status_stream(self, chip: int, kind: str, op: int) -> Stream:
        """One status read of ``chip`` alone, in a stream of its own (a busy poll)."""
        s = self.begin(chip)
        self.status(s, kind, op)
        return self.finish(s, read_pins=False)

    def calibration_stream(self, polls: int, pad_s: float = 0.0, lead_s: float = 0.0,
                           first_s: float = 0.0) -> tuple[Stream, list[tuple[float, int]]]:
        """Idle clocks for ``lead_s`` (the busy wait still owed to the previous stream), a
        check, RDSIGS (a read command: it changes nothing on the chip), idle clocks for
        ``first_s``, ``polls`` status reads ``pad_s`` of idle clocks apart (0: back to back),
        a wait of the documented worst case, and RDSIGS's word (so that no command is left
        half done), on chip 0.  Also returns, for each poll, what runs from RDSIGS's /WR
        rising edge to the poll's /RD falling edge: (seconds of idle clocks, MPSSE
        commands).  The idle clocks last exactly that on the TCK; what a command costs is the
        adapter's, and :func:`.ftdi_busy.busy_bounds` finds it from polls at two paddings or more."""
        times = []
        for cost in (0.0, 1.0):  # a poll's stream time is linear in what a command costs
            c = StreamCompiler(self.tck_hz, self.busy_s, cost, self.busy_pin)
            c.keep, c.keep_level = self.keep, self.keep_level
            s, at = c.calibration_polls(polls, pad_s, lead_s, first_s)
            times.append(at)
        return s, [(idle, round(both - idle)) for idle, both in zip(*times)]

    def calibration_polls(self, polls: int, pad_s: float, lead_s: float,
                          first_s: float) -> tuple[Stream, list[float]]:
        s = self.begin(0)
        self.delay(s, lead_s)
        self.status(s, "check", 0)
        self.write_byte(s, int(Cmd.RDSIGS), data_port=False)
        # /WR rose one command and one bit before: the hold bit after it, and its own command
        t0 = self.state.t - 1 / self.tck_hz - self.command_s
        times = []
        for k in range(polls):
            self.delay(s, pad_s if k else first_s)
            self.status(s, "status", 0)
            times.append(self.rd_fell_at - t0)
        self.delay(s, DEFAULT_BUSY_US * 1e-6)
        self.read_byte(s, Slot("hi", 0), data_port=True)
        self.read_byte(s, Slot("lo", 0), data_port=True)
        return self.finish(s), times

    def pin_check_stream(self, hold_s: float = DEFAULT_BUSY_US * 1e-6) -> Stream:
        """What the busy pin relies on, seen on chip 0: a check, RDSIGS (a read command: it
        changes nothing), then one status read held low, sampled (D0-D7, then ADBUS with
        GPIOL1) right away, while the command's busy is on, and again ``hold_s`` later (the
        documented worst case: busy is over), then /RD high and RDSIGS's word.  Answer slots:
        check, D0-D7, ADBUS, D0-D7, ADBUS, the word's two bytes, and the final ADBUS."""
        s = self.begin(0)
        self.status(s, "check", 0)
        self.write_byte(s, int(Cmd.RDSIGS), data_port=False)
        self._high(s, 0, pins.DATA_IN)  # release D0-D7 for the chip
        self._select(s, data_port=False)
        self._low(s, self.state.ctrl & ~pins.RD)
        self._bits(s, 2)  # read access time
        for k in range(2):
            if k:
                self.delay(s, hold_s)
            s.data += bytes((GET_HIGH, GET_LOW))
            s.slots += [Slot("status", 0), Slot("pins", -1)]
        self._low(s, self.state.ctrl | pins.RD)
        self._bits(s, 1)
        s.strobes += 1
        self.read_byte(s, Slot("hi", 0), data_port=True)
        self.read_byte(s, Slot("lo", 0), data_port=True)
        return self.finish(s)

    def _timed_check(self, s: Stream, kind: str, op: int) -> None:
        """A busy check after the wait still owed to the chip's last transfer: idle clocks,
        shortened by the MPSSE commands run since (when they are counted), then a status read
        whose byte the transport judges when the answer comes back."""
        st = self.state
        cs = st.cs
        if self.command_s:
            # what the stream runs between the transfer and the check's /RD counts
            ran = st.t - st.owed_from.get(cs, 0.0) + self._check_lead(False) * self.command_s
            self.delay(s, st.owed.get(cs, 0.0) - ran)
        else:
            self.delay(s, st.owed.get(cs, 0.0))
        st.owed[cs] = 0.0
        self.status(s, kind, op)

    def _transfer(self, s: Stream, o: BusOp, i: int) -> None:
        """The transfer of a COMMAND, WRITE or READ operation ``i``, after its check."""
        if o.op is Op.COMMAND:
            self.write_byte(s, o.arg, data_port=False)
            s.events.append(("command", o.arg))
        elif o.op is Op.WRITE:
            self.write_byte(s, o.arg >> 8, data_port=True)
            self.write_byte(s, o.arg & 0xFF, data_port=True)
            s.events.append(("write", o.arg))
        else:
            s.events.append(("read", len(s.slots)))
            self.read_byte(s, Slot("hi", i), data_port=True)
            self.read_byte(s, Slot("lo", i), data_port=True)

    def compile(self, ops: Sequence[BusOp], first: int = 0,
                lead_s: float | dict[int, float] = 0.0, max_bytes: int | None = None,
                chip: int = 0, skip: frozenset[int] | set[int] = frozenset()) -> Stream:
        """Compile ``ops`` (program operations ``first``, ``first + 1``...).  ``lead_s``: busy
        wait still owed to the previous stream's last transfer, per chip (a number: to every
        chip).  ``max_bytes``: stop before the first operation that would make the stream
        longer (the FT232H's 1 KiB buffer); the index after the last operation compiled is
        :attr:`end`.  ``chip``: the chip selected where the stream starts (``Op.SELECT``
        changes it); ``skip``: operation indices left out (a repeat's units already taken).

        The busy wait is owed per chip: after an STT on chip 0 the stream goes on at once to
        chip 1's status read and STT, so a synchronized start's STTs are a few MPSSE commands
        apart (microseconds), not a busy wait apart."""
        s = self.begin(chip)
        st = self.state
        n_chips = len(pins.CHIP_SELECTS)
        st.owed = (dict(lead_s) if isinstance(lead_s, dict)
                   else {k: float(lead_s) for k in range(n_chips)})
        self.end = first + len(ops)
        for i, o in enumerate(ops, first):
            mark = s.mark(st)
            op = o.op
            cs = st.cs
            if i in skip and op is not Op.SELECT:
                continue
            if op in (Op.COMMAND, Op.WRITE, Op.READ, Op.SYNC):
                kind = "sync" if op is Op.SYNC else "check"
                if self.busy_pin:
                    self.held_check(s, kind, i)
                else:
                    self._timed_check(s, kind, i)
                if op is not Op.SYNC:
                    self._transfer(s, o, i)
                    if self.busy_pin:
                        st.expect_busy = cs
                    else:
                        st.owed[cs] = (RESET_WAIT_S if op is Op.COMMAND and o.arg == Cmd.RESET
                                       else self.busy_s)
                st.owed_from[cs] = st.t
            elif op is Op.STATUS:
                self.status(s, "status", i)
            elif op is Op.RESET:
                self._low(s, pins.CTRL_IDLE & ~pins.RST)
                self.delay(s, RST_LOW_S)
                self._low(s, pins.CTRL_IDLE)
                s.events.append(("reset", 0))
                s.strobes += 1
                st.owed = {}
                st.expect_busy = None
            elif op is Op.WAIT:
                self.delay(s, o.arg * 1e-6)
                st.expect_busy = None
                if not self.command_s:  # else the idle clocks count in the stream time
                    st.owed = {k: max(0.0, v - o.arg * 1e-6) for k, v in st.owed.items()}
            elif op is Op.SELECT:
                if not 0 <= o.arg < n_chips:
                    raise ValueError(f"chip select {o.arg}: the FT232H wiring has {n_chips}")
                if o.arg != st.cs:
                    st.expect_busy = None
                st.cs = o.arg
                s.events.append(("select", o.arg))
            else:  # pragma: no cover - the FT232H has no far side for WAIT_STATUS
                raise AssertionError(op)
            if max_bytes is not None and (len(s.data) + STREAM_TAIL > max_bytes
                                          or len(s.slots) + 1 > max_bytes):
                if i == first:
                    raise ValueError(f"{o.describe()} alone does not fit a stream of "
                                     f"{max_bytes} bytes")
                self.state = st = s.rollback(mark)
                self.end = i
                break
        self.finish(s)
        # what is still owed when the stream ends (the commands after each last transfer ran)
        self.owed_after = ({k: max(0.0, v - (st.t - st.owed_from.get(k, 0.0)))
                            for k, v in st.owed.items()} if self.command_s else st.owed)
        return s


def units_of(ops: Sequence[BusOp]) -> list[tuple[int, int]]:
    """Split a program into units ``(start, end)``: a command with its data words, or one other
    operation.  A unit is what gets repeated."""
    units: list[tuple[int, int]] = []
    i = 0
    while i < len(ops):
        j = i + 1
        if ops[i].op is Op.COMMAND:
            while j < len(ops) and ops[j].op in (Op.WRITE, Op.READ):
                j += 1
        units.append((i, j))
        i = j
    return units


_KNOWN = frozenset(int(c) for c in Cmd)


def is_action(o: BusOp) -> bool:
    """An operation that acts on the chip: /RST, or a command that is not a plain load or read
    (an unknown opcode sent with ``LM629.raw`` counts as one: nothing says it is harmless)."""
    return o.op is Op.RESET or (o.op is Op.COMMAND and (o.arg in ACTIONS or o.arg not in _KNOWN))


def chips_of_units(ops: Sequence[BusOp], start_chip: int = 0) -> dict[int, int]:
    """The chip each operation addresses (a program starts on chip 0; SELECT switches)."""
    chip, out = start_chip, {}
    for i, o in enumerate(ops):
        if o.op is Op.SELECT:
            chip = o.arg
        out[i] = chip
    return out


def streams_of(ops: Sequence[BusOp], cut_actions: bool = True) -> list[list[tuple[int, int]]]:
    """Group units into streams: a new stream before an action that follows a transfer on the
    same chip (/RST: on any chip).  An action on another chip does not cut: its loads were
    checked in earlier programs, so a synchronized start on several chips is one stream.
    ``cut_actions`` False (busy pin wired: every transfer waits until the chip has taken the
    one before): one stream, as long as the program needs no /RST cut."""
    streams: list[list[tuple[int, int]]] = [[]]
    transfers: set[int] = set()
    chip = 0
    for u in units_of(ops):
        o = ops[u[0]]
        if o.op is Op.SELECT:
            chip = o.arg
        elif is_action(o) and ((cut_actions and chip in transfers)
                               or (o.op is Op.RESET and transfers)):
            streams.append([])
            transfers = set()
        streams[-1].append(u)
        if o.op in (Op.COMMAND, Op.WRITE, Op.READ):
            transfers.add(chip)
    return [s for s in streams if s]


__all__ = ["StreamCompiler", "CompilerState", "Mark", "Stream", "Slot", "units_of",
           "streams_of", "chips_of_units", "is_action", "ACTIONS", "DEFAULT_TCK_HZ",
           "DEFAULT_BUSY_US", "RST_LOW_S", "STREAM_TAIL"]
