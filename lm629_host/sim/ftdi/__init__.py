"""The emulated FT232H: a device model (:mod:`.device`) below a pyusb backend (:mod:`.backend`).

Used by ``sim+ftdi://`` and the FTDI tests to run the real FT232H transport and the real pyftdi
against the chip model, with no hardware.
"""

from lm629_host.sim.ftdi.backend import SHARED, EmulatedBackend
from lm629_host.sim.ftdi.device import Counters, EmulatedFT232H

__all__ = ["EmulatedBackend", "EmulatedFT232H", "Counters", "SHARED"]
