"""The simulated transports the suite runs its end-to-end tests on, named once.

``tests/conftest.py`` turns these lists into the fixtures ``transport_url`` (every simulated
transport, base URL), ``fast_transport_url`` (the same with the serial links at 1 Mbaud, for
tests whose subject is not the link's speed) and ``usb_transport_url`` (every simulated
transport and the serial links behind an Uno's USB chip); a test module that needs the plain list (to
parametrize) imports it from here.
"""

from __future__ import annotations

import importlib

import lm629_host

from lm629_host.transports import SCHEMES

#: the FT232H waiting on the busy bit in the adapter (D0 wired to GPIOL1) instead of timing it
FTDI_BUSY_PIN = "sim+ftdi://?busy_pin=gpiol1"

#: the chip model strobed directly, the Python bridge far end, the compiled bridge firmware in
#: simavr, the FT232H transport on the emulated FT232H (timed busy waits, and the busy pin)
SIM_URLS = ("sim://", "sim+emu://", "sim+avr://", "sim+ftdi://", FTDI_BUSY_PIN)

#: the same, the serial links at 1 Mbaud (the default 115200 adds ~1 ms a round trip)
FAST_LINK_URLS = ("sim://", "sim+emu://?baud=1000000", "sim+avr://?baud=1000000", "sim+ftdi://",
                  FTDI_BUSY_PIN)


#: a bench's USB: an Arduino Uno R3's 16U2 (4.096 ms flush tick, 1 ms frames) at 1 Mbaud
UNO = "usb=uno&fast_baud=1000000"

#: the two serial links behind an Uno's USB chip (:mod:`lm629_host.sim.usb`)
BEHIND_USB_URLS = (f"sim+emu://?{UNO}", f"sim+avr://?{UNO}")


def available(url: str) -> bool:
    """The transport's module imports, and for sim+avr:// the AVR toolchain is there to build
    the firmware (``.ci/run`` installs it, so CI never skips)."""
    module = SCHEMES[url.split("://")[0]].split(":")[0]
    try:
        importlib.import_module(module)
    except ImportError:
        return False
    if url.startswith("sim+avr"):
        from lm629_host.sim.harness import toolchain_missing

        return not toolchain_missing()
    return True


def with_params(url: str, params: str) -> str:
    """``url`` with ``params`` (``a=1&b=2``) added to its query."""
    if not params:
        return url
    return f"{url}{'&' if '?' in url else '?'}{params}"


def ready_chip(url: str, params: str = "", *, kp: int = 20, kd: int = 100) -> lm629_host.LM629:
    """``url`` (with ``params`` added) opened, reset and holding at ``kp``/``kd`` (applied): the
    start of most end-to-end tests.  Skipped where this machine cannot run the far end."""
    import pytest

    if not available(url):
        pytest.skip(f"{url}: not available here")
    chip = lm629_host.open(with_params(url, params))
    chip.reset()
    chip.load_filter(kp=kp, kd=kd)
    chip.update_filter()
    return chip
