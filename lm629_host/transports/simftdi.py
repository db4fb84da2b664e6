"""``sim+ftdi://``: the real FT232H transport and the real pyftdi, on an emulated FT232H wired
to the chip model (:mod:`lm629_host.ftdi_emu`).

URL parameters: every ``sim://`` parameter (chip, clock, strict, fault, record, motor...), the
``ftdi://`` options (``latency``, ``busy_us``, ``frequency``), and the emulation's costs:
``usb_us`` (per bulk transfer, default 125) and ``command_ns`` (per MPSSE command, default 500).

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

from .. import ftdi_pins
from ..errors import ProtocolViolation
from ..ftdi_emu import EmulatedBackend, EmulatedFT232H
from ..program import Program, ProgramResult, TraceCallback
from . import query_params
from .base import Clock
from .ftdi import (DEFAULT_LATENCY_MS, DEFAULT_TCK_HZ, FT232H_PID, FTDI_VID,
                   FtdiTransport, open_mpsse)
from ..model import chips_of
from .sim import build_bus

#: URL parameters that belong to this transport rather than to the chip model
OWN_PARAMS = frozenset({"latency", "busy_us", "frequency", "usb_us", "command_ns"})


class EmulatedClock(Clock):
    """The emulated FT232H's time; ``sleep`` runs the device (and the chip) forward."""

    def __init__(self, device: EmulatedFT232H) -> None:
        self.device = device

    def now(self) -> float:
        return self.device.now()

    def sleep(self, seconds: float) -> None:
        self.device.advance_ns(round(seconds * 1e9))


class SimFtdiTransport(FtdiTransport):
    scheme = "sim+ftdi"

    @classmethod
    def from_url(cls, url: str, *, trace: TraceCallback | None = None) -> SimFtdiTransport:
        model = build_bus(url, allowed=OWN_PARAMS, limit=len(ftdi_pins.CHIP_SELECTS))
        q = query_params(url)

        def num(name: str, default: float, lo: float, hi: float) -> float:
            text = q.get(name)
            if text is None:
                return default
            try:
                value = float(text)
            except ValueError:
                raise ValueError(f"{url}: {name}={text!r} is not a number") from None
            if not lo <= value <= hi:
                raise ValueError(f"{url}: {name}={text} is outside {lo:g}..{hi:g}")
            return value

        latency = int(num("latency", DEFAULT_LATENCY_MS, 1, 255))
        busy_us = None if q.get("busy_us", "auto") == "auto" else num("busy_us", 0, 0, 65535)
        frequency = num("frequency", DEFAULT_TCK_HZ, 1e5, 30e6)
        usb_us = num("usb_us", 125, 0, 1e6)
        command_ns = num("command_ns", 500, 0, 1e6)
        strict = model.params.strict
        for chip in chips_of(model):
            chip.params.strict = False
        device = EmulatedFT232H(model, usb_ns=round(usb_us * 1000), command_ns=round(command_ns))
        backend = EmulatedBackend([device])
        usb_dev = usb.core.find(backend=backend, idVendor=FTDI_VID, idProduct=FT232H_PID)
        ftdi = open_mpsse(url, latency, frequency, device=usb_dev)
        # busy_us None: measured at open on the chip model, through the emulated adapter
        t = cls(ftdi, url, trace=trace, clock=EmulatedClock(device),
                busy_s=None if busy_us is None else busy_us * 1e-6, tck_hz=frequency,
                latency_ms=latency)
        t.model, t.device, t.strict = model, device, strict
        t.models = chips_of(model)  # type: ignore[attr-defined]
        return t

    model: object
    device: EmulatedFT232H
    strict: bool

    def describe(self) -> str:
        p = self.model.params  # type: ignore[attr-defined]
        return (f"{self.url} (FT232H transport on an emulated FT232H, simulated "
                f"{p.variant.upper()} at {p.clock_hz / 1e6:g} MHz)")

    def execute(self, program: Program) -> ProgramResult:
        violations = self.model.violations  # type: ignore[attr-defined]
        mark, tmark, hits = len(violations), len(self.device.timing_violations), self.busy_hits
        try:
            return super().execute(program)
        finally:
            if self.strict:
                timing = self.device.timing_violations[tmark:]
                if timing:
                    raise ProtocolViolation("FT232H stream broke the chip's bus timing: "
                                            + "; ".join(timing))
                new = violations[mark:]
                if new and self.busy_hits == hits:
                    raise ProtocolViolation("host protocol violation: " + "; ".join(new))


__all__ = ["SimFtdiTransport", "EmulatedClock"]
