"""Opening an FT232H for the LM629 bus: the ``ftdi://`` URL's options, pyftdi's open in MPSSE
mode without a glitch on /RST or /CS, and what pyftdi's and pyusb's open-time errors mean on
a bench (the transport that runs programs over it is :mod:`.ftdi`).
"""

from __future__ import annotations

import errno as _errno
import os
from typing import Any

from lm629_host import data
from lm629_host.errors import TransportError
from lm629_host.transports.reports import Check, PortInfo
from lm629_host.transports.mpsse import DEFAULT_TCK_HZ
from lm629_host.bus.url_board import BOARD_ROWS
from lm629_host.urls import Option, PortURL, parse_options, port_url
from lm629_host.wiring import ft232h as pins

# the MPSSE commands sent at open (FTDI AN_108; defined in wiring.ft232h)
SET_LOW, SET_HIGH = pins.SET_LOW, pins.SET_HIGH
DISABLE_CLK_3PHASE, DISABLE_CLK_ADAPTIVE = pins.DISABLE_CLK_3PHASE, pins.DISABLE_CLK_ADAPTIVE

FTDI_VID = 0x0403
FT232H_PID = 0x6014

DEFAULT_LATENCY_MS = 1  #: the FTDI default is 16 ms, the floor of every short read
UDEV_RULE = f"{data.UDEV_RULES_DIR}/{data.UDEV_RULE}"  #: where the installed rule lives

#: the clock modes another tool may have left on switched off, then every line idle: one 0x80
#: sets the control lines' levels and directions together, one 0x82 releases D0-D7 (sent
#: when MPSSE is entered: :func:`open_mpsse`, :func:`reenter_mpsse`)
IDLE_LINES = bytes((DISABLE_CLK_ADAPTIVE, DISABLE_CLK_3PHASE,
                    SET_LOW, pins.CTRL_IDLE, pins.CTRL_DIRECTION, SET_HIGH, 0, pins.DATA_IN))


#: the URL options of the FT232H transport (``busy_us`` none, or ``auto``: measured;
#: ``busy_pin`` none, or a line wired to D0: ``ftdi_pins.BUSY_PINS``)
OPTIONS = (
    *BOARD_ROWS,
    Option("latency", "int", DEFAULT_LATENCY_MS, 1, 255, "ms"),
    Option("busy_us", "float", None, 0, 65535, "us", optional=True, none_words=("auto",)),
    Option("frequency", "hz", DEFAULT_TCK_HZ, 1e5, 30e6, "Hz"),
    Option("busy_pin", "str", "none", choices=("none", *pins.BUSY_PINS)),
    Option("heartbeat", "str", None, parse=lambda text: heartbeat_pin(text)),
    Option("heartbeat_hz", "float", 50.0, 1, 1000, "Hz"),
)


def heartbeat_pin(text: str) -> str | None:
    """The ``heartbeat`` option: a line the bus leaves free, or none; a line the bus uses is
    refused with what it carries."""
    name = text.strip().lower()
    if name in ("", "none"):
        return None
    if name in pins.HEARTBEAT_PINS:
        return name
    free = ", ".join(pins.HEARTBEAT_PINS)
    use = pins.LINE_USES.get(name)
    if use is not None:
        raise ValueError(f"{name.upper()} carries {use}: the heartbeat needs a line the wiring "
                         f"leaves free ({free}: the second chip's /CS, free on a one-chip bench)")
    raise ValueError(f"expected {free} or none")


def busy_pin_of(opts: dict[str, Any], url: str | PortURL) -> str | None:
    """The ``busy_pin`` option as the transport takes it (None: not wired).  ``busy_us`` with
    it is a ValueError naming both: with the pin each check waits on the chip itself, so a
    timed wait has no use, and silently dropping what was asked would hide a mistake."""
    pin = str(opts["busy_pin"]).lower()
    if pin == "none":
        return None
    if opts["busy_us"] is not None:
        raise ValueError(f"{url}: busy_us={opts['busy_us']:g} and busy_pin={pin} do not go "
                         "together: with the busy pin every check waits on the chip's busy "
                         "bit, there is no timed wait to set; give one of them")
    return pin


def options_of(url: str | PortURL) -> dict[str, Any]:
    return parse_options(url, OPTIONS, what="FT232H")


def pyftdi_url(url: str | PortURL) -> str:
    """Our URL without its options: what pyftdi parses."""
    return port_url(url).base


ADVICE_NO_BACKEND = (
    "no USB backend: pyusb found no libusb library. Install it (Debian/Ubuntu: "
    "sudo apt-get install libusb-1.0-0; Fedora: sudo dnf install libusb1; macOS: "
    "brew install libusb), then try again")
ADVICE_ACCESS = (
    "access denied to the FT232H's USB device. Install the udev rule shipped with this package "
    "and replug the adapter (`lm629 udev` prints these commands):\n"
    + "\n".join("    " + c for c in data.udev_install_commands()))
