"""``sim://``: the bundled chip model, in-process.

URL parameters (all optional)::

    sim://?chip=lm628&clock=6000000&strict=1&fault=reset|busy|rst&record=1
          &lines=500&reversed=1&...      (motor and encoder: see model.params.MotorParams)
          &axes=2                        (N chips, each with its own motor, on one bus and clock)

Each bus strobe costs ``CYCLE_S`` of simulated time (a fast host's bus cycle); while the chip
is busy, the busy check polls every ``poll_interval_s``.  ``chip.clock`` is the model's clock:
``sleep()`` runs the chip (and its motor) forward, it never sleeps on the wall clock.
"""

from __future__ import annotations

import threading
from typing import cast

from lm629_host.urls import PortURL
from lm629_host.bus.program import Op, Program, TraceCallback
from lm629_host.sim.build import SIM_OPTIONS, build_bus, sim_options
from lm629_host.sim.clock import SimClock
from lm629_host.sim.model import ChipBus, ChipModel, Violation, chips_of
from lm629_host.sim.vcd import close_probe, probe, vcd_of
from lm629_host.sim.wiring import BentChip, Miswiring, wiring_of
from lm629_host.transports.reports import PortInfo
from lm629_host.transports.cycle import CycleTransport

#: simulated duration of one /RD or /WR strobe cycle, recovery included
CYCLE_S = 0.5e-6

_STATUS, _COMMAND, _WRITE, _READ = Op.STATUS, Op.COMMAND, Op.WRITE, Op.READ
_RESET, _WAIT, _SYNC, _WAIT_STATUS = Op.RESET, Op.WAIT, Op.SYNC, Op.WAIT_STATUS
_SELECT = Op.SELECT


class ModelChips:
    """What every simulator transport (``sim``, ``sim+avr``, ``sim+emu``, ``sim+ftdi``) tells
    the driver about its chip model, so that nothing above the transports looks at the model:
    the chip's clock (:attr:`Transport.clock_hz`), how many chips were built
    (:attr:`Transport.chip_count`), and strict mode: whether a host protocol violation raises
    (:attr:`strict`, :meth:`set_strict`) and the violations recorded (:meth:`take_violations`),
    for a test harness (the pytest plugin).  Put before the transport class in the bases."""

    model: ChipModel | ChipBus  #: the chip (or the chips) on the simulated bus
    models: list[ChipModel]  #: the chips on chip selects 0, 1, ...
    lock: threading.RLock  #: the transport's (Transport.lock)

    @property
    def clock_hz(self) -> float:
        return float(self.model.clock_hz)

    @property
    def chip_count(self) -> int:
        return len(self.models)

    @property
    def strict(self) -> bool:
        """True when a host protocol violation raises :class:`ProtocolViolation` (the URL's
        ``strict=``); either way it is recorded for :meth:`take_violations`."""
        return self.models[0].params.strict

    def set_strict(self, strict: bool) -> bool:
        """Make host protocol violations raise (True) or only be recorded (False); returns
        the setting before, to put back."""
        with self.lock:
            before = self.strict
            for m in self.models:
                m.params.strict = strict
            return before

    def take_violations(self) -> list[Violation]:
        """The host protocol violations the simulated chips recorded since the last call
        (strict or not), oldest first, each with its simulated time; forgotten once taken."""
        with self.lock:
            recorded = self.model.violations  # one list for every chip of a bus
            taken = list(recorded)
            del recorded[:]
            return taken


