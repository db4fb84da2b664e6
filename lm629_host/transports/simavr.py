"""``sim+avr://``: the real bridge firmware, compiled for the ATmega328P, running in simavr
against the chip model; the host side is the unchanged link protocol (:class:`LinkTransport`).

URL parameters::

    sim+avr://?baud=115200&fast_baud=1000000&firmware=path/to/lm629_bridge.elf&axes=2&<any sim:// parameter>

``baud``: the simulated serial line (115200 or 1000000 with the images ``make -C
firmware_bridge`` builds; another rate needs ``firmware=`` built with ``make BAUD=...``).
``fast_baud``: after the handshake, switch the line to this rate (SET_BAUD; default: stay at
``baud``, so that the URL's rate is the one measured).  Every bus cycle the chip model sees
was made by the compiled AVR code; the transport's clock is the AVR's simulated time.
``usb=none|uno|ftdi|cdc`` (``usb_seed=``, ``latency_ms=``): the USB adapter between the host and
the firmware's UART (:mod:`lm629_host.sim.usb`; ``uno`` is the 16U2 of an Arduino Uno R3).
``transport.model`` is the chip, ``transport.sim`` the AVR.
"""

from __future__ import annotations

from pathlib import Path

from lm629_host.wiring.uno import CHIP_SELECTS
from lm629_host.bus.program import TraceCallback
from lm629_host.sim.avr import AvrPipe, AvrSim
from lm629_host.sim.harness import BUILT_BAUDS, DEFAULT_BAUD, check_firmware, firmware_path
from lm629_host.sim.build import SIM_ROWS, build_bus, sim_options
from lm629_host.sim.vcd import vcd_of
from lm629_host.sim.wiring import wiring_of
from lm629_host.sim.model import chips_of
from lm629_host.sim.usb import OPTIONS as USB_ROWS
from lm629_host.sim.usb import Adapter, adapter_of, wrap_usb
from lm629_host.bus.url_board import BOARD_ROWS
from lm629_host.urls import Option, PortURL, with_defaults
from lm629_host.transports.failsafe import FailsafeOptions
from lm629_host.transports.link import LINK_OPTIONS, LinkTransport
from lm629_host.transports.session import DEFAULT_RETRIES
from lm629_host.transports.sim import ModelChips

#: URL options of this transport: the board's, the link's, its own, the USB adapter's and the
#: chip model's (one table, parsed once)
OPTIONS = (*BOARD_ROWS, *with_defaults(LINK_OPTIONS, baud=DEFAULT_BAUD),
           Option("firmware", "str", ""), *USB_ROWS, *SIM_ROWS)


class SimAvrTransport(ModelChips, LinkTransport):
    """The link protocol to the compiled firmware in simavr, in simulated time."""

    scheme = "sim+avr"
    options = OPTIONS  #: its URL options, one table (parsed once, and listed by a message)
    simulated = True
    #: the wire time estimate counts 10 bits a byte, simavr's UART takes 11: the margin covers
    #: that (10% of two 253-byte frames at 115200 baud is 4.8 ms) and the firmware's own time
    margin_s = 0.02

    def __init__(self, sim: AvrSim, url: str | PortURL, *, trace: TraceCallback | None = None,
                 retries: int = DEFAULT_RETRIES, baud: int = DEFAULT_BAUD,
                 fast_baud: int = 0, failsafe: FailsafeOptions | None = None,
                 usb: Adapter | None = None) -> None:
        """``usb``: the USB adapter between host and bridge (:meth:`from_url` makes it from the
        URL's ``usb=`` rows, parsed with the rest of the URL); None: none."""
        self.sim = sim
        self.model = sim.model
        #: the chips on the bridge's chip selects 0, 1, ... (``sim+avr://?axes=N``)
        self.models = chips_of(sim.model)
        pipe = wrap_usb(AvrPipe(sim), usb)
        if usb is not None:
            self.margin_s = type(self).margin_s + usb.worst_s
        super().__init__(pipe, url, trace=trace, retries=retries, baud=baud, fast_baud=fast_baud,
                         failsafe=failsafe)

    @classmethod
    def from_url(cls, url: str | PortURL, *, trace: TraceCallback | None = None) -> SimAvrTransport:
        # checked before simavr starts, as a real port's before it opens
        opts = sim_options(url, OPTIONS, defaults=True)
        baud = opts["baud"]
        if opts["firmware"]:
            firmware = Path(opts["firmware"])
            check_firmware(firmware)  # before the build and before simavr starts
        elif baud in BUILT_BAUDS:
            firmware = firmware_path(baud)
        else:
            raise ValueError(f"{url}: baud={baud}: the built firmware images run at "
                             f"{' or '.join(map(str, BUILT_BAUDS))} baud; for another rate build "
                             f"one with `make -C firmware_bridge BAUD={baud}` and pass "
                             "firmware=firmware_bridge/build/lm629_bridge.elf")
        usb = adapter_of(url, opts)  # before simavr starts too
        model = build_bus(url, opts, limit=len(CHIP_SELECTS))
        if hasattr(model, "lines"):
            model.lines = len(CHIP_SELECTS)  # the firmware's four /CS, chips on the first N
        vcd = vcd_of(url, opts)
        sim = AvrSim(model, firmware, wiring=wiring_of(url, opts))
        if vcd is not None:
            sim.write_vcd(*vcd)
        return cls(sim, url, trace=trace, baud=baud, fast_baud=opts["fast_baud"],
                   retries=opts["retries"], failsafe=FailsafeOptions.of(opts), usb=usb)

    def describe(self) -> str:
        fw = self.info.firmware_version if self.info else "?"
        return (f"{self.url} (bridge firmware {fw} in simavr at {self.baud} baud, "
                f"{self.models[0].describe(len(self.models))})")


__all__ = ["SimAvrTransport"]