ADVICE_BUSY = (
    "device busy: another program, or the ftdi_sio kernel driver, holds the FT232H. Close other "
    "programs using it (another lm629, a serial terminal); to free it from ftdi_sio either "
    "unload the driver (sudo rmmod ftdi_sio; it blocks every FTDI serial port) or unbind this "
    "adapter only: ls /sys/bus/usb/drivers/ftdi_sio/ shows names like 1-1.2:1.0, then\n"
    "    echo -n 1-1.2:1.0 | sudo tee /sys/bus/usb/drivers/ftdi_sio/unbind")


def usb_errno(exc: BaseException) -> int | None:
    while exc is not None:
        code = getattr(exc, "backend_error_code", None) or getattr(exc, "errno", None)
        if code in (_errno.EACCES, _errno.EBUSY, -3, -6):
            return {-3: _errno.EACCES, -6: _errno.EBUSY}.get(code, code)
        text = str(exc).lower()
        if "access denied" in text or "permission" in text or "errno 13" in text:
            return _errno.EACCES
        if "resource busy" in text or "errno 16" in text:
            return _errno.EBUSY
        exc = exc.__cause__ or exc.__context__  # type: ignore[assignment]  # None ends the loop
    return None


def find_adapters() -> list[PortInfo]:
    """FT232H adapters on the USB bus (for ``lm629 list``); [] when pyftdi or libusb is
    missing (``doctor()`` says which)."""
    try:
        from pyftdi.ftdi import Ftdi
        found = Ftdi.find_all([(FTDI_VID, FT232H_PID)], nocache=True)
    except ImportError:
        return []
    except ValueError:  # no backend
        return []
    except Exception as exc:  # noqa: BLE001 - enumeration can fail on access rights
        code = usb_errno(exc)
        problem = ADVICE_ACCESS if code == _errno.EACCES else str(exc)
        return [PortInfo("ftdi://ftdi:232h/1", "FTDI FT232H (0403:6014)", False, problem)]
    ports = []
    for desc, _ifcount in sorted(found, key=lambda d: (d[0].bus or 0, d[0].address or 0)):
        where = f"bus {desc.bus} address {desc.address}"
        if desc.sn:
            url = f"ftdi://ftdi:232h:{desc.sn}/1"
        else:
            url = f"ftdi://ftdi:232h:{desc.bus:x}:{desc.address:x}/1"
        ports.append(PortInfo(url, f"FTDI FT232H {desc.description or ''} ({where}, "
                                   f"serial {desc.sn or 'none'})".replace("  ", " ")))
    return ports


def adapter_checks() -> list[Check]:
    """What ``lm629 doctor`` reports about FT232H support on this machine: pyftdi, libusb,
    the adapters found, the udev rule, the ftdi_sio driver."""
    checks: list[Check] = []
    try:
        import pyftdi
        checks.append(Check("pyftdi", True, f"pyftdi {pyftdi.__version__}"))
    except ImportError:
        # optional: only an FT232H needs it, so its absence is a note, not a problem
        return [Check("pyftdi", True, "not installed, optional: only ftdi:// needs it "
                                      "(pip install 'lm629-host[ftdi]')")]
    try:
        from pyftdi.usbtools import UsbTools
        UsbTools.find_backend()
        checks.append(Check("libusb", True, "pyusb found a libusb backend"))
    except ValueError:
        checks.append(Check("libusb", False, ADVICE_NO_BACKEND))
        return checks
    ports = find_adapters()
    usable = [p for p in ports if p.usable]
    if usable:
        checks.append(Check("FT232H", True, ", ".join(p.url for p in usable)))
    elif ports:
        checks.append(Check("FT232H", False, ports[0].problem))
    else:
        # like a serial bridge not found: nothing is wrong on a bench that uses another adapter
        checks.append(Check("FT232H", True, "none on the USB bus (0403:6014)"))
    rule = os.path.exists(UDEV_RULE)
    checks.append(Check("udev rule", rule or os.geteuid() == 0,
                        f"{UDEV_RULE} installed" if rule else
                        ("not installed (not needed as root)" if os.geteuid() == 0 else
                         "not installed: " + ADVICE_ACCESS.split("\n", 1)[1].strip())))
    if os.path.isdir("/sys/module/ftdi_sio"):
        checks.append(Check("ftdi_sio", True, "the ftdi_sio driver is loaded: pyftdi detaches it "
                                              "from the adapter when it opens it; if that fails, "
                                              "see the 'device busy' advice"))
    return checks


