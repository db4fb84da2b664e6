"""``sim+ftdi://``: the real FT232H transport and the real pyftdi, on an emulated FT232H wired
to the chip model (:mod:`lm629_host.sim.ftdi`).

URL parameters: every ``sim://`` parameter (chip, clock, strict, fault, record, motor...), the
``ftdi://`` options (``latency``, ``busy_us``, ``frequency``, ``busy_pin``: the emulated
adapter is then wired as ``connections("ft232h", busy_pin=True)``), and the emulation's costs:
``usb_us`` (per bulk transfer, default 125), ``command_ns`` (per MPSSE command, default 500)
and ``live_status`` (``0``: the emulated chip latches its status byte at /RD falling even with
the busy pin wired, the case the transport's pin check refuses).

The clock is the emulated FT232H's: USB transfers, MPSSE commands, idle clocks and
``clock.sleep`` all advance it, and the chip model with it.  Nothing sleeps on the wall clock.

Strict mode.  The model is built non-strict and strictness is applied here, after each
program: a protocol violation raises :class:`~lm629_host.errors.ProtocolViolation` unless the
transport itself saw busy before a transfer during that program.  That exception is the FT232H
design at work, not a hole: a stream makes its transfers before its status reads come back, so
on a chip that holds busy too long (``fault=busy``, ``stretch_busy``) it does write while busy,
sees it, and repeats or raises :class:`~lm629_host.errors.BusyTimeout`.  Timing violations at
the pins (a strobe too short, data sampled too early, bus contention) always raise when strict.
"""

from __future__ import annotations

import usb.core

from lm629_host.wiring import ft232h as ftdi_pins
from lm629_host.clock import Clock
from lm629_host.errors import ProtocolViolation
from lm629_host.bus.program import Program, ProgramResult, TraceCallback
from lm629_host.sim.build import SIM_ROWS, build_bus, sim_options
from lm629_host.sim.vcd import vcd_of
from lm629_host.sim.wiring import wiring_of
from lm629_host.sim.ftdi import EmulatedBackend, EmulatedFT232H
from lm629_host.sim.model import ChipBus, ChipModel, Violation, chips_of
from lm629_host.urls import Option, PortURL
from lm629_host.transports.reports import Check, PortInfo
from lm629_host.transports.ftdi import FtdiTransport
from lm629_host.transports.ftdi_open import FT232H_PID, FTDI_VID, busy_pin_of, open_mpsse
from lm629_host.transports.ftdi_open import OPTIONS as FTDI_OPTIONS
from lm629_host.transports.sim import ModelChips

#: URL options that belong to this transport rather than to the chip model: the FT232H
#: transport's and the emulation's costs
OPTIONS = (*FTDI_OPTIONS,
           Option("usb_us", "float", 125, 0, 1e6, "us"),
           Option("command_ns", "float", 500, 0, 1e6, "ns"),
           # whether the emulated chip shows its status live while /RD is held low (the
           # unknown a busy pin relies on: docs/ftdi.md); default: live with busy_pin
           Option("live_status", "str", "auto", choices=("auto", "0", "1")),
           *SIM_ROWS)


class EmulatedClock(Clock):
    """The emulated FT232H's time; ``sleep`` runs the device (and the chip) forward."""

    def __init__(self, device: EmulatedFT232H) -> None:
        self.device = device

    def now(self) -> float:
        return self.device.now()

    def sleep(self, seconds: float) -> None:
        self.device.advance_ns(round(seconds * 1e9))


