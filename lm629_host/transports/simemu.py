"""``sim+emu://?baud=115200&...``: the link protocol to the Python bridge
(:class:`~lm629_host.sim.bridge.BridgeEmulator`), in process and in simulated time (the other
parameters are the ``sim://`` ones).  The whole serial path without a pseudo-terminal or the AVR
toolchain."""

from __future__ import annotations

import dataclasses

from lm629_host.wiring.uno import CHIP_SELECTS
from lm629_host.sim.bridge import BUS_CYCLE_S, MULTI_AXIS_INFO, ONE_CHIP_INFO, BridgeEmulator, EmuPipe
from lm629_host.sim.build import SIM_ROWS, build_bus, sim_options
from lm629_host.sim.vcd import close_probe, probe, vcd_of
from lm629_host.sim.wiring import wiring_of
from lm629_host.sim.model import ChipBus, ChipModel, chips_of
from lm629_host.sim.usb import OPTIONS as USB_ROWS
from lm629_host.sim.usb import adapter_of, wrap_usb
from lm629_host.bridge.protocol.pipe import Pipe
from lm629_host.bus.program import TraceCallback
from lm629_host.bus.url_board import BOARD_ROWS
from lm629_host.urls import Option, PortURL, port_url
from lm629_host.transports.failsafe import FailsafeOptions
from lm629_host.transports.link import LINK_OPTIONS, LinkTransport
from lm629_host.transports.session import DEFAULT_RETRIES
from lm629_host.transports.sim import ModelChips


#: the options of ``sim+emu://``, one table: the board's, the link's (a line without wire
#: time: ``baud=0``), the far end's HELLO, a line's top rate, the USB adapter's, the chip model's
OPTIONS = (
    *BOARD_ROWS,
    *(dataclasses.replace(o, default=115200, off=0, unit="baud (0: no wire time)")
      if o.name == "baud" else o for o in LINK_OPTIONS),
    Option("bridge", "str", "", choices=("", "1", str(len(CHIP_SELECTS)))),
    Option("max_baud", "int", 0, 300, 4_000_000, "baud", off=0),  # 0: any
    *USB_ROWS,
    *SIM_ROWS,
)


class EmuLinkTransport(ModelChips, LinkTransport):
    """``sim+emu://?baud=115200&...``: the link protocol to the Python bridge emulator, in
    process and in simulated time (the other parameters are the ``sim://`` ones).  The whole
    serial path without a pseudo-terminal or the AVR toolchain."""

    scheme = "sim+emu"
    options = OPTIONS  #: its URL options, one table (parsed once, and listed by a message)
    simulated = True
    model: ChipModel | ChipBus  #: the chip (or the chips) behind the emulated bridge
    models: list[ChipModel]  #: the chips on the bridge's chip selects 0, 1, ...
    emulator: BridgeEmulator  #: the emulated bridge
    #: the emulated bridge answers at once: the margin only covers rounding
    margin_s = 1e-3

    def __init__(self, emulator: BridgeEmulator, model: ChipModel | ChipBus, pipe: Pipe,
                 url: str | PortURL, *, trace: TraceCallback | None = None,
                 retries: int = DEFAULT_RETRIES, baud: int | None = None,
                 margin_s: float = 1e-3, fast_baud: int = 0,
                 failsafe: FailsafeOptions | None = None) -> None:
        self.margin_s = margin_s
        self.model = model
        self.models = chips_of(model)
        self.emulator = emulator
        super().__init__(pipe, url, trace=trace, retries=retries, baud=baud, fast_baud=fast_baud,
                         failsafe=failsafe)

    @classmethod
    def from_url(cls, url: str | PortURL, *, trace=None) -> EmuLinkTransport:
        return open_emulated(url, trace=trace)

    def close(self) -> None:
        super().close()
        close_probe(self.model)


def open_emulated(url: str | PortURL = "sim://", *, baud: int | None = None,
                  retries: int = DEFAULT_RETRIES, wrap=None, trace=None, margin_s: float = 1e-3) -> EmuLinkTransport:
    """A :class:`EmuLinkTransport` to an emulated bridge over a model built from the simulator
    ``url`` (``sim://?record=1`` ...), all in simulated time.

    ``baud``: the simulated line (``None``: the URL's ``baud=``, else 115200; 0: no wire time).
    URL ``fast_baud=N``: switch the line to N baud after the handshake (SET_BAUD);
    ``max_baud=N``: the line carries nothing faster (a USB serial adapter that cannot), so
    such a switch falls back.
    ``usb=none|uno|ftdi|cdc`` (``usb_seed=``, ``latency_ms=``): the USB adapter between the
    host and the bridge's UART (:mod:`lm629_host.sim.usb`), outside any ``wrap``.
    ``wrap(pipe) -> pipe`` inserts a wrapper between host and bridge (e.g. a
    :class:`~lm629_host.sim.faults.FaultPipe`).  The model is ``transport.model``, the far end
    ``transport.emulator``.
    """
    url_of = port_url(url)
    # checked before the far end is built, as a real port's before it opens
    opts = sim_options(url_of, OPTIONS, defaults=True)
    if baud is None:
        baud = opts["baud"]
    # bridge=1: a one-chip bridge (firmware 1.0: no chip selects); else the multi-axis HELLO
    info = ONE_CHIP_INFO if opts["bridge"] == "1" else MULTI_AXIS_INFO
    model = build_bus(url, opts, limit=info.chip_selects)
    vcd = vcd_of(url, opts)
    if vcd is not None:  # the bridge's strobes drawn into a VCD, one bus cycle each
        model = probe(model, *vcd, cycle_clocks=max(1, round(BUS_CYCLE_S * model.clock_hz)))
    emu = BridgeEmulator(model, info, wiring=wiring_of(url, opts))
    pipe = EmuPipe(emu, baud=baud or None, max_baud=opts["max_baud"] or None)
    usb = adapter_of(url_of, opts)
    outer = wrap_usb(wrap(pipe) if wrap is not None else pipe, usb)
    return EmuLinkTransport(emu, model, outer, url, trace=trace,
                            retries=opts["retries"] if "retries" in url_of.query() else retries,
                            baud=baud or None, fast_baud=opts["fast_baud"],
                            failsafe=FailsafeOptions.of(opts),
                            margin_s=margin_s + (usb.worst_s if usb is not None else 0.0))


__all__ = ["EmuLinkTransport", "open_emulated"]