def translate_open_error(url: str | PortURL, exc: BaseException) -> TransportError:
    """The exceptions pyftdi and pyusb raise when opening, as errors that say what to do."""
    url = str(url)
    text = str(exc)
    if isinstance(exc, ValueError) and "backend" in text.lower():
        return TransportError(ADVICE_NO_BACKEND, port=url)
    code = usb_errno(exc)
    if code == _errno.EACCES:
        return TransportError(ADVICE_ACCESS, port=url)
    if code == _errno.EBUSY:
        return TransportError(ADVICE_BUSY, port=url)
    low = text.lower()
    if "no such device" in low or "not found" in low or "no usb device" in low \
            or "unknown" in low or isinstance(exc, OSError):
        found = [p.url for p in find_adapters()]
        seen = ", ".join(found) if found else "no FT232H at all (check the cable; `lsusb` " \
                                               "should list 0403:6014)"
        return TransportError(f"no FT232H matches {url} ({text}). Found: {seen}", port=url)
    return TransportError(f"cannot open the FT232H ({type(exc).__name__}: {text})", port=url)


def open_mpsse(url: str | PortURL, latency_ms: int = DEFAULT_LATENCY_MS,
               frequency: float = DEFAULT_TCK_HZ, device: object | None = None) -> object:
    """Open the FT232H at pyftdi ``url`` (or the pyusb ``device``) in MPSSE mode, lines idle
    (chip deselected, strobes and /RST high, D0-D7 released), latency timer ``latency_ms``,
    without ever driving a bus line low.

    pyftdi's ``open_mpsse(direction=...)`` passes the direction as the SET_BITMODE mask: the
    FT232H makes those lines outputs at once and drives its MPSSE low-byte latch, 0 after the
    mode change, until the first 0x80 sets them high.  /RST and /CS would fall for the
    milliseconds in between (every open would reset the chip: motor off, registers lost).  So
    the mask is 0 (all lines stay inputs, held high by the pull-ups); pyftdi's own 0x80/0x82
    then only preload the latches with the idle levels (direction 0); and one 0x80 sets the
    idle levels and the directions together (AN_108: a set-bits command takes value and
    direction at once).  Before that, the clock modes another tool may have left on are
    switched off explicitly: adaptive clocking (0x97; on, idle clocks would wait for an RTCK
    nothing drives) and 3-phase clocking (0x8D; on, every delay would be 1.5 x longer).  The
    divide-by-5 and the divisor are pyftdi's (0x8A/0x8B, 0x86, set for ``frequency``).
    Purge: pyftdi's ``purge_buffers`` empties both directions (values 1 and 2, libftdi's
    meaning) before MPSSE is entered."""
    url = str(url)
    try:
        from pyftdi.ftdi import Ftdi
    except ImportError as exc:
        raise TransportError("pyftdi is not installed: pip install 'lm629-host[ftdi]'",
                             port=url) from exc
    ftdi = Ftdi()
    initial = pins.CTRL_IDLE  # preloaded into the latch while every line is still an input
    try:
        if device is None:
            ftdi.open_mpsse_from_url(url, direction=0, initial=initial,
                                     frequency=frequency, latency=latency_ms)
        else:
            ftdi.open_mpsse_from_device(device, 1, direction=0, initial=initial,
                                        frequency=frequency, latency=latency_ms)
        ftdi.write_data(IDLE_LINES)
    except TransportError:
        raise
    except Exception as exc:  # pyftdi raises ValueError, IOError, UsbToolsError, FtdiError...
        raise translate_open_error(url, exc) from exc
    if ftdi.device_version != 0x0900:
        ic = ftdi.ic_name
        ftdi.close()
        raise TransportError(f"the device at {url} is an {ic}, not an FT232H: this transport "
                             "needs the FT232H's 16 MPSSE lines", port=url)
    return ftdi


def reenter_mpsse(ftdi: Any, frequency: float) -> None:
    """Purge both buffers of an opened ``ftdi``, leave MPSSE and enter it again (the engine
    drops the command it waits at: a wait on the busy pin that never ends), TCK ``frequency``,
    every line idle as at open.  For that moment the FT232H is in UART mode: /RD and /PS
    driven high by RTS# and DTR#, the other lines inputs held high by the pull-ups (see
    :mod:`lm629_host.wiring.ft232h`), so a held status read ends.  Raises
    what pyftdi raises."""
    from pyftdi.ftdi import Ftdi
    ftdi.purge_buffers()
    ftdi.set_bitmode(0, Ftdi.BitMode.RESET)
    ftdi.set_bitmode(0, Ftdi.BitMode.MPSSE)
    ftdi.set_frequency(frequency)
    ftdi.write_data(IDLE_LINES)


__all__ = ["ADVICE_ACCESS", "ADVICE_BUSY", "ADVICE_NO_BACKEND", "DEFAULT_LATENCY_MS", "FT232H_PID",
           "FTDI_VID", "OPTIONS", "busy_pin_of", "heartbeat_pin", "open_mpsse", "options_of",
           "pyftdi_url", "translate_open_error", "usb_errno", "find_adapters", "IDLE_LINES",
           "reenter_mpsse", "adapter_checks", "UDEV_RULE"]