class SimFtdiTransport(ModelChips, FtdiTransport):
    scheme = "sim+ftdi"
    options = OPTIONS  #: its URL options, one table (parsed once, and listed by a message)
    simulated = True

    @classmethod
    def from_url(cls, url: str | PortURL, *, trace: TraceCallback | None = None) -> SimFtdiTransport:
        opts = sim_options(url, OPTIONS, defaults=True)  # the one parse of the URL
        model = build_bus(url, opts, limit=len(ftdi_pins.CHIP_SELECTS))
        latency, busy_us, frequency = opts["latency"], opts["busy_us"], opts["frequency"]
        usb_us, command_ns = opts["usb_us"], opts["command_ns"]
        strict = model.params.strict
        for chip in chips_of(model):
            chip.params.strict = False
        busy_pin = busy_pin_of(opts, url)
        live = {"auto": None, "0": False, "1": True}[str(opts["live_status"]).lower()]
        device = EmulatedFT232H(model, usb_ns=round(usb_us * 1000), command_ns=round(command_ns),
                                busy_pin=busy_pin is not None, live_status=live,
                                wiring=wiring_of(url, opts))
        vcd = vcd_of(url, opts)
        if vcd is not None:
            device.chip_pins.write_vcd(*vcd)
        backend = EmulatedBackend([device])
        usb_dev = usb.core.find(backend=backend, idVendor=FTDI_VID, idProduct=FT232H_PID)
        ftdi = open_mpsse(url, latency, frequency, device=usb_dev)
        # busy_us None: measured at open on the chip model, through the emulated adapter
        if opts["heartbeat"] is not None:  # ADBUS7 is the heartbeat, not a second /CS
            device.chip_pins.chip_select_lines = ftdi_pins.CHIP_SELECTS[:1]
        t = cls(ftdi, url, trace=trace, clock=EmulatedClock(device),
                busy_s=None if busy_us is None else busy_us * 1e-6, tck_hz=frequency,
                latency_ms=latency, busy_pin=busy_pin, heartbeat=opts["heartbeat"],
                heartbeat_hz=opts["heartbeat_hz"])
        t.attach(model, device, strict)
        return t

    model: ChipModel | ChipBus
    models: list[ChipModel]  #: the chips on the emulated adapter's chip selects
    device: EmulatedFT232H
    #: strict mode, applied here after each program (the module doc says why)
    _strict: bool
    #: the violations strict mode counts (those of a program that saw no busy), not yet taken
    _violations: list[Violation]

    def attach(self, model: ChipModel | ChipBus, device: EmulatedFT232H, strict: bool) -> None:
        """The chip model behind the emulated adapter, the adapter, and strict mode's start."""
        self.model, self.device, self.models = model, device, chips_of(model)
        self._strict, self._violations = strict, []

    @property
    def strict(self) -> bool:
        return self._strict

    def set_strict(self, strict: bool) -> bool:
        with self.lock:
            before, self._strict = self._strict, strict
            return before

    def take_violations(self) -> list[Violation]:
        """The violations strict mode counts, strict or not (a transfer the transport saw
        busy before and repeated is the FT232H design at work, not one of them)."""
        with self.lock:
            taken, self._violations = self._violations, []
            del self.model.violations[:]
            return taken

    @classmethod
    def list_ports(cls) -> list[PortInfo]:
        return []  # the FT232H's adapters are not this simulator's

    @classmethod
    def doctor(cls, port: str | None = None) -> list[Check]:
        return []

    def close(self) -> None:
        super().close()
        self.device.chip_pins.close_vcd()

    def describe(self) -> str:
        chips = self.models[0].describe(len(self.models))
        return f"{self.url} (FT232H transport on an emulated FT232H, {chips})"

    def _execute(self, program: Program) -> ProgramResult:
        violations, timing_seen = self.model.violations, self.device.chip_pins.timing_violations
        mark, tmark, hits = len(violations), len(timing_seen), self.busy.hits
        try:
            return super()._execute(program)
        finally:
            new = violations[mark:] if self.busy.hits == hits else []
            self._violations += new
            if self._strict:
                timing = timing_seen[tmark:]
                if timing:
                    raise ProtocolViolation("FT232H stream broke the chip's bus timing: "
                                            + "; ".join(timing))
                if new:
                    raise ProtocolViolation("host protocol violation: " + "; ".join(new))


__all__ = ["SimFtdiTransport", "EmulatedClock"]