class SimTransport(ModelChips, CycleTransport):
    """Bus cycles straight into an in-process :class:`ChipModel`."""

    #: its URL options, one table (the board's rows and the simulator's)
    options = SIM_OPTIONS

    scheme = "sim"
    simulated = True
    has_reset_line = True

    def __init__(self, model: ChipModel | ChipBus, url: str | PortURL = "sim://", *,
                 trace: TraceCallback | None = None, wiring: Miswiring | None = None) -> None:
        super().__init__(url, trace=trace)
        self.model = model
        #: ``wiring=``: the model seen through miswired data lines (None: a correct bench);
        #: its programs take the general loop, whose strobes go through it
        self.bent = BentChip(model, wiring) if wiring is not None else None
        #: the chips on the bus, chip select 0 first (one chip: ``[model]``)
        self.models = chips_of(model)
        self.chip_selects = len(self.models)
        self.clock = SimClock(model)
        self._hz = model.clock_hz
        self._cycle_clocks = max(1, round(CYCLE_S * self._hz))
        #: the busy loop's sleep between two polls, in the model's clocks
        self._poll_clocks = max(0, round(self.poll_interval_s * self._hz))
        #: False: make every busy poll (the reference the skip is tested against); never
        #: skipped through miswired lines (the skip reads the chip's own busy, not the pins')
        self.skip_known_busy = self.bent is None
        #: a chip of the model, whose clock count is the model's (the chips of a bus share one
        #: oscillator): read per strobe as a plain attribute (``ChipBus.tick`` is a property)
        self._counter = self.models[0]
        #: what the strobes reach (:meth:`_select_chip`): the chip whose /CS is low
        self._target: ChipModel | ChipBus | BentChip = model
        self._select_chip(0)

    def _wait_not_busy(self, program: Program, index: int, words: list[int],
                       tracing: bool = True) -> int:
        """The busy check of the one cycle loop (:meth:`CycleTransport._execute`), with the
        polls the model's busy deadline already answers skipped (:meth:`_skip_busy_polls`)
        and the poll that finds busy clear made straight on the model: the same strobes at
        the same ticks and the same counters as the full poll loop, which runs instead with
        a trace (every poll shown), through miswired lines, or when a poll still finds the
        chip busy (tests/chip/test_waits_and_busy_checks.py compares the two)."""
        skip = not tracing and self.bent is None and self.skip_known_busy
        until = self._target.busy_deadline() if skip else None
        if until is None:
            return super()._wait_not_busy(program, index, words, tracing)
        c = self._cycle_clocks
        t0 = self._counter.tick
        at = t0 + c  # the first poll's read
        skipped = 0
        if until > at:  # _skip_busy_polls, with the deadline already read
            s = self._poll_clocks
            skipped = -(-(until - at) // (c + s))  # reads before the deadline
            hz = self._hz
            if (t0 + skipped * c + (skipped - 1) * s) / hz >= t0 / hz + program.busy_timeout_s:
                # the full loop times out before busy ends: let it, with its own message
                return super()._wait_not_busy(program, index, words, tracing)
            at += skipped * (c + s)
        # one advance over the skipped polls and the read's cycle: the model runs the same
        # samples whatever steps it is advanced in (see _skip_busy_polls)
        self.model.advance_to(at)
        status = self._target.read_status()
        stats = self.stats
        stats.bus_cycles += skipped + 1
        stats.busy_polls += skipped + 1
        if status & 1:  # busy after all (a reset moved its end): the full loop goes on
            self.model.advance_to(at + self._poll_clocks)
            return super()._wait_not_busy(program, index, words, tracing)
        return status

    def _skip_busy_polls(self, deadline: float) -> int:
        """Skip the busy polls the model's busy deadline already answers.

        The poll loop reads the status one strobe (``c`` clocks) after the last cycle, then
        sleeps ``poll_interval_s`` (``s`` clocks) while busy: read ``j`` happens at
        ``t0 + (j + 1) c + j s``.  Every read before the model's busy deadline answers busy, so
        the clock jumps over them to where the first read at or after the deadline happens;
        that read is made for real by the caller.  The model runs the same samples either way
        (it is advanced to the same ticks, only in fewer steps), so counters, simulated time
        and the chip's state are those of the full loop (tests/test_sim_fastpath.py)."""
        m = self.model
        if not self.skip_known_busy:
            return 0
        until = m.busy_deadline()
        c = self._cycle_clocks
        t0 = m.tick
        if until is None or until <= t0 + c:
            return 0  # busy has no known end (fault=busy), or the first read finds it clear
        s = self._poll_clocks
        k = -(-(until - t0 - c) // (c + s))  # reads before the deadline
        if (t0 + k * c + (k - 1) * s) / m.clock_hz >= deadline:
            return 0  # the full loop would time out: let it, with its own message
        m.advance_to(t0 + k * (c + s))
        return k

    @classmethod
    def from_url(cls, url: str | PortURL, *, trace: TraceCallback | None = None) -> SimTransport:
        opts = sim_options(url, cls.options, defaults=True)  # the one parse of the URL
        model = build_bus(url, opts)
        vcd = vcd_of(url, opts)
        if vcd is not None:  # the bus drawn into a VCD: every busy poll made, as on a bench
            model = probe(model, *vcd, cycle_clocks=max(1, round(CYCLE_S * model.clock_hz)))
        t = cls(model, url, trace=trace, wiring=wiring_of(url, opts))
        t.skip_known_busy = t.skip_known_busy and vcd is None
        return t

    def close(self) -> None:
        close_probe(self.model)

    @classmethod
    def list_ports(cls) -> list[PortInfo]:
        return [PortInfo("sim://", "the bundled chip simulator (always there)")]

    def describe(self) -> str:
        return f"{self.url} ({self.models[0].describe(len(self.models))})"

    def _select_chip(self, chip: int) -> None:
        """/CS of ``chip``: the strobes that follow go straight to that chip (to the bus itself
        on a select with no chip, where a read finds FF; through the miswired lines when
        ``wiring=`` bends them), with no routing per strobe."""
        m = self.model
        picked: ChipModel | None = m.select(chip) if isinstance(m, ChipBus) else m
        if self.bent is not None:
            self._target = self.bent
        else:
            self._target = m if picked is None else picked

    # the strobes: the model's clock one bus cycle on, then the byte; written out per strobe,
    # the host cost of every command
    def _read_status(self) -> int:
        self.model.advance_to(self._counter.tick + self._cycle_clocks)
        return self._target.read_status()

    def _write_command(self, byte: int) -> None:
        self.model.advance_to(self._counter.tick + self._cycle_clocks)
        self._target.write_command(byte)

    def _write_word(self, word: int) -> None:
        advance, chip, c = self.model.advance_to, self._target, self._cycle_clocks
        at = self._counter.tick + c
        advance(at)
        chip.write_data(word >> 8)
        advance(at + c)
        chip.write_data(word & 0xFF)

    def _read_word(self) -> int:
        advance, chip, c = self.model.advance_to, self._target, self._cycle_clocks
        at = self._counter.tick + c
        advance(at)
        hi = chip.read_data()
        advance(at + c)
        return (hi << 8) | chip.read_data()

    def _pulse_reset(self) -> None:
        m = self.model
        m.advance_to(m.tick + 8)  # /RST held low for 8 clocks, the datasheet minimum
        m.reset_pulse()

    def _sleep_until_status(self, mask: int, deadline: float) -> None:
        """Straight to the next status change (see :meth:`SimClock.advance_until_status`);
        through miswired lines the bits differ, so then one poll period at a time."""
        if self.bent is not None:
            return super()._sleep_until_status(mask, deadline)
        cast(SimClock, self._inner_clock).advance_until_status(mask, deadline)

    def _hi(self) -> bool:
        return self.model.hi
